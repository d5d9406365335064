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

/// `sqrt(a^2 + b^2)` without `hypot`'s guard against overflow, which metres and radians never
/// need (libm's `hypot` takes several times as long, in the calibration's innermost loops).
#[inline(always)]
pub fn norm2(a: f64, b: f64) -> f64 {
    (a * a + b * b).sqrt()
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

/// The inverse of a symmetric 3x3 matrix; `None` when singular.
pub fn invert3(m: [[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c = |r: usize, k: usize| {
        let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
        let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
        m[r1][k1] * m[r2][k2] - m[r1][k2] * m[r2][k1]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    let scale = m[0][0] * m[1][1] * m[2][2];
    if det.abs() <= 1e-12 * scale.abs() || !det.is_finite() {
        return None;
    }
    Some([0, 1, 2].map(|r| [0, 1, 2].map(|k| c(k, r) / det)))
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
    f: F,
    x0: &[f64],
    scale: &[f64],
    kind: Objective,
    opts: LmOptions,
) -> Option<OptResult>
where
    F: FnMut(&[f64], &mut Vec<f64>) -> bool,
{
    let mut problem = Numeric {
        f,
        acc: NormalAccumulator::new(kind, opts.newton, x0.len()),
        r: Vec::new(),
        trial: Vec::new(),
        plus: Vec::new(),
        minus: Vec::new(),
        jac: Vec::new(),
        scale,
        diff_step: opts.diff_step,
        extra: 0,
    };
    let mut res = lm_core(&mut problem, x0, scale, kind, opts)?;
    res.evaluations += problem.extra;
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
    let n = x0.len();
    let mut problem = Analytic {
        f,
        acc: NormalAccumulator::new(kind, opts.newton, n),
        r: Vec::new(),
        jac: Vec::new(),
    };
    lm_core(&mut problem, x0, scale, kind, opts)
}

/// [`levenberg_marquardt_jac`] for residual functions that never store their residuals or
/// Jacobian: `f(x, acc)` feeds them, pair by pair or row by row, into the
/// [`NormalAccumulator`] it is given (cleared, for `kind` and the options' `newton`), which
/// keeps only the objective and the normal equations. A long run's evaluation then costs no
/// memory beyond its integrator, and no second pass. The same iterations, step for step, as
/// [`levenberg_marquardt_jac`] on the same residuals.
pub fn levenberg_marquardt_streamed<F>(
    f: F,
    x0: &[f64],
    scale: &[f64],
    kind: Objective,
    opts: LmOptions,
) -> Option<OptResult>
where
    F: FnMut(&[f64], &mut NormalAccumulator) -> bool,
{
    let n = x0.len();
    let mut problem = Streamed {
        f,
        current: NormalAccumulator::new(kind, opts.newton, n),
        trial: NormalAccumulator::new(kind, opts.newton, n),
    };
    lm_core(&mut problem, x0, scale, kind, opts)
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

/// Smallest residual norm taken for a sum-of-norms weight `1/|r_k|` (m).
const NORM_FLOOR: f64 = 1e-9;

/// The objective and the normal equations of residuals given one group at a time (one
/// residual, or one x/y pair for [`Objective::SumOfNorms`]) with their Jacobian rows:
/// `J^T W J` and `J^T W r` with `kind`'s weights (1 for squares, `1/|r_k|` per pair for the
/// sum of norms: the IRLS majoriser), or, with `newton`, the sum of norms' Gauss-Newton
/// Hessian `J^T (I - u u^T) J / |r|` (`u = r/|r|`) and its gradient. The sums run in the
/// order the groups come, so a vector fed group by group gives exactly [`objective`] and
/// the normal equations of the whole vector.
#[derive(Debug, Clone)]
pub struct NormalAccumulator {
    kind: Objective,
    newton: bool,
    n: usize,
    cost: f64,
    /// Upper triangle of `J^T W J` (row-major, n x n).
    jtj: Vec<f64>,
    jtr: Vec<f64>,
    residuals: usize,
}

impl NormalAccumulator {
    /// Empty sums for `n` unknowns.
    pub fn new(kind: Objective, newton: bool, n: usize) -> Self {
        Self {
            kind,
            newton,
            n,
            cost: 0.0,
            jtj: vec![0.0; n * n],
            jtr: vec![0.0; n],
            residuals: 0,
        }
    }

    /// Empties the sums.
    pub fn clear(&mut self) {
        self.cost = 0.0;
        self.jtj.iter_mut().for_each(|v| *v = 0.0);
        self.jtr.iter_mut().for_each(|v| *v = 0.0);
        self.residuals = 0;
    }

    /// The objective of the residuals added so far.
    pub fn cost(&self) -> f64 {
        self.cost
    }

    /// Number of residuals added so far.
    pub fn residuals(&self) -> usize {
        self.residuals
    }

    /// Adds the pair `(rx, ry)` with its Jacobian rows `jx`, `jy` (`n` entries each): for
    /// [`Objective::Squares`] two residuals, for [`Objective::SumOfNorms`] one norm.
    #[inline(always)]
    pub fn add_pair(&mut self, rx: f64, ry: f64, jx: &[f64], jy: &[f64]) {
        let n = self.n;
        let (jx, jy) = (&jx[..n], &jy[..n]);
        self.residuals += 2;
        match self.kind {
            Objective::Squares => {
                self.add_row(rx, jx, 1.0);
                self.add_row(ry, jy, 1.0);
            }
            Objective::SumOfNorms => {
                let norm = norm2(rx, ry);
                self.cost += norm;
                let d = norm.max(NORM_FLOOR);
                let w = 1.0 / d;
                if self.newton {
                    // Gradient sum J_k^T u_k; Hessian sum J_k^T (I - u_k u_k^T) J_k / |r_k|,
                    // that is (v v^T) / |r_k| with v = J_k^T t_k, t_k the unit vector across r_k.
                    let (ux, uy) = (rx / d, ry / d);
                    for a in 0..n {
                        self.jtr[a] += jx[a] * ux + jy[a] * uy;
                        let va = -jx[a] * uy + jy[a] * ux;
                        for b in a..n {
                            let vb = -jx[b] * uy + jy[b] * ux;
                            self.jtj[a * n + b] += w * va * vb;
                        }
                    }
                } else {
                    self.add_weighted(rx, jx, w);
                    self.add_weighted(ry, jy, w);
                }
            }
        }
    }

    /// Adds one residual `r` with its Jacobian row `j`: a squared residual, or, for the sum
    /// of norms, a group of one (its norm `|r|`, IRLS weight).
    pub fn add_single(&mut self, r: f64, j: &[f64]) {
        self.residuals += 1;
        let j = &j[..self.n];
        match self.kind {
            Objective::Squares => self.add_row(r, j, 1.0),
            Objective::SumOfNorms => {
                let norm = (r * r).sqrt();
                self.cost += norm;
                self.add_weighted(r, j, 1.0 / norm.max(NORM_FLOOR));
            }
        }
    }

    /// A squared residual: cost `r^2`, normal equations with weight `w`.
    #[inline(always)]
    fn add_row(&mut self, r: f64, j: &[f64], w: f64) {
        self.cost += r * r;
        self.add_weighted(r, j, w);
    }

    /// `w j^T j` and `w j^T r` into the sums (upper triangle).
    #[inline(always)]
    fn add_weighted(&mut self, r: f64, j: &[f64], w: f64) {
        let n = self.n;
        for a in 0..n {
            let wa = w * j[a];
            self.jtr[a] += wa * r;
            for (sum, jb) in self.jtj[a * n + a..(a + 1) * n].iter_mut().zip(&j[a..n]) {
                *sum += wa * jb;
            }
        }
    }

    /// `J^T W J` (full, symmetric, row-major) and `J^T W r`.
    pub fn equations(&self) -> (Vec<f64>, Vec<f64>) {
        let n = self.n;
        let mut jtj = self.jtj.clone();
        for a in 0..n {
            for b in 0..a {
                jtj[a * n + b] = jtj[b * n + a];
            }
        }
        (jtj, self.jtr.clone())
    }

    /// Adds a whole residual vector `r` with its Jacobian (row-major, `r.len()` rows): in
    /// groups of `kind` (pairs for the sum of norms; an odd last residual alone); the Newton
    /// form needs whole pairs, so an odd-length vector is taken with the IRLS weights.
    pub fn add_all(&mut self, r: &[f64], jac: &[f64]) {
        let n = self.n;
        let newton = self.newton;
        if self.kind == Objective::SumOfNorms && r.len() % 2 == 1 {
            self.newton = false;
        }
        let step = match self.kind {
            Objective::Squares => 1,
            Objective::SumOfNorms => 2,
        };
        for (k, rk) in r.chunks(step).enumerate() {
            let i = k * step;
            if rk.len() == 2 {
                self.add_pair(rk[0], rk[1], &jac[i * n..], &jac[(i + 1) * n..]);
            } else {
                self.add_single(rk[0], &jac[i * n..]);
            }
        }
        self.newton = newton;
    }
}

/// What [`lm_core`] asks of the problem it minimises.
trait LmProblem {
    /// Evaluates `x` as the trial point: its objective, `None` when not admissible.
    fn trial(&mut self, x: &[f64]) -> Option<f64>;
    /// The last trial becomes the current point.
    fn accept(&mut self);
    /// The normal equations at the current point `x`.
    fn equations(&mut self, x: &[f64]) -> Option<(Vec<f64>, Vec<f64>)>;
}

/// Residuals with a central-difference Jacobian, computed once per iteration at the current
/// point.
struct Numeric<'s, F> {
    f: F,
    acc: NormalAccumulator,
    r: Vec<f64>,
    trial: Vec<f64>,
    plus: Vec<f64>,
    minus: Vec<f64>,
    jac: Vec<f64>,
    scale: &'s [f64],
    diff_step: f64,
    /// Evaluations of the differences.
    extra: usize,
}

impl<F: FnMut(&[f64], &mut Vec<f64>) -> bool> LmProblem for Numeric<'_, F> {
    fn trial(&mut self, x: &[f64]) -> Option<f64> {
        let ok =
            (self.f)(x, &mut self.trial) && (self.r.is_empty() || self.trial.len() == self.r.len());
        ok.then(|| objective(self.acc.kind, &self.trial))
    }

    fn accept(&mut self) {
        std::mem::swap(&mut self.r, &mut self.trial);
    }

    fn equations(&mut self, x: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
        self.extra += central_differences(
            &mut self.f,
            x,
            &self.r,
            self.scale,
            self.diff_step,
            (&mut self.plus, &mut self.minus),
            &mut self.jac,
        );
        self.acc.clear();
        self.acc.add_all(&self.r, &self.jac);
        Some(self.acc.equations())
    }
}

/// Residuals and an analytic Jacobian at every trial, stored.
struct Analytic<F> {
    f: F,
    acc: NormalAccumulator,
    r: Vec<f64>,
    jac: Vec<f64>,
}

impl<F: FnMut(&[f64], &mut Vec<f64>, Option<&mut Vec<f64>>) -> bool> LmProblem for Analytic<F> {
    fn trial(&mut self, x: &[f64]) -> Option<f64> {
        let (n, m) = (x.len(), self.acc.residuals());
        if !(self.f)(x, &mut self.r, Some(&mut self.jac))
            || self.jac.len() != self.r.len() * n
            || (m > 0 && self.r.len() != m)
        {
            return None;
        }
        self.acc.clear();
        self.acc.add_all(&self.r, &self.jac);
        Some(self.acc.cost())
    }

    fn accept(&mut self) {}

    fn equations(&mut self, _: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
        // Only an accepted trial's sums are asked for, and none is evaluated in between.
        Some(self.acc.equations())
    }
}

/// Objective and normal equations accumulated during the evaluation.
struct Streamed<F> {
    f: F,
    current: NormalAccumulator,
    trial: NormalAccumulator,
}

impl<F: FnMut(&[f64], &mut NormalAccumulator) -> bool> LmProblem for Streamed<F> {
    fn trial(&mut self, x: &[f64]) -> Option<f64> {
        self.trial.clear();
        let m = self.current.residuals();
        let ok = (self.f)(x, &mut self.trial) && (m == 0 || self.trial.residuals() == m);
        ok.then(|| self.trial.cost())
    }

    fn accept(&mut self) {
        std::mem::swap(&mut self.current, &mut self.trial);
    }

    fn equations(&mut self, _: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
        Some(self.current.equations())
    }
}

/// The Levenberg-Marquardt iteration over `problem`.
fn lm_core(
    problem: &mut impl LmProblem,
    x0: &[f64],
    scale: &[f64],
    kind: Objective,
    opts: LmOptions,
) -> Option<OptResult> {
    let n = x0.len();
    let mut x = x0.to_vec();
    let mut evals = 1;
    let mut cost = problem.trial(&x)?;
    problem.accept();
    let mut lambda = opts.lambda0;
    let mut iterations = 0;
    let mut converged = false;
    let mut current = false;
    let mut equations = None;
    while iterations < opts.max_iter {
        if !current {
            equations = Some(problem.equations(&x)?);
            current = true;
        }
        let (jtj, jtr) = equations.as_ref()?;
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
                let lin: f64 = dx.iter().zip(jtr).map(|(d, g)| d * g).sum();
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
            if let Some(c) = problem.trial(&xn).filter(|&c| c < cost) {
                problem.accept();
                current = false;
                let gain = (cost - c) / cost.max(1e-300);
                x = xn;
                cost = c;
                lambda = (lambda / 3.0).max(1e-12);
                accepted = true;
                if gain < opts.ftol || step_small {
                    converged = true;
                }
                break;
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

/// Brent's minimisation of a function of one variable on `[a, b]` (golden sections with
/// parabolic steps; no derivatives), to an absolute tolerance `tol` in `x`. Returns
/// `(x, f(x), evaluations)`. For a unimodal `f` on the interval it finds the minimum; at an
/// end of the interval it returns that end's neighbourhood.
pub fn brent_min(mut f: impl FnMut(f64) -> f64, a: f64, b: f64, tol: f64) -> (f64, f64, usize) {
    const GOLD: f64 = 0.381_966_011_250_105_1;
    let (mut a, mut b) = if a <= b { (a, b) } else { (b, a) };
    let mut x = a + GOLD * (b - a);
    let (mut w, mut v) = (x, x);
    let mut fx = f(x);
    let (mut fw, mut fv) = (fx, fx);
    let mut evals = 1;
    let (mut d, mut e) = (0.0f64, 0.0f64);
    for _ in 0..200 {
        let m = 0.5 * (a + b);
        let tol1 = tol + 1e-12 * x.abs();
        let tol2 = 2.0 * tol1;
        if (x - m).abs() <= tol2 - 0.5 * (b - a) {
            break;
        }
        let mut golden = true;
        if e.abs() > tol1 {
            // Parabola through x, w, v.
            let r = (x - w) * (fx - fv);
            let q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            let mut q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            }
            q = q.abs();
            if p.abs() < (0.5 * q * e).abs() && p > q * (a - x) && p < q * (b - x) {
                e = d;
                d = p / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = tol1.copysign(m - x);
                }
                golden = false;
            }
        }
        if golden {
            e = if x < m { b - x } else { a - x };
            d = GOLD * e;
        }
        let u = if d.abs() >= tol1 {
            x + d
        } else {
            x + tol1.copysign(d)
        };
        let fu = f(u);
        evals += 1;
        if fu <= fx {
            if u < x {
                b = x;
            } else {
                a = x;
            }
            (v, fv, w, fw, x, fx) = (w, fw, x, fx, u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv, w, fw) = (w, fw, u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
    (x, fx, evals)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invert3_inverts_and_refuses_a_singular_matrix() {
        let m = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        let inv = invert3(m).unwrap();
        for (r, row) in m.iter().enumerate() {
            for c in 0..3 {
                let v: f64 = row.iter().zip(&inv).map(|(a, i)| a * i[c]).sum();
                assert!((v - f64::from(u8::from(r == c))).abs() < 1e-12);
            }
        }
        assert!(invert3([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_none());
    }

    #[test]
    fn brent_finds_smooth_and_kinked_minima_and_the_interval_end() {
        // (function, interval, minimiser): a parabola, a quartic, |x - 0.3| (no parabola
        // fits its kink), a minimum beyond the interval (the end is returned), a nearly
        // flat log-likelihood shape.
        type Case = (fn(f64) -> f64, f64, f64, f64);
        let cases: [Case; 5] = [
            (|x| (x - 1.7).powi(2), -5.0, 5.0, 1.7),
            (|x| (x + 0.4).powi(4) + 2.0, -3.0, 1.0, -0.4),
            (|x| (x - 0.3).abs(), -1.0, 2.0, 0.3),
            (|x| x, 2.0, 4.0, 2.0),
            (|x| x.exp() - 2.0 * x, -10.0, 10.0, 2f64.ln()),
        ];
        for (f, a, b, want) in cases {
            let (x, fx, evals) = brent_min(f, a, b, 1e-6);
            assert!((x - want).abs() < 1e-4, "{x} against {want}");
            assert!((fx - f(x)).abs() < 1e-15);
            assert!(evals < 60, "{evals} evaluations");
        }
        // A parabola converges in a few steps.
        let (_, _, evals) = brent_min(|x| 3.0 * (x - 0.25).powi(2), -4.0, 4.0, 1e-3);
        assert!(evals <= 12, "{evals}");
    }

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
            let opts = LmOptions {
                newton,
                pred_tol: 1e-14,
                ..LmOptions::default()
            };
            let a =
                levenberg_marquardt_jac(fj, &[3.0, 2.0], &[1.0, 1.0], Objective::SumOfNorms, opts)
                    .unwrap();
            assert!(a.cost <= nm.cost + 1e-7, "newton {newton}: {a:?} {nm:?}");
            assert!((a.x[0] - nm.x[0]).abs() < 1e-4, "newton {newton}: {a:?}");
            assert!((a.x[1] - nm.x[1]).abs() < 1e-4, "newton {newton}: {a:?}");
            // Streamed into the accumulator instead of stored: the same iterations exactly.
            let streamed = levenberg_marquardt_streamed(
                |x: &[f64], acc: &mut NormalAccumulator| {
                    for p in pts {
                        acc.add_pair(x[0] - p.0, x[1] - p.1, &[1.0, 0.0], &[0.0, 1.0]);
                    }
                    true
                },
                &[3.0, 2.0],
                &[1.0, 1.0],
                Objective::SumOfNorms,
                opts,
            )
            .unwrap();
            assert_eq!(streamed.x, a.x, "newton {newton}");
            assert_eq!(streamed.cost, a.cost);
            assert_eq!(
                (streamed.iterations, streamed.evaluations),
                (a.iterations, a.evaluations)
            );
        }
    }

    /// The accumulator's sums equal `objective` and the normal equations computed from the
    /// stored vectors the way the LM did before it streamed (exactly: same order of sums),
    /// for both objectives and both Hessians; a residual count that changes is refused.
    #[test]
    fn accumulated_sums_equal_the_stored_vectors() {
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let n = 3;
        let r: Vec<f64> = (0..200).map(|_| next()).collect();
        let jac: Vec<f64> = (0..200 * n).map(|_| next()).collect();
        for (kind, newton) in [
            (Objective::Squares, false),
            (Objective::SumOfNorms, false),
            (Objective::SumOfNorms, true),
        ] {
            let mut pairs = NormalAccumulator::new(kind, newton, n);
            for k in 0..100 {
                let (i, j) = (2 * k, 2 * k + 1);
                pairs.add_pair(r[i], r[j], &jac[i * n..], &jac[j * n..]);
            }
            let mut all = NormalAccumulator::new(kind, newton, n);
            all.add_all(&r, &jac);
            assert_eq!(pairs.cost(), objective(kind, &r), "{kind:?}");
            assert_eq!(pairs.equations(), all.equations());
            assert_eq!(pairs.residuals(), 200);
            let (jtj, jtr) = pairs.equations();
            // Symmetric, and the gradient of the objective (central differences along the
            // residuals' linear model r + J dx).
            for a in 0..n {
                for b in 0..n {
                    assert_eq!(jtj[a * n + b], jtj[b * n + a]);
                }
                let h = 1e-6;
                let moved = |d: f64| {
                    let rr: Vec<f64> = (0..200).map(|i| r[i] + d * jac[i * n + a]).collect();
                    objective(kind, &rr)
                };
                let g = (moved(h) - moved(-h)) / (2.0 * h);
                let g_acc = match kind {
                    Objective::Squares => 2.0 * jtr[a],
                    Objective::SumOfNorms => jtr[a],
                };
                assert!(
                    (g - g_acc).abs() < 1e-6 * (1.0 + g.abs()),
                    "{kind:?} {a}: {g} {g_acc}"
                );
            }
            pairs.clear();
            assert_eq!((pairs.cost(), pairs.residuals()), (0.0, 0));
            assert_eq!(pairs.equations(), (vec![0.0; n * n], vec![0.0; n]));
        }
        // A trial with another number of residuals than the current point is not admissible.
        let mut calls = 0;
        let res = levenberg_marquardt_streamed(
            |x: &[f64], acc: &mut NormalAccumulator| {
                calls += 1;
                let pairs = if calls == 1 { 2 } else { 3 };
                for _ in 0..pairs {
                    acc.add_pair(x[0] - 1.0, 0.5, &[1.0], &[0.0]);
                }
                true
            },
            &[0.0],
            &[1.0],
            Objective::Squares,
            LmOptions::default(),
        )
        .unwrap();
        assert_eq!((res.x, res.iterations), (vec![0.0], 0));
    }
}
