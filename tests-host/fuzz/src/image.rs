//! Model images into the board's store.
//!
//! * [`raw`]: arbitrary bytes as an image (`ModelStore::load` with the board's
//!   capacity and limits): the header, CRC and length checks, then, for the rare
//!   input that passes them, the reader and the validator.
//! * [`edited`]: the factory image (`fpi_firmware::board::factory_model::MODEL_IMAGE`) changed by
//!   an edit script ([`edit`]), its header's body length and CRC recomputed, so the
//!   reader and the validator see every change.
//!
//! A model that loads must build its controller (the validator runs the checks of
//! the constructors `controller` calls), and that controller is stepped as the ISR
//! steps it: references across and beyond the stroke, plausible and implausible
//! forces. The step must respect the output limits.

use piezo_fpi::q::{Micrometres, Newtons, Volts};
use fpi_firmware::board::capacity::{Store, BOARD};
use fpi_firmware::board::factory_model::MODEL_IMAGE;
use piezo_fpi::model::image::{encode, encoded_len, CRC32, HEADER_LEN};

/// Bytes per edit: op, offset (u16 LE), value (4 bytes).
pub const EDIT: usize = 7;

/// Applies an edit script to `base`: records of [`EDIT`] bytes `op, offset, value`
/// (a trailing partial record is ignored). Offsets wrap at the image's length.
///
/// | `op % 8` | edit |
/// |---|---|
/// | 0, 1 | write the 4 value bytes at `offset` |
/// | 2 | xor the byte at `offset` with `value[0]` |
/// | 3 | write the 4 value bytes at the 4-aligned `4·offset` (a field of the body) |
/// | 4 | truncate to `offset` bytes |
/// | 5 | insert the 4 value bytes at `offset` |
/// | 6 | remove 4 bytes at `offset` |
/// | 7 | `value[0]` bit 0: leave the header's length as edited; bit 1: the CRC |
///
/// Then the header's body length and CRC are recomputed (unless op 7 said not to).
pub fn edit(base: &[u8], script: &[u8]) -> Vec<u8> {
    let mut img = base.to_vec();
    let (mut fix_len, mut fix_crc) = (true, true);
    for rec in script.chunks_exact(EDIT) {
        let off = crate::u16_at(rec, 1) as usize;
        let val = [rec[3], rec[4], rec[5], rec[6]];
        let n = img.len();
        match rec[0] % 8 {
            0 | 1 if n >= 4 => {
                let at = off % (n - 3);
                img[at..at + 4].copy_from_slice(&val);
            }
            2 if n > 0 => img[off % n] ^= val[0],
            3 if n >= 4 => {
                let at = (4 * off) % (n - 3) / 4 * 4;
                img[at..at + 4].copy_from_slice(&val);
            }
            4 => img.truncate(off % (n + 1)),
            5 => {
                let at = off % (n + 1);
                img.splice(at..at, val);
            }
            6 if n >= 4 => {
                let at = off % (n - 3);
                img.drain(at..at + 4);
            }
            7 => {
                fix_len = val[0] & 1 == 0;
                fix_crc = val[0] & 2 == 0;
            }
            _ => {}
        }
    }
    if img.len() >= HEADER_LEN {
        if fix_len {
            let body = (img.len() - HEADER_LEN) as u32;
            img[8..12].copy_from_slice(&body.to_le_bytes());
        }
        if fix_crc {
            let crc = CRC32.checksum(&img[HEADER_LEN..]);
            img[12..16].copy_from_slice(&crc.to_le_bytes());
        }
    }
    img
}

/// Arbitrary bytes as an image.
pub fn raw(input: &[u8]) {
    load(input);
}

/// The factory image edited by the input (an edit script).
pub fn edited(script: &[u8]) {
    let img = edit(MODEL_IMAGE, script);
    if std::env::var_os("FPI_FUZZ_DUMP_IMAGE").is_some() {
        let hex: String = img.iter().map(|b| format!("{b:02x}")).collect();
        eprintln!("image ({} bytes): {hex}", img.len());
    }
    load(&img);
}

/// Loads `img` into an empty store of the board's capacity; runs a model that
/// loads. The store is on the heap (24 KiB).
pub fn load(img: &[u8]) {
    let mut store = Box::new(Store::new());
    let Ok(shape) = store.load(img, &BOARD) else {
        assert!(
            !store.is_loaded(),
            "a refused image left a model in the store"
        );
        return;
    };
    assert!(store.is_loaded());
    // Written again, the model is the same model (images are not canonical: the
    // reader ignores the padding after the counts and unknown flags).
    let spec = store.spec();
    let mut again = vec![0; encoded_len(&spec)];
    encode(&spec, &mut again).expect("a loaded model encodes");
    let mut other = Box::new(Store::new());
    assert_eq!(
        other.load(&again, &BOARD).ok(),
        Some(shape),
        "a loaded model, encoded again, does not load"
    );
    assert_eq!(
        other.spec(),
        spec,
        "a loaded model changes when encoded again"
    );
    run(&store);
}

/// The loaded model's controller, stepped as the ISR steps it.
pub fn run(store: &Store) {
    let ctl = store.controller().unwrap_or_else(|e| {
        panic!("a model the store validated does not build its controller: {e}")
    });
    let lim = *ctl.limits();
    let r = ctl.reference();
    let f = ctl.force();
    let mut st = ctl.initial_state();
    let mut prev = st.voltage();
    let span = r.hi.to_bits() as i64 - r.lo.to_bits() as i64;
    for k in 0..96i64 {
        // A ramp up and down over the stroke and 10 % beyond each end.
        let phase = if k < 48 { k } else { 96 - k };
        let x = r.lo.to_bits() as i64 + span * (phase - 4) / 40;
        let x = Micrometres::from_bits(x.clamp(i32::MIN as i64, i32::MAX as i64) as i32);
        let force = match k % 16 {
            13 => f.lo,
            14 => f.hi,
            15 => Newtons::MAX,
            _ => ctl.preload(st.x_pea_est()),
        };
        let out = ctl.step(&mut st, x, force);
        assert!(
            out.voltage >= lim.min() && out.voltage <= lim.max(),
            "step {k}: voltage {} outside {}..{}",
            out.voltage,
            lim.min(),
            lim.max()
        );
        let dv = (out.voltage.to_bits() as i64 - prev.to_bits() as i64).abs();
        assert!(
            dv <= lim.max_step().to_bits() as i64,
            "step {k}: the voltage moved {} V, more than {} V",
            Volts::from_bits(dv as i32),
            lim.max_step()
        );
        prev = out.voltage;
        if k % 32 == 31 && st.fault().is_some() {
            // What the firmware does to re-arm: clear the fault (once parked).
            let _ = st.clear_fault(&ctl);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Found by `model_image_edit` (the smoke, 6 476 executions): the factory image
    /// with its coupling offset `k0` (image bytes 104..108, after the 9 operators) set
    /// to `0x7fff_ffff` (32 768 V), CRC fixed up. `Coupling::check`
    /// (`src/fpi.rs`), which the store's validator runs, bounds `F_ref`, `F_q` and
    /// `k_q` but not `k0`, so the store loads the image; the first control step
    /// then overflows in `Fpi::force_terms_at` (`k0 + k_f·F`). Over the link the
    /// same image panics the board's link task in `ModelCommit` (the baseline drive
    /// steps the controller). The host never writes such a model (`signal()`
    /// quantises `offset_v` within ±4096 V); the board must refuse it too.
    #[test]
    fn a_coupling_offset_beyond_the_signal_range_is_refused() {
        let script = [3, 0x1a, 0, 0xff, 0xff, 0xff, 0x7f];
        let img = edit(MODEL_IMAGE, &script);
        assert_eq!(
            &img[HEADER_LEN + 88..HEADER_LEN + 92],
            &[0xff, 0xff, 0xff, 0x7f]
        );
        let mut store = Box::new(Store::new());
        assert!(
            store.load(&img, &BOARD).is_err(),
            "the store accepts a coupling offset of 32768 V"
        );
        // What the fuzz target runs on it.
        edited(&script);
    }
}
