//! Link-time proof that the control path cannot panic.
//!
//! This firmware only runs the embedded model's control step and the whole ISR
//! body (`ControlLoop::run`) on opaque inputs. Its panic handler calls a function
//! that exists nowhere, so if the optimiser leaves any panic branch reachable
//! (an index, an overflow check, an `unwrap`, a division) the release build fails
//! to link with `undefined symbol: control_path_can_panic`. CI builds it.
//!
//! `cargo build --release --target thumbv7em-none-eabihf -p fpi-firmware --bin no-panic --features qemu`
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod proof {
    use core::hint::black_box;
    use cortex_m_rt::entry;
    use fpi_firmware::frontend::{FORCE_ADC, SETPOINT_DAC};
    use fpi_firmware::model::CONTROLLER;
    use fpi_firmware::reference::RaisedCosine;
    use fpi_firmware::runner::{Command, ControlLoop};
    use fpi_firmware::sim_io::SimLink;
    use piezo_fpi::control::Mode;
    use piezo_fpi::q::{Micrometres, Newtons};
    use stm32f4xx_hal as _;

    static LINK: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);

    #[entry]
    fn main() -> ! {
        let cfg = black_box(&CONTROLLER);
        let mut st = cfg.initial_state();
        let first = Command {
            mode: black_box(Mode::Compensated),
            wave: black_box(RaisedCosine {
                center: Micrometres::ZERO,
                amplitude: Micrometres::ZERO,
                phase_step: 0,
                amplitude_step: Micrometres::ZERO,
            }),
            clear_fault: false,
        };
        let mut lp = ControlLoop::new(cfg, LINK.hardware(), first);
        loop {
            let x = Micrometres::from_bits(black_box(0));
            let f = Newtons::from_bits(black_box(0));
            black_box(cfg.step(&mut st, x, f));
            black_box(lp.run());
            if black_box(false) {
                lp.apply(black_box(first));
            }
        }
    }

    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        extern "C" {
            fn control_path_can_panic() -> !;
        }
        // SAFETY: never called if the proof holds; if it can be called, linking fails.
        unsafe { control_path_can_panic() }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("no-panic is a link-time check for the firmware target (see its doc comment).");
    std::process::exit(2);
}
