//! Small dense optimisers for the calibration: Levenberg-Marquardt on a residual vector, its
//! iteratively reweighted form that minimises a sum of Euclidean norms (eq 16 of the paper is
//! the sum of the horizontal distances, not of their squares), and Nelder-Mead with restarts.
//!
//! Residual functions write their residuals into a vector and return `false` when the
//! parameters are not admissible (for example outside `ChassisParams::validate`'s ranges).
//! Jacobians are numerical (central differences).

/// What is minimised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Objective {
    /// Sum of squared residuals.
    Squares,
    /// Sum of the Euclidean norms of consecutive residual pairs `(r[2k], r[2k+1])`: eq (16)
    /// when the pairs are the x and y differences. Minimised by iteratively reweighted
    /// Levenberg-Marquardt: weights `1/|r_k|` make the weighted squares a majoriser of the
    /// sum of norms, so every accepted step lowers the sum of norms itself.
    SumOfNorms,
}

/// Options of [`levenberg_marquardt`].
#[derive(Debug, Clone, Copy)]
pub struct LmOptions {
    /// Largest number of accepted iterations.
    pub max_iter: usize,
    /// Stop when an accepted step lowers the objective by less than this fraction.
    pub ftol: f64,
    /// Stop when every step component is below this fraction of its parameter's scale.
    pub xtol: f64,
    /// Central-difference step, as a fraction of each parameter's scale.
    pub diff_step: f64,
    /// Largest step of one iteration, as a fraction of each parameter's scale (a trust
    /// region: steps are shortened to it). Keeps nearly flat directions from jumping.
    pub max_step: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self {
            max_iter: 100,
            ftol: 1e-12,
            xtol: 1e-11,
            diff_step: 1e-5,
            max_step: 0.25,
        }
    }
}

/// Result of an optimisation.
#[derive(Debug, Clone)]
pub struct OptResult {
    /// The best parameters found.
    pub x: Vec<f64>,
    /// The objective at `x`.
    pub cost: f64,
    /// Accepted iterations.
    pub iterations: usize,
    /// Residual-function evaluations.
    pub evaluations: usize,
    /// True when a convergence test (rather than the iteration limit) ended the run.
    pub converged: bool,
}

/// The objective of a residual vector.
pub fn objective(kind: Objective, r: &[f64]) -> f64 {
    match kind {
        Objective::Squares => r.iter().map(|v| v * v).sum(),
        Objective::SumOfNorms => r
            .chunks(2)
            .map(|c| c.iter().map(|v| v * v).sum::<f64>().sqrt())
            .sum(),
    }
}

/// Solves the dense system `a x = b` (n x n, row-major) by Gaussian elimination with partial
/// pivoting; `None` when singular.
pub fn solve(mut a: Vec<f64>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for col in 0..n {
        let piv =
            (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if a[piv * n + col].abs() < 1e-300 || !a[piv * n + col].is_finite() {
            return None;
        }
        if piv != col {
            for k in 0..n {
                a.swap(piv * n + k, col * n + k);
            }
            b.swap(piv, col);
        }
        for row in col + 1..n {
            let f = a[row * n + col] / a[col * n + col];
            for k in col..n {
                a[row * n + k] -= f * a[col * n + k];
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|k| a[row * n + k] * x[k]).sum();
        x[row] = (b[row] - s) / a[row * n + row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Levenberg-Marquardt (Marquardt's diagonal scaling) minimising `kind` of the residuals of
/// `f`, starting at `x0`; `scale[i]` is the typical magnitude of parameter `i` (difference
/// steps and the step test use it).
pub fn levenberg_marquardt<F>(
    mut f: F,
    x0: &[f64],
    scale: &[f64],
    kind: Objective,
    opts: LmOptions,
) -> Option<OptResult>
where
    F: FnMut(&[f64], &mut Vec<f64>) -> bool,
{
    let n = x0.len();
    let mut x = x0.to_vec();
    let mut r = Vec::new();
    let mut evals = 1;
    if !f(&x, &mut r) {
        return None;
    }
    let mut cost = objective(kind, &r);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut converged = false;
    let mut rp = Vec::new();
    let mut rm = Vec::new();
    let mut jac = vec![0.0; r.len() * n];
    while iterations < opts.max_iter {
        // Weights: 1 for squares, 1/|r_k| for the sum of norms (IRLS majoriser).
        let m = r.len();
        let weights: Vec<f64> = match kind {
            Objective::Squares => vec![1.0; m],
            Objective::SumOfNorms => {
                let floor = 1e-9;
                r.chunks(2)
                    .flat_map(|c| {
                        let d = c.iter().map(|v| v * v).sum::<f64>().sqrt().max(floor);
                        std::iter::repeat_n(1.0 / d, c.len())
                    })
                    .collect()
            }
        };
        // Central-difference Jacobian, column by column.
        jac.resize(m * n, 0.0);
        for j in 0..n {
            let h = opts.diff_step * scale[j];
            let mut xp = x.clone();
            xp[j] += h;
            let mut xm = x.clone();
            xm[j] -= h;
            evals += 2;
            let okp = f(&xp, &mut rp) && rp.len() == m;
            let okm = f(&xm, &mut rm) && rm.len() == m;
            for i in 0..m {
                jac[i * n + j] = match (okp, okm) {
                    (true, true) => (rp[i] - rm[i]) / (2.0 * h),
                    (true, false) => (rp[i] - r[i]) / h,
                    (false, true) => (r[i] - rm[i]) / h,
                    (false, false) => 0.0,
                };
            }
        }
        let mut jtj = vec![0.0; n * n];
        let mut jtr = vec![0.0; n];
        for i in 0..m {
            let w = weights[i];
            let row = &jac[i * n..(i + 1) * n];
            for a in 0..n {
                jtr[a] += w * row[a] * r[i];
                for b in a..n {
                    jtj[a * n + b] += w * row[a] * row[b];
                }
            }
        }
        for a in 0..n {
            for b in 0..a {
                jtj[a * n + b] = jtj[b * n + a];
            }
        }
        let mut accepted = false;
        let mut step_small;
        for _ in 0..30 {
            let mut a = jtj.clone();
            for d in 0..n {
                let diag = jtj[d * n + d];
                a[d * n + d] = diag + lambda * (diag + 1e-12 * (1.0 + diag));
            }
            let Some(mut dx) = solve(a, jtr.iter().map(|v| -v).collect()) else {
                lambda *= 10.0;
                continue;
            };
            let worst = dx
                .iter()
                .zip(scale)
                .map(|(d, s)| d.abs() / s)
                .fold(0.0, f64::max);
            if worst > opts.max_step {
                dx.iter_mut().for_each(|d| *d *= opts.max_step / worst);
            }
            let xn: Vec<f64> = x.iter().zip(&dx).map(|(a, b)| a + b).collect();
            step_small = dx.iter().zip(scale).all(|(d, s)| d.abs() <= opts.xtol * s);
            evals += 1;
            if f(&xn, &mut rp) && rp.len() == m {
                let c = objective(kind, &rp);
                if c < cost {
                    let gain = (cost - c) / cost.max(1e-300);
                    x = xn;
                    std::mem::swap(&mut r, &mut rp);
                    cost = c;
                    lambda = (lambda / 3.0).max(1e-12);
                    accepted = true;
                    if gain < opts.ftol || step_small {
                        converged = true;
                    }
                    break;
                }
            }
            if step_small {
                break;
            }
            lambda *= 4.0;
            if lambda > 1e16 {
                break;
            }
        }
        if accepted {
            iterations += 1;
        }
        if !accepted || converged {
            converged = true;
            break;
        }
    }
    Some(OptResult {
        x,
        cost,
        iterations,
        evaluations: evals,
        converged,
    })
}

/// Options of [`nelder_mead`].
#[derive(Debug, Clone, Copy)]
pub struct NmOptions {
    /// Largest number of function evaluations over all restarts.
    pub max_evals: usize,
    /// Stop a run when the simplex's spread of values is below this fraction of the best.
    pub ftol: f64,
    /// Restarts from the best point (each with a fresh simplex of the initial size / 10^k).
    pub restarts: usize,
}

impl Default for NmOptions {
    fn default() -> Self {
        Self {
            max_evals: 2000,
            ftol: 1e-13,
            restarts: 3,
        }
    }
}

/// Nelder-Mead (adaptive coefficients of Gao and Han) minimising `f`, restarted from the best
/// point with a shrinking initial simplex; `step[i]` is the initial simplex size along `i`.
/// `f` returns `None` (treated as +inf) for inadmissible points.
pub fn nelder_mead<F>(mut f: F, x0: &[f64], step: &[f64], opts: NmOptions) -> OptResult
where
    F: FnMut(&[f64]) -> Option<f64>,
{
    let n = x0.len();
    let nf = n as f64;
    let (alpha, beta, gamma, delta) =
        (1.0, 1.0 + 2.0 / nf, 0.75 - 1.0 / (2.0 * nf), 1.0 - 1.0 / nf);
    let mut evals = 0;
    let mut eval = |x: &[f64], evals: &mut usize| {
        *evals += 1;
        f(x).filter(|v| v.is_finite()).unwrap_or(f64::INFINITY)
    };
    let mut best = x0.to_vec();
    let mut best_f = eval(&best, &mut evals);
    let mut iterations = 0;
    let mut converged = false;
    for restart in 0..=opts.restarts {
        let shrink = 10f64.powi(restart as i32);
        let mut simplex: Vec<(Vec<f64>, f64)> = vec![(best.clone(), best_f)];
        for i in 0..n {
            let mut x = best.clone();
            x[i] += step[i] / shrink;
            let v = eval(&x, &mut evals);
            simplex.push((x, v));
        }
        let start_best = best_f;
        loop {
            simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
            let (lo, hi) = (simplex[0].1, simplex[n].1);
            if evals >= opts.max_evals || (hi - lo).abs() <= opts.ftol * lo.abs().max(1e-300) {
                converged = (hi - lo).abs() <= opts.ftol * lo.abs().max(1e-300);
                break;
            }
            iterations += 1;
            let centroid: Vec<f64> = (0..n)
                .map(|i| simplex[..n].iter().map(|p| p.0[i]).sum::<f64>() / nf)
                .collect();
            let worst = simplex[n].0.clone();
            let along = |t: f64| -> Vec<f64> {
                (0..n)
                    .map(|i| centroid[i] + t * (centroid[i] - worst[i]))
                    .collect()
            };
            let xr = along(alpha);
            let fr = eval(&xr, &mut evals);
            if fr < simplex[0].1 {
                let xe = along(alpha * beta);
                let fe = eval(&xe, &mut evals);
                simplex[n] = if fe < fr { (xe, fe) } else { (xr, fr) };
            } else if fr < simplex[n - 1].1 {
                simplex[n] = (xr, fr);
            } else {
                let (xc, fc) = if fr < simplex[n].1 {
                    let xc = along(alpha * gamma);
                    let fc = eval(&xc, &mut evals);
                    (xc, fc)
                } else {
                    let xc = along(-gamma);
                    let fc = eval(&xc, &mut evals);
                    (xc, fc)
                };
                if fc < simplex[n].1.min(fr) {
                    simplex[n] = (xc, fc);
                } else {
                    let x0 = simplex[0].0.clone();
                    for p in simplex.iter_mut().skip(1) {
                        let x: Vec<f64> =
                            (0..n).map(|i| x0[i] + delta * (p.0[i] - x0[i])).collect();
                        let v = eval(&x, &mut evals);
                        *p = (x, v);
                    }
                }
            }
        }
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        if simplex[0].1 < best_f {
            best = simplex[0].0.clone();
            best_f = simplex[0].1;
        }
        if evals >= opts.max_evals || (restart > 0 && best_f >= start_best) {
            break;
        }
    }
    OptResult {
        x: best,
        cost: best_f,
        iterations,
        evaluations: evals,
        converged,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rosenbrock_res(x: &[f64], r: &mut Vec<f64>) -> bool {
        r.clear();
        r.push(10.0 * (x[1] - x[0] * x[0]));
        r.push(1.0 - x[0]);
        true
    }

    #[test]
    fn lm_solves_rosenbrock() {
        let res = levenberg_marquardt(
            rosenbrock_res,
            &[-1.2, 1.0],
            &[1.0, 1.0],
            Objective::Squares,
            LmOptions::default(),
        )
        .unwrap();
        assert!(
            (res.x[0] - 1.0).abs() < 1e-6 && (res.x[1] - 1.0).abs() < 1e-6,
            "{res:?}"
        );
    }

    #[test]
    fn sum_of_norms_finds_geometric_median() {
        // The point minimising the sum of distances to four points of a square and a far
        // outlier stays near the square's centre (a least-squares fit would move towards it).
        let pts = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (30.0, 30.0)];
        let f = |x: &[f64], r: &mut Vec<f64>| {
            r.clear();
            for p in pts {
                r.push(x[0] - p.0);
                r.push(x[1] - p.1);
            }
            true
        };
        let ls = levenberg_marquardt(
            f,
            &[3.0, 2.0],
            &[1.0, 1.0],
            Objective::Squares,
            LmOptions::default(),
        )
        .unwrap();
        assert!((ls.x[0] - 6.4).abs() < 1e-6);
        let l1 = levenberg_marquardt(
            f,
            &[3.0, 2.0],
            &[1.0, 1.0],
            Objective::SumOfNorms,
            LmOptions::default(),
        )
        .unwrap();
        let nm = nelder_mead(
            |x| {
                let mut r = Vec::new();
                f(x, &mut r);
                Some(objective(Objective::SumOfNorms, &r))
            },
            &[3.0, 2.0],
            &[0.5, 0.5],
            NmOptions::default(),
        );
        assert!((l1.cost - nm.cost).abs() < 1e-7, "{l1:?} {nm:?}");
        assert!(
            (l1.x[0] - nm.x[0]).abs() < 1e-4 && (l1.x[1] - nm.x[1]).abs() < 1e-4,
            "{l1:?} {nm:?}"
        );
        assert!(l1.x[0] < 0.8 && l1.x[0] > 0.5, "{l1:?}");
    }
}
