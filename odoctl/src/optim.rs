//! Small dense optimisers for the calibration: Levenberg-Marquardt on a residual vector, its
//! iteratively reweighted form that minimises a sum of Euclidean norms (eq 16 of the paper is
//! the sum of the horizontal distances, not of their squares), and Nelder-Mead with restarts.
//!
//! Residual functions write their residuals into a vector and return `false` when the
//! parameters are not admissible (for example outside `ChassisParams::validate`'s ranges).
//! Jacobians are numerical (central differences) or, with [`levenberg_marquardt_jac`],
//! supplied by the residual function itself (the calibration's forward sensitivities).

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
    /// Stop, without evaluating the trial, when the step's predicted reduction (of the
    /// Gauss-Newton model, or of the IRLS majoriser for the sum of norms) is below this
    /// fraction of the objective; 0 = off. Set it at the objective's own noise level (a
    /// fixed-point integrator's cost is not smooth below about 1e-7 relative) so that the
    /// fit stops where no real progress is left instead of shrinking the step 30 times.
    pub pred_tol: f64,
    /// For [`Objective::SumOfNorms`]: use the Gauss-Newton Hessian of the norms,
    /// `J^T (I - u u^T) J / |r|` per pair (`u = r/|r|`), instead of the IRLS majoriser
    /// `J^T J / |r|`. The gradient is the same; the majoriser converges linearly and slowly
    /// when the residuals are large (a long run's drift), the Newton model quadratically
    /// near the minimum. Steps are still accepted only when the sum of norms falls.
    pub newton: bool,
    /// Initial damping (relative to the diagonal): small when starting near the minimum.
    pub lambda0: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self {
            max_iter: 100,
            ftol: 1e-12,
            xtol: 1e-11,
            diff_step: 1e-5,
            max_step: 0.25,
            pred_tol: 0.0,
            newton: false,
            lambda0: 1e-3,
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
/// steps and the step test use it). The Jacobian is numerical (central differences, `2n`
/// extra evaluations per iteration); [`levenberg_marquardt_jac`] takes an analytic one.
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
    let mut extra = 0;
    let (mut rp, mut rm) = (Vec::new(), Vec::new());
    let mut res = lm_core(
        |x: &[f64], r: &mut Vec<f64>, jac: Option<&mut Vec<f64>>| match jac {
            // Asked at the current point, whose residuals `r` already holds.
            Some(jac) => {
                extra += central_differences(
                    &mut f,
                    x,
                    r,
                    scale,
                    opts.diff_step,
                    (&mut rp, &mut rm),
                    jac,
                );
                true
            }
            None => f(x, r),
        },
        x0,
        scale,
        kind,
        opts,
        false,
    )?;
    res.evaluations += extra;
    Some(res)
}

/// [`levenberg_marquardt`] with an analytic Jacobian: `f(x, r, jac)` writes the residuals
/// into `r` and, when `jac` is given, the Jacobian `d r_i / d x_j` into it (row-major,
/// `r.len()` rows of `x.len()`), in the same pass; it returns `false` when `x` is not
/// admissible. The Jacobian is requested at every trial point (it is taken to cost about as
/// much as the residuals), so an accepted step needs no further evaluation.
pub fn levenberg_marquardt_jac<F>(
    f: F,
    x0: &[f64],
    scale: &[f64],
    kind: Objective,
    opts: LmOptions,
) -> Option<OptResult>
where
    F: FnMut(&[f64], &mut Vec<f64>, Option<&mut Vec<f64>>) -> bool,
{
    lm_core(f, x0, scale, kind, opts, true)
}

/// Central-difference Jacobian of `f` at `x` (residuals `r` there) into `jac` (row-major);
/// returns the number of evaluations.
fn central_differences<F>(
    f: &mut F,
    x: &[f64],
    r: &[f64],
    scale: &[f64],
    diff_step: f64,
    (rp, rm): (&mut Vec<f64>, &mut Vec<f64>),
    jac: &mut Vec<f64>,
) -> usize
where
    F: FnMut(&[f64], &mut Vec<f64>) -> bool,
{
    let (m, n) = (r.len(), x.len());
    jac.clear();
    jac.resize(m * n, 0.0);
    for j in 0..n {
        let h = diff_step * scale[j];
        let mut xp = x.to_vec();
        xp[j] += h;
        let mut xm = x.to_vec();
        xm[j] -= h;
        let okp = f(&xp, rp) && rp.len() == m;
        let okm = f(&xm, rm) && rm.len() == m;
        for i in 0..m {
            jac[i * n + j] = match (okp, okm) {
                (true, true) => (rp[i] - rm[i]) / (2.0 * h),
                (true, false) => (rp[i] - r[i]) / h,
                (false, true) => (r[i] - rm[i]) / h,
                (false, false) => 0.0,
            };
        }
    }
    2 * n
}

/// The normal equations `J^T W J`, `J^T W r` of `kind`'s weights (1 for squares, `1/|r_k|`
/// per pair for the sum of norms: the IRLS majoriser).
fn normal_equations(
    kind: Objective,
    newton: bool,
    r: &[f64],
    jac: &[f64],
    n: usize,
) -> (Vec<f64>, Vec<f64>) {
    let mut jtj = vec![0.0; n * n];
    let mut jtr = vec![0.0; n];
    let floor = 1e-9;
    let pair = match kind {
        Objective::Squares => 1,
        Objective::SumOfNorms => 2,
    };
    if newton && kind == Objective::SumOfNorms && r.len() % 2 == 0 {
        // Gradient sum J_k^T u_k; Hessian sum J_k^T (I - u_k u_k^T) J_k / |r_k|, that is
        // (v v^T) / |r_k| with v = J_k^T t_k, t_k the unit vector across r_k.
        for (k, rk) in r.chunks(2).enumerate() {
            let d = rk[0].hypot(rk[1]).max(floor);
            let (ux, uy) = (rk[0] / d, rk[1] / d);
            let (rx, ry) = (
                &jac[2 * k * n..(2 * k + 1) * n],
                &jac[(2 * k + 1) * n..(2 * k + 2) * n],
            );
            let w = 1.0 / d;
            for a in 0..n {
                jtr[a] += rx[a] * ux + ry[a] * uy;
                let va = -rx[a] * uy + ry[a] * ux;
                for b in a..n {
                    let vb = -rx[b] * uy + ry[b] * ux;
                    jtj[a * n + b] += w * va * vb;
                }
            }
        }
        for a in 0..n {
            for b in 0..a {
                jtj[a * n + b] = jtj[b * n + a];
            }
        }
        return (jtj, jtr);
    }
    for (k, rk) in r.chunks(pair).enumerate() {
        let w = match kind {
            Objective::Squares => 1.0,
            Objective::SumOfNorms => 1.0 / rk.iter().map(|v| v * v).sum::<f64>().sqrt().max(floor),
        };
        for (c, &ri) in rk.iter().enumerate() {
            let i = k * pair + c;
            let row = &jac[i * n..(i + 1) * n];
            for a in 0..n {
                let wa = w * row[a];
                jtr[a] += wa * ri;
                for b in a..n {
                    jtj[a * n + b] += wa * row[b];
                }
            }
        }
    }
    for a in 0..n {
        for b in 0..a {
            jtj[a * n + b] = jtj[b * n + a];
        }
    }
    (jtj, jtr)
}

/// The Levenberg-Marquardt iteration. With `jac_at_trials`, `f` is asked for the residuals
/// and the Jacobian at every trial point and an accepted trial's Jacobian is reused.
/// Otherwise `f(x, r, None)` evaluates residuals and `f(x, r, Some(jac))` is called once per
/// iteration at the current point with `r` holding its residuals, and must only fill `jac`
/// (its evaluations are not counted here).
fn lm_core<F>(
    mut f: F,
    x0: &[f64],
    scale: &[f64],
    kind: Objective,
    opts: LmOptions,
    jac_at_trials: bool,
) -> Option<OptResult>
where
    F: FnMut(&[f64], &mut Vec<f64>, Option<&mut Vec<f64>>) -> bool,
{
    let n = x0.len();
    let mut x = x0.to_vec();
    let mut r = Vec::new();
    let mut jac = Vec::new();
    let mut evals = 1;
    if !f(&x, &mut r, jac_at_trials.then_some(&mut jac)) {
        return None;
    }
    let mut cost = objective(kind, &r);
    let mut lambda = opts.lambda0;
    let mut iterations = 0;
    let mut converged = false;
    let mut rp = Vec::new();
    let mut jacp = Vec::new();
    let mut jac_current = jac_at_trials;
    while iterations < opts.max_iter {
        let m = r.len();
        if !jac_current && !f(&x, &mut r, Some(&mut jac)) {
            return None;
        }
        if jac.len() != m * n {
            return None;
        }
        let (jtj, jtr) = normal_equations(kind, opts.newton, &r, &jac, n);
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
            if opts.pred_tol > 0.0 {
                // Model decrease: -(2 g.dx + dx.H.dx) for squares, half that for the
                // majoriser of the sum of norms (sum of w |r + J dx|^2 / 2).
                let quad: f64 = (0..n)
                    .map(|i| dx[i] * (0..n).map(|j| jtj[i * n + j] * dx[j]).sum::<f64>())
                    .sum();
                let lin: f64 = dx.iter().zip(&jtr).map(|(d, g)| d * g).sum();
                let pred = match kind {
                    Objective::Squares => -(2.0 * lin + quad),
                    Objective::SumOfNorms => -(lin + 0.5 * quad),
                };
                if pred < opts.pred_tol * cost {
                    converged = true;
                    break;
                }
            }
            let xn: Vec<f64> = x.iter().zip(&dx).map(|(a, b)| a + b).collect();
            step_small = dx.iter().zip(scale).all(|(d, s)| d.abs() <= opts.xtol * s);
            evals += 1;
            if f(&xn, &mut rp, jac_at_trials.then_some(&mut jacp)) && rp.len() == m {
                let c = objective(kind, &rp);
                if c < cost {
                    let gain = (cost - c) / cost.max(1e-300);
                    x = xn;
                    std::mem::swap(&mut r, &mut rp);
                    if jac_at_trials {
                        std::mem::swap(&mut jac, &mut jacp);
                    }
                    jac_current = jac_at_trials;
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
        // The same with the analytic Jacobian (the identity per pair), by the IRLS majoriser
        // and by the Newton Hessian of the norms: the same minimum.
        let fj = |x: &[f64], r: &mut Vec<f64>, jac: Option<&mut Vec<f64>>| {
            if let Some(jac) = jac {
                jac.clear();
                for _ in pts {
                    jac.extend_from_slice(&[1.0, 0.0, 0.0, 1.0]);
                }
            }
            f(x, r)
        };
        for newton in [false, true] {
            let a = levenberg_marquardt_jac(
                fj,
                &[3.0, 2.0],
                &[1.0, 1.0],
                Objective::SumOfNorms,
                LmOptions {
                    newton,
                    pred_tol: 1e-14,
                    ..LmOptions::default()
                },
            )
            .unwrap();
            assert!(a.cost <= nm.cost + 1e-7, "newton {newton}: {a:?} {nm:?}");
            assert!((a.x[0] - nm.x[0]).abs() < 1e-4, "newton {newton}: {a:?}");
            assert!((a.x[1] - nm.x[1]).abs() < 1e-4, "newton {newton}: {a:?}");
        }
    }
}
