//! `fpi`: the paper's force-dependent PI (FPI-FFEM, Actuators 2025, eqs. 5–7):
//! `w0` and one-sided play operators on the effective voltage
//! `û = max(u − k_f·F, 0)`.

use anyhow::Result;

use crate::method::fit::{golden, Fit, Input, Layout, Nonlinear, Problem};
use crate::method::kinds::play::{coupling_line, Recipe};
use crate::method::model::{HostModel, Kind, Options};
use crate::method::series::CalibData;

/// The `fpi` kind.
pub struct Fpi;

#[allow(non_upper_case_globals)]
impl Kind {
    /// `fpi`.
    pub const Fpi: Kind = Kind::of(&Fpi);
}

impl Recipe for Fpi {
    const NAME: &'static str = "fpi";
    const METHOD: &'static str = "FPI-FFEM";
    const USES_FORCE: bool = true;
    const COUPLED: bool = true;

    fn defaults(&self) -> Options {
        Options::common(Kind::Fpi)
    }

    fn layout(&self, opt: &Options, data: &[CalibData]) -> Layout {
        Layout {
            input: Input::Coupled,
            ..Layout::plain(opt, data)
        }
    }

    /// `k_f` by golden section.
    fn search(&self, pr: &Problem<'_>, _: &Options) -> Result<(Nonlinear, Fit, String)> {
        let with = |k_f| Nonlinear {
            k_f,
            ..Default::default()
        };
        let p = with(golden(0.0, 0.4, 1e-5, |k_f| pr.rmse(&with(k_f))));
        let f = pr.fit_all(&p)?;
        Ok((
            p,
            f,
            "k_f by golden section on the output RMSE; weights by NNLS".into(),
        ))
    }

    fn firmware(&self, _: &HostModel) -> Result<()> {
        Ok(())
    }

    fn identified(&self, m: &HostModel) -> Option<String> {
        Some(coupling_line(m))
    }
}
