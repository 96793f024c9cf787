//! The handler's model orders: the running model's report, a model's upload
//! (begin, chunks, commit, optionally stored in flash), the factory model
//! restored, and the swap of the running model under a parked board.

use embedded_storage::nor_flash::NorFlash;

use super::{Board, Handler};
use crate::control::exchange::Order;
use crate::control::slots::{Origin, Running};
use crate::link::protocol::{ModelReport, Refusal, Reply};
use crate::link::refusal::{refuse, Refuse};

impl<F: NorFlash, const N: usize> Handler<F, N> {
    pub(super) fn model_report(&self) -> ModelReport {
        let s = self.model();
        ModelReport {
            crc: s.crc,
            origin: s.origin,
            size: [s.shape.operators as u8, s.shape.creep_terms as u8],
            maps: [s.shape.dead_zone, s.shape.saturation],
            window: [
                s.reference.lo.to_bits(),
                s.reference.hi.to_bits(),
                s.safe_voltage.to_bits(),
            ],
            stored: self
                .stored
                .filter(|_| self.axis == 0)
                .map(|st| (st.generation, st.crc)),
            slots: self.slots,
            feedback: s.feedback.map(|f| {
                let f = f.spec();
                [
                    f.kp.to_bits(),
                    f.ki.to_bits(),
                    f.limit.to_bits(),
                    f.sensor.lo.to_bits(),
                    f.sensor.hi.to_bits(),
                    f.tolerance.to_bits(),
                ]
            }),
            dynamics: s.dynamics.map(|d| {
                [
                    d.mode_mhz as i32,
                    d.damping.to_bits(),
                    d.lag_mhz as i32,
                    d.force_gain.to_bits(),
                ]
            }),
            damping: s.damping.map(|d| {
                let d = d.spec();
                [d.gain.to_bits(), d.leak.to_bits(), d.limit.to_bits()]
            }),
            force_channel: [s.channel.split.to_bits(), s.channel.dynamic_limit.to_bits()],
        }
    }

    pub(super) fn begin(
        &mut self,
        board: &mut impl Board<N>,
        len: u32,
        crc: u32,
    ) -> Result<Reply, Refuse> {
        self.upload.begin(len, crc)?;
        // The buffer no longer holds the running model's image.
        self.image_len = None;
        self.ack(board)
    }

    pub(super) fn chunk(
        &mut self,
        board: &mut impl Board<N>,
        offset: u32,
        data: &[u8],
    ) -> Result<Reply, Refuse> {
        self.upload.chunk(offset, data)?;
        self.ack(board)
    }

    /// The parked stage's check before a model change of the addressed axis.
    fn parked(&self, board: &mut impl Board<N>) -> Result<(), Refuse> {
        let axis = self.axis;
        let (fault, voltage) = board.exchange(|x| {
            let s = x.snapshot.axis(axis);
            (s.fault, s.now.voltage)
        });
        match fault {
            Some(_) if voltage == self.model().safe_voltage => Ok(()),
            Some(_) => Err(refuse(
                Refusal::StillRamping,
                format_args!("the output is still ramping to the safe voltage"),
            )),
            None => Err(refuse(
                Refusal::NotAtRest,
                format_args!("a new model needs the stage parked: send `safe` first"),
            )),
        }
    }

    pub(super) fn commit(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        store: bool,
    ) -> Result<Reply, Refuse> {
        let len = self.upload.complete()?;
        self.parked(board)?;
        if store && self.axis != 0 {
            return Err(refuse(
                Refusal::Storage,
                format_args!(
                    "the flash keeps the first axis's model only: load axis {}'s without                      storing it (it runs until the board restarts)",
                    super::axis_name(self.axis)
                ),
            ));
        }
        let running = self.activate(Origin::Received, len)?;
        if store {
            let image = self.upload.image.get(..len).unwrap_or(&[]);
            board.long_operation(true);
            let stored = self.flash.store(image);
            board.long_operation(false);
            match stored {
                Ok(s) => self.stored = Some(s),
                Err(e) => {
                    self.spare = Some(running.retire());
                    return Err(refuse(
                        Refusal::Storage,
                        format_args!("{}; the board keeps its model", e.message()),
                    ));
                }
            }
        }
        self.upload.done();
        let result = self.swap(board, seq, running);
        if result.is_ok() {
            self.image_len = Some((self.axis, len));
        }
        result
    }

    /// Loads the first `len` bytes of the upload buffer into the spare store and
    /// activates it.
    fn activate(&mut self, origin: Origin, len: usize) -> Result<Running, Refuse> {
        let Some(mut spare) = self.spare.take() else {
            return Err(refuse(Refusal::Model, format_args!("no free model store")));
        };
        let image = self.upload.image.get(..len).unwrap_or(&[]);
        if let Err(e) = spare.load(image) {
            self.spare = Some(spare);
            return Err(refuse(Refusal::Model, format_args!("{e}")));
        }
        match spare.activate(image, origin) {
            Ok(r) => Ok(r),
            Err((back, e)) => {
                self.spare = Some(back);
                Err(refuse(Refusal::Model, format_args!("{e}")))
            }
        }
    }

    /// Hands `running` to the ISR and takes back the model it replaces.
    fn swap(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        running: Running,
    ) -> Result<Reply, Refuse> {
        let summary = *running.summary();
        let mut running = Some(running);
        board.exchange(|x| x.model = running.take());
        let result = self.post(board, seq, Order::Swap);
        if let Some(back) = board.exchange(|x| x.model.take()) {
            self.spare = Some(back.retire());
        }
        result?;
        if let Some(s) = self.summary.get_mut(self.axis) {
            *s = summary;
        }
        Ok(Reply::Ack)
    }

    /// The factory model on the addressed axis; on the first axis, the
    /// stored model erased first (the flash keeps that axis's).
    pub(super) fn factory(&mut self, board: &mut impl Board<N>, seq: u16) -> Result<Reply, Refuse> {
        self.parked(board)?;
        if self.axis == 0 {
            board.long_operation(true);
            let erased = self.flash.erase_all();
            board.long_operation(false);
            if let Err(e) = erased {
                return Err(refuse(Refusal::Storage, format_args!("{}", e.message())));
            }
            self.stored = None;
        }
        let n = self.upload.hold(crate::board::factory_model::MODEL_IMAGE);
        let running = self.activate(Origin::Factory, n)?;
        let result = self.swap(board, seq, running);
        if result.is_ok() {
            self.image_len = Some((self.axis, n));
        }
        result
    }
}
