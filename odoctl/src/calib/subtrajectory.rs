//! The sub-trajectory estimator, `odoctl calibrate`'s default: the run is cut into consecutive
//! sub-trajectories of about `length` metres of reference path; on each the odometry path
//! restarts, its start position and heading fitted as nuisance parameters, while
//! `left_diameter`, `right_diameter`, `track_width` (and the antenna lever arm with
//! `--fit-antenna`) are shared. Least squares on the x and y differences between the
//! odometry's observed point ([`observed_point`]) and the reference.
//!
//! Why: over a whole run (eq 16) slip makes the heading a random walk and the position error
//! grow faster than the distance; the fit bends the chassis parameters to follow that drift,
//! and the error of the estimate grows with the log. Restarted every few metres, the drift
//! never accumulates, and every sub-trajectory adds its information: the error shrinks as
//! the log grows.
//!
//! Solution (variable projection with a Schur complement):
//! - for given chassis parameters, a sub-trajectory is integrated once (the core integrator
//!   with its forward sensitivities, [`Run::integrate_with_sensitivity`]) from its anchor at
//!   its current heading; a change of the start heading turns the whole path about its start,
//!   so the best start heading and position follow in closed form (the 2-D Procrustes
//!   rotation and translation); the path is re-integrated at the new heading when the turn
//!   exceeds [`RESTART_TURN_EXACT`]. The cost is the sum over sub-trajectories of these
//!   minima;
//! - each sub-trajectory's normal equations over (shared unknowns, heading, x, y) are summed
//!   in a [`NormalAccumulator`] and its three nuisance parameters eliminated by the Schur
//!   complement `S_j = A - B C^-1 B^T`, `g_j = g_A - B C^-1 g_C`: the shared system stays
//!   3x3 (5x5 with the lever arm) whatever the number of sub-trajectories;
//! - Levenberg-Marquardt on that reduced system, a step accepted when the cost falls; the
//!   sub-trajectories are evaluated on all cores.
//!
//! Standard errors: cluster-robust over the sub-trajectories, the linearised
//! delete-one-sub-trajectory jackknife ([`cluster_jackknife`]) from the reduced `S_j` and
//! `g_j` (the plain sandwich [`cluster_sandwich`] covers the truth less often with a few dozen
//! sub-trajectories); the formal `H^-1 s^2`, which takes every residual as independent, is
//! kept beside it for comparison.
//!
//! The trade of the length: shorter sub-trajectories follow less drift but each spends three
//! unknowns and needs turning to see the track width; longer ones carry more drift into the
//! fit. 10 m (20 s at 0.5 m/s) loses about a twentieth of the information to the nuisance
//! parameters at a slip of 0.1 % and keeps the drift at millimetres.

use anyhow::{anyhow, bail, Result};
use odo_core::odometry::ChassisParams;

use crate::optim::{self, NormalAccumulator, Objective};

use super::*;

/// Default sub-trajectory length (m of reference path).
pub const SUBTRAJECTORY_LENGTH: f64 = 10.0;

/// Common times a sub-trajectory needs after its start to be used.
const MIN_POINTS: usize = 10;

/// A path turned by up to this (rad) is taken as the re-integrated path; a larger change of
/// a start heading is integrated anew (see [`fit_restart_heading`]'s constant).
const RESTART_TURN_EXACT: f64 = 0.01;

/// The antenna lever arm of a fit: `(forward, left)` metres from the axle centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LeverArm {
    /// Measured, held.
    Fixed(f64, f64),
    /// Estimated with the geometry, from this first guess.
    Fitted(f64, f64),
}

impl Default for LeverArm {
    /// No lever arm: the reference is the axle centre.
    fn default() -> Self {
        Self::Fixed(0.0, 0.0)
    }
}

impl LeverArm {
    /// The (first) value.
    pub fn value(self) -> (f64, f64) {
        match self {
            Self::Fixed(f, l) | Self::Fitted(f, l) => (f, l),
        }
    }

    /// True when estimated.
    pub fn fitted(self) -> bool {
        matches!(self, Self::Fitted(..))
    }
}

/// Options of [`fit_subtrajectories`].
#[derive(Debug, Clone, Copy)]
pub struct SubtrajectoryOptions {
    /// Sub-trajectory length (m of reference path).
    pub length: f64,
    /// The lever arm.
    pub antenna: LeverArm,
    /// The track width (and a fitted lever arm) is estimated only when the run turns at least
    /// this much in all (rad); else held.
    pub min_turning: f64,
    /// Largest number of accepted iterations.
    pub max_iter: usize,
}

impl Default for SubtrajectoryOptions {
    /// 10 m, no lever arm, 30 degrees, 100 iterations.
    fn default() -> Self {
        Self {
            length: SUBTRAJECTORY_LENGTH,
            antenna: LeverArm::default(),
            min_turning: 30f64.to_radians(),
            max_iter: 100,
        }
    }
}

/// One sub-trajectory at the estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Subtrajectory {
    /// First and last match.
    pub a: usize,
    /// Last match.
    pub b: usize,
    /// Fitted start heading (rad, clockwise from north).
    pub heading: f64,
    /// Fitted start position of the observed point (the antenna, or the centre without a
    /// lever arm) relative to the anchor [`Run::anchor`] (m, east and north).
    pub shift: (f64, f64),
}

/// The unknowns of [`SubtrajectoryFit::std_errors`], in order.
pub const SHARED_UNKNOWNS: [&str; 5] = [
    "left_diameter",
    "right_diameter",
    "track_width",
    "antenna_forward",
    "antenna_left",
];

/// Result of [`fit_subtrajectories`].
#[derive(Debug, Clone)]
pub struct SubtrajectoryFit {
    /// The parameters with the estimated diameters and track width.
    pub params: ChassisParams,
    /// The lever arm (m; fitted or as given).
    pub antenna: (f64, f64),
    /// The sub-trajectories with their nuisance parameters.
    pub blocks: Vec<Subtrajectory>,
    /// Sum of squared horizontal distances at the estimate (m^2).
    pub cost: f64,
    /// Common times used (after each sub-trajectory's start).
    pub points: usize,
    /// Accepted iterations.
    pub iterations: usize,
    /// Passes over all sub-trajectories.
    pub evaluations: usize,
    /// Cluster-robust standard errors of [`SHARED_UNKNOWNS`] (m; `None` where held): the
    /// jackknife over the sub-trajectories.
    pub std_errors: [Option<f64>; 5],
    /// The formal standard errors for independent residuals, `H^-1 s^2` (m; `None` where
    /// held): far too small with correlated slip.
    pub independent_std_errors: [Option<f64>; 5],
    /// The cluster-robust covariance of the free unknowns (row-major, in the order of
    /// [`SHARED_UNKNOWNS`] with the held ones left out).
    pub covariance: Vec<f64>,
    /// The [`SHARED_UNKNOWNS`] index of each row (and column) of `covariance`.
    pub covariance_unknowns: Vec<usize>,
    /// RMS of the x and y residuals with the nuisance parameters' degrees of freedom taken
    /// out (m).
    pub residual_sigma: f64,
    /// False when the run turned too little for the track width, then held.
    pub track_estimated: bool,
    /// Total absolute heading change of the run (rad, from the initial estimate).
    pub turning: f64,
}

impl SubtrajectoryFit {
    /// The cluster-robust covariance of two [`SHARED_UNKNOWNS`] (m^2), `None` when either
    /// was held.
    pub fn covariance_of(&self, i: usize, j: usize) -> Option<f64> {
        let n = self.covariance_unknowns.len();
        let a = self.covariance_unknowns.iter().position(|&u| u == i)?;
        let b = self.covariance_unknowns.iter().position(|&u| u == j)?;
        self.covariance.get(a * n + b).copied()
    }
}

/// One sub-trajectory's share at given shared unknowns: its cost, its reduced normal
/// equations, and what a step of the shared unknowns does to its start heading.
#[derive(Debug, Clone)]
struct BlockEval {
    cost: f64,
    points: usize,
    /// The start heading and position at their optimum for these shared unknowns.
    heading: f64,
    shift: (f64, f64),
    /// Reduced `p x p` Hessian `A - B C^-1 B^T` (row-major) and gradient `g_A - B C^-1 g_C`.
    s: Vec<f64>,
    g: Vec<f64>,
    /// The heading's change for a step `dx` of the shared unknowns:
    /// `dh = h_const + h_lin . dx` (the heading row of `-C^-1 (g_C + B^T dx)`).
    h_const: f64,
    h_lin: Vec<f64>,
}

/// Per-point rows of one integration: observed point and reference relative to the anchor,
/// and the observed point's derivatives (shared unknowns, then the start heading).
#[derive(Clone, Copy, Default)]
struct Row {
    q: (f64, f64),
    r: (f64, f64),
    jx: [f64; MODEL_UNKNOWNS],
    jy: [f64; MODEL_UNKNOWNS],
}

/// The parameters and lever arm of a vector of shared unknowns over `cols`.
fn unpack(
    base: &ChassisParams,
    antenna: (f64, f64),
    cols: &[usize],
    x: &[f64],
) -> (ChassisParams, (f64, f64)) {
    let mut p = *base;
    let mut a = antenna;
    for (&c, &v) in cols.iter().zip(x) {
        match c {
            0 => p.left_diameter = v,
            1 => p.right_diameter = v,
            2 => p.track_width = v,
            ANTENNA_FORWARD => a.0 = v,
            ANTENNA_LEFT => a.1 = v,
            _ => unreachable!("not a shared unknown"),
        }
    }
    (p, a)
}

/// Evaluates sub-trajectory `a..=b` at `params`, `antenna` from start heading `guess`.
fn eval_block(
    run: &Run,
    params: &ChassisParams,
    antenna: (f64, f64),
    cols: &[usize],
    (a, b): (usize, usize),
    guess: f64,
    rows: &mut Vec<Row>,
) -> Option<BlockEval> {
    let p = cols.len();
    let mut all = cols.to_vec();
    all.push(3);
    let (x0, y0) = run.anchor(a);
    let mut h = guess;
    let mut phi = 0.0;
    for pass in 0..3 {
        rows.clear();
        let mut row = Row::default();
        run.integrate_with_sensitivity(params, a, b, h, |k, pose, d| {
            let (ox, oy) = observed_with_rows(pose, d, antenna, h, &all, &mut row.jx, &mut row.jy);
            let r = run.reference_at(k);
            row.q = (ox - x0, oy - y0);
            row.r = (r.x - x0, r.y - y0);
            rows.push(row);
        })
        .ok()?;
        if rows.is_empty() {
            return None;
        }
        // Procrustes: the turn about the start (clockwise by phi, as a heading change turns
        // the path) and shift that bring the path nearest the reference.
        let n = rows.len() as f64;
        let (mut qx, mut qy, mut rx, mut ry) = (0.0, 0.0, 0.0, 0.0);
        for w in rows.iter() {
            qx += w.q.0;
            qy += w.q.1;
            rx += w.r.0;
            ry += w.r.1;
        }
        let (qx, qy, rx, ry) = (qx / n, qy / n, rx / n, ry / n);
        let (mut dot, mut cross) = (0.0, 0.0);
        for w in rows.iter() {
            let (ux, uy) = (w.q.0 - qx, w.q.1 - qy);
            let (vx, vy) = (w.r.0 - rx, w.r.1 - ry);
            dot += vx * ux + vy * uy;
            cross += vx * uy - vy * ux;
        }
        phi = cross.atan2(dot);
        if phi.abs() <= RESTART_TURN_EXACT || pass == 2 {
            break;
        }
        h += phi;
    }
    let (s, c) = phi.sin_cos();
    let turn = |x: f64, y: f64| (x * c + y * s, -x * s + y * c);
    let n = rows.len() as f64;
    let (mut tx, mut ty) = (0.0, 0.0);
    for w in rows.iter() {
        let (px, py) = turn(w.q.0, w.q.1);
        tx += w.r.0 - px;
        ty += w.r.1 - py;
    }
    let shift = (tx / n, ty / n);
    // Normal equations over (shared, heading, shift x, shift y).
    let m = p + 3;
    let mut acc = NormalAccumulator::new(Objective::Squares, false, m);
    let (mut jx, mut jy) = ([0.0; MODEL_UNKNOWNS + 3], [0.0; MODEL_UNKNOWNS + 3]);
    for w in rows.iter() {
        let (px, py) = turn(w.q.0, w.q.1);
        for j in 0..=p {
            (jx[j], jy[j]) = turn(w.jx[j], w.jy[j]);
        }
        (jx[p + 1], jy[p + 1], jx[p + 2], jy[p + 2]) = (1.0, 0.0, 0.0, 1.0);
        acc.add_pair(px + shift.0 - w.r.0, py + shift.1 - w.r.1, &jx, &jy);
    }
    let cost = acc.cost();
    if !cost.is_finite() {
        return None;
    }
    let (hess, grad) = acc.equations();
    // Schur complement of the nuisance block C (rows/columns p..p+3).
    let mut cm = vec![0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            cm[i * 3 + j] = hess[(p + i) * m + p + j];
        }
    }
    for i in 0..3 {
        cm[i * 3 + i] += 1e-12 * (1.0 + cm[i * 3 + i]);
    }
    let cinv = inverse(&cm, 3)?;
    let bm = |i: usize, j: usize| hess[i * m + p + j];
    // K = C^-1 B^T (3 x p), k0 = C^-1 g_C.
    let mut kmat = vec![0.0; 3 * p];
    let mut k0 = [0.0; 3];
    for i in 0..3 {
        for j in 0..3 {
            k0[i] += cinv[i * 3 + j] * grad[p + j];
            for l in 0..p {
                kmat[i * p + l] += cinv[i * 3 + j] * bm(l, j);
            }
        }
    }
    let mut sred = vec![0.0; p * p];
    let mut gred = vec![0.0; p];
    for i in 0..p {
        gred[i] = grad[i] - (0..3).map(|j| bm(i, j) * k0[j]).sum::<f64>();
        for l in 0..p {
            sred[i * p + l] =
                hess[i * m + l] - (0..3).map(|j| bm(i, j) * kmat[j * p + l]).sum::<f64>();
        }
    }
    Some(BlockEval {
        cost,
        points: rows.len(),
        heading: h + phi,
        shift,
        s: sred,
        g: gred,
        h_const: -k0[0],
        h_lin: (0..p).map(|l| -kmat[l]).collect(),
    })
}

/// Evaluates every sub-trajectory, spread over the cores (the same results, in order, as one
/// after the other); `None` when the parameters are not admissible.
fn eval_all(
    run: &Run,
    params: &ChassisParams,
    antenna: (f64, f64),
    cols: &[usize],
    blocks: &[(usize, usize)],
    headings: &[f64],
) -> Option<Vec<BlockEval>> {
    params.validate().ok()?;
    let threads = cores().min(blocks.len()).max(1);
    let chunk = blocks.len().div_ceil(threads);
    std::thread::scope(|scope| {
        let jobs: Vec<_> = blocks
            .chunks(chunk)
            .zip(headings.chunks(chunk))
            .map(|(bl, hs)| {
                scope.spawn(move || {
                    let mut rows = Vec::new();
                    bl.iter()
                        .zip(hs)
                        .map(|(&ab, &h)| eval_block(run, params, antenna, cols, ab, h, &mut rows))
                        .collect::<Option<Vec<_>>>()
                })
            })
            .collect();
        jobs.into_iter()
            .map(|j| j.join().expect("sub-trajectory evaluation panicked"))
            .collect::<Option<Vec<_>>>()
    })
    .map(|v| v.concat())
}

/// Stop when the predicted relative reduction of the cost falls below this (the
/// fixed-point integrator's cost is not smooth below about 1e-7 of it).
const PRED_TOL: f64 = 1e-10;

/// Largest step of one iteration, as a fraction of each unknown's scale.
const MAX_STEP: f64 = 0.1;

/// Estimates the shared unknowns by the sub-trajectory method of the module documentation,
/// from `start` (its diameters and track width) and `opts.antenna`.
pub fn fit_subtrajectories(
    run: &Run,
    start: &ChassisParams,
    opts: SubtrajectoryOptions,
) -> Result<SubtrajectoryFit> {
    start
        .validate()
        .map_err(|e| anyhow!("initial parameters: {e}"))?;
    if !(opts.length > 0.0 && opts.length.is_finite()) {
        bail!(
            "sub-trajectory length {}: must be a positive number of metres",
            opts.length
        );
    }
    let blocks = windows(run, opts.length, MIN_POINTS);
    if blocks.len() < 2 {
        bail!(
            "the run is too short for sub-trajectories of {} m ({} of at least {} m with {MIN_POINTS} points; at least 2): use a shorter --subtrajectory-length or --method paper",
            opts.length,
            blocks.len(),
            0.5 * opts.length
        );
    }
    let antenna0 = opts.antenna.value();
    let last = run.len() - 1;
    let h0 = run.heading_guess(0);
    let turned = turning(run, start, 0, last, h0);
    let track_estimated = turned >= opts.min_turning;
    let mut cols = vec![0, 1];
    if track_estimated {
        cols.push(2);
    }
    if opts.antenna.fitted() {
        if !track_estimated {
            bail!(
                "the run turned {:.0} deg in all: too little to estimate the antenna lever arm (--fit-antenna needs {:.0})",
                turned.to_degrees(),
                opts.min_turning.to_degrees()
            );
        }
        cols.extend([ANTENNA_FORWARD, ANTENNA_LEFT]);
    }
    let p = cols.len();
    let mut x: Vec<f64> = cols
        .iter()
        .map(|&c| match c {
            0 => start.left_diameter,
            1 => start.right_diameter,
            2 => start.track_width,
            ANTENNA_FORWARD => antenna0.0,
            _ => antenna0.1,
        })
        .collect();
    let scale: Vec<f64> = cols
        .iter()
        .map(|&c| match c {
            0 => start.left_diameter,
            1 => start.right_diameter,
            2 => start.track_width,
            _ => start.track_width,
        })
        .collect();
    let headings: Vec<f64> = blocks.iter().map(|&(a, _)| run.heading_guess(a)).collect();
    let at = |x: &[f64]| unpack(start, antenna0, &cols, x);
    let (pp, aa) = at(&x);
    let mut evals = eval_all(run, &pp, aa, &cols, &blocks, &headings)
        .ok_or_else(|| anyhow!("initial parameters: a sub-trajectory could not be evaluated"))?;
    let mut evaluations = 1;
    let mut cost: f64 = evals.iter().map(|e| e.cost).sum();
    let mut lambda = 1e-6;
    let mut iterations = 0;
    'outer: while iterations < opts.max_iter {
        let mut s = vec![0.0; p * p];
        let mut g = vec![0.0; p];
        for e in &evals {
            s.iter_mut().zip(&e.s).for_each(|(a, b)| *a += b);
            g.iter_mut().zip(&e.g).for_each(|(a, b)| *a += b);
        }
        let mut accepted = false;
        for _ in 0..30 {
            let mut m = s.clone();
            for d in 0..p {
                m[d * p + d] += lambda * (s[d * p + d] + 1e-12 * (1.0 + s[d * p + d]));
            }
            let Some(mut dx) = optim::solve(m, g.iter().map(|v| -v).collect()) else {
                lambda *= 10.0;
                continue;
            };
            let worst = dx
                .iter()
                .zip(&scale)
                .map(|(d, s)| d.abs() / s)
                .fold(0.0, f64::max);
            if worst > MAX_STEP {
                dx.iter_mut().for_each(|d| *d *= MAX_STEP / worst);
            }
            let quad: f64 = (0..p)
                .map(|i| dx[i] * (0..p).map(|j| s[i * p + j] * dx[j]).sum::<f64>())
                .sum();
            let lin: f64 = dx.iter().zip(&g).map(|(d, g)| d * g).sum();
            if -(2.0 * lin + quad) < PRED_TOL * cost {
                break 'outer;
            }
            let xn: Vec<f64> = x.iter().zip(&dx).map(|(a, b)| a + b).collect();
            let hn: Vec<f64> = evals
                .iter()
                .map(|e| {
                    e.heading + e.h_const + e.h_lin.iter().zip(&dx).map(|(a, b)| a * b).sum::<f64>()
                })
                .collect();
            let (pp, aa) = at(&xn);
            evaluations += 1;
            if let Some(trial) = eval_all(run, &pp, aa, &cols, &blocks, &hn) {
                let c: f64 = trial.iter().map(|e| e.cost).sum();
                if c < cost {
                    x = xn;
                    cost = c;
                    evals = trial;
                    lambda = (lambda / 3.0).max(1e-12);
                    accepted = true;
                    break;
                }
            }
            lambda *= 4.0;
            if lambda > 1e16 {
                break;
            }
        }
        if !accepted {
            break;
        }
        iterations += 1;
    }
    let (params, antenna) = at(&x);
    // Standard errors at the estimate (the sums of the last accepted evaluation).
    let mut h = vec![0.0; p * p];
    for e in &evals {
        h.iter_mut().zip(&e.s).for_each(|(a, b)| *a += b);
    }
    let points: usize = evals.iter().map(|e| e.points).sum();
    let dof = (2 * points).saturating_sub(p + 3 * evals.len()).max(1);
    let s2 = cost / dof as f64;
    // Squares: the Hessian of the cost is 2 J^T J, its gradient 2 J^T r; the factors cancel in
    // the jackknife's shifts, and H^-1 s^2 is the usual (J^T J)^-1 s^2 on the reduced J^T J.
    let clusters: Vec<(Vec<f64>, Vec<f64>)> =
        evals.iter().map(|e| (e.s.clone(), e.g.clone())).collect();
    let robust = cluster_jackknife(&h, p, &clusters)
        .ok_or_else(|| anyhow!("the sub-trajectory fit's normal equations are singular"))?;
    let formal = independent(&h, p, s2)
        .ok_or_else(|| anyhow!("the sub-trajectory fit's normal equations are singular"))?;
    let (rse, fse) = (
        diagonal_std_errors(&robust, p),
        diagonal_std_errors(&formal, p),
    );
    let slot = |c: usize| if c >= ANTENNA_FORWARD { c - 1 } else { c };
    let mut std_errors = [None; 5];
    let mut independent_std_errors = [None; 5];
    for (j, &c) in cols.iter().enumerate() {
        std_errors[slot(c)] = Some(rse[j]);
        independent_std_errors[slot(c)] = Some(fse[j]);
    }
    Ok(SubtrajectoryFit {
        params,
        antenna,
        blocks: blocks
            .iter()
            .zip(&evals)
            .map(|(&(a, b), e)| Subtrajectory {
                a,
                b,
                heading: e.heading,
                shift: e.shift,
            })
            .collect(),
        cost,
        points,
        iterations,
        evaluations,
        std_errors,
        independent_std_errors,
        covariance: robust,
        covariance_unknowns: cols.iter().map(|&c| slot(c)).collect(),
        residual_sigma: s2.sqrt(),
        track_estimated,
        turning: turned,
    })
}
