//! `pi`: the conventional Prandtl–Ishlinskii baseline (PI-FEM): `w0` and one-sided
//! play operators on the voltage; it ignores the preload. As the paper does,
//! identify it at one preload.

use anyhow::Result;

use crate::method::fit::{Fit, Layout, Nonlinear, Problem};
use crate::method::kinds::play::{weights_alone, Recipe};
use crate::method::model::{HostModel, Kind, Options};
use crate::method::series::CalibData;

/// The `pi` kind.
pub struct Pi;

#[allow(non_upper_case_globals)]
impl Kind {
    /// `pi`.
    pub const Pi: Kind = Kind::of(&Pi);
}

impl Recipe for Pi {
    const NAME: &'static str = "pi";
    const METHOD: &'static str = "PI-FEM";
    const ONE_PRELOAD: bool = true;

    fn defaults(&self) -> Options {
        Options::common(Kind::Pi)
    }

    fn layout(&self, opt: &Options, data: &[CalibData]) -> Layout {
        Layout::plain(opt, data)
    }

    /// The weights alone, by NNLS.
    fn search(&self, pr: &Problem<'_>, _: &Options) -> Result<(Nonlinear, Fit, String)> {
        weights_alone(pr)
    }

    fn firmware(&self, _: &HostModel) -> Result<()> {
        Ok(())
    }
}
