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
//! The fit: kappa of white slip (a grid in log scale and golden sections), then kappa and `L`
//! together (Nelder-Mead over their logarithms from two starts); the more likely is kept and
//! its kappa, the long-range rate, is what the unit's white-slip model gets: correlated slip
//! is smoother over a few centimetres than white slip of the same long-range rate, and a
//! white-slip fit alone took it for less slip (a third of it at `L` = 2 m). Then opposite-phase
//! slip when turning ([`Turning`], the unit's `kappa_diff`), white or correlated over the
//! wheel-distance difference, kept only when the likelihood says it is there.

// Dense 8x8 matrix arithmetic reads best by index.
#![allow(clippy::needless_range_loop)]

use anyhow::{anyhow, Result};
use odo_core::odometry::{ChassisParams, Pose};

use crate::optim::{nelder_mead, NmOptions};
use crate::replay::{counts, index_refs};
use crate::stats::wrap_angle;

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
/// ensemble test (`tests/uncertainty_ensemble.rs`) was measured with.
pub const OBSERVATION_BLOCK: f64 = 1.0;

/// Longest time one averaged observation spans (s): a standstill is not one observation.
const BLOCK_TIME: f64 = 2.0;

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
    steps: Vec<Step>,
    track: f64,
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
                steps[at].obs = Some(o);
                observations += 1;
            }
        }
        Ok(Self {
            steps,
            track: w,
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
        let mut p: M = [[0.0; N]; N];
        p[0][0] = self.p0.0;
        p[1][1] = self.p0.0;
        p[2][2] = self.p0.1;
        for (i, row) in p.iter_mut().enumerate().take(6).skip(3) {
            row[i] = GEOMETRY_PRIOR * GEOMETRY_PRIOR;
        }
        let slip_var = if corr > 0.0 {
            kappa / (2.0 * corr)
        } else {
            0.0
        };
        p[6][6] = slip_var;
        p[7][7] = slip_var;
        let turn_var = if turning.corr > 0.0 {
            turning.kappa_diff / (2.0 * turning.corr)
        } else {
            0.0
        };
        p[8][8] = turn_var;
        let mut x = [0.0f64; N];
        let w = self.track;
        let mut nll = 0.0;
        let (mut hn, mut h1, mut h3, mut an, mut a1, mut a3) = (0usize, 0, 0, 0usize, 0, 0);
        for st in &self.steps {
            let (sn, cs) = st.mid.sin_cos();
            // Linearised step: new = A old + G noise, state (x, y, a, c1, c2, b).
            let half_w = 0.5 / w;
            // Position by each wheel distance (chord ~ ds for a sample's small turn).
            let dxds = [
                0.5 * sn + st.chord * cs * half_w,
                0.5 * sn - st.chord * cs * half_w,
            ];
            let dyds = [
                0.5 * cs - st.chord * sn * half_w,
                0.5 * cs + st.chord * sn * half_w,
            ];
            let dads = [1.0 / w, -1.0 / w];
            let diff = st.rolled_diff;
            let mut a: M = [[0.0; N]; N];
            for (i, row) in a.iter_mut().enumerate() {
                row[i] = 1.0;
            }
            a[0][2] = st.chord * cs;
            a[1][2] = -st.chord * sn;
            for j in 0..2 {
                for c in [3 + j, 6 + j] {
                    a[0][c] = dxds[j] * st.s[j];
                    a[1][c] = dyds[j] * st.s[j];
                    a[2][c] = dads[j] * st.s[j];
                }
            }
            a[2][5] = -st.dalpha;
            let mut rho = [0.0; 2];
            if corr > 0.0 {
                for j in 0..2 {
                    rho[j] = (-st.rolled[j] / corr).exp();
                    a[6 + j][6 + j] = rho[j];
                }
            }
            let mut rho_turn = 0.0;
            if turning.corr > 0.0 {
                let ge0 = [
                    0.5 * sn + st.chord * cs * half_w - (0.5 * sn - st.chord * cs * half_w),
                    0.5 * cs - st.chord * sn * half_w - (0.5 * cs + st.chord * sn * half_w),
                    2.0 / w,
                ];
                for (r, g) in ge0.iter().enumerate() {
                    a[r][8] = g * diff;
                }
                rho_turn = (-diff / turning.corr).exp();
                a[8][8] = rho_turn;
            }
            x = mat_vec(&a, &x);
            p = mat_mul_t(&mat_mul(&a, &p), &a);
            if turning.corr > 0.0 {
                p[8][8] += (1.0 - rho_turn * rho_turn) * turn_var;
            }
            if corr > 0.0 {
                for j in 0..2 {
                    p[6 + j][6 + j] += (1.0 - rho[j] * rho[j]) * slip_var;
                }
            }
            let white = if corr > 0.0 { 0.0 } else { kappa };
            let q = [white * st.rolled[0], white * st.rolled[1]];
            let g = [[dxds[0], dxds[1]], [dyds[0], dyds[1]], [dads[0], dads[1]]];
            let ge = g.map(|row| row[0] - row[1]);
            let qe = if turning.corr > 0.0 {
                // The correlated opposite-phase slip moves the pose through the state, as
                // the wheel slip does (added to `a` before the propagation below).
                0.0
            } else {
                turning.kappa_diff * diff
            };
            for r in 0..3 {
                for c in 0..3 {
                    p[r][c] +=
                        g[r][0] * g[c][0] * q[0] + g[r][1] * g[c][1] * q[1] + ge[r] * ge[c] * qe;
                }
            }
            let Some(o) = st.obs else { continue };
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

    /// The kappa of the largest likelihood in `[lo, hi]` (a grid in log scale, then golden
    /// sections).
    pub fn fit(&self, lo: f64, hi: f64) -> f64 {
        largest_likelihood(|k| self.score(k).nll, lo, hi)
    }
}

/// The value in `[lo, hi]` where `nll` is least: a grid in log scale, then golden sections.
fn largest_likelihood(nll: impl Fn(f64) -> f64, lo: f64, hi: f64) -> f64 {
    let f = |l: f64| nll(l.exp());
    let (a, b) = (lo.ln(), hi.ln());
    let n = 24;
    let step = (b - a) / n as f64;
    let (mut best, mut best_f) = (a, f64::INFINITY);
    for i in 0..=n {
        let l = a + step * i as f64;
        let v = f(l);
        if v < best_f {
            best = l;
            best_f = v;
        }
    }
    let (mut l, mut h) = ((best - step).max(a), (best + step).min(b));
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut c, mut d) = (h - g * (h - l), l + g * (h - l));
    let (mut fc, mut fd) = (f(c), f(d));
    while h - l > 1e-4 {
        if fc < fd {
            h = d;
            d = c;
            fd = fc;
            c = h - g * (h - l);
            fc = f(c);
        } else {
            l = c;
            c = d;
            fc = fd;
            d = l + g * (h - l);
            fd = f(d);
        }
    }
    let m = 0.5 * (l + h);
    if f(m) <= best_f {
        m.exp()
    } else {
        best.exp()
    }
}

/// Least decrease of the negative log-likelihood for which opposite-phase slip is kept:
/// the 95 % point of a likelihood-ratio test with one degree of freedom (3.84 / 2).
const OPPOSITE_PHASE_EVIDENCE: f64 = 1.92;

/// Shortest and longest slip correlation length the fit considers (m of wheel travel).
pub const SLIP_CORR_RANGE: (f64, f64) = (0.05, 20.0);

impl Innovations {
    /// The long-range kappa and the slip correlation length (0: white) of the largest
    /// likelihood: the white-slip fit ([`Innovations::fit`]), then Nelder-Mead over
    /// `ln kappa` and `ln corr` from it; the white fit is kept unless correlated slip is more
    /// likely.
    pub fn fit_correlated(&self, lo: f64, hi: f64) -> (f64, f64) {
        let white = self.fit(lo, hi);
        let white_nll = self.score(white).nll;
        let (cl, ch) = SLIP_CORR_RANGE;
        let mut best = (white, 0.0, white_nll);
        for start in [0.3f64, 3.0] {
            let r = nelder_mead(
                |x: &[f64]| {
                    let (k, c) = (x[0].exp(), x[1].exp());
                    if !(lo..=hi).contains(&k) || !(cl..=ch).contains(&c) {
                        return None;
                    }
                    Some(self.score_correlated(k, c).nll)
                },
                &[white.ln(), start.ln()],
                &[0.5, 1.0],
                NmOptions {
                    max_evals: 100,
                    ftol: 1e-10,
                    restarts: 1,
                },
            );
            if r.cost < best.2 {
                best = (r.x[0].exp(), r.x[1].exp(), r.cost);
            }
        }
        (best.0, best.1)
    }

    /// [`Innovations::fit_correlated`], then opposite-phase slip ([`Turning`]): white (a
    /// search over `kappa_diff`) and correlated (Nelder-Mead over `ln kappa_diff` and
    /// `ln corr`), kept only when it raises the likelihood by more than
    /// [`OPPOSITE_PHASE_EVIDENCE`] per parameter it adds, and then kappa fitted again beside
    /// it. Returns `(kappa, corr, turning)`.
    pub fn fit_with_turning(&self, lo: f64, hi: f64) -> (f64, f64, Turning) {
        let (kappa, corr) = self.fit_correlated(lo, hi);
        let without = self.score_correlated(kappa, corr).nll;
        let white = |d: f64| Turning {
            kappa_diff: d,
            corr: 0.0,
        };
        let kd = largest_likelihood(|d| self.score_with(kappa, corr, white(d)).nll, lo, hi);
        let mut best = (white(kd), self.score_with(kappa, corr, white(kd)).nll, 1.0);
        let (cl, ch) = SLIP_CORR_RANGE;
        for start in [0.3f64, 3.0] {
            let r = nelder_mead(
                |x: &[f64]| {
                    let t = Turning {
                        kappa_diff: x[0].exp(),
                        corr: x[1].exp(),
                    };
                    if !(lo..=hi).contains(&t.kappa_diff) || !(cl..=ch).contains(&t.corr) {
                        return None;
                    }
                    Some(self.score_with(kappa, corr, t).nll)
                },
                &[kd.ln(), start.ln()],
                &[0.5, 1.0],
                NmOptions {
                    max_evals: 80,
                    ftol: 1e-10,
                    restarts: 0,
                },
            );
            if r.cost + OPPOSITE_PHASE_EVIDENCE < best.1 {
                best = (
                    Turning {
                        kappa_diff: r.x[0].exp(),
                        corr: r.x[1].exp(),
                    },
                    r.cost,
                    2.0,
                );
            }
        }
        if best.1 > without - OPPOSITE_PHASE_EVIDENCE * best.2 {
            return (kappa, corr, Turning::NONE);
        }
        let turning = best.0;
        let kappa = largest_likelihood(|k| self.score_with(k, corr, turning).nll, lo, hi);
        (kappa, corr, turning)
    }
}

/// Opposite-phase slip in the filter: an error `e` on wheel 1's distance and `-e` on wheel
/// 2's, growing by `eps |s_1 - s_2|` per sample. White (`corr` 0): `e` of variance
/// `kappa_diff |s_1 - s_2|` per sample, the core's `kappa_diff`. Correlated: `eps` a
/// Gauss-Markov process over the wheel-distance difference, of correlation length `corr` (m)
/// and variance `kappa_diff / (2 corr)`, which has the same long-range variance
/// `kappa_diff D` over a difference `D >> corr`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Turning {
    /// Long-range variance of `e` per metre of `|s_1 - s_2|` (m^2/m).
    pub kappa_diff: f64,
    /// Correlation length (m of `|s_1 - s_2|`; 0: white).
    pub corr: f64,
}

impl Turning {
    /// No opposite-phase slip.
    pub const NONE: Self = Self {
        kappa_diff: 0.0,
        corr: 0.0,
    };
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

fn mat_mul(a: &M, b: &M) -> M {
    let mut out = [[0.0; N]; N];
    for r in 0..N {
        for k in 0..N {
            let v = a[r][k];
            if v != 0.0 {
                for c in 0..N {
                    out[r][c] += v * b[k][c];
                }
            }
        }
    }
    out
}

/// `a b^T`, skipping the zeros of `b` (the filter's transition is mostly the identity).
fn mat_mul_t(a: &M, b: &M) -> M {
    let mut out = [[0.0; N]; N];
    for (c, brow) in b.iter().enumerate() {
        let mut nz = [(0usize, 0.0f64); N];
        let mut n = 0;
        for (k, &v) in brow.iter().enumerate() {
            if v != 0.0 {
                nz[n] = (k, v);
                n += 1;
            }
        }
        for r in 0..N {
            out[r][c] = nz[..n].iter().map(|&(k, v)| a[r][k] * v).sum();
        }
    }
    out
}

fn mat_vec(a: &M, x: &[f64; N]) -> [f64; N] {
    let mut out = [0.0; N];
    for r in 0..N {
        out[r] = (0..N).map(|k| a[r][k] * x[k]).sum();
    }
    out
}

/// The covariance model's kappa by the filter's likelihood (module documentation): the
/// long-range wheel-distance variance per metre, with the slip's correlation length fitted
/// beside it (the unit's model has white slip; over the tens of metres a sigma is used for,
/// the long-range rate is what it must carry).
pub fn fit_kappa_filter(
    innovations: &Innovations,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    mode: DeltaMode,
) -> (UncertaintyFit, f64) {
    let hi = f64::from(ChassisParams::MAX_KAPPA);
    let lo = hi * 1e-12;
    let (kappa, corr, turning) = innovations.fit_with_turning(lo, hi);
    let mut params = set_coefficient(
        &ChassisParams {
            uncertainty_model: odo_core::odometry::UncertaintyModel::Covariance,
            ..*geometry
        },
        mode,
        initial,
        kappa,
    );
    params.kappa_diff = turning.kappa_diff as f32;
    let score = innovations.score_with(kappa, corr, turning);
    let warning = if kappa <= lo * 1.01 {
        Some(
            "the errors are explained by the reference noise alone: kappa is not identifiable"
                .to_string(),
        )
    } else if kappa >= hi * 0.99 {
        Some(format!("kappa reached its largest admissible value {hi:e}"))
    } else {
        None
    };
    (
        UncertaintyFit {
            model: params.uncertainty_model,
            params,
            keys: ("kappa_left", "kappa_right"),
            windows: 1,
            points: innovations.observations,
            coverage1: score.horizontal.0,
            coverage3: score.horizontal.1,
            warning,
            diff: None,
            criterion: UncertaintyCriterion::Likelihood,
            heading_coverage: (!score.heading.0.is_nan()).then_some(score.heading),
        },
        corr,
    )
}
