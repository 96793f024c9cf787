//! The handler's orders of several axes at once: a raster over two axes and
//! the axes' decoupling, each checked against every axis it moves or couples
//! before the control ISR sees it.

use embedded_storage::nor_flash::NorFlash;
use piezo_fpi::decoupling::{Decoupling, Entry, Matrix, Preload, PRELOAD_MAX};
use piezo_fpi::q::{Micrometres, NewtonsPerUm};

use super::{axis_name, Board, Handler, Milli};
use crate::board::capacity::{MAX_AXES, RATE_HZ};
use crate::control::exchange::{AxisSet, Order};
use crate::control::reference::raster::{line_ticks, Raster};
use crate::link::protocol::{RasterOrder, Refusal, Reply};
use crate::link::refusal::{refuse, Refuse};

/// A matrix's rows as the link carries them (`I2F30` or `I16F16` bits).
type Rows = [[i32; MAX_AXES]; MAX_AXES];

impl<F: NorFlash, const N: usize> Handler<F, N> {
    /// A raster, checked: two axes of the board, each span within its
    /// axis's stroke, a line (half the fast axis's period) of 2 – 65 535
    /// ticks, a line at least (two for a staircase).
    pub(super) fn raster(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        r: &RasterOrder,
    ) -> Result<Reply, Refuse> {
        // (A board of one axis carries none of what follows.)
        one_axis::<N>("a raster takes two axes")?;
        for a in [r.fast, r.slow] {
            if usize::from(a) >= N {
                return Err(refuse(
                    Refusal::Axis,
                    format_args!(
                        "raster on axis {}: this board has {N} axes",
                        axis_name(a.into())
                    ),
                ));
            }
        }
        if r.fast == r.slow {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!(
                    "a raster's fast and slow axes are two: both are {}",
                    axis_name(r.fast.into())
                ),
            ));
        }
        for (a, span, what) in [(r.fast, r.fast_span, "fast"), (r.slow, r.slow_span, "slow")] {
            for (end, x) in ["start", "end"].into_iter().zip(span) {
                let mut name = heapless::String::<32>::new();
                let _ = core::fmt::Write::write_fmt(&mut name, format_args!("{what} axis's {end}"));
                self.in_stroke_of(a.into(), &name, x)?;
            }
        }
        let ticks = line_ticks(r.freq_mhz, RATE_HZ).ok_or_else(|| {
            refuse(
                Refusal::BadArgument,
                format_args!(
                    "raster at {} mHz: a line (half the period) takes 2 – 65 535 ticks at \
                     {RATE_HZ} Hz",
                    r.freq_mhz
                ),
            )
        })?;
        let span = |s: [i32; 2]| (Micrometres::from_bits(s[0]), Micrometres::from_bits(s[1]));
        let raster = Raster::new(
            (r.fast.into(), span(r.fast_span)),
            (r.slow.into(), span(r.slow_span)),
            ticks,
            r.lines,
            r.staircase,
        )
        .ok_or_else(|| {
            refuse(
                Refusal::BadArgument,
                format_args!(
                    "{} lines: a raster has one line at least, a staircase two",
                    r.lines
                ),
            )
        })?;
        self.axes = AxisSet::one(r.fast.into()).with(r.slow.into());
        self.order(board, seq, Order::Raster(raster))
    }

    /// Moves on several axes from one tick: each axis of `mask` one the
    /// board has, each target within its axis's stroke, the speed within the
    /// board's.
    pub(super) fn move_axes(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        mask: u8,
        targets: &[i32; MAX_AXES],
        speed: i32,
    ) -> Result<Reply, Refuse> {
        one_axis::<N>("`move` moves its one axis")?;
        if mask == 0 || usize::from(mask) >> N != 0 {
            return Err(refuse(
                Refusal::Axis,
                format_args!("axes {mask:#05b} to move: name some of this board's {N}"),
            ));
        }
        let step = super::move_step(speed)?;
        let mut to = [None; MAX_AXES];
        for (i, (&t, slot)) in targets.iter().zip(&mut to).enumerate() {
            if mask & (1 << i) == 0 {
                continue;
            }
            let mut name = heapless::String::<16>::new();
            let _ =
                core::fmt::Write::write_fmt(&mut name, format_args!("{}'s target", axis_name(i)));
            *slot = Some(self.in_stroke_of(i, &name, t)?);
        }
        self.order(board, seq, Order::Moves { targets: to, step })
    }

    /// The axes' decoupling, checked: every axis parked (it changes every
    /// stack's command at once), entries within their ranges, and no
    /// coupling of an axis the board does not have.
    pub(super) fn decoupling(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        input: &Rows,
        output: &Rows,
        preload: &Rows,
    ) -> Result<Reply, Refuse> {
        one_axis::<N>("it has no axes to decouple")?;
        let parked = board.exchange(|x| x.snapshot.axes.iter().all(|s| s.fault.is_some()));
        if !parked {
            return Err(refuse(
                Refusal::NotAtRest,
                format_args!(
                    "a new decoupling needs every axis parked (it changes every stack's \
                     command at once): send `safe` first"
                ),
            ));
        }
        let d = Decoupling {
            input: matrix("input", input)?,
            output: matrix("output", output)?,
            preload: preload_of(preload)?,
        };
        if d.leading::<N>().is_none() {
            return Err(refuse(
                Refusal::Axis,
                format_args!(
                    "the decoupling couples an axis this board does not have (it has {N})"
                ),
            ));
        }
        self.order(board, seq, Order::Decoupling(d))
    }
}

/// The refusal of an order of several axes on a board of one (`why`).
fn one_axis<const N: usize>(why: &str) -> Result<(), Refuse> {
    if N > 1 {
        return Ok(());
    }
    Err(refuse(
        Refusal::Axis,
        format_args!("this board has one axis: {why}"),
    ))
}

/// `rows` (`I2F30` bits) as the `which` matrix, or the refusal naming the
/// entry and its rule.
fn matrix(which: &str, rows: &Rows) -> Result<Matrix<MAX_AXES>, Refuse> {
    Matrix::new(rows.map(|r| r.map(Entry::from_bits))).map_err(|e| {
        let (i, j) = at(&e);
        let v = rows.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0);
        refuse(
            Refusal::BadArgument,
            format_args!(
                "{which} matrix [{}][{}] = {}/1000: the diagonal within 800–1250/1000, off it \
                 within ±100/1000",
                axis_name(i),
                axis_name(j),
                (i64::from(v) * 1000 + (1 << 29)) >> 30
            ),
        )
    })
}

/// `rows` (`I16F16` bits, N/µm) as the preload coupling, or the refusal
/// naming the entry and its rule.
fn preload_of(rows: &Rows) -> Result<Preload<MAX_AXES>, Refuse> {
    Preload::new(rows.map(|r| r.map(NewtonsPerUm::from_bits))).map_err(|e| {
        let (i, j) = at(&e);
        let v = rows.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0);
        refuse(
            Refusal::BadArgument,
            format_args!(
                "preload coupling [{}][{}] = {} N/µm: zero on the diagonal, within ±{} off it",
                axis_name(i),
                axis_name(j),
                Milli(v),
                PRELOAD_MAX as u32
            ),
        )
    })
}

/// The row and column a matrix's error names.
fn at(e: &piezo_fpi::ModelError) -> (usize, usize) {
    use piezo_fpi::ModelError as E;
    match *e {
        E::MatrixEntryOutOfRange { row, col } | E::PreloadCouplingOutOfRange { row, col } => {
            (row.into(), col.into())
        }
        _ => (0, 0),
    }
}
