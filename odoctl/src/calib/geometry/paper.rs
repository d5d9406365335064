//! The paper's estimator (`--method paper`): eq (16) over the whole run for the diameters,
//! the track width and the initial heading, by continuation, damped Newton and an optional
//! polish; its formal and cluster-robust standard errors.

use anyhow::{anyhow, bail, Result};
use indicatif::ProgressBar;
use odo_unit::odometry::ChassisParams;

use crate::calib::antenna::{
    observed_with_rows, LeverArm, ANTENNA_FORWARD, ANTENNA_LEFT, MODEL_UNKNOWNS,
};
use crate::calib::run::Run;
use crate::calib::sensitivity::with_geometry;
use crate::optim::{self, LmOptions, NmOptions, NormalAccumulator, Objective};

use super::covariance::{cluster_jackknife, diagonal_std_errors};
use super::subtrajectory::SUBTRAJECTORY_LENGTH;
use super::turning::{track_width_warning, turning};

/// Result of the eq (16) fit.
#[derive(Debug, Clone)]
pub struct GeomFit {
    /// The parameters with the estimated diameters and track width.
    pub params: ChassisParams,
    /// The estimated initial heading (rad).
    pub heading0: f64,
    /// Eq (16) at the estimate (m).
    pub cost: f64,
    /// Number of terms of eq (16) (common times after the start).
    pub points: usize,
    /// Accepted optimiser iterations over all stages.
    pub iterations: usize,
    /// Integrator runs over all stages.
    pub evaluations: usize,
    /// Continuation stages.
    pub stages: usize,
    /// False when the stretch turned too little to determine the track width, which was
    /// then kept at its starting value.
    pub track_estimated: bool,
    /// Total absolute heading change along the stretch at the estimate (rad).
    pub turning: f64,
    /// The start position the fit used (x east, y north, m): the reference point at the
    /// first common time, or the mean over the standstill there ([`Run::anchor`]). A replay
    /// from it with `heading0` and `params` reproduces `cost`.
    pub start: (f64, f64),
    /// Standard errors of [`GEOMETRY_UNKNOWNS`](crate::calib::sensitivity::GEOMETRY_UNKNOWNS) (m, m, m, rad; `None` for an unknown that was
    /// held) for independent residuals; see [`standard_errors`]. Far too small when slip
    /// makes the residuals correlated: see `robust_std_errors`.
    pub std_errors: [Option<f64>; 4],
    /// Cluster-robust standard errors of [`GEOMETRY_UNKNOWNS`](crate::calib::sensitivity::GEOMETRY_UNKNOWNS) (see [`paper_cluster_errors`];
    /// for the sub-trajectory method, [`SubtrajectoryFit::std_errors`](super::subtrajectory::SubtrajectoryFit::std_errors), the heading `None`):
    /// what `calibrate` reports.
    pub robust_std_errors: [Option<f64>; 4],
    /// Clusters of the robust errors (stretches, or sub-trajectories).
    pub clusters: usize,
    /// The lever arm of the fit (`(forward, left)`, m): fitted, or as given.
    pub antenna: (f64, f64),
    /// Cluster-robust standard errors of a fitted lever arm (m).
    pub antenna_std_errors: Option<[f64; 2]>,
    /// Residual standard deviation `s` of the x and y differences at the estimate (m).
    pub residual_sigma: f64,
    /// Set when the trajectory turned too little to determine the track width
    /// ([`track_width_warning`]).
    pub track_warning: Option<String>,
}

/// Options of [`fit_geometry`].
#[derive(Debug, Clone, Copy)]
pub struct GeomOptions {
    /// Path length of the first continuation stage (m).
    pub first_stage: f64,
    /// Growth of the prefix per stage.
    pub stage_growth: f64,
    /// Run a Nelder-Mead polish of eq (16) after the Newton fit (off by default: it costs
    /// up to 600 integrator runs and finds only the cost's arithmetic noise, about 1e-7 of
    /// it, below the Newton minimum).
    pub polish: bool,
    /// The track width is estimated only on a stretch whose total absolute heading change
    /// reaches this (rad); on a straighter one it is not identifiable (eq 8: only turning
    /// reveals it) and is held at its current value.
    pub min_turning: f64,
    /// The antenna lever arm: held at the run's ([`Run::antenna`]) or fitted from a guess.
    pub antenna: LeverArm,
    /// Length of the stretches of the cluster-robust standard errors (m of reference path).
    pub cluster_length: f64,
}

impl Default for GeomOptions {
    fn default() -> Self {
        Self {
            first_stage: 2.0,
            stage_growth: 1.5,
            polish: false,
            min_turning: 30f64.to_radians(),
            antenna: LeverArm::Fixed(0.0, 0.0),
            cluster_length: SUBTRAJECTORY_LENGTH,
        }
    }
}

/// Stop a continuation stage's fit when the predicted relative reduction of its cost falls
/// below this: the stages only carry the estimate along the trajectory, the last fit sets it.
const STAGE_PRED_TOL: f64 = 1e-4;

/// Stop the final eq (16) fit when the predicted relative reduction falls below this: well
/// under the noise of eq (16) as the fixed-point integrator computes it (about 1e-7 of the
/// cost: position increments are rounded to 2^-32 m, transfer constants to 2^-48 m).
const FINAL_PRED_TOL: f64 = 1e-10;

/// Levenberg-Marquardt over the geometry unknowns marked free in `free` (the others held),
/// with the analytic Jacobian of [`Run::accumulate_normal`] (its columns of the free
/// unknowns).
#[allow(clippy::too_many_arguments)]
fn lm_subset(
    run: &Run,
    base: &ChassisParams,
    a: usize,
    b: usize,
    x: &[f64],
    scale: &[f64],
    free: &[bool],
    kind: Objective,
    opts: LmOptions,
) -> Option<optim::OptResult> {
    let idx: Vec<usize> = (0..x.len()).filter(|&i| free[i]).collect();
    let full = |sub: &[f64]| {
        let mut v = x.to_vec();
        for (j, &i) in idx.iter().enumerate() {
            v[i] = sub[j];
        }
        v
    };
    let sub0: Vec<f64> = idx.iter().map(|&i| x[i]).collect();
    let sub_scale: Vec<f64> = idx.iter().map(|&i| scale[i]).collect();
    let f = |s: &[f64], acc: &mut NormalAccumulator| {
        let v = full(s);
        let antenna = lever_arm_of(run, &v);
        run.accumulate_normal_with(&with_geometry(base, &v), antenna, a, b, v[3], &idx, acc)
    };
    let mut res = optim::levenberg_marquardt_streamed(f, &sub0, &sub_scale, kind, opts)?;
    res.x = full(&res.x);
    Some(res)
}

/// Estimates `left_diameter`, `right_diameter`, `track_width` and the initial heading on
/// matches `a..=b` by minimising eq (16), from `start` and `heading0`.
pub fn fit_geometry(
    run: &Run,
    start: &ChassisParams,
    heading0: f64,
    a: usize,
    b: usize,
    opts: GeomOptions,
    progress: &ProgressBar,
) -> Result<GeomFit> {
    if b < a + 4 {
        bail!(
            "too few common times to fit ({} after the start; at least 4)",
            b.saturating_sub(a)
        );
    }
    start
        .validate()
        .map_err(|e| anyhow!("initial parameters: {e}"))?;
    let mut search = Eq16Search::new(run, start, heading0, a, opts.antenna);
    let ends = continuation_ends(run, a, b, &opts);
    progress.set_length((ends.len() + 1 + usize::from(opts.polish)) as u64);
    search.continuation(&ends, opts.min_turning, progress)?;
    let mut cost = search.newton(b, progress)?;
    // (The polish varies the geometry alone: not with a fitted lever arm.)
    if opts.polish && search.x.len() == 4 {
        cost = search.polish(b, cost);
        progress.inc(1);
    }
    search.result(b, cost, ends.len(), &opts)
}

/// The last match of each continuation stage of [`fit_geometry`] on `a..=b`: the prefixes of
/// `opts.first_stage` metres of reference path, then `opts.stage_growth` times longer each,
/// of at least 4 common times; the last is `b`.
fn continuation_ends(run: &Run, a: usize, b: usize, opts: &GeomOptions) -> Vec<usize> {
    let total = run.dist[b] - run.dist[a];
    let mut ends = Vec::new();
    let mut len = opts.first_stage;
    while len < total {
        let e = run.last_within(a, len);
        if e >= a + 4 && ends.last().is_none_or(|&l| e > l) {
            ends.push(e);
        }
        len *= opts.stage_growth;
    }
    if ends.last() != Some(&b) {
        ends.push(b);
    }
    ends
}

/// Options of the continuation stages' Levenberg-Marquardt fits.
fn stage_lm() -> LmOptions {
    LmOptions {
        max_iter: 60,
        pred_tol: STAGE_PRED_TOL,
        // Light damping from the start: the trust region (max_step) bounds the first steps
        // from a poor estimate, and each stage starts near its minimum.
        lambda0: 1e-9,
        ..LmOptions::default()
    }
}

/// The eq (16) search of [`fit_geometry`] from match `a`: the estimate `x` (the
/// [`GEOMETRY_UNKNOWNS`](crate::calib::sensitivity::GEOMETRY_UNKNOWNS), then a fitted lever
/// arm), which unknowns are free, and the optimisers' counts so far.
struct Eq16Search<'a> {
    run: &'a Run<'a>,
    start: &'a ChassisParams,
    a: usize,
    x: Vec<f64>,
    scale: Vec<f64>,
    free: Vec<bool>,
    iterations: usize,
    evaluations: usize,
    debug: bool,
}

impl<'a> Eq16Search<'a> {
    /// At `start`'s geometry and `heading0`, the track width (and a fitted lever arm) held.
    fn new(
        run: &'a Run<'a>,
        start: &'a ChassisParams,
        heading0: f64,
        a: usize,
        antenna: LeverArm,
    ) -> Self {
        let mut scale = vec![
            start.left_diameter,
            start.right_diameter,
            start.track_width,
            1.0,
        ];
        let mut x = vec![
            start.left_diameter,
            start.right_diameter,
            start.track_width,
            heading0,
        ];
        // A fitted lever arm: unknowns 4 and 5 ([`ANTENNA_FORWARD`], [`ANTENNA_LEFT`]), free with
        // the track width (only turning reveals it too).
        if let LeverArm::Fitted(f, l) = antenna {
            x.extend([f, l]);
            scale.extend([1.0, 1.0]);
        }
        let mut free = vec![true, true, false, true];
        free.resize(x.len(), false);
        Self {
            run,
            start,
            a,
            x,
            scale,
            free,
            iterations: 0,
            evaluations: 0,
            debug: std::env::var_os("ODOCTL_DEBUG").is_some(),
        }
    }

    /// Levenberg-Marquardt on the squared distances over each stage `a..=e` of `ends`, each
    /// from the one before; the track width (and a fitted lever arm) joins once the stretch
    /// has turned `min_turning` (rad).
    fn continuation(
        &mut self,
        ends: &[usize],
        min_turning: f64,
        progress: &ProgressBar,
    ) -> Result<()> {
        let (run, start, a) = (self.run, self.start, self.a);
        for &e in ends {
            let x = &self.x;
            // The track width joins once the stretch has turned enough (it stays free after).
            if !self.free[2] && turning(run, &with_geometry(start, x), a, e, x[3]) >= min_turning {
                self.free[2..].iter_mut().for_each(|f| *f = true);
            }
            let res = lm_subset(
                run,
                start,
                a,
                e,
                x,
                &self.scale,
                &self.free,
                Objective::Squares,
                stage_lm(),
            )
            .ok_or_else(|| anyhow!("the starting parameters are not admissible"))?;
            self.x = res.x;
            self.iterations += res.iterations;
            self.evaluations += res.evaluations;
            if self.debug {
                eprintln!(
                    "stage to {e} ({:.1} m): {:?} cost {} iterations {} runs {} free {:?}",
                    run.dist[e] - run.dist[a],
                    self.x,
                    res.cost,
                    res.iterations,
                    res.evaluations,
                    self.free
                );
            }
            progress.inc(1);
        }
        Ok(())
    }

    /// Damped Newton on eq (16) itself over `a..=b`; returns eq (16) at the estimate (m).
    fn newton(&mut self, b: usize, progress: &ProgressBar) -> Result<f64> {
        let res = lm_subset(
            self.run,
            self.start,
            self.a,
            b,
            &self.x,
            &self.scale,
            &self.free,
            Objective::SumOfNorms,
            LmOptions {
                max_iter: 200,
                pred_tol: FINAL_PRED_TOL,
                newton: true,
                ..stage_lm()
            },
        )
        .ok_or_else(|| anyhow!("the fit left the admissible parameter range"))?;
        self.x = res.x;
        self.iterations += res.iterations;
        self.evaluations += res.evaluations;
        if self.debug {
            eprintln!(
                "final fit: {:?} cost {} iterations {} runs {}",
                self.x, res.cost, res.iterations, res.evaluations
            );
        }
        progress.inc(1);
        Ok(res.cost)
    }

    /// Nelder-Mead on eq (16) over `a..=b` from the estimate of eq (16) `cost`, kept when
    /// lower; returns eq (16) at the estimate (m).
    fn polish(&mut self, b: usize, cost: f64) -> f64 {
        let (run, start, a) = (self.run, self.start, self.a);
        let x = &self.x;
        let idx: Vec<usize> = (0..4).filter(|&i| self.free[i]).collect();
        let full = |sub: &[f64]| {
            let mut v = x.clone();
            for (j, &i) in idx.iter().enumerate() {
                v[i] = sub[j];
            }
            v
        };
        let sub0: Vec<f64> = idx.iter().map(|&i| x[i]).collect();
        let step: Vec<f64> = idx.iter().map(|&i| self.scale[i] * 1e-4).collect();
        let nm = optim::nelder_mead(
            |s| {
                let v = full(s);
                run.eq16(&with_geometry(start, &v), a, b, v[3])
            },
            &sub0,
            &step,
            NmOptions {
                max_evals: 600,
                ..NmOptions::default()
            },
        );
        self.evaluations += nm.evaluations;
        self.iterations += nm.iterations;
        if nm.cost < cost {
            self.x = full(&nm.x);
            nm.cost
        } else {
            cost
        }
    }

    /// The fit at the estimate over `a..=b` (eq (16) `cost`, `stages` continuation stages):
    /// its parameters, turning, standard errors and warnings.
    fn result(self, b: usize, cost: f64, stages: usize, opts: &GeomOptions) -> Result<GeomFit> {
        let (run, a, x, free) = (self.run, self.a, &self.x, &self.free);
        let params = with_geometry(self.start, x);
        let antenna = lever_arm_of(run, x);
        if opts.antenna.fitted() && !free[4] {
            bail!(
                "the stretch turned too little to estimate the antenna lever arm (--fit-antenna needs {:.0} deg)",
                opts.min_turning.to_degrees()
            );
        }
        let turned = turning(run, &params, a, b, x[3]);
        let held = [free[0], free[1], free[2], free[3]];
        let (std_errors, residual_sigma) = if x.len() == 4 {
            standard_errors(run, &params, a, b, x[3], held)
        } else {
            standard_errors_with(run, &params, antenna, a, b, x[3], free)
                .map(|(se, s)| ([se[0], se[1], se[2], se[3]], s))
        }
        .ok_or_else(|| anyhow!("the fit left the admissible parameter range"))?;
        let robust =
            paper_cluster_errors(run, &params, antenna, a, b, x[3], free, opts.cluster_length);
        let track_warning =
            track_width_warning(free[2], turned, opts.min_turning, &params, &std_errors);
        Ok(GeomFit {
            params,
            heading0: x[3],
            start: run.anchor(a),
            cost,
            points: b - a,
            iterations: self.iterations,
            evaluations: self.evaluations + 3,
            stages,
            track_estimated: free[2],
            turning: turned,
            std_errors,
            robust_std_errors: robust
                .as_ref()
                .map_or([None; 4], |(se, _)| [se[0], se[1], se[2], se[3]]),
            clusters: robust.as_ref().map_or(0, |(_, g)| *g),
            antenna,
            antenna_std_errors: robust
                .as_ref()
                .and_then(|(se, _)| Some([se.get(4).copied()??, se.get(5).copied()??])),
            residual_sigma,
            track_warning,
        })
    }
}

/// The lever arm of a geometry-fit vector: its entries 4 and 5 when it has them (fitted),
/// else the run's.
fn lever_arm_of(run: &Run, x: &[f64]) -> (f64, f64) {
    if x.len() > ANTENNA_LEFT {
        (x[ANTENNA_FORWARD], x[ANTENNA_LEFT])
    } else {
        run.antenna
    }
}

/// Cluster-robust standard errors of an eq (16) estimate over matches `a..=b` (the unknowns
/// `free`, indices as [`MODEL_UNKNOWNS`]; `None` for the held ones) and the number of
/// clusters: the run is cut into consecutive stretches of `length` metres of reference path,
/// and the linearised delete-one-stretch jackknife ([`cluster_jackknife`]) is formed from
/// each stretch's share of the Newton Hessian of eq (16) and of its gradient
/// `sum J_k^T u_k`. `None` with fewer than two
/// stretches or a singular Hessian. Eq (16)'s residuals are one drifting path, correlated
/// along the whole run, so even these errors hold only when the drift within a stretch
/// dominates (docs/RESULTS.md, Standard errors).
#[allow(clippy::too_many_arguments)]
pub fn paper_cluster_errors(
    run: &Run,
    params: &ChassisParams,
    antenna: (f64, f64),
    a: usize,
    b: usize,
    heading0: f64,
    free: &[bool],
    length: f64,
) -> Option<(Vec<Option<f64>>, usize)> {
    let idx: Vec<usize> = (0..free.len()).filter(|&i| free[i]).collect();
    let mut clusters = Clusters::new(run.dist[a], length, idx.len())?;
    let (mut jx, mut jy) = ([0.0; MODEL_UNKNOWNS], [0.0; MODEL_UNKNOWNS]);
    run.integrate_with_sensitivity(params, a, b, heading0, |k, pose, d| {
        let r = run.reference_at(k);
        let (ox, oy) = observed_with_rows(pose, d, antenna, heading0, &idx, &mut jx, &mut jy);
        clusters.add(run.dist[k], (ox - r.x, oy - r.y), &jx, &jy);
    })
    .ok()?;
    clusters.errors(&idx, free.len())
}

/// The stretches of [`paper_cluster_errors`]: one eq (16) accumulator per `length` metres of
/// reference path from `start` (m), over `p` unknowns.
struct Clusters {
    start: f64,
    length: f64,
    p: usize,
    clusters: Vec<NormalAccumulator>,
}

impl Clusters {
    /// `None` when `length` is not positive.
    fn new(start: f64, length: f64, p: usize) -> Option<Self> {
        (length > 0.0).then_some(Self {
            start,
            length,
            p,
            clusters: Vec::new(),
        })
    }

    /// The residual `r` (m) and its rows at the point `dist` metres along the reference path.
    fn add(&mut self, dist: f64, r: (f64, f64), jx: &[f64], jy: &[f64]) {
        let c = ((dist - self.start) / self.length) as usize;
        while self.clusters.len() <= c {
            let acc = NormalAccumulator::new(Objective::SumOfNorms, true, self.p);
            self.clusters.push(acc);
        }
        self.clusters[c].add_pair(r.0, r.1, jx, jy);
    }

    /// The standard errors of the unknowns `idx` (of `n`; `None` for the others) and the
    /// number of stretches with residuals.
    fn errors(mut self, idx: &[usize], n: usize) -> Option<(Vec<Option<f64>>, usize)> {
        let p = self.p;
        self.clusters.retain(|c| c.residuals() > 0);
        let mut h = vec![0.0; p * p];
        let mut parts = Vec::with_capacity(self.clusters.len());
        for c in &self.clusters {
            let (hc, gc) = c.equations();
            h.iter_mut().zip(&hc).for_each(|(a, b)| *a += b);
            parts.push((hc, gc));
        }
        let cov = cluster_jackknife(&h, p, &parts)?;
        let se = diagonal_std_errors(&cov, p);
        let mut out = vec![None; n];
        for (j, &i) in idx.iter().enumerate() {
            out[i] = Some(se[j]);
        }
        Some((out, self.clusters.len()))
    }
}

/// The start heading's formal ([`standard_errors`]) and cluster-robust
/// ([`paper_cluster_errors`], stretches of `length` m) standard errors (rad) at `params` and
/// `heading0` over the whole run, the geometry held, from one integration (the two functions'
/// results: the same points in the same order). The calibration takes them from the turned
/// path (`fit_whole_run_heading`); this is what its test compares them with.
#[cfg(test)]
pub fn heading_errors(
    run: &Run,
    params: &ChassisParams,
    heading0: f64,
    length: f64,
) -> (Option<f64>, Option<f64>) {
    let (idx, last, antenna) = ([3], run.len() - 1, run.antenna);
    let mut errors = HeadingErrors::new(run.dist[0], length);
    let (mut jx, mut jy) = ([0.0; MODEL_UNKNOWNS], [0.0; MODEL_UNKNOWNS]);
    let ok = run
        .integrate_with_sensitivity(params, 0, last, heading0, |k, pose, d| {
            let r = run.reference_at(k);
            let (ox, oy) = observed_with_rows(pose, d, antenna, heading0, &idx, &mut jx, &mut jy);
            errors.add(run.dist[k], (ox - r.x, oy - r.y), jx[0], jy[0]);
        })
        .is_ok();
    if !ok {
        return (None, None);
    }
    errors.finish()
}

/// The start heading's formal and cluster-robust standard errors (rad) accumulated from the
/// residuals and their derivatives by the start heading, the geometry held
/// ([`heading_errors`]).
pub struct HeadingErrors {
    acc: NormalAccumulator,
    clusters: Option<Clusters>,
    finite: bool,
}

impl HeadingErrors {
    /// Stretches of `length` m of reference path from `start` (m).
    pub fn new(start: f64, length: f64) -> Self {
        Self {
            acc: NormalAccumulator::new(Objective::Squares, false, 1),
            clusters: Clusters::new(start, length, 1),
            finite: true,
        }
    }

    /// The residual `r` (m) at `dist` m along the reference path and its derivatives by the
    /// start heading (m/rad).
    pub fn add(&mut self, dist: f64, r: (f64, f64), dx: f64, dy: f64) {
        self.finite &= r.0.is_finite() && r.1.is_finite();
        self.acc.add_pair(r.0, r.1, &[dx], &[dy]);
        if let Some(c) = &mut self.clusters {
            c.add(dist, r, &[dx], &[dy]);
        }
    }

    /// The formal and the cluster-robust standard error (rad).
    pub fn finish(self) -> (Option<f64>, Option<f64>) {
        let idx = [3];
        let formal = (self.finite && self.acc.cost().is_finite())
            .then(|| formal_errors(&self.acc, &idx, 4).0[3])
            .flatten();
        let clustered = self
            .clusters
            .and_then(|c| c.errors(&idx, 4))
            .and_then(|(e, _)| e[3]);
        (formal, clustered)
    }
}

/// Standard errors of the geometry unknowns ([`GEOMETRY_UNKNOWNS`](crate::calib::sensitivity::GEOMETRY_UNKNOWNS)) at an eq (16) estimate
/// over matches `a..=b`, with the held ones (`free[i]` false) `None`, and the residual
/// standard deviation `s` (m). From the analytic Jacobian `J` of the x and y residuals (the
/// unknowns that were free): `cov = (J^T J)^-1 s^2`, `s^2 = sum r^2 / (m - p)` with `m` residual
/// components (two per common time) and `p` free unknowns: the least-squares approximation
/// at the eq (16) optimum, for independent residuals (odometry drift is correlated along the
/// run, so these are lower bounds of the real uncertainty; the stability study shows the
/// spread over sub-trajectories). An unknown that the data do not determine (`J^T J`
/// singular) gets an infinite error; `None` when the parameters are not admissible.
pub fn standard_errors(
    run: &Run,
    params: &ChassisParams,
    a: usize,
    b: usize,
    heading0: f64,
    free: [bool; 4],
) -> Option<([Option<f64>; 4], f64)> {
    standard_errors_with(run, params, run.antenna, a, b, heading0, &free)
        .map(|(se, s)| ([se[0], se[1], se[2], se[3]], s))
}

/// [`standard_errors`] with the lever arm `antenna` and any of the [`MODEL_UNKNOWNS`] free
/// (`free[i]`, one entry per unknown up to the last one of interest).
pub fn standard_errors_with(
    run: &Run,
    params: &ChassisParams,
    antenna: (f64, f64),
    a: usize,
    b: usize,
    heading0: f64,
    free: &[bool],
) -> Option<(Vec<Option<f64>>, f64)> {
    let idx: Vec<usize> = (0..free.len()).filter(|&i| free[i]).collect();
    let mut acc = NormalAccumulator::new(Objective::Squares, false, idx.len());
    if !run.accumulate_normal_with(params, antenna, a, b, heading0, &idx, &mut acc) {
        return None;
    }
    Some(formal_errors(&acc, &idx, free.len()))
}

/// The standard errors of [`standard_errors_with`] from its accumulated normal equations
/// `acc` over the unknowns `idx` (of `n`; `None` for the others), and the residual standard
/// deviation (m).
fn formal_errors(acc: &NormalAccumulator, idx: &[usize], n: usize) -> (Vec<Option<f64>>, f64) {
    let p = idx.len();
    let (jtj, _) = acc.equations();
    let m = acc.residuals();
    let s2 = acc.cost() / (m.saturating_sub(p).max(1)) as f64;
    let mut se = vec![None; n];
    for (j, &i) in idx.iter().enumerate() {
        let mut e = vec![0.0; p];
        e[j] = 1.0;
        let var = optim::solve(jtj.clone(), e).map_or(f64::INFINITY, |col| col[j] * s2);
        se[i] = Some(if var >= 0.0 {
            var.sqrt()
        } else {
            f64::INFINITY
        });
    }
    (se, s2.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testing::{run_of, sim};
    use crate::simulate::{default_truth, PathKind};

    /// The start heading's two standard errors from one integration are those of the two
    /// functions, to the bit (on a run long enough for the two-core pipeline too).
    #[test]
    fn heading_errors_are_those_of_the_two_functions() {
        for length in [30.0, 400.0] {
            let s = sim(PathKind::Random, length, 3);
            let run = run_of(&s);
            let (p, last, h0) = (default_truth(), run.len() - 1, run.heading_guess(0));
            let free = [false, false, false, true];
            let formal = standard_errors(&run, &p, 0, last, h0, free).and_then(|(e, _)| e[3]);
            let clustered = paper_cluster_errors(&run, &p, run.antenna, 0, last, h0, &free, 10.0)
                .and_then(|(e, _)| e[3]);
            assert!(formal.is_some() && clustered.is_some());
            assert_eq!(heading_errors(&run, &p, h0, 10.0), (formal, clustered));
        }
    }

    #[test]
    fn standard_errors_and_the_track_width_warning() {
        let s = sim(PathKind::Estimation, 30.0, 6);
        let run = run_of(&s);
        let last = run.len() - 1;
        let fit = fit_geometry(
            &run,
            &default_truth(),
            0.3,
            0,
            last,
            GeomOptions::default(),
            &ProgressBar::hidden(),
        )
        .unwrap();
        assert!(
            fit.track_estimated && fit.track_warning.is_none(),
            "{fit:?}"
        );
        for se in fit.std_errors {
            let se = se.unwrap();
            assert!(se > 0.0 && se < 1e-3, "{se}");
        }
        // The errors scale with the residual sigma: the same fit with all four free again.
        let (se, s) = standard_errors(&run, &fit.params, 0, last, fit.heading0, [true; 4]).unwrap();
        assert_eq!(se, fit.std_errors);
        assert!(
            (s - fit.residual_sigma).abs() < 1e-15 && s > 0.004 && s < 0.02,
            "{s}"
        );
        // Held unknowns have no error; too little turning warns.
        let (se, _) = standard_errors(
            &run,
            &fit.params,
            0,
            last,
            fit.heading0,
            [true, true, false, true],
        )
        .unwrap();
        assert!(se[2].is_none() && se[0].is_some());
        let p = fit.params;
        let held = track_width_warning(false, 0.2, 0.5, &p, &fit.std_errors).unwrap();
        assert!(held.contains("not estimated"), "{held}");
        let little = track_width_warning(true, 1.0, 0.5, &p, &fit.std_errors).unwrap();
        assert!(little.contains("poorly determined"), "{little}");
        let mut loose = fit.std_errors;
        loose[2] = Some(2e-3 * p.track_width);
        assert!(track_width_warning(true, 10.0, 0.5, &p, &loose).is_some());
        assert!(track_width_warning(true, 10.0, 0.5, &p, &fit.std_errors).is_none());
    }
}
