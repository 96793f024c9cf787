//! The fixed-point core against its f64 reference on every recorded file of
//! `pea-rig/` and `stage-a/` (see `fpi_host::board::accuracy` for the contract): stack
//! extension within 1 nm; effective voltage within one LSB of a 16-bit DAC over
//! 0–150 V, and the setpoint too wherever the stack responds. Prints the measured
//! worst cases (`cargo test -p fpi-tests --test fixed_vs_f64 -- --nocapture`).

use fpi_host::board::accuracy::{self, BOUND_U_V, BOUND_X_UM};

#[test]
fn fixed_point_core_meets_its_error_bounds_on_every_recording() {
    let files = accuracy::all_files().unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(files.len(), 21 + 6, "every pea-rig and stage-a recording");
    let (mut dx, mut du, mut duh) = (0.0f64, 0.0f64, 0.0f64);
    println!(
        "{:<34} {:>7} {:>10} {:>10} {:>10} {:>6} {:>7}",
        "file", "samples", "|dx| nm", "|du| mV", "|dû| mV", "foot", "limited"
    );
    for f in &files {
        println!(
            "{:<34} {:>7} {:>10.4} {:>10.4} {:>10.4} {:>6} {:>7}",
            f.path
                .file_name()
                .map(|n| n.to_string_lossy())
                .unwrap_or_default(),
            f.samples,
            f.max_dx_um * 1e3,
            f.max_du_v * 1e3,
            f.max_duh_v * 1e3,
            f.foot_samples,
            f.limited_steps
        );
        dx = dx.max(f.max_dx_um);
        du = du.max(f.max_du_v);
        duh = duh.max(f.max_duh_v);
        let name = f.path.display();
        assert!(
            f.max_dx_um <= BOUND_X_UM,
            "{name}: stack extension off by {} um",
            f.max_dx_um
        );
        assert!(
            f.max_du_v <= BOUND_U_V,
            "{name}: setpoint off by {} V",
            f.max_du_v
        );
        assert!(
            f.max_duh_v <= BOUND_U_V,
            "{name}: effective voltage off by {} V",
            f.max_duh_v
        );
    }
    println!(
        "worst: stack extension {:.4} nm (bound 1 nm); setpoint {:.4} mV where the stack \
         responds, effective voltage {:.4} mV everywhere (bound {:.4} mV = 1 LSB of 16 bits \
         over 150 V)",
        dx * 1e3,
        du * 1e3,
        duh * 1e3,
        BOUND_U_V * 1e3
    );
}
