//! What both benchmarks measure with (`isr-bench`, `isr-bench-axes`): the
//! instruction count of a call (SysTick under `-icount`), the counts'
//! summary, the painted stack, the full-stroke reference and the
//! closed-loop model they run.

use core::hint::black_box;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_semihosting::debug::{self, EXIT_FAILURE, EXIT_SUCCESS};
use cortex_m_semihosting::hprintln;
use fpi_firmware::board::capacity::{self, Store, BOARD};
use fpi_firmware::board::factory_model::{CONTROLLER, MODEL_IMAGE};
use fpi_firmware::control::exchange::Exchange;
use fpi_firmware::control::reference::wave::{Shape as WaveShape, Wave};
use fpi_firmware::control::task::ControlLoop;
use fpi_firmware::emulation::virtual_io::{SimAmplifier, SimAnalog, SimEnable, SimLink, SimSensor};
use piezo_fpi::model::{image, ModelSpec};
use piezo_fpi::q::Micrometres;

/// SysTick ticks per instruction at `-icount shift=10` on a 168 MHz core clock.
pub(crate) const TICKS_PER_INSTRUCTION: f32 = 0.168 * 1024.0;

/// min, sum, max of instruction counts.
#[derive(Clone, Copy)]
pub(crate) struct Counts {
    pub(crate) min: u32,
    pub(crate) sum: u64,
    pub(crate) max: u32,
    pub(crate) n: u32,
}

impl Counts {
    pub(crate) fn new() -> Self {
        Self {
            min: u32::MAX,
            sum: 0,
            max: 0,
            n: 0,
        }
    }
    pub(crate) fn add(&mut self, c: u32) {
        self.min = self.min.min(c);
        self.max = self.max.max(c);
        self.sum += c as u64;
        self.n += 1;
    }
    pub(crate) fn merge(&mut self, o: &Self) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.sum += o.sum;
        self.n += o.n;
    }
    pub(crate) fn mean_x10(&self) -> u32 {
        (self.sum * 10 / self.n.max(1) as u64) as u32
    }
}

/// `min M mean A.B`: the counts' least and mean, as every figure prints them.
impl core::fmt::Display for Counts {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let m = self.mean_x10();
        write!(f, "min {} mean {}.{}", self.min, m / 10, m % 10)
    }
}

/// SysTick ticks of `f`, the two counter reads included.
#[inline(always)]
pub(crate) fn ticks<R>(f: impl FnOnce() -> R) -> u32 {
    let t0 = SYST::get_current();
    black_box(f());
    let t1 = SYST::get_current();
    t0.wrapping_sub(t1) & 0x00FF_FFFF
}

pub(crate) fn instructions(ticks: u32, baseline: u32) -> u32 {
    ((ticks.saturating_sub(baseline)) as f32 / TICKS_PER_INSTRUCTION + 0.5) as u32
}

#[inline(never)]
pub(crate) fn nop_1000() {
    // SAFETY: nops only.
    unsafe {
        core::arch::asm!(
            ".rept 1000",
            "nop",
            ".endr",
            options(nomem, nostack, preserves_flags)
        )
    }
}

#[inline(never)]
pub(crate) fn nop_0() {
    // SAFETY: empty.
    unsafe { core::arch::asm!("", options(nomem, nostack, preserves_flags)) }
}

pub(crate) const STEPS: u32 = 4000;

/// A raised cosine over 2–38 µm at `hz`, continuous.
pub(crate) fn full_stroke(hz: f32) -> Wave {
    Wave {
        shape: WaveShape::RaisedCosine,
        offset: Micrometres::from_num(20),
        amplitude: Micrometres::from_num(18),
        phase_step: Wave::phase_step_for((hz * 1000.0) as u32, 20_000),
        cycles: 0,
    }
}

/// The embedded model with every loop on, as `fpi tune --dynamics` tunes it for
/// stage A (its 850.9 Hz mode, ζ 0.0301, the 2027 Hz lag, κ 7.02 N/µm): active
/// damping (IFF, 1316 µm/(N·s) between 100 Hz corners), the position PI
/// (kp 0.75, ki 1762.6/s) and the feedforward of the damped stage (16 taps on the preview's line);
/// its image in `buf`. The validator's loop check runs on it as on any model.
pub(crate) fn closed_image<'b>(store: &mut Store, buf: &'b mut [u8]) -> Option<&'b [u8]> {
    use piezo_fpi::damping::{DampingSpec, DynamicsSpec};
    use piezo_fpi::q::{CreepRate, LoopGain, NewtonsPerUm};
    store.load(MODEL_IMAGE, &BOARD).ok()?;
    let spec = store.spec();
    let um = |x: f64| piezo_fpi::q::signal(x).map_or(Micrometres::ZERO, Micrometres::from_raw);
    let gain = |x: f64| LoopGain::from_num(x);
    let r = spec.supervision.reference;
    let rate = capacity::RATE_HZ as f64;
    let feedback = piezo_fpi::feedback::FeedbackSpec {
        kp: gain(0.75),
        ki: gain(1762.611 / rate),
        limit: um(9.98),
        // Inside the position channel's rails (−10…70 µm), as the
        // validator has a sensor window.
        sensor: piezo_fpi::control::Interval {
            lo: r.lo - um(9.0),
            hi: r.hi + um(9.0),
        },
        tolerance: um(6.0),
    };
    // 1 − e^{−2π·100 Hz/20 kHz}
    let corner = CreepRate::from_num(0.030_929_031_800_5);
    let damping = DampingSpec {
        gain: gain(1315.733 / rate),
        highpass: corner,
        leak: corner,
        limit: um(39.921),
    };
    let dynamics = DynamicsSpec {
        mode_mhz: 850_852,
        damping: CreepRate::from_num(0.030_098),
        lag_mhz: 2_026_966,
        force_gain: NewtonsPerUm::from_num(7.017),
    };
    // Autotune's feedforward: taps on the preview's delay line, 4 ticks
    // ahead (the delay line, the taps and the damping's lead force, with
    // its learned mass ratio, run).
    let one = f64::from(1 << piezo_fpi::biquad::COEFF_FRAC);
    let mut taps = [
        1.67, -0.08, -0.63, -0.57, -0.7, -0.04, 0.61, 0.74, 0.2, -0.1, -0.15, 0.05, 0.1, -0.05,
        -0.05, 0.02,
    ]
    .map(|t| (t * one) as i32);
    taps[0] += (1 << piezo_fpi::biquad::COEFF_FRAC) - taps.iter().sum::<i32>();
    let shaping = piezo_fpi::biquad::ShapingSpec {
        preview: 4,
        taps,
        ..piezo_fpi::biquad::ShapingSpec::IDENTITY
    };
    let closed = ModelSpec {
        feedback: Some(feedback),
        shaping: Some(shaping),
        dynamics: Some(dynamics),
        damping: Some(damping),
        // The lead's learned mass ratio, applied (piezo_fpi::lead).
        lead_baseline: Some(piezo_fpi::q::LeadRatio::from_num(0.88)),
        // The watch's least half swing (the most half-cycles counted).
        watch_swing: Some(piezo_fpi::model::WATCH_SWING_MIN),
        ..spec
    };
    let len = match image::encode(&closed, buf) {
        Ok(len) => len,
        Err(e) => {
            hprintln!("the closed-loop model was refused: {}", e);
            return None;
        }
    };
    buf.get(..len)
}

/// A benchmark's control loop of `N` axes on the simulated links.
pub(crate) type Loop<const N: usize> = ControlLoop<
    SimSensor<'static>,
    SimAmplifier<'static>,
    SimEnable<'static>,
    SimAnalog<'static>,
    N,
>;

/// [`STEPS`] ticks of the loop as it runs, every axis recorded: their
/// instruction counts, whether every axis ran without a fault and recorded
/// every tick, and the stack the tick used, bytes. Between ticks the link
/// task reads the recorder and each axis's sensors (on `links`) follow the
/// stage its model estimates.
pub(crate) fn run_ticks<const N: usize>(
    lp: &mut Loop<N>,
    x: &mut Exchange<'static, N>,
    links: [&SimLink; N],
    baseline: u32,
) -> (Counts, bool, usize) {
    let kept = x.recorder.kept();
    let mut c = Counts::new();
    const PAINT: usize = 8192;
    let sp = paint_below(PAINT);
    for _ in 0..STEPS {
        let t = ticks(|| {
            lp.tick(x);
            for t in lp.telemetry() {
                lp.record(x, t, None);
            }
        });
        c.add(instructions(t, baseline));
        while x.recorder.take().is_some() {}
        for ((axis, s), link) in lp.axes().iter().zip(&x.snapshot.axes).zip(links) {
            let f = CONTROLLER.preload(axis.state().x_pea_est());
            link.set_force(f.to_num::<f32>());
            link.set_position(s.now.x_est.to_num::<f32>());
        }
    }
    let ok = x.snapshot.axes.iter().all(|a| a.fault.is_none())
        && x.recorder.kept() >= kept + N as u32 * STEPS;
    (c, ok, depth_below(sp, PAINT))
}

/// Paints `bytes` of the unused stack below the current stack pointer with a
/// pattern; [`depth_below`] then tells how much of it a call used.
#[inline(never)]
pub(crate) fn paint_below(bytes: usize) -> usize {
    let sp = cortex_m::register::msp::read() as usize;
    // SAFETY: the region lies below the stack pointer of this function, in the
    // stack's free space (the benchmark's statics are far below); nothing else
    // runs (no interrupts are enabled in the benchmark).
    unsafe {
        let mut p = sp - bytes;
        while p < sp - 64 {
            core::ptr::write_volatile(p as *mut u32, 0xCCCC_CCCC);
            p += 4;
        }
    }
    sp
}

/// Bytes below `sp` (from [`paint_below`]) that were written since it painted.
#[inline(never)]
pub(crate) fn depth_below(sp: usize, bytes: usize) -> usize {
    let mut p = sp - bytes;
    // SAFETY: reads the region `paint_below` painted.
    while p < sp && unsafe { core::ptr::read_volatile(p as *const u32) } == 0xCCCC_CCCC {
        p += 4;
    }
    sp - p
}

/// The counter's own cost (the two reads, SysTick ticks) and, as a check,
/// a block of 1000 nops counted in instructions (exactly 1000 ± 1: a
/// function of 1000 nops minus an empty function); printed.
pub(crate) fn calibrate() -> (u32, u32) {
    let baseline = (0..64).map(|_| ticks(|| ())).min().unwrap_or(0);
    let best = |f: fn()| (0..8).map(|_| ticks(f)).min().unwrap_or(0);
    let nops = instructions(best(nop_1000).saturating_sub(best(nop_0)), 0);
    hprintln!(
        "calibration: 1000 nops counted as {} instructions (baseline {} SysTick ticks)",
        nops,
        baseline
    );
    (baseline, nops)
}

/// Starts SysTick on the core clock, counting down from its top (the
/// counter [`ticks`] reads); ends the run as failed if the core's
/// peripherals are taken.
pub(crate) fn start_counter() {
    let Some(mut cp) = cortex_m::Peripherals::take() else {
        exit(false)
    };
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(0x00FF_FFFF);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();
}

/// Ends the run (semihosting exit): success if `ok`.
pub(crate) fn exit(ok: bool) -> ! {
    debug::exit(if ok { EXIT_SUCCESS } else { EXIT_FAILURE });
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    exit(false)
}
