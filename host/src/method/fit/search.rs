//! The searches of the nonlinear parameters outside the least squares:
//! golden section on one, Nelder–Mead (argmin) on several.

use super::*;

/// Golden-section minimisation of `f` on `[a, b]`.
pub fn golden(mut a: f64, mut b: f64, tol: f64, mut f: impl FnMut(f64) -> f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    while (b - a).abs() > tol {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    (a + b) / 2.0
}

/// Nelder–Mead (`argmin`) on the output RMSE of the problem's search samples,
/// from `start` with initial steps `steps` (one per coordinate), a point mapped
/// to parameters by `params`: the best point (at most 400 iterations).
pub fn nelder_mead(
    pr: &Problem<'_>,
    start: &[f64],
    steps: &[f64],
    params: fn(&[f64]) -> Nonlinear,
) -> Result<Vec<f64>> {
    let mut simplex = vec![start.to_vec()];
    for (i, s) in steps.iter().enumerate() {
        let mut v = start.to_vec();
        v[i] += s;
        simplex.push(v);
    }
    let solver = NelderMead::new(simplex)
        .with_sd_tolerance(1e-7)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let res = Executor::new(
        Cost {
            problem: pr,
            params,
        },
        solver,
    )
    .configure(|s| s.max_iters(400))
    .run()
    .map_err(|e| anyhow::anyhow!("Nelder–Mead: {e}"))?;
    Ok(res
        .state()
        .get_best_param()
        .cloned()
        .unwrap_or_else(|| start.to_vec()))
}

/// The cost [`nelder_mead`] minimises.
struct Cost<'p, 'a> {
    problem: &'p Problem<'a>,
    params: fn(&[f64]) -> Nonlinear,
}

impl CostFunction for Cost<'_, '_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, q: &Vec<f64>) -> Result<f64, ArgminError> {
        Ok(self.problem.rmse(&(self.params)(q)))
    }
}
