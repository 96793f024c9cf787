//! `ldpi`: the load-dependent PI baseline (LDPI-FEM), as we implement it (the
//! paper's source for it is not available): PI weights affine in the preload,
//! `w_i(F) = a_i + b_i·F`, on the voltage. Its weights depend on the force, so it
//! is inverted by search and the firmware does not run it.

use anyhow::{bail, Result};

use crate::method::fit::{Fit, Layout, Nonlinear, Problem};
use crate::method::invert::Inverse;
use crate::method::kinds::play::{weights_alone, Recipe};
use crate::method::model::{HostModel, Kind, Options};
use crate::method::series::CalibData;

/// The `ldpi` kind.
pub struct Ldpi;

#[allow(non_upper_case_globals)]
impl Kind {
    /// `ldpi`.
    pub const Ldpi: Kind = Kind::of(&Ldpi);
}

impl Recipe for Ldpi {
    const NAME: &'static str = "ldpi";
    const METHOD: &'static str = "LDPI-FEM";
    const USES_FORCE: bool = true;
    const FORCE_PART: Option<&'static str> = Some("the force slopes of the ldpi model's weights");
    const INVERSE: Inverse = Inverse::Search;

    fn defaults(&self) -> Options {
        Options::common(Kind::Ldpi)
    }

    fn layout(&self, opt: &Options, data: &[CalibData]) -> Layout {
        Layout {
            ldpi: true,
            ..Layout::plain(opt, data)
        }
    }

    /// The weights and their slopes alone, signed.
    fn search(&self, pr: &Problem<'_>, _: &Options) -> Result<(Nonlinear, Fit, String)> {
        weights_alone(pr)
    }

    fn firmware(&self, _: &HostModel) -> Result<()> {
        bail!("its weights depend on the force (the firmware's operators have fixed weights)")
    }

    fn check(&self, m: &HostModel) -> Result<()> {
        if m.ldpi.is_none() {
            bail!("kind = \"ldpi\" needs an [ldpi] section");
        }
        Ok(())
    }
}
