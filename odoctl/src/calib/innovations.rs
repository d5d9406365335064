//! The covariance model's kappa by the exact likelihood of the reference's observations: an
//! error-state Kalman filter along the whole run, scored on its innovations (the
//! prediction-error decomposition).
//!
//! The odometry is integrated once from the run's start (the reference position, averaged over
//! the opening standstill; the reference heading averaged there, or eq (16)'s start heading
//! without reference headings). The state is the odometry's error `(dx, dy, dalpha)`, the
//! relative errors of the geometry just fitted, `(c_1, c_2, b)` (the two wheels' distance
//! scales and the track width), and the two wheels' relative slip `(e_1, e_2)`. Each sample
//! moves it by the linearised odometry: `F` (the Jacobian by the previous pose, as the core's
//! covariance model), the wheel-distance errors `(c_i + e_i) s_i`, the heading error
//! `-b dalpha` of a track-width error. The slip is either white (process noise
//! `J diag(kappa |s_1|, kappa |s_2|) J^T`, the core's covariance model) or Gauss-Markov over
//! the distance rolled, of correlation length `L` and variance `kappa / (2 L)`, which has the
//! same long-range variance `kappa d` of the distance error over `d >> L`. The reference's
//! epochs are averaged over each metre of path ([`OBSERVATION_BLOCK`]) into one observation of
//! `(dx, dy)` (noise: the epochs' own sigmas, else `--reference-sigma`, over their number) and,
//! where they have headings, of `dalpha` (`--reference-heading-sigma-deg`). The
//! log-likelihood is `-1/2 sum (ln det S_k + v_k^T S_k^-1 v_k)` over the innovations `v_k`:
//! each is scored on a prediction from the observations before it only, so nothing a point is
//! judged on was fitted to it, neither a start heading nor the geometry (the filter carries
//! the geometry's errors with a wide prior: the errors the eq (16) fit absorbed on this run
//! are not taken for an absence of slip).
//!
//! The filter runs over the steps of 5 cm ([`MERGED_STEP`]) between two observations composed
//! into one transition (`filter_blocks`), so a score costs one prediction and one update per
//! observation; a run longer than [`MAX_OBSERVATIONS`] metres uses a share of its
//! observations. The fit of the slip on this likelihood is `slip_fit`.

// Dense 9x9 matrix arithmetic reads best by index.
#![allow(clippy::needless_range_loop)]

use anyhow::{anyhow, Result};
use odo_core::odometry::{ChassisParams, Pose};

use crate::replay::{counts, index_refs};
use crate::stats::wrap_angle;

use super::filter_blocks::{Composed, GaussMarkovBlock, StepTerms};
use super::*;

/// Prior standard deviation of the geometry's relative errors in the filter: wide against
/// what a calibration leaves (1e-4 .. 1e-3), so the likelihood does not depend on it.
const GEOMETRY_PRIOR: f64 = 1e-2;

/// One sample's motion and, where it has one, the reference observation after it.
#[derive(Debug, Clone, Copy)]
struct Step {
    /// Chord (m), heading change (rad), chord direction (rad).
    chord: f64,
    dalpha: f64,
    mid: f64,
    /// Wheel distances (m).
    s: [f64; 2],
    /// Wheel distances rolled, summed over the samples merged into the step (m): what the
    /// slip's variance grows with.
    rolled: [f64; 2],
    /// `|s_1 - s_2|` summed over the merged samples (m).
    rolled_diff: f64,
    /// Observation after the step: position innovation base (reference - odometry, m),
    /// its noise variance per axis (m^2), heading difference (rad).
    obs: Option<Obs>,
}

#[derive(Debug, Clone, Copy)]
struct Obs {
    dx: f64,
    dy: f64,
    r: f64,
    dh: Option<f64>,
    /// Noise variance of `dh` (rad^2).
    rh: f64,
}

/// Reference path over which the filter's observations are averaged (m): one observation per
/// metre (at most [`BLOCK_TIME`]), the mean of the reference's epochs minus the odometry,
/// applied at the block's middle sample with its noise divided by their number. What the
/// ensemble test (`tests/uncertainty_ensemble.rs`) was measured with. Of runs longer than
/// [`MAX_OBSERVATIONS`] of them, a share is used.
pub const OBSERVATION_BLOCK: f64 = 1.0;

/// Longest time one averaged observation spans (s): a standstill is not one observation.
const BLOCK_TIME: f64 = 2.0;

/// Most observations the filter takes from one run: of a longer run's blocks, only every
/// second, third, ... is observed (the steps between composed through), which keeps the
/// likelihood's cost of a long log to that of a 1 km one (each score runs once per
/// observation). The estimate stays unbiased (the likelihood of a subset of the data) and
/// loses precision: on 70 m runs with the truth's geometry, every second or third observation
/// gave `ln(kappa / q^2)` within -0.97..0.84 against -0.29..0.38 with all of them
/// (`the_filter_likelihood_recovers_kappa_with_the_true_geometry`'s nine runs).
pub const MAX_OBSERVATIONS: f64 = 1000.0;

/// Shortest centre distance of one filter step (m): consecutive samples are merged into one
/// step (never across an observation) until it rolled this far, which makes the filter run
/// over a 50 Hz log 10 times faster at 1 m/s; its first-order transition over 0.2 m of arc
/// is what each sample's was.
const MERGED_STEP: f64 = 0.05;

/// The reference epochs of one block, summed.
#[derive(Debug, Clone, Default)]
struct Block {
    n: usize,
    x: f64,
    y: f64,
    r: f64,
    h: f64,
    h_first: Option<f64>,
    nh: usize,
    steps: Vec<usize>,
}

impl Block {
    fn add(&mut self, dx: f64, dy: f64, r: f64, dh: Option<f64>, step: usize) {
        self.n += 1;
        self.x += dx;
        self.y += dy;
        self.r += r;
        if let Some(h) = dh {
            let h0 = *self.h_first.get_or_insert(h);
            self.h += wrap_angle(h - h0);
            self.nh += 1;
        }
        self.steps.push(step);
    }

    /// The block's mean observation, at its middle step; empties the block.
    fn take(&mut self, rh2: f64) -> (usize, Obs) {
        let n = self.n as f64;
        let at = self.steps[self.steps.len() / 2];
        let o = Obs {
            dx: self.x / n,
            dy: self.y / n,
            r: self.r / (n * n),
            dh: self
                .h_first
                .map(|h0| wrap_angle(h0 + self.h / self.nh as f64)),
            rh: rh2 / self.nh.max(1) as f64,
        };
        *self = Self::default();
        (at, o)
    }
}

/// The run's motion and observations, ready for the likelihood of any kappa.
pub struct Innovations {
    /// The steps between observations, composed.
    composed: Composed,
    /// The observation at the end of each block.
    obs: Vec<Obs>,
    /// Initial variances of the position (per axis) and heading.
    p0: (f64, f64),
    /// Observations (positions) used.
    pub observations: usize,
}

/// What the filter gives at one `kappa`.
#[derive(Debug, Clone, Copy, Default)]
pub struct FilterScore {
    /// Negative log-likelihood (without the constant).
    pub nll: f64,
    /// Share of position innovations within 1 and 3 times `sqrt(trace S)`.
    pub horizontal: (f64, f64),
    /// Share of heading innovations within 1 and 3 sigma (NaN without headings).
    pub heading: (f64, f64),
    /// The geometry's relative errors after the last observation, `(c_1, c_2, b)`: the
    /// true wheel distance is `(1 + c_i)` times the odometry's, the true track `(1 + b)`
    /// times the one integrated with; a generalised least-squares estimate that weights each
    /// observation by the slip's noise at the kappa scored.
    pub geometry: [f64; 3],
    /// Covariance of [`FilterScore::geometry`].
    pub geometry_cov: [[f64; 3]; 3],
}

impl Step {
    /// The step's linearised motion on a track `w` (m).
    fn terms(&self, w: f64) -> StepTerms {
        let (sn, cs) = self.mid.sin_cos();
        let half_w = 0.5 / w;
        // Pose (x, y, heading) by each wheel's distance (chord ~ ds for a step's small turn).
        let g = [
            [
                0.5 * sn + self.chord * cs * half_w,
                0.5 * cs - self.chord * sn * half_w,
                1.0 / w,
            ],
            [
                0.5 * sn - self.chord * cs * half_w,
                0.5 * cs + self.chord * sn * half_w,
                -1.0 / w,
            ],
        ];
        let ge = [0, 1, 2].map(|r| g[0][r] - g[1][r]);
        let outer = |a: [f64; 3], b: [f64; 3], k: f64| a.map(|x| b.map(|y| x * y * k));
        let mut qw = outer(g[0], g[0], self.rolled[0]);
        let q2 = outer(g[1], g[1], self.rolled[1]);
        for r in 0..3 {
            for c in 0..3 {
                qw[r][c] += q2[r][c];
            }
        }
        StepTerms {
            m: [self.chord * cs, -self.chord * sn],
            wheel: [0, 1].map(|j| g[j].map(|v| v * self.s[j])),
            turn: ge.map(|v| v * self.rolled_diff),
            track: [0.0, 0.0, -self.dalpha],
            qw,
            qt: outer(ge, ge, self.rolled_diff),
            decay: [self.rolled[0], self.rolled[1], self.rolled_diff],
        }
    }
}

/// The slip the filter is run with: white or Gauss-Markov, the latter's blocks composed.
#[derive(Clone, Copy)]
pub(super) struct SlipModel<'a> {
    /// Long-range wheel-distance variance (m^2 per m rolled).
    pub kappa: f64,
    /// Wheel slip's correlation length (m) and its two states composed; `None`: white.
    pub wheels: Option<(f64, &'a [Vec<GaussMarkovBlock>; 2])>,
    /// Long-range opposite-phase variance (m^2 per m of `|s_1 - s_2|`).
    pub kappa_diff: f64,
    /// Its correlation length (m) and state composed; `None`: white.
    pub turning: Option<(f64, &'a [GaussMarkovBlock])>,
}

impl Innovations {
    /// Integrates the odometry with `geometry` over the whole run and takes the observations.
    pub fn new(
        run: &Run,
        geometry: &ChassisParams,
        heading0: f64,
        ref_sigma: f64,
        ref_heading_sigma: f64,
        block_length: f64,
    ) -> Result<Self> {
        let rh2 = ref_heading_sigma * ref_heading_sigma;
        // Every `stride`-th block's observation is used.
        let path = run.dist[run.len() - 1] - run.dist[0];
        let stride = (path / (MAX_OBSERVATIONS * block_length)).ceil().max(1.0) as usize;
        let mut blocks = 0usize;
        let r2 = |k: usize| {
            let s = run.reference_at(k).sigma_h.unwrap_or(ref_sigma);
            s * s / 2.0
        };
        // Start heading: the reference's over the opening standstill when it has headings.
        let (lo, hi) = run.standstill(0);
        let n0 = (hi - lo + 1) as f64;
        let pos_var0 = (lo..=hi).map(r2).sum::<f64>() / (n0 * n0);
        let (h0, heading_var0) = match run
            .opening_heading(geometry, heading0)
            .map_err(|e| anyhow!("parameters: {e}"))?
        {
            // One epoch's variance: the epochs averaged are observed again in the first block.
            Some((h, _)) => (h, rh2),
            None => (heading0, 1e-6),
        };
        let mut integ = run
            .start(geometry, 0, h0)
            .map_err(|e| anyhow!("parameters: {e}"))?;
        let w = geometry.track_width;
        let first = run.matches[0].0;
        let last = run.matches[run.len() - 1].0;
        let mut steps = Vec::with_capacity(last - first);
        let mut k = 1;
        let mut prev = integ.pose();
        // The step being merged: its start pose and what it rolled so far.
        let mut start = prev;
        let (mut rolled, mut rolled_diff) = ([0.0f64; 2], 0.0f64);
        // Observations of one block, averaged: (ref - odo) x, y, noise var, heading, count.
        let mut block = Block::default();
        let mut block_start = 0usize;
        let mut observations = 0;
        for i in first + 1..=last {
            let s = &run.samples[i];
            let _ = integ.step_pose(counts(s), index_refs(s));
            let p = integ.pose();
            let ws = wheel_distances(prev, p, w);
            rolled[0] += ws[0].abs();
            rolled[1] += ws[1].abs();
            rolled_diff += (ws[0] - ws[1]).abs();
            prev = p;
            // A reference epoch joins its block; the block's averaged observation goes on the
            // step holding its middle epoch, which is closed when the block ends.
            let mut block_done = false;
            if k < run.len() && run.matches[k].0 == i {
                let r = run.reference_at(k);
                if block.n == 0 {
                    block_start = k;
                }
                block.add(
                    r.x - p.x,
                    r.y - p.y,
                    r2(k),
                    r.heading.map(|h| wrap_angle(h - p.heading)),
                    steps.len(),
                );
                block_done = k + 1 >= run.len()
                    || run.dist[k + 1] - run.dist[block_start] > block_length
                    || run.reference_at(k + 1).t - run.reference_at(block_start).t > BLOCK_TIME;
                k += 1;
            }
            if block_done || 0.5 * (rolled[0] + rolled[1]) >= MERGED_STEP || i == last {
                let dalpha = p.heading - start.heading;
                let mid = start.heading + 0.5 * dalpha;
                let (ddx, ddy) = (p.x - start.x, p.y - start.y);
                let along = ddx * mid.sin() + ddy * mid.cos();
                steps.push(Step {
                    chord: ddx.hypot(ddy).copysign(along),
                    dalpha,
                    mid,
                    s: wheel_distances(start, p, w),
                    rolled,
                    rolled_diff,
                    obs: None,
                });
                start = p;
                (rolled, rolled_diff) = ([0.0; 2], 0.0);
            }
            if block_done {
                let (at, o) = block.take(rh2);
                blocks += 1;
                if blocks.is_multiple_of(stride) || k >= run.len() {
                    steps[at].obs = Some(o);
                    observations += 1;
                }
            }
        }
        // The steps after the last observation are not observed.
        let mut ends = Vec::with_capacity(observations);
        let mut obs = Vec::with_capacity(observations);
        let terms: Vec<StepTerms> = steps
            .iter()
            .enumerate()
            .map(|(i, st)| {
                if let Some(o) = st.obs {
                    ends.push(i + 1);
                    obs.push(o);
                }
                st.terms(w)
            })
            .collect();
        let used = ends.last().copied().unwrap_or(0);
        Ok(Self {
            composed: Composed::new(&terms[..used], &ends),
            obs,
            p0: (pos_var0, heading_var0),
            observations,
        })
    }

    /// Runs the filter with the wheel-distance variance `kappa` (m^2 per m rolled).
    pub fn score(&self, kappa: f64) -> FilterScore {
        self.score_correlated(kappa, 0.0)
    }

    /// Runs the filter with wheel slip of long-range variance `kappa` (m^2 per m rolled):
    /// white when `corr` is 0, else a Gauss-Markov relative slip of correlation length
    /// `corr` (m of wheel travel) and variance `kappa / (2 corr)`, whose distance error has
    /// the variance `kappa d` over `d >> corr`.
    pub fn score_correlated(&self, kappa: f64, corr: f64) -> FilterScore {
        self.score_with(kappa, corr, Turning::NONE)
    }

    /// [`Innovations::score_correlated`] with opposite-phase slip beside it ([`Turning`]).
    pub fn score_with(&self, kappa: f64, corr: f64, turning: Turning) -> FilterScore {
        let wheels = (corr > 0.0).then(|| self.wheel_slip(corr));
        let turn = (turning.corr > 0.0).then(|| self.turning_slip(turning.corr));
        self.filter(SlipModel {
            kappa,
            wheels: wheels.as_ref().map(|w| (corr, w)),
            kappa_diff: turning.kappa_diff,
            turning: turn.as_deref().map(|t| (turning.corr, t)),
        })
    }

    /// The two wheels' Gauss-Markov slip of correlation length `corr` (m) composed.
    pub(super) fn wheel_slip(&self, corr: f64) -> [Vec<GaussMarkovBlock>; 2] {
        [0, 1].map(|j| self.composed.gauss_markov(j, corr))
    }

    /// The opposite-phase Gauss-Markov slip of correlation length `corr` (m) composed.
    pub(super) fn turning_slip(&self, corr: f64) -> Vec<GaussMarkovBlock> {
        self.composed.gauss_markov(2, corr)
    }

    /// The filter over the composed blocks: one prediction and one update per observation.
    pub(super) fn filter(&self, slip: SlipModel) -> FilterScore {
        let mut p: M = [[0.0; N]; N];
        p[0][0] = self.p0.0;
        p[1][1] = self.p0.0;
        p[2][2] = self.p0.1;
        for (i, row) in p.iter_mut().enumerate().take(6).skip(3) {
            row[i] = GEOMETRY_PRIOR * GEOMETRY_PRIOR;
        }
        if let Some((corr, _)) = slip.wheels {
            p[6][6] = slip.kappa / (2.0 * corr);
            p[7][7] = p[6][6];
        }
        if let Some((corr, _)) = slip.turning {
            p[8][8] = slip.kappa_diff / (2.0 * corr);
        }
        let mut x = [0.0f64; N];
        let mut nll = 0.0;
        let (mut hn, mut h1, mut h3, mut an, mut a1, mut a3) = (0usize, 0, 0, 0usize, 0, 0);
        for (b, (base, o)) in self.composed.blocks.iter().zip(&self.obs).enumerate() {
            // The block's transition: rows 0-2 (the pose) full, the others diagonal.
            let mut phi = [[0.0; N]; 3];
            for r in 0..3 {
                phi[r][r] = 1.0;
                for c in 0..3 {
                    phi[r][3 + c] = base.g[r][c];
                }
            }
            phi[0][2] = base.r[0];
            phi[1][2] = base.r[1];
            let mut d = [1.0; N];
            let mut gm: [Option<(usize, &GaussMarkovBlock, f64)>; 3] = [None; 3];
            if let Some((_, w)) = slip.wheels {
                gm[0] = Some((6, &w[0][b], slip.kappa));
                gm[1] = Some((7, &w[1][b], slip.kappa));
            }
            if let Some((_, t)) = slip.turning {
                gm[2] = Some((8, &t[b], slip.kappa_diff));
            }
            for &(i, g, _) in gm.iter().flatten() {
                for r in 0..3 {
                    phi[r][i] = g.z[r];
                }
                d[i] = g.z[3];
            }
            // x <- Phi x, P <- Phi P Phi^T.
            let pose = [0, 1, 2].map(|r| (0..N).map(|k| phi[r][k] * x[k]).sum::<f64>());
            x[..3].copy_from_slice(&pose);
            for i in 3..N {
                x[i] *= d[i];
            }
            let mut y = p;
            for r in 0..3 {
                for c in 0..N {
                    y[r][c] = (0..N).map(|k| phi[r][k] * p[k][c]).sum();
                }
            }
            for r in 3..N {
                for c in 0..N {
                    y[r][c] = d[r] * p[r][c];
                }
            }
            for r in 0..N {
                for c in 0..3 {
                    p[r][c] = (0..N).map(|k| y[r][k] * phi[c][k]).sum();
                }
                for c in 3..N {
                    p[r][c] = y[r][c] * d[c];
                }
            }
            // The block's noise.
            let white = if slip.wheels.is_none() {
                slip.kappa
            } else {
                0.0
            };
            let white_turn = if slip.turning.is_none() {
                slip.kappa_diff
            } else {
                0.0
            };
            for r in 0..3 {
                for c in 0..3 {
                    p[r][c] += white * base.qw[r][c] + white_turn * base.qt[r][c];
                }
            }
            for &(i, g, k) in gm.iter().flatten() {
                let idx = [0, 1, 2, i];
                for (a, &ia) in idx.iter().enumerate() {
                    for (c, &ic) in idx.iter().enumerate() {
                        p[ia][ic] += k * g.q[a][c];
                    }
                }
            }
            // Position: 2-D update.
            let v = [o.dx - x[0], o.dy - x[1]];
            let s = [[p[0][0] + o.r, p[0][1]], [p[1][0], p[1][1] + o.r]];
            let det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
            if det.is_nan() || det <= 0.0 {
                return FilterScore {
                    nll: f64::INFINITY,
                    ..FilterScore::default()
                };
            }
            let si = [
                [s[1][1] / det, -s[0][1] / det],
                [-s[1][0] / det, s[0][0] / det],
            ];
            let quad = v[0] * (si[0][0] * v[0] + si[0][1] * v[1])
                + v[1] * (si[1][0] * v[0] + si[1][1] * v[1]);
            nll += 0.5 * (det.ln() + quad);
            hn += 1;
            let tr = (s[0][0] + s[1][1]).sqrt();
            let e = v[0].hypot(v[1]);
            h1 += usize::from(e <= tr);
            h3 += usize::from(e <= 3.0 * tr);
            // K = P H^T S^-1 (H picks x, y).
            let mut kg = [[0.0; 2]; N];
            for (r, kr) in kg.iter_mut().enumerate() {
                for c in 0..2 {
                    kr[c] = p[r][0] * si[0][c] + p[r][1] * si[1][c];
                }
            }
            for r in 0..N {
                x[r] += kg[r][0] * v[0] + kg[r][1] * v[1];
            }
            let prow = [p[0], p[1]];
            for r in 0..N {
                for c in 0..N {
                    p[r][c] -= kg[r][0] * prow[0][c] + kg[r][1] * prow[1][c];
                }
            }
            // Heading: scalar update.
            if let Some(dh) = o.dh {
                let v = wrap_angle(dh - x[2]);
                let s = p[2][2] + o.rh;
                nll += 0.5 * (s.ln() + v * v / s);
                an += 1;
                a1 += usize::from(v.abs() <= s.sqrt());
                a3 += usize::from(v.abs() <= 3.0 * s.sqrt());
                let k: Vec<f64> = (0..N).map(|r| p[r][2] / s).collect();
                for r in 0..N {
                    x[r] += k[r] * v;
                }
                let prow = p[2];
                for r in 0..N {
                    for c in 0..N {
                        p[r][c] -= k[r] * prow[c];
                    }
                }
            }
            // Keep P symmetric against rounding.
            for r in 0..N {
                for c in r + 1..N {
                    let m = 0.5 * (p[r][c] + p[c][r]);
                    p[r][c] = m;
                    p[c][r] = m;
                }
            }
        }
        let share = |n: usize, d: usize| {
            if d == 0 {
                f64::NAN
            } else {
                n as f64 / d as f64
            }
        };
        FilterScore {
            nll: if nll.is_finite() { nll } else { f64::INFINITY },
            horizontal: (share(h1, hn), share(h3, hn)),
            heading: (share(a1, an), share(a3, an)),
            geometry: [x[3], x[4], x[5]],
            geometry_cov: [0, 1, 2].map(|r| [0, 1, 2].map(|c| p[3 + r][3 + c])),
        }
    }
}

/// The wheel distances (m) of the arc from `a` to `b` on a track `w`: its centre distance
/// (the chord over `sinc(dalpha / 2)`) plus and minus `w dalpha / 2`.
fn wheel_distances(a: Pose, b: Pose, w: f64) -> [f64; 2] {
    let dalpha = b.heading - a.heading;
    let mid = a.heading + 0.5 * dalpha;
    let (ddx, ddy) = (b.x - a.x, b.y - a.y);
    let along = ddx * mid.sin() + ddy * mid.cos();
    let chord = ddx.hypot(ddy).copysign(along);
    let half = 0.5 * dalpha;
    let ds = if half.abs() > 1e-9 {
        chord * half / half.sin()
    } else {
        chord
    };
    [ds + 0.5 * w * dalpha, ds - 0.5 * w * dalpha]
}

/// Filter state: position and heading errors, the geometry's relative errors (wheel 1 and 2
/// scale, track width), the two wheels' correlated slip, the correlated opposite-phase slip.
const N: usize = 9;
type M = [[f64; N]; N];
