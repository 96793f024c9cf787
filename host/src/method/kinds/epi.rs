//! `epi`: the extended model without the force coupling (EPI-FEM), for recordings
//! without a force channel (the default there): the structure of `efpi` with
//! `k_f = k_q = 0` and no compliance — the effective voltage `û = g(u − k0)` with
//! a soft dead zone `g`, creep lags of `û`, the output saturation `z + β·z² = Y`
//! (and an offset, for recordings not zeroed at rest). Fitted: weights, creep
//! gains and `β` linear, `(k0, s)` by Nelder–Mead. Its creep lags are `efpi`'s,
//! but for those slower than the fitted rows last: over a shorter window a lag is
//! a drift, and the offset absorbs it (and, as for `efpi`, those faster than ten
//! sample periods: [`resolved_lags`]). The firmware runs it (with `k_f = 0`) when
//! it has no offset.

use anyhow::Result;

use crate::method::fit::{nelder_mead, Fit, Input, Layout, MapFit, Nonlinear, Problem};
use crate::method::kinds::play::{resolved_lags, Recipe, CREEP_TAUS_S};
use crate::method::model::{HostModel, Kind, Options};
use crate::method::series::CalibData;

/// The `epi` kind.
pub struct Epi;

#[allow(non_upper_case_globals)]
impl Kind {
    /// `epi`.
    pub const Epi: Kind = Kind::of(&Epi);
}

impl Recipe for Epi {
    const NAME: &'static str = "epi";
    const METHOD: &'static str = "EPI-FEM";
    const COUPLED: bool = true;

    /// The creep lags of `efpi`.
    fn defaults(&self) -> Options {
        Options {
            creep_taus: CREEP_TAUS_S.to_vec(),
            ..Options::common(Kind::Epi)
        }
    }

    fn layout(&self, opt: &Options, data: &[CalibData]) -> Layout {
        Layout {
            input: Input::Extended,
            creep: within_rows(&resolved_lags(&opt.creep_taus, data), data),
            map: MapFit::Saturation,
            ..Layout::plain(opt, data)
        }
    }

    /// `(k0, s)` by Nelder–Mead from no offset and a 1 V soft edge.
    fn search(&self, pr: &Problem<'_>, _: &Options) -> Result<(Nonlinear, Fit, String)> {
        let q = nelder_mead(pr, &[0.0, 1.0], &[0.5, 0.5], params)?;
        let p = params(&q);
        let f = pr.fit_all(&p)?;
        Ok((
            p,
            f,
            format!(
                "(k0, s) by Nelder–Mead on the output RMSE; weights, creep gains and \
                 saturation by NNLS (equation error); creep time constants {:?} s fixed",
                pr.layout.creep
            ),
        ))
    }

    fn firmware(&self, _: &HostModel) -> Result<()> {
        Ok(())
    }

    fn identified(&self, m: &HostModel) -> Option<String> {
        Some(format!(
            "k0 {:.3} V, dead-zone softness {:.3} V (û = g(u − k0); no force coupling)",
            m.coupling.offset_v, m.dead_zone_softness_v
        ))
    }
}

/// The time constants no longer than every recording's fitted rows last.
fn within_rows(taus: &[f64], data: &[CalibData]) -> Vec<f64> {
    let shortest = data
        .iter()
        .map(|d| (d.fit.1 - d.fit.0) as f64 * d.dt)
        .fold(f64::INFINITY, f64::min);
    taus.iter().copied().filter(|&t| t <= shortest).collect()
}

/// The parameters of a Nelder–Mead point `(k0, s)`.
fn params(q: &[f64]) -> Nonlinear {
    Nonlinear {
        k0: q[0],
        softness: q[1].abs().max(1e-3),
        ..Default::default()
    }
}
