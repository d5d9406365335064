//! The Kalman filter of the likelihood over the composed blocks ([`Composed`]): per
//! observation one prediction (the block's transition and noise) and one update (the averaged
//! position, then the heading where the reference has one), scored on the innovations.
//!
//! The state: the pose error `(dx, dy, dalpha)`, the geometry's relative errors
//! `(c_1, c_2, b)` (with a wide prior), then the Gauss-Markov slip states the slip model has
//! (the two wheels', the opposite-phase one); only those, so that the arithmetic is dense.

// Dense 9x9 matrix arithmetic reads best by index.
#![allow(clippy::needless_range_loop)]

use crate::stats::wrap_angle;

use super::blocks::{BlockBase, Composed, GaussMarkovBlock};

/// Prior standard deviation of the geometry's relative errors in the filter: wide against
/// what a calibration leaves (1e-4 .. 1e-3), so the likelihood does not depend on it.
const GEOMETRY_PRIOR: f64 = 1e-2;

/// One observation of the filter, after its block: the position innovation base (reference -
/// odometry, m, x and y), its noise variance per axis (m^2), the heading difference (rad)
/// where the reference has one, and its noise variance.
#[derive(Debug, Clone, Copy)]
pub(super) struct Obs {
    pub(super) dx: f64,
    pub(super) dy: f64,
    /// How a heading error moves the observed point (m per rad, x and y): the lever arm
    /// turned by a further quarter turn, `R'(h) a`; zero when the reference observes the axle
    /// centre.
    pub(super) j: [f64; 2],
    pub(super) r: f64,
    pub(super) dh: Option<f64>,
    /// Noise variance of `dh` (rad^2).
    pub(super) rh: f64,
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
    /// Mean over the observations of the heading error's variance after each (rad^2): how far
    /// the odometry re-anchored to the estimate turns from the truth.
    pub heading_var: f64,
}

impl FilterScore {
    /// The score of a filter not run (its thread's calibration cancelled): NaN throughout.
    pub(super) fn cancelled() -> Self {
        Self {
            nll: f64::NAN,
            horizontal: (f64::NAN, f64::NAN),
            heading: (f64::NAN, f64::NAN),
            geometry: [f64::NAN; 3],
            geometry_cov: [[f64::NAN; 3]; 3],
            heading_var: f64::NAN,
        }
    }
}

/// The slip the filter is run with: white or Gauss-Markov, the latter's blocks composed.
#[derive(Clone, Copy)]
pub(super) struct SlipModel<'a> {
    /// Long-range wheel-distance variance (m^2 per m rolled).
    pub(super) kappa: f64,
    /// Wheel slip's correlation length (m) and its two states composed; `None`: white.
    pub(super) wheels: Option<(f64, &'a [Vec<GaussMarkovBlock>; 2])>,
    /// Long-range opposite-phase variance (m^2 per m of `|s_1 - s_2|`).
    pub(super) kappa_diff: f64,
    /// Its correlation length (m) and state composed; `None`: white.
    pub(super) turning: Option<(f64, &'a [GaussMarkovBlock])>,
}

/// What the filter runs over: the composed blocks with the observation after each, the
/// initial variances of the position (per axis, m^2) and heading (rad^2), and per observation
/// the shift of the pose error that the odometry's re-anchoring makes there.
pub(super) struct FilterRun<'a> {
    pub(super) composed: &'a Composed,
    pub(super) obs: &'a [Obs],
    pub(super) p0: (f64, f64),
    pub(super) shifts: &'a [[f64; 3]],
}

/// A Gauss-Markov state of one block: its index in the state, its block composed, its kappa.
type GaussMarkovState<'a> = (usize, &'a GaussMarkovBlock, f64);

impl FilterRun<'_> {
    /// The filter under `slip`, pushing the pose error's estimate after each observation to
    /// `track` when given.
    pub(super) fn score(&self, slip: SlipModel, track: Option<&mut Vec<[f64; 3]>>) -> FilterScore {
        // Only the states the slip model has: the arithmetic is dense in them.
        match (slip.wheels.is_some(), slip.turning.is_some()) {
            (false, false) => self.score_with::<6>(slip, track),
            (false, true) => self.score_with::<7>(slip, track),
            (true, false) => self.score_with::<8>(slip, track),
            (true, true) => self.score_with::<9>(slip, track),
        }
    }

    /// [`FilterRun::score`] over `N` states: the pose error and the geometry's (6), the two
    /// wheels' Gauss-Markov slip (6 and 7) when the model has them, the opposite-phase one
    /// (the last) when it has it.
    fn score_with<const N: usize>(
        &self,
        slip: SlipModel,
        mut track: Option<&mut Vec<[f64; 3]>>,
    ) -> FilterScore {
        let mut state = State::<N>::new(self.p0, &slip);
        let mut tally = Tally::default();
        for (b, (base, o)) in self.composed.blocks.iter().zip(self.obs).enumerate() {
            state.predict(base, &gauss_markov_states::<N>(&slip, b), &slip);
            for (xi, d) in state.x.iter_mut().zip(&self.shifts[b]) {
                *xi -= d;
            }
            if !state.update_position(o, &mut tally) {
                return FilterScore {
                    nll: f64::INFINITY,
                    ..FilterScore::default()
                };
            }
            if let Some(dh) = o.dh {
                state.update_heading(dh, o.rh, &mut tally);
            }
            if let Some(t) = track.as_deref_mut() {
                t.push([state.x[0], state.x[1], state.x[2]]);
            }
            tally.heading_var += state.p[2][2];
            state.symmetrise();
        }
        tally.score(&state, self.obs.len())
    }
}

/// The Gauss-Markov states of `slip` in block `b` (wheel 1, wheel 2, opposite-phase; `None`
/// where the model has none), in a state of `N`.
fn gauss_markov_states<'a, const N: usize>(
    slip: &SlipModel<'a>,
    b: usize,
) -> [Option<GaussMarkovState<'a>>; 3] {
    let turning_state = N - 1;
    let mut gm: [Option<GaussMarkovState<'a>>; 3] = [None; 3];
    if let Some((_, w)) = slip.wheels {
        gm[0] = Some((6, &w[0][b], slip.kappa));
        gm[1] = Some((7, &w[1][b], slip.kappa));
    }
    if let Some((_, t)) = slip.turning {
        gm[2] = Some((turning_state, &t[b], slip.kappa_diff));
    }
    gm
}

/// The filter's estimate `x` and covariance `p` over `N` states.
struct State<const N: usize> {
    x: [f64; N],
    p: [[f64; N]; N],
}

/// The running sums of a score: the negative log-likelihood, the heading error's variance
/// after each observation, and the counts of innovations in and within 1 and 3 sigma
/// (position: `h`, heading: `a`).
#[derive(Default)]
struct Tally {
    nll: f64,
    heading_var: f64,
    hn: usize,
    h1: usize,
    h3: usize,
    an: usize,
    a1: usize,
    a3: usize,
}

impl<const N: usize> State<N> {
    /// Zero error; the initial variances `p0` of the position (per axis) and heading, the
    /// geometry's wide prior, the Gauss-Markov states' stationary variances.
    fn new(p0: (f64, f64), slip: &SlipModel) -> Self {
        let turning_state = N - 1;
        let mut p = [[0.0; N]; N];
        p[0][0] = p0.0;
        p[1][1] = p0.0;
        p[2][2] = p0.1;
        for (i, row) in p.iter_mut().enumerate().take(6).skip(3) {
            row[i] = GEOMETRY_PRIOR * GEOMETRY_PRIOR;
        }
        if let Some((corr, _)) = slip.wheels {
            p[6][6] = slip.kappa / (2.0 * corr);
            p[7][7] = p[6][6];
        }
        if let Some((corr, _)) = slip.turning {
            p[turning_state][turning_state] = slip.kappa_diff / (2.0 * corr);
        }
        Self { x: [0.0f64; N], p }
    }

    /// The prediction over one block: `x <- Phi x`, `P <- Phi P Phi^T` plus the block's
    /// noise (the white slip's, the Gauss-Markov states' `gm`).
    fn predict(&mut self, base: &BlockBase, gm: &[Option<GaussMarkovState>; 3], slip: &SlipModel) {
        let (x, p) = (&mut self.x, &mut self.p);
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
        let mut y = *p;
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
    }

    /// The 2-D update by the position of observation `o`, scored into `tally`; false when the
    /// innovation's covariance is not positive.
    fn update_position(&mut self, o: &Obs, tally: &mut Tally) -> bool {
        let (x, p) = (&mut self.x, &mut self.p);
        // H picks x, y and adds the heading error turned into position by the lever arm:
        // rows (1, 0, jx, 0..) and (0, 1, jy, 0..); HP's rows, and S = H P H^T + R.
        let j = o.j;
        let hp: [[f64; N]; 2] = [0, 1].map(|i| std::array::from_fn(|c| p[i][c] + j[i] * p[2][c]));
        let v = [o.dx - (x[0] + j[0] * x[2]), o.dy - (x[1] + j[1] * x[2])];
        let s = [0, 1].map(|i| [0, 1].map(|k| hp[i][k] + hp[i][2] * j[k]));
        let s = [[s[0][0] + o.r, s[0][1]], [s[1][0], s[1][1] + o.r]];
        let det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
        if det.is_nan() || det <= 0.0 {
            return false;
        }
        let si = [
            [s[1][1] / det, -s[0][1] / det],
            [-s[1][0] / det, s[0][0] / det],
        ];
        let quad =
            v[0] * (si[0][0] * v[0] + si[0][1] * v[1]) + v[1] * (si[1][0] * v[0] + si[1][1] * v[1]);
        tally.nll += 0.5 * (det.ln() + quad);
        tally.hn += 1;
        let tr = (s[0][0] + s[1][1]).sqrt();
        let e = v[0].hypot(v[1]);
        tally.h1 += usize::from(e <= tr);
        tally.h3 += usize::from(e <= 3.0 * tr);
        // K = P H^T S^-1.
        let mut kg = [[0.0; 2]; N];
        for (r, kr) in kg.iter_mut().enumerate() {
            let pht = [0, 1].map(|k| p[r][k] + p[r][2] * j[k]);
            for c in 0..2 {
                kr[c] = pht[0] * si[0][c] + pht[1] * si[1][c];
            }
        }
        for r in 0..N {
            x[r] += kg[r][0] * v[0] + kg[r][1] * v[1];
        }
        for r in 0..N {
            for c in 0..N {
                p[r][c] -= kg[r][0] * hp[0][c] + kg[r][1] * hp[1][c];
            }
        }
        true
    }

    /// The scalar update by the heading difference `dh` (rad) of noise variance `rh`, scored
    /// into `tally`.
    fn update_heading(&mut self, dh: f64, rh: f64, tally: &mut Tally) {
        let (x, p) = (&mut self.x, &mut self.p);
        let v = wrap_angle(dh - x[2]);
        let s = p[2][2] + rh;
        tally.nll += 0.5 * (s.ln() + v * v / s);
        tally.an += 1;
        tally.a1 += usize::from(v.abs() <= s.sqrt());
        tally.a3 += usize::from(v.abs() <= 3.0 * s.sqrt());
        let k: [f64; N] = std::array::from_fn(|r| p[r][2] / s);
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

    /// Keeps `P` symmetric against rounding.
    fn symmetrise(&mut self) {
        let p = &mut self.p;
        for r in 0..N {
            for c in r + 1..N {
                let m = 0.5 * (p[r][c] + p[c][r]);
                p[r][c] = m;
                p[c][r] = m;
            }
        }
    }
}

impl Tally {
    /// The score of a filter that ended in `state` after `observations` observations.
    fn score<const N: usize>(&self, state: &State<N>, observations: usize) -> FilterScore {
        let (x, p) = (&state.x, &state.p);
        let share = |n: usize, d: usize| {
            if d == 0 {
                f64::NAN
            } else {
                n as f64 / d as f64
            }
        };
        let nll = self.nll;
        FilterScore {
            nll: if nll.is_finite() { nll } else { f64::INFINITY },
            horizontal: (share(self.h1, self.hn), share(self.h3, self.hn)),
            heading: (share(self.a1, self.an), share(self.a3, self.an)),
            geometry: [x[3], x[4], x[5]],
            geometry_cov: [0, 1, 2].map(|r| [0, 1, 2].map(|c| p[3 + r][3 + c])),
            heading_var: self.heading_var / observations.max(1) as f64,
        }
    }
}
