//! `gpi`: PI followed by a monotone quadratic output map `x = Y + γ·Y²` (closed-form
//! inverse) and an offset, on the voltage: a model for recordings without force
//! (the firmware has no quadratic map; `epi` is the extended model without force).

use anyhow::{bail, Result};

use crate::method::fit::{golden, Fit, Layout, MapFit, Nonlinear, Problem};
use crate::method::kinds::play::Recipe;
use crate::method::model::{HostModel, Kind, Options};
use crate::method::series::CalibData;

/// The `gpi` kind.
pub struct Gpi;

#[allow(non_upper_case_globals)]
impl Kind {
    /// `gpi`.
    pub const Gpi: Kind = Kind::of(&Gpi);
}

impl Recipe for Gpi {
    const NAME: &'static str = "gpi";
    const METHOD: &'static str = "GPI-FEM";

    /// 21 operators and an offset.
    fn defaults(&self) -> Options {
        Options {
            operators: 21,
            offset: true,
            ..Options::common(Kind::Gpi)
        }
    }

    fn layout(&self, opt: &Options, data: &[CalibData]) -> Layout {
        Layout {
            map: MapFit::Quadratic,
            ..Layout::plain(opt, data)
        }
    }

    /// The output curvature by golden section (scaled by the data's range).
    fn search(&self, pr: &Problem<'_>, _: &Options) -> Result<(Nonlinear, Fit, String)> {
        let scale = pr
            .data
            .iter()
            .flat_map(|d| d.x[d.fit.0..d.fit.1].iter())
            .fold(0.0f64, |a, &b| a.max(b.abs()))
            .max(1e-9);
        let with = |g: f64| Nonlinear {
            gamma: g / scale,
            ..Default::default()
        };
        let p = with(golden(-0.3, 0.3, 1e-6, |g| pr.rmse(&with(g))));
        let f = pr.fit_all(&p)?;
        Ok((
            p,
            f,
            "output curvature by golden section on the output RMSE; weights by weighted NNLS \
             on the inverse-mapped extension"
                .into(),
        ))
    }

    fn firmware(&self, _: &HostModel) -> Result<()> {
        bail!("the firmware has no quadratic output map (epi is the model without force it runs)")
    }
}
