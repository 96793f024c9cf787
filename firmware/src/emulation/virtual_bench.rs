//! The emulated board's virtual bench: the virtual stage (`piezo_sim::stage`,
//! stage A) behind the [`SimLink`], stepped after every control tick, with the
//! fault injection a test needs (an open or stuck force sensor, the analog input's
//! reading), and the analog front end it converts with (`BenchOrder::FrontEnd`:
//! the [`SimLink`]'s converters and, for the precision front end, the ADC's
//! transition noise, [`crate::emulation::virtual_io::PRECISION_ADC_NOISE_LSB`]).
//!
//! [`tick`] is one period of the emulated board: bench orders, the control loop,
//! the virtual stage, the recorder. The QEMU firmware's control task calls it; the
//! host's twin calls the same function in a plain loop with the same orders at the
//! same ticks, and so reproduces a recording bit for bit (fixed-point core, IEEE
//! `f32` virtual stage with `libm` on both, seeded sensor noise).

use embedded_hal::digital::OutputPin;
use piezo_fpi::io::{ForceSensor, Setpoint};
use piezo_fpi::q::{Micrometres, Newtons};
use piezo_sim::stage::{stage_a, Overrides, Stage};

use embedded_storage::nor_flash::NorFlash;

use crate::board::analog_in::AnalogIn;
use crate::board::capacity::{Store, IMAGE_BYTES};
use crate::board::definition::{precision, POSITION};
use crate::board::factory_model::MODEL_IMAGE;
use crate::board::storage::{ModelFlash, RamFlash, Slots};
use crate::control::exchange::{Applied, Exchange, Order, Posted, Refused};
use crate::control::recorder::Sample;
use crate::control::slots::Spare;
use crate::control::task::ControlLoop;
use crate::emulation::virtual_io::{
    SimAmplifier, SimAnalog, SimEnable, SimLink, SimSensor, PRECISION_ADC_NOISE_LSB,
};
use crate::link::handler::{Board, Handler};
use crate::link::protocol::{BenchOrder, BoardKind, FrontEndKind, ResetReason};

/// Sensor reading of a broken wire: the ADC's top rail through the board's scale (N).
pub const BROKEN_WIRE_N: f32 = 500.0;
/// Position reading of a broken wire: beyond the channel's top rail (µm).
pub const BROKEN_POSITION_UM: f32 = 1000.0;
/// Seed of the virtual sensor's noise.
pub const SEED: u32 = 0x5EED;
/// Seed of the precision ADC's transition noise.
pub const ADC_NOISE_SEED: u32 = 0xAD76_06AD;
/// Bytes of one of the emulated board's flash slots (a model image and its header).
pub const FLASH_SLOT: usize = 13_056;
/// The emulated board's flash: two slots in RAM (QEMU cannot program its flash).
pub type EmulatedFlash = RamFlash<{ 2 * FLASH_SLOT }, FLASH_SLOT>;
/// Where the two slots lie in [`EmulatedFlash`].
pub const FLASH_SLOTS: Slots = Slots {
    a: 0,
    b: FLASH_SLOT as u32,
    len: FLASH_SLOT as u32,
};

/// The virtual stage and the faults injected into its sensor (state).
pub struct Bench {
    stage: Stage<'static>,
    sensor_open: bool,
    stuck: Option<f32>,
    position_open: bool,
    position_stuck: Option<f32>,
    position: f32,
    x_true: Micrometres,
    offset: f32,
    stall: u16,
    /// Ticks the trigger input stays high.
    trigger_in: u16,
    force: f32,
    /// The precision front end's ADC noise generator (xorshift32); `None` with the
    /// internal front end, which adds none.
    adc_noise: Option<u32>,
}

/// A zero-mean, unit-variance sample (the sum of four uniforms, as the virtual
/// stage's sensor noise), from a xorshift32 state.
fn unit_noise(rng: &mut u32) -> f32 {
    let mut s = 0.0;
    for _ in 0..4 {
        *rng ^= *rng << 13;
        *rng ^= *rng >> 17;
        *rng ^= *rng << 5;
        s += (*rng >> 8) as f32 / 16_777_216.0 - 0.5;
    }
    s * 1.732_050_8
}

impl Bench {
    /// Stage A at rest; `None` if its built-in parameters do not make a model.
    pub fn new() -> Option<Self> {
        let stage = Stage::new(&stage_a::PARAMS, SEED)?;
        let force = stage.rest_force();
        Some(Self {
            stage,
            sensor_open: false,
            stuck: None,
            position_open: false,
            position_stuck: None,
            position: 0.0,
            x_true: Micrometres::ZERO,
            offset: 0.0,
            stall: 0,
            trigger_in: 0,
            force,
            adc_noise: None,
        })
    }

    /// Leaves the first force reading (the stage at rest) on the link.
    pub fn prime(&mut self, link: &SimLink) {
        let f = self.stage.sense_force(self.force);
        link.set_force(f);
        link.set_position(self.position);
    }

    /// Carries out a bench order.
    pub fn apply(&mut self, order: BenchOrder, link: &SimLink) {
        match order {
            BenchOrder::SensorOpen(open) => self.sensor_open = open,
            BenchOrder::SensorStuck(stuck) => {
                self.stuck = stuck.then_some(self.force);
            }
            BenchOrder::Analog(counts) => link.set_analog_counts(counts),
            BenchOrder::SensorOffset(bits) => {
                self.offset = Newtons::from_bits(bits).to_num::<f32>();
            }
            BenchOrder::Stall(ticks) => self.stall = ticks,
            BenchOrder::TriggerIn(ticks) => self.trigger_in = ticks,
            // The link handler damages the stored model and paces the link itself.
            BenchOrder::DamageStored | BenchOrder::Link(_) => {}
            BenchOrder::PositionOpen(open) => self.position_open = open,
            BenchOrder::PositionStuck(stuck) => {
                self.position_stuck = stuck.then_some(self.position);
            }
            BenchOrder::FrontEnd(kind) => {
                link.select(kind);
                self.adc_noise = (kind == FrontEndKind::Precision).then_some(ADC_NOISE_SEED);
            }
            BenchOrder::Stage(v) => {
                let base = if v.built {
                    &stage_a::BUILT
                } else {
                    &stage_a::PARAMS
                };
                let p = base.with(&overrides(&v));
                if let Some(s) = Stage::new(&p, SEED) {
                    // Its readings at rest, as `new` starts with (what
                    // `prime` leaves on the link).
                    self.force = s.rest_force();
                    self.position = 0.0;
                    self.stage = s;
                    self.x_true = Micrometres::ZERO;
                }
            }
        }
    }

    /// Burns more than a control period if a stall was ordered (a control tick
    /// that cannot keep its rate); whether it did.
    pub fn stall(&mut self) -> bool {
        if self.stall == 0 {
            return false;
        }
        self.stall -= 1;
        // ~80 000 instructions: longer than the 50 000 of a period under QEMU's
        // one instruction per nanosecond.
        for k in 0..20_000u32 {
            core::hint::black_box(k);
        }
        true
    }

    /// A reading as the selected ADC sees it before its quantisation: with its
    /// transition noise (`lsb`: a code in the reading's unit) on the precision
    /// front end, unchanged on the internal one.
    fn convert(&mut self, reading: f32, lsb: f32) -> f32 {
        match &mut self.adc_noise {
            Some(rng) => reading + unit_noise(rng) * PRECISION_ADC_NOISE_LSB * lsb,
            None => reading,
        }
    }

    /// The stage's true position now, µm: where it was when this tick's sensors
    /// were read (the position the last step left it at).
    pub fn true_position(&self) -> Micrometres {
        self.x_true
    }

    /// Steps the stage with the amplifier's output (0 V while it is disabled) and
    /// leaves the next force and position readings on the link; the stage's true
    /// position after the step (the next tick's), µm.
    pub fn after_tick(&mut self, link: &SimLink) -> Micrometres {
        let (voltage, on) = link.output();
        let s = self.stage.step(if on { voltage } else { 0.0 });
        let sensed = self.stage.sense_force(s.force_n);
        let reading = match (self.sensor_open, self.stuck) {
            (true, _) => BROKEN_WIRE_N,
            (false, Some(f)) => f,
            (false, None) => sensed + self.offset,
        };
        self.force = reading;
        link.set_force(self.convert(reading, per_code(&precision::FORCE)));
        let sensed = self.stage.sense_position(s.x_fhps_um);
        let position = match (self.position_open, self.position_stuck) {
            (true, _) => BROKEN_POSITION_UM,
            (false, Some(x)) => x,
            (false, None) => sensed,
        };
        self.position = position;
        link.set_position(self.convert(position, per_code(&POSITION)));
        self.x_true = Micrometres::from_num(s.x_fhps_um);
        self.x_true
    }
}

/// A code of an ADC channel, in its unit.
fn per_code(s: &piezo_fpi::io::AdcScale) -> f32 {
    s.per_count.to_num::<f32>()
}

/// One period of the emulated board: a pending bench order, the control tick, the
/// virtual stage, the recorder (with the true position); the tick's sample.
pub fn tick<S: ForceSensor, A: Setpoint, E: OutputPin, R: AnalogIn>(
    lp: &mut ControlLoop<S, A, E, R>,
    bench: &mut Bench,
    link: &SimLink,
    x: &mut Exchange<'_>,
) -> Sample {
    if let Some(Posted {
        seq,
        order: Order::Bench(b),
        ..
    }) = x.order
    {
        x.order = None;
        let swap = matches!(b, BenchOrder::Stage(_));
        let result = if swap && !lp.is_parked() {
            Err(Refused::StageNotParked)
        } else {
            bench.apply(b, link);
            if swap {
                // A fresh stage at rest: the board starts on it as at power-up.
                bench.prime(link);
                lp.restart_on_new_stage();
            }
            Ok(())
        };
        x.applied = Some(Applied {
            seq,
            tick: lp.next_tick(),
            result,
        });
    }
    // The true position at the instant this tick's sensors are read, like them.
    let x_true = bench.true_position();
    x.trigger_in = bench.trigger_in > 0;
    bench.trigger_in = bench.trigger_in.saturating_sub(1);
    let [t] = *lp.tick(x);
    bench.after_tick(link);
    bench.stall();
    lp.record(x, &t, Some(x_true))
}

/// The control loop of the emulated board (its I/O is the [`SimLink`]).
pub type Loop =
    ControlLoop<SimSensor<'static>, SimAmplifier<'static>, SimEnable<'static>, SimAnalog<'static>>;

/// The emulated board in one thread: the control loop, the bench and the exchange,
/// advanced one tick whenever the link handler waits. The host runs it as the
/// twin of the QEMU board, and tests drive its handler without QEMU.
pub struct Virtual {
    /// The virtual analog world.
    pub link: &'static SimLink,
    /// The control loop.
    pub control: Loop,
    /// The virtual stage.
    pub bench: Bench,
    /// What the loop shares with the link handler.
    pub exchange: Exchange<'static>,
}

impl Virtual {
    /// Boots the emulated board as the firmware does: the newest model in `flash`
    /// or the factory default, a parked loop, the stage at rest. The handler that
    /// serves its link comes with it.
    pub fn boot<F: NorFlash>(
        link: &'static SimLink,
        stores: [&'static mut Store; 2],
        image: &'static mut [u8; IMAGE_BYTES],
        exchange: Exchange<'static>,
        flash: ModelFlash<F>,
    ) -> Option<(Self, Handler<F>)> {
        let [a, b] = stores;
        let (handler, running) = Handler::boot(
            BoardKind::Emulated,
            Spare::new(a),
            Spare::new(b),
            image,
            flash,
            MODEL_IMAGE,
            ResetReason::PowerOn,
        )?;
        let mut bench = Bench::new()?;
        bench.prime(link);
        let control = ControlLoop::new([(running, link.hardware(), link.analog())]);
        Some((
            Self {
                link,
                control,
                bench,
                exchange,
            },
            handler,
        ))
    }

    /// One period; its sample.
    pub fn tick(&mut self) -> Sample {
        tick(
            &mut self.control,
            &mut self.bench,
            self.link,
            &mut self.exchange,
        )
    }
}

impl crate::emulation::Emulated<1> for Virtual {
    fn period(&mut self) {
        self.tick();
    }
    fn next_tick(&self) -> u32 {
        self.control.next_tick()
    }
}

impl Board for Virtual {
    fn exchange<T>(&mut self, f: impl FnOnce(&mut Exchange<'_>) -> T) -> T {
        f(&mut self.exchange)
    }
    fn wait(&mut self) {
        self.tick();
    }
}

/// The values a stage variant replaces in its base's parameters.
pub fn overrides(v: &fpi_protocol::StageVariant) -> Overrides {
    Overrides {
        mode_hz: v.mode_hz,
        mode_damping: v.mode_damping,
        output_gain: v.output_gain,
        force_scale: v.force_scale,
        creep_scale: v.creep_scale,
        position_noise_um: v.position_noise_um,
        force_noise_n: v.force_noise_n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::capacity::RATE_HZ;
    use crate::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
    use crate::control::recorder::{signal, Recorder, Sample};
    use crate::control::reference::stream::Points;
    use crate::control::reference::wave::Shape;
    use crate::emulation::link_host::{self, leak, um};
    use crate::link::frame;
    use crate::link::protocol::{
        Command, Header, LinkKind, Refusal, Reply, SlotReport, MAX_FRAME, NO_SEQ, VERSION,
    };
    use piezo_fpi::control::Fault;

    type Flash = EmulatedFlash;

    type Host = link_host::Host<Virtual>;

    fn host() -> Host {
        host_with(Flash::new())
    }

    /// A board booted with `flash` as its model flash.
    fn host_with(flash: Flash) -> Host {
        let link = leak(SimLink::new(FORCE_ADC, SETPOINT_DAC));
        let flash = ModelFlash::new(flash, FLASH_SLOTS);
        let (board, handler) = Virtual::boot(
            link,
            [leak(Store::new()), leak(Store::new())],
            leak([0; IMAGE_BYTES]),
            Exchange::new(leak(Recorder::new()), leak(Points::new())),
            flash,
        )
        .unwrap();
        Host::new(board, handler)
    }

    #[test]
    fn the_board_boots_parked_and_moves_without_a_jump() {
        let mut h = host();
        h.run(10);
        let s = h.status();
        assert_eq!(
            s.fault.map(|f| f.code),
            Some(Fault::Stopped as u8),
            "parked"
        );
        assert!(!s.amplifier_on);
        let t0 = h.ack(Command::Move {
            axis: 0,
            target: um(20.0),
            speed: um(1000.0),
        });
        assert!(t0 > 0);
        // The 20 ms move, and time to settle.
        h.run(1000);
        let s = h.status();
        assert_eq!(s.fault, None, "armed by the move");
        assert_eq!(s.signals[0], um(20.0));
        // The estimate follows within a few nm after settling.
        assert!((s.signals[1] - um(20.0)).abs() < um(0.05), "{s:?}");
    }

    #[test]
    fn targets_outside_the_stroke_and_bad_arguments_are_refused() {
        let mut h = host();
        assert_eq!(
            h.refused(Command::Move {
                axis: 0,
                target: um(500.0),
                speed: um(100.0)
            }),
            Refusal::OutOfRange
        );
        assert_eq!(
            h.refused(Command::Move {
                axis: 0,
                target: um(5.0),
                speed: 0
            }),
            Refusal::BadArgument
        );
        let wave = |freq_mhz, amplitude| Command::Wave {
            axis: 0,
            shape: Shape::Sine,
            offset: um(20.0),
            amplitude,
            freq_mhz,
            cycles: 1,
        };
        assert_eq!(h.refused(wave(15_000, um(30.0))), Refusal::OutOfRange);
        assert_eq!(h.refused(wave(10_000_000, um(1.0))), Refusal::BadArgument);
        h.ack(Command::Bench(BenchOrder::Analog(1)));
    }

    #[test]
    fn an_axis_the_board_does_not_have_is_refused() {
        let mut h = host();
        let commands = [
            Command::Status { axis: 1 },
            Command::Move {
                axis: 1,
                target: um(5.0),
                speed: um(100.0),
            },
            Command::Hold { axis: 255 },
            Command::Loop {
                axis: 1,
                mode: crate::control::tracking::LoopMode::Open,
            },
        ];
        for c in commands {
            assert_eq!(h.refused(c), Refusal::Axis);
        }
        // Nothing moved, and axis 0 still answers.
        assert_eq!(
            h.status().source,
            crate::control::reference::SourceKind::Hold
        );
        assert_eq!(h.status().axis, 0);
    }

    #[test]
    fn a_model_is_uploaded_validated_swapped_at_rest_and_stored() {
        let mut h = host();
        h.run(5);
        let before = h.status().model_crc;
        // A corrupted model (a weight made negative, the CRC recomputed so only the
        // validator can catch it) is refused by key and the old model kept.
        let mut bad = MODEL_IMAGE.to_vec();
        let w0 = piezo_fpi::model::image::HEADER_LEN + 4;
        bad[w0..w0 + 4].copy_from_slice(&(-1i32).to_le_bytes());
        let body = piezo_fpi::model::image::CRC32.checksum(&bad[16..]);
        bad[12..16].copy_from_slice(&body.to_le_bytes());
        match h.upload(0, &bad, true) {
            Reply::Refused { code, reason } => {
                assert_eq!(code, Refusal::Model);
                assert!(reason.starts_with("pi."), "names the key: {reason}");
            }
            r => panic!("{r:?}"),
        }
        assert_eq!(h.status().model_crc, before);
        // While the stage moves, a good model is refused too.
        h.ack(Command::Move {
            axis: 0,
            target: um(10.0),
            speed: um(1000.0),
        });
        h.run(200);
        assert!(matches!(
            h.upload(0, MODEL_IMAGE, false),
            Reply::Refused {
                code: Refusal::NotAtRest,
                ..
            }
        ));
        // Parked, it is taken, and stored.
        h.ack(Command::Safe);
        h.run(400);
        assert!(matches!(h.upload(0, MODEL_IMAGE, true), Reply::Ack));
        match h.send(Command::ModelInfo { axis: 0 }) {
            Reply::Model(m) => {
                assert_eq!(m.crc, piezo_fpi::model::image::CRC32.checksum(MODEL_IMAGE));
                assert_eq!(m.origin, crate::control::slots::Origin::Received);
                assert_eq!(m.stored.map(|s| s.0), Some(1));
            }
            r => panic!("{r:?}"),
        }
        // Out-of-order chunks are refused.
        h.ack(Command::ModelBegin { len: 100, crc: 0 });
        assert_eq!(
            h.refused(Command::ModelChunk {
                offset: 50,
                data: &[1, 2]
            }),
            Refusal::Upload
        );
        assert_eq!(
            h.refused(Command::ModelCommit {
                axis: 0,
                store: false
            }),
            Refusal::Upload
        );
    }

    #[test]
    fn garbage_truncated_and_wrong_crc_frames_are_refused_and_counted() {
        let mut h = host();
        h.run(5);
        let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
        let hd = Header {
            version: VERSION,
            seq: 77,
        };
        let n = frame::encode(&hd, &Command::Hello, &mut scratch, &mut out).unwrap();
        let good = out[..n - 1].to_vec();
        let mut bad_crc = good.clone();
        bad_crc[2] ^= 0x10;
        let mut cut = good[..good.len() - 2].to_vec();
        let mut garbage = vec![0x55u8; 40];
        for f in [&mut bad_crc, &mut cut, &mut garbage] {
            let (head, reply) = h.raw(f);
            assert_eq!(head.seq, NO_SEQ);
            assert!(
                matches!(
                    reply,
                    Reply::Refused {
                        code: Refusal::Malformed,
                        ..
                    }
                ),
                "{reply:?}"
            );
        }
        // An unknown command, a wrong version.
        let n = frame::encode(&hd, &99u8, &mut scratch, &mut out).unwrap();
        let (head, reply) = h.raw(&mut out[..n - 1]);
        assert_eq!(head.seq, 77);
        assert!(matches!(
            reply,
            Reply::Refused {
                code: Refusal::Unknown,
                ..
            }
        ));
        let old = Header {
            version: 0,
            seq: 78,
        };
        let n = frame::encode(&old, &Command::Hello, &mut scratch, &mut out).unwrap();
        assert!(matches!(
            h.raw(&mut out[..n - 1]).1,
            Reply::Refused {
                code: Refusal::Version,
                ..
            }
        ));
        match h.send(Command::Counters) {
            Reply::Counters(c) => {
                assert_eq!(
                    (c.malformed, c.crc_errors, c.unknown, c.version),
                    (3, 1, 1, 1)
                );
                assert_eq!(c.refused, 5);
            }
            r => panic!("{r:?}"),
        }
    }

    #[test]
    fn a_recording_reads_back_with_its_ticks_and_drops_are_counted() {
        let mut h = host();
        h.run(5);
        // 5 000 samples/s of two signals: more than the UART carries.
        h.ack(Command::Bench(BenchOrder::Link(LinkKind::Usb)));
        h.ack(Command::Record {
            axis: 0,
            decimation: 4,
            signals: signal::X_REF | signal::X_TRUE,
        });
        h.ack(Command::Move {
            axis: 0,
            target: um(5.0),
            speed: um(2000.0),
        });
        h.run(2000);
        let mut ticks = Vec::new();
        loop {
            match h.send(Command::ReadRecord { max: 1000 }) {
                Reply::Record(b) => {
                    assert_eq!(b.values.len() % 3, 0);
                    ticks.extend(Sample::batch(b.signals, &b.values).map(|s| s.tick));
                    if b.waiting == 0 {
                        assert_eq!(b.dropped, 0);
                        break;
                    }
                }
                r => panic!("{r:?}"),
            }
        }
        assert!(ticks.len() > 400);
        assert!(
            ticks.windows(2).all(|w| w[1] - w[0] == 4),
            "every 4th tick, none lost"
        );
        // Not read for long enough, the ring fills and the rest is counted as dropped.
        h.run(4 * crate::board::capacity::RECORDER_SAMPLES as u32 + 400);
        let s = h.status();
        assert_eq!(
            s.recorder[3],
            crate::board::capacity::RECORDER_SAMPLES as u32
        );
        assert!(s.recorder[2] >= 90, "dropped: {:?}", s.recorder);
    }

    /// Reads a recording for `ticks` of board time as fast as the link allows;
    /// the samples read, the bytes of their replies per second of board time
    /// and the samples dropped.
    fn read_for(h: &mut Host, ticks: u32) -> (usize, f64, u32) {
        let (mut samples, mut bytes, mut dropped) = (0, 0, 0);
        let start = h.board.control.next_tick();
        let end = start + ticks;
        while h.board.control.next_tick() < end {
            let (n, reply) = h.sized(Command::ReadRecord { max: u16::MAX });
            let Reply::Record(b) = reply else {
                panic!("{reply:?}")
            };
            samples += Sample::batch(b.signals, &b.values).count();
            bytes += n;
            dropped = b.dropped;
        }
        let seconds = f64::from(h.board.control.next_tick() - start) / f64::from(RATE_HZ);
        (samples, bytes as f64 / seconds, dropped)
    }

    #[test]
    fn the_link_carries_what_its_line_rate_allows() {
        let mut h = host();
        h.run(5);
        // Every signal at 2 000 samples/s: about 20 kB/s of differences.
        h.ack(Command::Record {
            axis: 0,
            decimation: 10,
            signals: signal::ALL,
        });
        h.ack(Command::Wave {
            axis: 0,
            shape: Shape::Sine,
            offset: um(20.0),
            amplitude: um(15.0),
            freq_mhz: 15_000,
            cycles: 0,
        });
        // The UART: 11 520 B/s; the ring fills and the rest is dropped.
        let (samples, rate, dropped) = read_for(&mut h, 20_000);
        assert!((10_500.0..=11_520.0).contains(&rate), "{rate} B/s");
        assert!(
            dropped > 200 && samples < 1_900,
            "{samples} read, {dropped} dropped"
        );
        // Over USB even every tick is kept: 20 000 samples/s.
        h.ack(Command::Bench(BenchOrder::Link(LinkKind::Usb)));
        h.ack(Command::Record {
            axis: 0,
            decimation: 1,
            signals: signal::ALL,
        });
        let (samples, rate, dropped) = read_for(&mut h, 20_000);
        assert_eq!(dropped, 0);
        assert!(samples >= 19_900, "{samples}");
        // Measured: 15.7 B a sample, framing and polling included (the stage
        // moving along a 15 Hz sine, all seven signals and the tick): 314 kB/s,
        // 39 % of the USB link.
        let per_sample = rate / f64::from(RATE_HZ);
        println!("USB, every tick, every signal: {per_sample:.1} B a sample, {rate:.0} B/s");
        assert!(
            per_sample < 20.0,
            "{per_sample} B a sample, framing included"
        );
    }

    #[test]
    fn a_silent_host_parks_a_streaming_stage_within_its_timeout() {
        let mut h = host();
        h.run(5);
        let points: heapless::Vec<i32, 64> = (0..64).map(|k| um(2.0 + 0.05 * k as f64)).collect();
        h.ack(Command::Points {
            axis: 0,
            first: 0,
            points,
        });
        assert_eq!(
            h.refused(Command::Points {
                axis: 0,
                first: 5,
                points: heapless::Vec::new()
            }),
            Refusal::Stream
        );
        h.ack(Command::Supervise { timeout_ms: 50 });
        h.ack(Command::Stream {
            axis: 0,
            interval: 10,
        });
        // 64 points × 10 ticks, then underruns; no request for 50 ms = 1000 ticks.
        h.run(1200);
        let s = h.status();
        assert!(s.stream[3] > 0, "underruns counted: {:?}", s.stream);
        let f = s.fault.unwrap();
        assert_eq!(f.code, Fault::LinkLost as u8);
        let safe_at = f.safe_at.unwrap();
        let full = piezo_fpi::limits::park_ticks(piezo_fpi::q::Volts::const_from_int(150));
        assert!(safe_at > f.at && safe_at - f.at <= full, "{f:?}");
        // A fault must be cleared before the stage moves again.
        assert_eq!(
            h.refused(Command::Move {
                axis: 0,
                target: um(5.0),
                speed: um(100.0)
            }),
            Refusal::Fault
        );
        h.ack(Command::ClearFault);
        h.ack(Command::Move {
            axis: 0,
            target: um(5.0),
            speed: um(100.0),
        });
    }

    #[test]
    fn an_open_force_sensor_parks_the_stage_and_the_analog_input_drives_it() {
        let mut h = host();
        h.run(5);
        h.ack(Command::Bench(BenchOrder::Analog(2048)));
        h.ack(Command::Analog { axis: 0 });
        h.run(3000);
        let s = h.status();
        assert_eq!(s.fault, None);
        let x = Micrometres::from_bits(s.signals[0]).to_num::<f64>();
        assert!(x > 15.0 && x < 25.0, "mid-scale: {x}");
        h.ack(Command::Bench(BenchOrder::SensorOpen(true)));
        h.run(piezo_fpi::limits::park_ticks(piezo_fpi::q::Volts::const_from_int(150)) + 2);
        let f = h.status().fault.unwrap();
        assert_eq!(f.code, Fault::ForceOutOfRange as u8);
        assert!(f.safe_at.is_some());
    }

    #[test]
    fn late_ticks_are_counted_and_a_run_of_them_parks_the_stage() {
        use crate::control::task::OVERRUN_RUN;
        let mut h = host();
        h.ack(Command::Move {
            axis: 0,
            target: um(10.0),
            speed: um(1000.0),
        });
        h.run(100);
        // Runs one short of the limit, broken by a tick on time, are only counted.
        for _ in 0..3 {
            for _ in 0..OVERRUN_RUN - 1 {
                h.board.control.late(true);
                h.run(1);
            }
            h.board.control.late(false);
            h.run(1);
        }
        let s = h.status();
        assert_eq!(s.fault, None);
        assert_eq!(s.overruns, 3 * (OVERRUN_RUN - 1));
        for _ in 0..OVERRUN_RUN {
            h.board.control.late(true);
        }
        // The run, then the park (from 10 µm: well under the whole 150 V's).
        h.run(
            OVERRUN_RUN + piezo_fpi::limits::park_ticks(piezo_fpi::q::Volts::const_from_int(150)),
        );
        let s = h.status();
        let f = s.fault.unwrap();
        assert_eq!(f.code, Fault::Overrun as u8);
        assert!(f.safe_at.is_some() && !s.amplifier_on, "{s:?}");
        assert_eq!(s.overruns, 4 * OVERRUN_RUN - 3);
    }

    #[test]
    fn a_damaged_stored_model_is_reported_and_the_older_one_runs() {
        let mut flash = ModelFlash::new(Flash::new(), FLASH_SLOTS);
        flash.store(MODEL_IMAGE).unwrap();
        let newest = flash.store(MODEL_IMAGE).unwrap();
        flash.damage(&newest, 100).unwrap();
        let mut h = host_with(flash.into_inner());
        match h.send(Command::ModelInfo { axis: 0 }) {
            Reply::Model(m) => {
                assert_eq!(m.origin, crate::control::slots::Origin::Stored(1));
                assert!(m.slots.contains(&SlotReport::Damaged), "{:?}", m.slots);
                assert!(m.slots.contains(&SlotReport::Valid(1)), "{:?}", m.slots);
            }
            r => panic!("{r:?}"),
        }
        // Both damaged: the factory model.
        let mut flash = ModelFlash::new(Flash::new(), FLASH_SLOTS);
        let stored = [MODEL_IMAGE; 2].map(|image| flash.store(image).unwrap());
        for s in &stored {
            flash.damage(s, 7).unwrap();
        }
        let mut h = host_with(flash.into_inner());
        match h.send(Command::ModelInfo { axis: 0 }) {
            Reply::Model(m) => {
                assert_eq!(m.origin, crate::control::slots::Origin::Factory);
                assert_eq!(m.slots, [SlotReport::Damaged; 2]);
            }
            r => panic!("{r:?}"),
        }
    }

    #[test]
    fn the_precision_front_end_converts_finer_on_both_sides() {
        use crate::link::protocol::FrontEndKind;
        let mut h = host();
        h.run(5);
        let hello = |h: &mut Host| match h.send(Command::Hello) {
            Reply::Hello(hello) => (hello.axes, hello.front_end),
            r => panic!("{r:?}"),
        };
        assert_eq!(h.board.link.front_end(), FrontEndKind::Internal);
        assert_eq!(hello(&mut h), (1, FrontEndKind::Internal));
        h.ack(Command::Bench(BenchOrder::FrontEnd(
            FrontEndKind::Precision,
        )));
        assert_eq!(h.board.link.front_end(), FrontEndKind::Precision);
        // The hello names the front end the board converts with.
        assert_eq!(hello(&mut h), (1, FrontEndKind::Precision));
        h.ack(Command::Move {
            axis: 0,
            target: um(20.0),
            speed: um(1000.0),
        });
        // The 20 ms move, and time to settle.
        h.run(1000);
        let s = h.status();
        assert_eq!(s.fault, None);
        assert!((s.signals[1] - um(20.0)).abs() < um(0.05), "{s:?}");
        // The setpoint moves by less than one of the 12-bit DAC's codes
        // (36.6 mV), the force reading by less than one of its counts (0.125 N).
        let (mut dv, mut df) = (f32::MAX, f32::MAX);
        let (mut v0, _) = h.board.link.output();
        let mut f0 = h.board.link.hardware().sensor.read_force();
        for _ in 0..200 {
            h.run(1);
            let (v, on) = h.board.link.output();
            assert!(on);
            let f = h.board.link.hardware().sensor.read_force();
            if v != v0 {
                dv = dv.min((v - v0).abs());
            }
            if f != f0 {
                df = df.min((f - f0).abs().to_num::<f32>());
            }
            (v0, f0) = (v, f);
        }
        assert!(dv < 0.01 && df < 0.05, "{dv} V, {df} N");
        // Back to the internal front end: the 12-bit grids again.
        h.ack(Command::Bench(BenchOrder::FrontEnd(FrontEndKind::Internal)));
        h.run(2);
        let (v, _) = h.board.link.output();
        let codes = v * 4095.0 / 150.0;
        assert!((codes - codes.round()).abs() < 1e-3, "{v} V");
        let f = h.board.link.hardware().sensor.read_force().to_num::<f32>();
        assert!(((f + 5.0) * 8.0).fract() == 0.0, "{f} N");
    }

    #[test]
    fn a_reset_is_acknowledged_before_it_happens_and_the_reason_told() {
        let mut h = host();
        match h.send(Command::Hello) {
            Reply::Hello(hello) => assert_eq!(hello.reset, ResetReason::PowerOn),
            r => panic!("{r:?}"),
        }
        assert!(!h.handler.reset_requested());
        h.ack(Command::Reset);
        assert!(h.handler.reset_requested());
    }
}
