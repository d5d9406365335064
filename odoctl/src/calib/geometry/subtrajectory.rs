//! The sub-trajectory estimator, `odoctl calibrate`'s default: the run is cut into consecutive
//! sub-trajectories of about `length` metres of reference path (every `length` metres, or
//! with [`Cuts::Straights`] on straights so that no turn is split); on each the odometry path
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
//! `g_j` (the plain sandwich [`cluster_sandwich`] covers the truth less often with a few
//! dozen sub-trajectories); the formal `H^-1 s^2`, which takes every residual as independent, is
//! kept beside it for comparison.
//!
//! The trade of the length: shorter sub-trajectories follow less drift but each spends three
//! unknowns and needs turning to see the track width; longer ones carry more drift into the
//! fit. 10 m (20 s at 0.5 m/s) loses about a twentieth of the information to the nuisance
//! parameters at a slip of 0.1 % and keeps the drift at millimetres. On a short run the
//! track width is set by the slip during the turns (docs/RESULTS.md, Calibration accuracy).
//!
//! [`observed_point`]: crate::calib::antenna::observed_point
//! [`cluster_sandwich`]: super::covariance::cluster_sandwich

use std::cell::OnceCell;

use anyhow::{anyhow, bail, Result};
use odo_unit::odometry::ChassisParams;

use crate::calib::antenna::{
    observed_with_rows, LeverArm, ANTENNA_FORWARD, ANTENNA_LEFT, MODEL_UNKNOWNS,
};
use crate::calib::heading_fit::RESTART_TURN_EXACT;
use crate::calib::pipeline::cores;
use crate::calib::run::{windows, Run};
use crate::cancel::check_this_thread;
use crate::optim::{self, NormalAccumulator, Objective};

use super::covariance::{cluster_jackknife, diagonal_std_errors, independent, inverse};
use super::turning::turning;

/// Default sub-trajectory length (m of reference path).
pub const SUBTRAJECTORY_LENGTH: f64 = 10.0;

/// Common times a sub-trajectory needs after its start to be used.
pub(crate) const MIN_POINTS: usize = 10;

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
    /// Where one sub-trajectory ends and the next begins.
    pub cuts: Cuts,
}

/// Where the run is cut into sub-trajectories.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Cuts {
    /// Every `length` metres of reference path, wherever that falls; a last piece shorter
    /// than half a length is left out (the default).
    #[default]
    Distance,
    /// Near every `length` metres (between a half and one and a half lengths), at the point
    /// farthest from any turning ([`straight_cuts`]): every arc and spin stays whole inside
    /// one sub-trajectory with straight path before and after it, where the reference fixes
    /// the heading on both sides of the turn; no piece is shorter than half a length (a
    /// short last one joins the one before). Better on the 70 m track width
    /// (docs/RESULTS.md, Calibration accuracy), not yet the default: with a few
    /// sub-trajectories its standard errors from a 10 Hz log are not always above those from the 50 Hz CSV of the same run
    /// (tests/reference.rs).
    Straights,
}

impl Default for SubtrajectoryOptions {
    /// 10 m cut by distance, no lever arm, 30 degrees, 100 iterations.
    fn default() -> Self {
        Self {
            length: SUBTRAJECTORY_LENGTH,
            antenna: LeverArm::default(),
            min_turning: 30f64.to_radians(),
            max_iter: 100,
            cuts: Cuts::default(),
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
    /// Its last evaluation, for a warm start ([`SubtrajectoryFit::warm_start`]).
    last: Kept,
}

/// Where a sub-trajectory fit left its iterations, for a fit of the same drive on more data
/// ([`fit_subtrajectories_from`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SubtrajectoryStart {
    /// The left diameter, right diameter and track width (m).
    pub geometry: [f64; 3],
    /// The lever arm: forward, left (m, chassis frame).
    pub antenna: (f64, f64),
    /// The sub-trajectories' first matches and fitted start headings (rad), by first match.
    pub headings: Vec<(usize, f64)>,
    last: Kept,
}

impl SubtrajectoryStart {
    /// The fitted start heading (rad) of the sub-trajectory that started at match `a`.
    pub fn heading_at(&self, a: usize) -> Option<f64> {
        self.headings
            .binary_search_by(|(first, _)| first.cmp(&a))
            .ok()
            .map(|i| self.headings[i].1)
    }
}

/// A fit's last evaluation: the shared unknowns (their columns and values) and each
/// sub-trajectory's first and last match, the start heading it was evaluated from, a
/// fingerprint of its data ([`block_data`]) and its evaluation.
#[derive(Debug, Clone, PartialEq, Default)]
struct Kept {
    cols: Vec<usize>,
    x: Vec<f64>,
    blocks: Vec<((usize, usize), f64, u64, BlockEval)>,
}

impl SubtrajectoryFit {
    /// Where this fit left its iterations: its estimate, its sub-trajectories' start
    /// headings and its last evaluation (taken over where a sub-trajectory and its data are
    /// the same and the fit starts at this estimate).
    pub fn warm_start(&self) -> SubtrajectoryStart {
        let p = &self.params;
        SubtrajectoryStart {
            geometry: [p.left_diameter, p.right_diameter, p.track_width],
            antenna: self.antenna,
            headings: self.blocks.iter().map(|b| (b.a, b.heading)).collect(),
            last: self.last.clone(),
        }
    }
}

/// A 64-bit fingerprint of what sub-trajectory `a..=b` is evaluated on: its samples, its
/// matches and their reference points, the lever arm.
fn block_data(run: &Run, (a, b): (usize, usize)) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut add = |v: u64| h = (h ^ v).wrapping_mul(0x0000_0100_0000_01b3);
    let (sa, sb) = (run.matches[a].0, run.matches[b].0);
    let opt = |v: Option<i64>| v.map_or(u64::MAX, |v| v as u64);
    for s in &run.samples[sa..=sb] {
        add(s.t.to_bits());
        add(s.left as u64);
        add(s.right as u64);
        add(opt(s.left_index));
        add(opt(s.right_index));
        add(s.flags.unwrap_or(u64::MAX));
    }
    for k in a..=b {
        let r = run.reference_at(k);
        add((run.matches[k].0 - sa) as u64);
        for v in [r.t, r.x, r.y, r.heading.unwrap_or(f64::NAN)] {
            add(v.to_bits());
        }
        add(r.sigma_h.unwrap_or(f64::NAN).to_bits());
    }
    add(run.antenna.0.to_bits());
    add(run.antenna.1.to_bits());
    h
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
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct BlockEval {
    pub(crate) cost: f64,
    pub(crate) points: usize,
    /// The start heading and position at their optimum for these shared unknowns.
    pub(crate) heading: f64,
    pub(crate) shift: (f64, f64),
    /// Reduced `p x p` Hessian `A - B C^-1 B^T` (row-major) and gradient `g_A - B C^-1 g_C`.
    pub(crate) s: Vec<f64>,
    pub(crate) g: Vec<f64>,
    /// The heading's change for a step `dx` of the shared unknowns:
    /// `dh = h_const + h_lin . dx` (the heading row of `-C^-1 (g_C + B^T dx)`).
    pub(crate) h_const: f64,
    pub(crate) h_lin: Vec<f64>,
}

/// Per-point rows of one integration: observed point and reference relative to the anchor,
/// and the observed point's derivatives (shared unknowns, then the start heading).
#[derive(Clone, Copy, Default)]
pub(crate) struct Row {
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
pub(crate) fn eval_block(
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

/// A match is taken as turning when the heading changes from it to the next by more than
/// this curvature (rad per metre of the chassis centre's travel; a 20 m radius) ...
const TURNING_CURVATURE: f64 = 0.05;

/// ... plus this (rad): about two increments of differential travel on a 0.57 m track.
const TURNING_FLOOR: f64 = 2e-4;

/// The clearance [`straight_cuts`] asks of a cut is capped at this fraction of the length:
/// among the points that far from any turning, the one nearest the nominal cut is taken.
const CLEARANCE_CAP: f64 = 0.25;

/// Sub-trajectories of about `length` metres of reference path cut on straights
/// ([`Cuts::Straights`]): `(first, last)` matches, consecutive (the last of one is the first
/// of the next), each with at least `min_points` matches. The turning is that of the
/// encoder counts at `params` (the diameters and track width only scale it); a match's
/// clearance is the reference path distance to the nearest turning match. Each cut is taken
/// among the matches between 0.5 and 1.5 `length` after the previous one and at least 0.5
/// `length` before the end, the one of largest clearance (capped at [`CLEARANCE_CAP`]
/// `length`), of those the nearest to `length`; a rest shorter than `length` is one piece,
/// joined to the one before when shorter than half a length, and so is the rest after a cut
/// that would leave less than half a length (except on a run of one piece, which is cut in
/// two).
pub fn straight_cuts(
    run: &Run,
    params: &ChassisParams,
    length: f64,
    min_points: usize,
) -> Vec<(usize, usize)> {
    let n = run.len();
    if n < 2 || length.is_nan() || length <= 0.0 {
        return windows(run, length, min_points);
    }
    let ticks = f64::from(params.ticks_per_rev.max(1));
    let (cl, cr) = (
        std::f64::consts::PI * params.left_diameter / ticks,
        std::f64::consts::PI * params.right_diameter / ticks,
    );
    let b = params.track_width;
    let turning: Vec<bool> = (0..n - 1)
        .map(|k| {
            let (s0, s1) = (
                &run.samples[run.matches[k].0],
                &run.samples[run.matches[k + 1].0],
            );
            let dl = (s1.left - s0.left) as f64 * cl;
            let dr = (s1.right - s0.right) as f64 * cr;
            let dh = ((dl - dr) / b).abs();
            dh > TURNING_CURVATURE * (0.5 * (dl + dr)).abs() + TURNING_FLOOR
        })
        .collect();
    // Clearance: path distance to the nearest turning step (a step k..k+1 sits at both ends).
    let mut clearance = vec![f64::INFINITY; n];
    let mut last: Option<f64> = None;
    for k in 0..n {
        if k > 0 && turning[k - 1] {
            last = Some(run.dist[k - 1]);
        }
        if k + 1 < n && turning[k] {
            last = Some(run.dist[k]);
        }
        if let Some(d) = last {
            clearance[k] = run.dist[k] - d;
        }
    }
    let mut next: Option<f64> = None;
    for k in (0..n).rev() {
        if k + 1 < n && turning[k] {
            next = Some(run.dist[k + 1]);
        }
        if k > 0 && turning[k - 1] {
            next = Some(run.dist[k]);
        }
        if let Some(d) = next {
            clearance[k] = clearance[k].min(d - run.dist[k]);
        }
    }
    let cap = CLEARANCE_CAP * length;
    let last = n - 1;
    let mut out = Vec::new();
    let mut a = 0;
    while a < last {
        let rest = run.dist[last] - run.dist[a];
        if rest < length {
            // The rest: one sub-trajectory (it joins the previous one if too short).
            if rest < 0.5 * length || last - a < min_points {
                if let Some(prev) = out.last_mut() {
                    let (_, e): &mut (usize, usize) = prev;
                    *e = last;
                }
            } else {
                out.push((a, last));
            }
            break;
        }
        // The best cut in `lo..=hi` (path distances): `(match, clearance, offset)`.
        let search = |lo: f64, hi: f64| {
            let mut best: Option<(usize, f64, f64)> = None;
            let from = a + min_points;
            for (k, (&d, &clear)) in run.dist.iter().zip(&clearance).enumerate().skip(from) {
                if d < lo {
                    continue;
                }
                if d > hi {
                    break;
                }
                let c = clear.min(cap);
                let off = (d - run.dist[a] - length).abs();
                let better = match best {
                    None => true,
                    Some((_, bc, bo)) => c > bc || (c == bc && off < bo),
                };
                if better {
                    best = Some((k, c, off));
                }
            }
            best
        };
        let lo = run.dist[a] + 0.5 * length;
        let end = run.dist[last] - 0.5 * length;
        let mut best = search(lo, run.dist[a] + 1.5 * length);
        if best.is_some_and(|(k, _, _)| run.dist[k] > end) {
            if out.is_empty() {
                // The whole run: two pieces, each at least half a length.
                best = search(lo, end);
            } else {
                // A cut would leave less than half a length: the rest is one piece.
                out.push((a, last));
                break;
            }
        }
        let Some((k, _, _)) = best else {
            // No match in range (a gap in the reference): fall back to the nominal cut.
            let b = run.last_within(a, length).max(a + 1);
            if b - a >= min_points {
                out.push((a, b));
            }
            a = b;
            continue;
        };
        out.push((a, k));
        a = k;
    }
    out
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
    fit_subtrajectories_from(run, start, opts, None)
}

/// [`fit_subtrajectories`], its iterations started from `warm` when given (an earlier fit of
/// the same drive on less data: [`SubtrajectoryStart`]; its evaluations taken over where a
/// sub-trajectory's data are the same); the step limits stay `start`'s.
pub fn fit_subtrajectories_from(
    run: &Run,
    start: &ChassisParams,
    opts: SubtrajectoryOptions,
    warm: Option<&SubtrajectoryStart>,
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
    let blocks = cut_run(run, start, &opts)?;
    let last = run.len() - 1;
    let h0 = run.heading_guess(0);
    let problem = |track_estimated: bool, turned: f64| -> Result<SharedProblem> {
        Ok(SharedProblem {
            run,
            start,
            antenna0: opts.antenna.value(),
            cols: shared_columns(track_estimated, turned, &opts)?,
            blocks: blocks.clone(),
            fingerprints: OnceCell::new(),
        })
    };
    // From a warm start that estimated the track width, the fit runs with it estimated while
    // the turning that decides it is integrated beside; again when the turning says otherwise.
    let speculated = warm.is_some_and(|w| w.last.cols.contains(&2));
    let (turned, early) = std::thread::scope(|scope| {
        let turned = scope.spawn(|| turning(run, start, 0, last, h0));
        let early = speculated.then(|| {
            let p = problem(true, f64::NAN)?;
            let minimum = p.minimise(opts.max_iter, warm)?;
            Ok::<_, anyhow::Error>((p, minimum))
        });
        (
            turned.join().expect("the turning's integration panicked"),
            early,
        )
    });
    let track_estimated = turned >= opts.min_turning;
    if let (Some(early), true) = (early, track_estimated) {
        let (p, minimum) = early?;
        return p.result(minimum, track_estimated, turned);
    }
    let p = problem(track_estimated, turned)?;
    let minimum = p.minimise(opts.max_iter, warm)?;
    p.result(minimum, track_estimated, turned)
}

/// The sub-trajectories of `opts.cuts`; at least two, else an error.
fn cut_run(
    run: &Run,
    start: &ChassisParams,
    opts: &SubtrajectoryOptions,
) -> Result<Vec<(usize, usize)>> {
    let blocks = match opts.cuts {
        Cuts::Distance => windows(run, opts.length, MIN_POINTS),
        Cuts::Straights => straight_cuts(run, start, opts.length, MIN_POINTS),
    };
    if blocks.len() < 2 {
        bail!(
            "the run is too short for sub-trajectories of {} m ({} of at least {} m with {MIN_POINTS} points; at least 2): use a shorter --subtrajectory-length or --method paper",
            opts.length,
            blocks.len(),
            0.5 * opts.length
        );
    }
    Ok(blocks)
}

/// The columns ([`MODEL_UNKNOWNS`] indices) of the shared unknowns: the diameters, the track
/// width when the run turned `turned` (rad) enough to estimate it, a fitted lever arm (an error
/// when the run turned too little for it).
fn shared_columns(
    track_estimated: bool,
    turned: f64,
    opts: &SubtrajectoryOptions,
) -> Result<Vec<usize>> {
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
    Ok(cols)
}

/// The sub-trajectory fit's least-squares problem in its shared unknowns `cols` (the
/// sub-trajectories' nuisance parameters eliminated): from `start`'s geometry and the lever
/// arm `antenna0`.
struct SharedProblem<'a> {
    run: &'a Run<'a>,
    start: &'a ChassisParams,
    antenna0: (f64, f64),
    cols: Vec<usize>,
    blocks: Vec<(usize, usize)>,
    /// The fingerprints of the blocks' data ([`block_data`]), once asked for.
    fingerprints: OnceCell<Vec<u64>>,
}

/// The minimum [`SharedProblem::minimise`] reached: the shared unknowns, the cost (m^2), the
/// sub-trajectories' evaluations there, accepted iterations and passes.
struct Minimum {
    x: Vec<f64>,
    cost: f64,
    evals: Vec<BlockEval>,
    /// The start headings `evals` were evaluated from.
    guesses: Vec<f64>,
    iterations: usize,
    evaluations: usize,
}

impl SharedProblem<'_> {
    /// The fingerprint of each block's data ([`block_data`]), spread over the cores.
    fn fingerprints(&self) -> &[u64] {
        self.fingerprints.get_or_init(|| {
            let chunk = self.blocks.len().div_ceil(cores()).max(1);
            std::thread::scope(|scope| {
                let jobs: Vec<_> = (self.blocks.chunks(chunk))
                    .map(|bl| {
                        scope.spawn(|| bl.iter().map(|&ab| block_data(self.run, ab)).collect())
                    })
                    .collect();
                jobs.into_iter()
                    .flat_map(|j| -> Vec<u64> { j.join().expect("fingerprint panicked") })
                    .collect()
            })
        })
    }

    /// The parameters and lever arm at the shared unknowns `x`.
    fn at(&self, x: &[f64]) -> (ChassisParams, (f64, f64)) {
        unpack(self.start, self.antenna0, &self.cols, x)
    }

    /// Every sub-trajectory at the shared unknowns `x` from the start headings `headings`.
    fn eval(&self, x: &[f64], headings: &[f64]) -> Option<Vec<BlockEval>> {
        let (pp, aa) = self.at(x);
        eval_all(self.run, &pp, aa, &self.cols, &self.blocks, headings)
    }

    /// The first point of [`SharedProblem::minimise`]: the shared unknowns, the
    /// sub-trajectories evaluated there and the start headings they were evaluated from;
    /// `warm`'s when given and admissible (its evaluations taken over where the point, the
    /// sub-trajectory and its data are the same; the other sub-trajectories from `warm`'s
    /// fitted heading, else their first), else `start`'s and the first headings.
    fn first_point(
        &self,
        warm: Option<&SubtrajectoryStart>,
    ) -> Result<(Vec<f64>, Vec<BlockEval>, Vec<f64>)> {
        let (start, antenna0, run) = (self.start, self.antenna0, self.run);
        let point = |g: [f64; 3], a: (f64, f64)| -> Vec<f64> {
            self.cols
                .iter()
                .map(|&c| match c {
                    0..=2 => g[c],
                    ANTENNA_FORWARD => a.0,
                    _ => a.1,
                })
                .collect()
        };
        let guess = |a: usize| run.heading_guess(a);
        if let Some(w) = warm {
            let x = point(w.geometry, w.antenna);
            if let Some(first) = self.warm_point(w, &x) {
                return Ok(first);
            }
        }
        let geometry = [start.left_diameter, start.right_diameter, start.track_width];
        let x = point(geometry, antenna0);
        let headings: Vec<f64> = self.blocks.iter().map(|&(a, _)| guess(a)).collect();
        let evals = self.eval(&x, &headings).ok_or_else(|| {
            anyhow!("initial parameters: a sub-trajectory could not be evaluated")
        })?;
        Ok((x, evals, headings))
    }

    /// [`SharedProblem::first_point`] at `warm`'s point `x`; `None` where a sub-trajectory
    /// cannot be evaluated.
    fn warm_point(
        &self,
        w: &SubtrajectoryStart,
        x: &[f64],
    ) -> Option<(Vec<f64>, Vec<BlockEval>, Vec<f64>)> {
        let same_point = w.last.cols == self.cols && w.last.x == x;
        let kept: std::collections::HashMap<(usize, usize), (f64, u64, &BlockEval)> = w
            .last
            .blocks
            .iter()
            .filter(|_| same_point)
            .map(|(ab, g, d, e)| (*ab, (*g, *d, e)))
            .collect();
        let mut evals: Vec<Option<BlockEval>> = Vec::with_capacity(self.blocks.len());
        let mut headings = Vec::with_capacity(self.blocks.len());
        let (mut fresh, mut fresh_headings) = (Vec::new(), Vec::new());
        for (&ab, &data) in self.blocks.iter().zip(self.fingerprints()) {
            match kept.get(&ab) {
                Some(&(g, d, e)) if d == data => {
                    evals.push(Some(e.clone()));
                    headings.push(g);
                }
                _ => {
                    let g = w
                        .heading_at(ab.0)
                        .unwrap_or_else(|| self.run.heading_guess(ab.0));
                    evals.push(None);
                    headings.push(g);
                    fresh.push(ab);
                    fresh_headings.push(g);
                }
            }
        }
        let (pp, aa) = self.at(x);
        let mut new = if fresh.is_empty() {
            Vec::new()
        } else {
            eval_all(self.run, &pp, aa, &self.cols, &fresh, &fresh_headings)?
        };
        new.reverse();
        let evals = evals
            .into_iter()
            .map(|e| e.or_else(|| new.pop()))
            .collect::<Option<Vec<_>>>()?;
        Some((x.to_vec(), evals, headings))
    }

    /// Levenberg-Marquardt on the reduced system from [`SharedProblem::first_point`], a step
    /// accepted when the cost falls, at most `max_iter` accepted.
    fn minimise(&self, max_iter: usize, warm: Option<&SubtrajectoryStart>) -> Result<Minimum> {
        let start = self.start;
        let p = self.cols.len();
        let (mut x, mut evals, mut guesses) = self.first_point(warm)?;
        let scale: Vec<f64> = self
            .cols
            .iter()
            .map(|&c| match c {
                0 => start.left_diameter,
                1 => start.right_diameter,
                2 => start.track_width,
                _ => start.track_width,
            })
            .collect();
        let mut evaluations = 1;
        let mut cost: f64 = evals.iter().map(|e| e.cost).sum();
        let mut lambda = 1e-6;
        let mut iterations = 0;
        'outer: while iterations < max_iter {
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
                        e.heading
                            + e.h_const
                            + e.h_lin.iter().zip(&dx).map(|(a, b)| a * b).sum::<f64>()
                    })
                    .collect();
                evaluations += 1;
                check_this_thread()?;
                if let Some(trial) = self.eval(&xn, &hn) {
                    let c: f64 = trial.iter().map(|e| e.cost).sum();
                    if c < cost {
                        x = xn;
                        cost = c;
                        evals = trial;
                        guesses = hn;
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
        Ok(Minimum {
            x,
            cost,
            evals,
            guesses,
            iterations,
            evaluations,
        })
    }

    /// The fit at `minimum`: its parameters, sub-trajectories, and the cluster-robust and
    /// formal standard errors (from the sums of its last evaluation).
    fn result(
        &self,
        minimum: Minimum,
        track_estimated: bool,
        turned: f64,
    ) -> Result<SubtrajectoryFit> {
        let Minimum {
            x,
            cost,
            evals,
            guesses,
            iterations,
            evaluations,
        } = minimum;
        let (cols, p) = (&self.cols, self.cols.len());
        let (params, antenna) = self.at(&x);
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
        let last = Kept {
            cols: cols.clone(),
            x,
            blocks: (self.blocks.iter().zip(guesses).zip(evals.iter()))
                .zip(self.fingerprints())
                .map(|(((&ab, g), e), &d)| (ab, g, d, e.clone()))
                .collect(),
        };
        Ok(SubtrajectoryFit {
            params,
            antenna,
            blocks: self
                .blocks
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
            last,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testing::run_of;
    use crate::csvio::match_times;
    use crate::simulate::{self, default_truth, PathKind, Segment, SimOptions, SimSettings};

    /// True heading change (rad) over the samples of matches `k - 1 ..= k + 1`.
    fn true_turn_at(run: &Run, truth: &[(f64, f64, f64)], k: usize) -> f64 {
        let lo = run.matches[k.saturating_sub(1)].0;
        let hi = run.matches[(k + 1).min(run.len() - 1)].0;
        (truth[hi].2 - truth[lo].2).abs()
    }

    fn check_cover(blocks: &[(usize, usize)], run: &Run, length: f64) {
        assert_eq!(blocks.first().unwrap().0, 0);
        assert_eq!(blocks.last().unwrap().1, run.len() - 1);
        for w in blocks.windows(2) {
            assert_eq!(w[0].1, w[1].0, "consecutive: {blocks:?}");
        }
        for &(a, b) in blocks {
            let l = run.dist[b] - run.dist[a];
            assert!(
                (0.5 * length - 1e-9..=2.0 * length + 1e-9).contains(&l),
                "{a}..{b}: {l} m of {length}"
            );
        }
    }

    /// Boundary table: on the estimation path (arcs and a spin) no cut of 10 or 20 m falls in
    /// a turn and every 10 m cut has straight path on both sides (5 m ones cannot avoid its
    /// 9 m arc); a path without turns is cut at the nominal
    /// lengths; a run shorter than a length is one piece, one between one and one and a half
    /// lengths two; the pieces are
    /// consecutive and cover the run.
    #[test]
    fn cuts_fall_on_straights_and_cover_the_run() {
        let s = simulate::simulate_path(
            PathKind::Estimation,
            70.0,
            default_truth(),
            SimSettings::default(),
        );
        let run = run_of(&s);
        let start = ChassisParams {
            track_width: 0.7,
            ..default_truth()
        };
        for length in [5.0, 10.0, 20.0] {
            let blocks = straight_cuts(&run, &start, length, MIN_POINTS);
            check_cover(&blocks, &run, length);
            if length < 10.0 {
                continue;
            }
            for &(_, b) in &blocks[..blocks.len() - 1] {
                assert!(
                    true_turn_at(&run, &s.truth, b) < 1e-6,
                    "{length} m: cut at {b} ({} m) turns",
                    run.dist[b]
                );
            }
            // The nominal cuts of the same length do fall in turns (what the placement is for).
            let nominal = windows(&run, length, MIN_POINTS);
            assert!(
                nominal
                    .iter()
                    .any(|&(_, b)| true_turn_at(&run, &s.truth, b) > 1e-3),
                "{length} m"
            );
        }
        // 10 m: every cut at least 1 m of straight from the nearest turn on either side.
        let blocks = straight_cuts(&run, &start, 10.0, MIN_POINTS);
        for &(_, b) in &blocks[..blocks.len() - 1] {
            for k in [run.last_within(b, 1.0), back_within(&run, b, 1.0)] {
                assert!(
                    true_turn_at(&run, &s.truth, k) < 1e-6,
                    "cut {b}: turn at {k}"
                );
            }
        }

        // A straight line: cut every `length` metres (to a match), the rest joined.
        let straight = simulate::simulate(&SimOptions {
            truth: default_truth(),
            segments: vec![Segment::Straight(46.0)],
            settings: SimSettings::default(),
        });
        let run = Run::new(
            &straight.samples,
            &straight.reference,
            match_times(&straight.samples, &straight.reference),
        );
        let blocks = straight_cuts(&run, &start, 10.0, MIN_POINTS);
        check_cover(&blocks, &run, 10.0);
        assert_eq!(blocks.len(), 5, "{blocks:?}");
        for &(a, b) in &blocks[..4] {
            assert!((run.dist[b] - run.dist[a] - 10.0).abs() < 0.05);
        }
        assert!((5.0..7.0).contains(&(run.dist[blocks[4].1] - run.dist[blocks[4].0])));
        // Between one and one and a half lengths: two pieces, each at least half a length.
        let two = straight_cuts(&run, &start, 40.0, MIN_POINTS);
        assert_eq!(two.len(), 2, "{two:?}");
        check_cover(&two, &run, 40.0);
        // Shorter than a length: one piece (too few for the fit).
        let one = straight_cuts(&run, &start, 50.0, MIN_POINTS);
        assert_eq!(one, vec![(0, run.len() - 1)]);
        assert!(fit_subtrajectories(
            &run,
            &start,
            SubtrajectoryOptions {
                length: 50.0,
                ..Default::default()
            }
        )
        .is_err());
    }

    /// Started warm from the fit of the run's first 90 %, the fit of the whole run reaches the
    /// cold fit's minimum (within 0.01 of its standard errors, and its standard errors within
    /// 1 %) in fewer evaluations; warm from its own fit, it takes over every evaluation and
    /// stops where that fit did, to the bit; a warm start that cannot be evaluated falls back
    /// to the cold one.
    #[test]
    fn a_warm_start_reaches_the_cold_minimum() {
        let s = simulate::simulate_path(
            PathKind::Random,
            300.0,
            default_truth(),
            SimSettings::default(),
        );
        let matches = match_times(&s.samples, &s.reference);
        let run = Run::new(&s.samples, &s.reference, matches.clone());
        let part = &matches[..matches.len() * 9 / 10];
        let first = Run::new(&s.samples, &s.reference, part.to_vec());
        let start = ChassisParams::DESIGNED;
        let opts = SubtrajectoryOptions::default();
        let earlier = fit_subtrajectories(&first, &start, opts).unwrap();
        let warm = earlier.warm_start();
        let cold = fit_subtrajectories(&run, &start, opts).unwrap();
        let hot = fit_subtrajectories_from(&run, &start, opts, Some(&warm)).unwrap();
        let values = |f: &SubtrajectoryFit| {
            [
                f.params.left_diameter,
                f.params.right_diameter,
                f.params.track_width,
            ]
        };
        for i in 0..3 {
            let se = cold.std_errors[i].unwrap();
            let d = (values(&hot)[i] - values(&cold)[i]).abs() / se;
            assert!(d < 0.01, "unknown {i}: {d} SE apart");
            assert!((hot.std_errors[i].unwrap() / se - 1.0).abs() < 0.01);
        }
        assert!(
            hot.evaluations < cold.evaluations,
            "{} vs {}",
            hot.evaluations,
            cold.evaluations
        );
        let again = fit_subtrajectories_from(&run, &start, opts, Some(&cold.warm_start()));
        let again = again.unwrap();
        assert_eq!((again.iterations, again.evaluations), (0, 1));
        assert_eq!(values(&again), values(&cold));
        assert_eq!(again.std_errors, cold.std_errors);
        let bad = SubtrajectoryStart {
            geometry: [-1.0, 0.26, 0.56],
            ..warm.clone()
        };
        let fallback = fit_subtrajectories_from(&run, &start, opts, Some(&bad)).unwrap();
        assert_eq!(values(&fallback), values(&cold));
        // A warm start that estimated the track width, on a run that turned too little for
        // it (here: a turning threshold above the run's): the track width is held, as cold.
        let held = SubtrajectoryOptions {
            min_turning: 1e9,
            ..opts
        };
        let cold = fit_subtrajectories(&run, &start, held).unwrap();
        let hot = fit_subtrajectories_from(&run, &start, held, Some(&warm)).unwrap();
        assert!(!cold.track_estimated && !hot.track_estimated);
        assert_eq!(hot.params.track_width, start.track_width);
        assert_eq!(hot.turning, cold.turning);
        for i in 0..2 {
            let se = cold.std_errors[i].unwrap();
            let d = (values(&hot)[i] - values(&cold)[i]).abs() / se;
            assert!(d < 0.01, "unknown {i}: {d} SE apart");
        }
    }

    /// First match `a <= b` whose path distance to match `b` is at most `length`.
    fn back_within(run: &Run, b: usize, length: f64) -> usize {
        let mut a = b;
        while a > 0 && run.dist[b] - run.dist[a - 1] <= length {
            a -= 1;
        }
        a
    }
}
