//! Calibration of the branch model: its least squares' layout and normal
//! equations, the force gain searched outside them, and the fitted section.

use super::*;

/// Columns of a least-squares row: the rest offset, then up to [`MAX_DEGREE`]
/// ascending and as many descending coefficients (scaled to the voltage span).
const COLUMNS: usize = 1 + 2 * MAX_DEGREE;

/// A least-squares row.
type Row = SVector<f64, COLUMNS>;

/// What is fitted: degrees, whether the rest offset is, and the voltage scale.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Layout {
    up: usize,
    down: usize,
    offset: bool,
    /// Voltage scale of the columns, V (the data's span).
    scale: f64,
    memory: Memory,
}

impl Layout {
    /// The columns in use, in [`Row`]'s order.
    fn active(&self) -> Vec<usize> {
        let mut c = Vec::new();
        if self.offset {
            c.push(0);
        }
        c.extend(1..=self.up);
        c.extend(1 + MAX_DEGREE..1 + MAX_DEGREE + self.down);
        c
    }

    /// The row of `P(rising, Δ)`: `(Δ/scale)^k` in the branch's columns.
    fn shape(&self) -> impl Fn(bool, f64) -> Row + '_ {
        move |rising, d| {
            let (first, n) = if rising {
                (1, self.up)
            } else {
                (1 + MAX_DEGREE, self.down)
            };
            let mut r = Row::zeros();
            let z = d / self.scale;
            let mut p = 1.0;
            for k in 0..n {
                p *= z;
                r[first + k] = p;
            }
            r
        }
    }

    /// The rest state's row.
    fn rest(&self) -> Row {
        let mut r = Row::zeros();
        if self.offset {
            r[0] = 1.0;
        }
        r
    }
}

/// Normal equations of one trial (full [`Row`] size; unused columns stay 0).
#[derive(Debug, Clone)]
struct Normal {
    ata: nalgebra::SMatrix<f64, COLUMNS, COLUMNS>,
    atb: Row,
    btb: f64,
    n: usize,
}

impl Normal {
    fn new() -> Self {
        Self {
            ata: nalgebra::SMatrix::zeros(),
            atb: Row::zeros(),
            btb: 0.0,
            n: 0,
        }
    }
    fn merge(mut self, o: Normal) -> Self {
        self.ata += o.ata;
        self.atb += o.atb;
        self.btb += o.btb;
        self.n += o.n;
        self
    }
}

/// One recording's normal equations for coupling `k_f`: its rows run through the
/// memory (every sample up to the window's end; the window's samples added).
fn normal_of(d: &CalibData, k_f: f64, input_max: f64, lay: &Layout) -> Normal {
    let shape = lay.shape();
    let mut st = BranchState::at_rest(lay.rest());
    let mut ne = Normal::new();
    let end = d.fit.1.min(d.u.len());
    for k in 0..end {
        let v = (d.u[k] - k_f * d.f[k]).clamp(0.0, input_max);
        let r = st.advance(v, lay.memory, &shape);
        if k >= d.fit.0 {
            ne.ata += r * r.transpose();
            ne.atb += r * d.x[k];
            ne.btb += d.x[k] * d.x[k];
            ne.n += 1;
        }
    }
    ne
}

/// Least squares on the active columns: the coefficients (in [`Row`]'s order,
/// scaled) and the output RMSE, µm.
fn solve_normal(ne: &Normal, lay: &Layout) -> Result<(Row, f64)> {
    let cols = lay.active();
    let m = cols.len();
    let a = DMatrix::from_fn(m, m, |i, j| ne.ata[(cols[i], cols[j])]);
    let b = DVector::from_fn(m, |i, _| ne.atb[cols[i]]);
    let svd = a.clone().svd(true, true);
    let tol = 1e-13 * svd.singular_values.max();
    let x = svd
        .solve(&b, tol)
        .map_err(|e| anyhow::anyhow!("branch least squares: {e}"))?;
    let mut theta = Row::zeros();
    for (i, &c) in cols.iter().enumerate() {
        theta[c] = x[i];
    }
    let sse = ne.btb - 2.0 * x.dot(&b) + x.dot(&(&a * &x));
    let rmse = (sse.max(0.0) / ne.n.max(1) as f64).sqrt();
    Ok((theta, rmse))
}

/// Fits the coefficients for coupling `k_f` over every recording.
fn fit_at(data: &[CalibData], k_f: f64, input_max: f64, lay: &Layout) -> Result<(Row, f64)> {
    let ne = data
        .par_iter()
        .map(|d| normal_of(d, k_f, input_max, lay))
        .reduce(Normal::new, Normal::merge);
    solve_normal(&ne, lay)
}

/// The section a fit's scaled coefficients `theta` describe.
fn section(theta: &Row, lay: &Layout, input_max: f64) -> BranchSection {
    let unscale = |first: usize, n: usize| -> Vec<f64> {
        (0..n)
            .map(|k| theta[first + k] / lay.scale.powi(k as i32 + 1))
            .collect()
    };
    BranchSection {
        input_max_v: input_max,
        memory: lay.memory,
        ascending_um_per_vk: unscale(1, lay.up),
        descending_um_per_vk: unscale(1 + MAX_DEGREE, lay.down),
    }
}

/// Where a major branch falls while the voltage moves its way (a branch should
/// rise with the voltage): a warning naming the key, or none.
fn monotony_warning(s: &BranchSection, span: f64) -> Option<String> {
    let steps = 400;
    for (key, c, sign) in [
        ("branch.ascending_um_per_vk", &s.ascending_um_per_vk, 1.0),
        ("branch.descending_um_per_vk", &s.descending_um_per_vk, -1.0),
    ] {
        let worst = (0..=steps)
            .map(|i| {
                let d = sign * span * i as f64 / steps as f64;
                (dpoly(c, d), d)
            })
            .fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a });
        if worst.0 < 0.0 {
            return Some(format!(
                "{key}: the major branch falls with the voltage ({:.4} µm/V at {:.1} V from the \
                 turning point): the coupled solve may have several roots there",
                worst.0, worst.1
            ));
        }
    }
    None
}

/// Calibrates a branch model: `k_f` by golden section on the output RMSE (0 for
/// recordings without force), the coefficients by least squares.
pub(super) fn calibrate(data: &[CalibData], opt: &Options, mut warnings: Vec<String>) -> Result<HostModel> {
    let (up, down) = opt.branch_degrees;
    for (what, n) in [("ascending", up), ("descending", down)] {
        if !(1..=MAX_DEGREE).contains(&n) {
            bail!("the {what} branch's degree {n}: must be 1..={MAX_DEGREE}");
        }
    }
    let span = voltage_span(data);
    let input_max = opt.input_max.max(span);
    let lay = Layout {
        up,
        down,
        offset: opt.offset,
        scale: span,
        memory: opt.branch_memory,
    };
    let has_force = data.iter().all(|d| d.has_force);
    let k_f = if has_force {
        golden(0.0, 0.4, 1e-5, |k_f| {
            fit_at(data, k_f, input_max, &lay).map_or(f64::MAX, |f| f.1)
        })
    } else {
        0.0
    };
    let (theta, _) = fit_at(data, k_f, input_max, &lay).context("fitting the branch model")?;
    let mut model = HostModel::new(Kind::Branch, no_pi());
    model.branch = Some(section(&theta, &lay, input_max));
    model.coupling.k_f_v_per_n = k_f;
    model.offset_um = theta[0];
    warnings.extend(
        model
            .branch
            .as_ref()
            .and_then(|s| monotony_warning(s, span)),
    );
    let b = BranchModel::of(&model)?;
    let per_file = data
        .par_iter()
        .map(|d| {
            let w = d.fit.0..d.fit.1;
            file_fit(
                d,
                &ErrorStats::of_difference(&b.simulate(d)[w.clone()], &d.x[w]),
            )
        })
        .collect::<Vec<_>>();
    model.calibration = Calibration::new(
        data.iter().map(|d| d.name.clone()).collect(),
        pooled_rmse(&per_file),
        per_file,
        format!(
            "k_f by golden section on the output RMSE; branch coefficients (degrees {up} up, \
             {down} down, {} memory) by output-error least squares",
            match lay.memory {
                Memory::Stack => "stack",
                Memory::Last => "last-point",
            }
        ),
        warnings,
    );
    Ok(model)
}
