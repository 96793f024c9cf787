//! `efpi`: the extended FPI the firmware runs (EFPI-FFEM): the effective voltage
//! `û = g(u − U_p(F))` with a preload offset that curves with the preload,
//! `U_p(F) = k0 + k_f·F + k_q·(F − F_q)²`, and a soft dead zone `g`; creep lags of
//! `û`; an output saturation `z + β·z² = Y`; stack compliance. Fitted: weights,
//! creep gains and `β` linear, `(k_f, k_q, k0, s)` by Nelder–Mead from the fpi
//! fit; the compliance is the datasheet's (the rig cannot identify it: there the
//! force rises in proportion to the extension, so compliance only rescales the
//! weights), the creep time constants fixed (10 ms, 30 ms, 0.3 s, 3 s; those
//! shorter than ten sample periods dropped: [`resolved_lags`]), the curvature of
//! `U_p` centred on the data's mean preload.

use anyhow::Result;

use crate::method::fit::{golden, nelder_mead, Fit, Input, Layout, MapFit, Nonlinear, Problem};
use crate::method::kinds::play::{coupling_line, resolved_lags, Recipe, CREEP_TAUS_S};
use crate::method::model::{HostModel, Kind, Options};
use crate::method::series::CalibData;

/// The `efpi` kind.
pub struct Efpi;

#[allow(non_upper_case_globals)]
impl Kind {
    /// `efpi`.
    pub const Efpi: Kind = Kind::of(&Efpi);
}

impl Recipe for Efpi {
    const NAME: &'static str = "efpi";
    const METHOD: &'static str = "EFPI-FFEM";
    const USES_FORCE: bool = true;
    const COUPLED: bool = true;
    const TAKES_COMPLIANCE: bool = true;

    /// Stage A's stack compliance (0.02 µm/N) and the creep lags.
    fn defaults(&self) -> Options {
        Options {
            compliance: 0.02,
            creep_taus: CREEP_TAUS_S.to_vec(),
            ..Options::common(Kind::Efpi)
        }
    }

    fn layout(&self, opt: &Options, data: &[CalibData]) -> Layout {
        Layout {
            input: Input::Extended,
            creep: resolved_lags(&opt.creep_taus, data),
            map: MapFit::Saturation,
            compliance: opt.compliance,
            ..Layout::plain(opt, data)
        }
    }

    /// `(k_f, k_q, k0, s)` by Nelder–Mead from the paper's FPI fit: its `k_f`, no
    /// curvature, no offset, a 1 V soft edge.
    fn search(&self, pr: &Problem<'_>, opt: &Options) -> Result<(Nonlinear, Fit, String)> {
        let fpi = pr.with_layout(Layout {
            input: Input::Coupled,
            creep: Vec::new(),
            map: MapFit::Identity,
            compliance: 0.0,
            ..pr.layout.clone()
        });
        let k_f0 = golden(0.0, 0.4, 1e-4, |k_f| {
            fpi.rmse(&Nonlinear {
                k_f,
                ..Default::default()
            })
        });
        drop(fpi);
        let q = nelder_mead(pr, &[k_f0, 0.0, 0.0, 1.0], &[0.01, 1.0, 0.5, 0.5], params)?;
        let p = params(&q);
        let f = pr.fit_all(&p)?;
        Ok((
            p,
            f,
            format!(
                "(k_f, k_q, k0, s) by Nelder–Mead on the output RMSE from the fpi fit; weights, \
                 creep gains and saturation by NNLS (equation error); compliance {} µm/N \
                 fixed; creep time constants {:?} s fixed",
                opt.compliance, opt.creep_taus
            ),
        ))
    }

    fn firmware(&self, _: &HostModel) -> Result<()> {
        Ok(())
    }

    fn identified(&self, m: &HostModel) -> Option<String> {
        Some(coupling_line(m))
    }
}

/// The parameters of a Nelder–Mead point `(k_f, k_q·10⁴, k0, s)`.
fn params(q: &[f64]) -> Nonlinear {
    Nonlinear {
        k_f: q[0],
        k_q: q[1] * 1e-4,
        k0: q[2],
        softness: q[3].abs().max(1e-3),
        gamma: 0.0,
    }
}
