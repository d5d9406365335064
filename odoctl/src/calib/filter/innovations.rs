//! The run prepared for the likelihood of the reference's observations under an error-state
//! Kalman filter along the whole run ([`Innovations`]), scored on its innovations (the
//! prediction-error decomposition), and the slip of the largest likelihood.
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
//! where they have headings, the middle epoch's `dalpha` (`--reference-heading-sigma-deg`):
//! the heading error is a random walk, whose block means are smoother than its values (their
//! steps have 2/3 of the variance), so a filter that takes the means for values at the middle
//! reads the slip 13 % (q 0.001) to 26 % (q 0.003) low on 70 m runs with the true geometry.
//! The lateral position error, an integral of it, is smooth over a metre, but the along-track
//! error is a random walk of its own: against a precise reference the positions are averaged
//! over a shorter span about the middle epoch ([`position_span`]). The
//! log-likelihood is `-1/2 sum (ln det S_k + v_k^T S_k^-1 v_k)` over the innovations `v_k`:
//! each is scored on a prediction from the observations before it only, so nothing a point is
//! judged on was fitted to it, neither a start heading nor the geometry (the filter carries
//! the geometry's errors with a wide prior: the errors the eq (16) fit absorbed on this run
//! are not taken for an absence of slip).
//!
//! The filter runs over the steps of 5 cm ([`MERGED_STEP`]) between two observations composed
//! into one transition ([`Composed`]), so a score costs one prediction and one update per
//! observation (`kalman.rs`); a run longer than [`MAX_OBSERVATIONS`] metres uses a share of
//! its observations.
//!
//! The slip of the largest likelihood ([`Innovations::fit_with_turning`]): white wheel slip,
//! then Gauss-Markov slip profiled over its correlation length, then opposite-phase slip when
//! turning ([`Turning`]: the unit's `kappa_diff`, and its correlation length
//! `kappa_diff_corr`, which the unit's covariance model carries as the same Gauss-Markov
//! state), each kept only when the likelihood says it is there. The more likely of white and
//! correlated wheel slip is kept and its kappa, the long-range rate, is what the unit's
//! white-slip model gets: correlated slip is smoother over a few centimetres than white slip
//! of the same long-range rate, and a white-slip fit alone took it for less slip (a third of
//! it at `L` = 2 m).

// Dense matrix arithmetic reads best by index.
#![allow(clippy::needless_range_loop)]

use anyhow::{anyhow, Result};
use odo_unit::odometry::{ChassisParams, Pose};

use crate::calib::antenna::{antenna_offset, observed_point};
use crate::calib::pipeline::cores;
use crate::calib::run::Run;
use crate::cancel::{check_this_thread, this_thread_cancelled};
use crate::replay::{counts, index_refs};
use crate::stats::{median, wrap_angle};

use super::blocks::{Composed, GaussMarkovBlock, StepTerms, PARALLEL_STEPS};
use super::kalman::{FilterRun, FilterScore, Obs, SlipModel};
use super::search::{
    best_over_grid, polish, posterior_mean, slip_rate_range, Search, SearchLog,
    EVIDENCE_PER_PARAMETER,
};

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

/// Reference path over which the filter's observations are averaged (m): one observation per
/// metre (at most [`BLOCK_TIME`]), the mean of the reference's positions minus the odometry's,
/// applied at the block's middle sample with its noise divided by their number, and the middle
/// epoch's heading (module documentation). What the
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

/// Most rounds of the alternate fit of kappa and `kappa_diff` once opposite-phase slip is in.
const JOINT_ROUNDS: usize = 4;

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

/// One reference epoch of a block: reference minus odometry `(x, y)` (m), its noise variance
/// per axis (m^2), heading difference (rad), and the step it is on.
#[derive(Debug, Clone, Copy)]
struct Epoch {
    dx: f64,
    dy: f64,
    /// [`Obs::j`] at this epoch (m per rad).
    j: [f64; 2],
    r: f64,
    dh: Option<f64>,
    step: usize,
    /// Reference path from the run's first match (m).
    dist: f64,
}

/// The reference epochs of one block.
#[derive(Debug, Clone, Default)]
struct Block {
    epochs: Vec<Epoch>,
}

impl Block {
    fn add(&mut self, e: Epoch) {
        self.epochs.push(e);
    }

    fn is_empty(&self) -> bool {
        self.epochs.is_empty()
    }

    /// The block's observation at its middle step: the mean of the positions of its epochs
    /// within `span / 2` metres of path of the middle epoch (all of them when `span` is
    /// `None`; noise divided by their number) and the middle epoch's heading. Empties the
    /// block.
    fn take(&mut self, rh2: f64, span: Option<f64>) -> (usize, Obs) {
        let mid = self.epochs[self.epochs.len() / 2];
        if let Some(span) = span {
            self.epochs
                .retain(|e| (e.dist - mid.dist).abs() <= 0.5 * span);
        }
        let e = &self.epochs;
        let n = e.len() as f64;
        let o = Obs {
            dx: e.iter().map(|e| e.dx).sum::<f64>() / n,
            dy: e.iter().map(|e| e.dy).sum::<f64>() / n,
            j: [0, 1].map(|a| e.iter().map(|e| e.j[a]).sum::<f64>() / n),
            r: e.iter().map(|e| e.r).sum::<f64>() / (n * n),
            dh: mid.dh,
            rh: rh2,
        };
        self.epochs.clear();
        (mid.step, o)
    }
}

/// The run's motion and observations, ready for the likelihood of any kappa.
#[derive(Debug, Clone)]
pub struct Innovations {
    /// The steps between observations, composed.
    composed: Composed,
    /// The observation at the end of each block.
    obs: Vec<Obs>,
    /// Initial variances of the position (per axis) and heading.
    p0: (f64, f64),
    /// Per observation, the shift of the pose error `(x, y, alpha)` that the odometry's
    /// re-anchoring after the observation before makes at this one (zero without anchors).
    shifts: Vec<[f64; 3]>,
    /// The odometry's pose at the end of each observed block, before any re-anchoring: where
    /// the filter's estimate after that block's observation puts the next pass's anchor.
    closes: Vec<Pose>,
    /// Per observed block, how its heading error moves the position from its observation's
    /// step to its end (m per rad, x and y).
    levers: Vec<[f64; 2]>,
    /// What it was built with.
    settings: Settings,
    /// Observations (positions) used.
    pub observations: usize,
}

/// How [`Innovations`] takes a run's observations.
#[derive(Debug, Clone, Copy)]
struct Settings {
    /// The run's start heading without reference headings (rad).
    heading0: f64,
    /// The reference's position (horizontal RMS, m) and heading (rad) noise.
    sigmas: (f64, f64),
    /// [`OBSERVATION_BLOCK`] or another (m).
    block_length: f64,
    /// Path around each block's middle epoch whose positions are averaged (m; `None`: the
    /// whole block); see [`position_span`].
    span: Option<f64>,
}

impl Step {
    /// The step from `start` to `p` on a track `w` (m), the wheels having rolled `rolled` and
    /// `rolled_diff` (m), without observation.
    fn between(start: Pose, p: Pose, w: f64, rolled: [f64; 2], rolled_diff: f64) -> Self {
        let dalpha = p.heading - start.heading;
        let mid = start.heading + 0.5 * dalpha;
        let (ddx, ddy) = (p.x - start.x, p.y - start.y);
        let along = ddx * mid.sin() + ddy * mid.cos();
        Self {
            chord: ddx.hypot(ddy).copysign(along),
            dalpha,
            mid,
            s: wheel_distances(start, p, w),
            rolled,
            rolled_diff,
            obs: None,
        }
    }

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

impl Innovations {
    /// Integrates the odometry with `geometry` over the whole run and takes the observations,
    /// then linearises again about the filter's estimate at the white slip of the largest
    /// likelihood ([`Innovations::reanchored`]).
    pub fn new(
        run: &Run,
        geometry: &ChassisParams,
        heading0: f64,
        ref_sigma: f64,
        ref_heading_sigma: f64,
        block_length: f64,
    ) -> Result<Self> {
        let sigmas = (ref_sigma, ref_heading_sigma);
        let log = SearchLog::default();
        Self::new_after(run, geometry, (heading0, sigmas, block_length), &log)
    }

    /// [`Innovations::new`] (`heading0`, the reference's sigmas and the block length in
    /// `setup`) with the open-loop filter's kappa searched from where `log`'s earlier fit's
    /// ended ([`Search::OpenLoop`]), and recorded there.
    pub fn new_after(
        run: &Run,
        geometry: &ChassisParams,
        (heading0, sigmas, block_length): (f64, (f64, f64), f64),
        log: &SearchLog,
    ) -> Result<Self> {
        let settings = Settings {
            heading0,
            sigmas,
            block_length,
            span: None,
        };
        let path = OpenLoop::new(run, geometry, settings)?;
        check_this_thread()?;
        let open_loop = Self::anchored(run, geometry, settings, &path, None)?;
        let (lo, hi) = slip_rate_range();
        let nll = |k: f64| open_loop.nll(k, None, 0.0, None);
        let kappa = log.largest(Search::OpenLoop, nll, lo, hi);
        check_this_thread()?;
        open_loop.reanchored(run, geometry, &path, kappa)
    }

    /// The filter for `geometry` linearised about this one's estimate at white slip `kappa`
    /// rather than about the odometry integrated open-loop, whose heading drifts from the
    /// truth by the slip's random walk (at q 0.003 over 70 m about 3 degrees): the positions'
    /// second order in that drift is a systematic error the linear filter cannot carry, and
    /// the likelihood took it for slip (correlated slip of a long correlation length, kappa
    /// 27 % high on 70 m runs with the true geometry), the geometry's estimate for a scale. The
    /// filter's estimate after each observation becomes the pose the odometry is re-anchored
    /// to at the end of that block (any anchor is exact: the filter shifts its state by the
    /// re-anchoring; only the point of linearisation changes). Falls back to `self`'s own
    /// linearisation when the filter fails at `kappa`.
    fn reanchored(
        &self,
        run: &Run,
        geometry: &ChassisParams,
        path: &OpenLoop,
        kappa: f64,
    ) -> Result<Self> {
        let anchors = self.anchors(kappa);
        let settings = Settings {
            span: position_span(run, self.settings, kappa),
            ..self.settings
        };
        Self::anchored(run, geometry, settings, path, anchors.as_deref())
    }

    /// The filter's estimate of the pose at the end of each observed block, at white slip
    /// `kappa`; `None` when it fails.
    fn anchors(&self, kappa: f64) -> Option<Vec<Pose>> {
        let mut track = Vec::with_capacity(self.obs.len());
        self.filter_tracked(
            SlipModel {
                kappa,
                wheels: None,
                kappa_diff: 0.0,
                turning: None,
            },
            Some(&mut track),
        );
        if track.len() != self.closes.len()
            || self.levers.len() != track.len()
            || track.iter().flatten().any(|v| !v.is_finite())
        {
            return None;
        }
        Some(
            self.closes
                .iter()
                .zip(&track)
                .zip(&self.levers)
                .map(|((c, e), m)| Pose {
                    x: c.x + e[0] + m[0] * e[2],
                    y: c.y + e[1] + m[1] * e[2],
                    heading: c.heading + e[2],
                })
                .collect(),
        )
    }

    /// [`Innovations::new`]'s run: the odometry `path` as integrated (`anchors` `None`) or
    /// moved to `anchors[b]` at the end of observed block `b` (the path after it turned and
    /// shifted with the anchor, as an integration restarted there would run).
    fn anchored(
        run: &Run,
        geometry: &ChassisParams,
        settings: Settings,
        path: &OpenLoop,
        anchors: Option<&[Pose]>,
    ) -> Result<Self> {
        let w = geometry.track_width;
        let taken = StepsTaken::along(run, w, settings, path, anchors);
        Ok(Self::from_steps(taken, w, settings, path))
    }

    /// The filter of the steps `taken` on a track `w` (m): their terms composed between the
    /// observations, the re-anchorings' shifts of the pose error and the blocks' levers.
    fn from_steps(taken: StepsTaken, w: f64, settings: Settings, path: &OpenLoop) -> Self {
        let StepsTaken {
            steps,
            closes,
            close_steps,
            resets,
            observations,
        } = taken;
        // The steps after the last observation are not observed.
        let mut ends = Vec::with_capacity(observations);
        let mut obs = Vec::with_capacity(observations);
        for (i, st) in steps.iter().enumerate() {
            if let Some(o) = st.obs {
                ends.push(i + 1);
                obs.push(o);
            }
        }
        let terms = step_terms(&steps, w);
        let used = ends.last().copied().unwrap_or(0);
        // A re-anchoring by `d` before step `j` moves the truth-minus-odometry error by `-d`
        // there; at the next observation (the end of step `ends[b] - 1`) that is `-d` carried
        // by the steps between: the heading part turns into position by their `m`.
        let sum_m = |steps: &[StepTerms]| {
            steps
                .iter()
                .fold([0.0; 2], |acc, t| [acc[0] + t.m[0], acc[1] + t.m[1]])
        };
        let mut shifts = vec![[0.0; 3]; obs.len()];
        for (b, &(j, d)) in resets.iter().enumerate() {
            let Some(&end) = ends.get(b + 1) else {
                break;
            };
            let m = sum_m(&terms[j.min(end)..end]);
            shifts[b + 1] = [d[0] + m[0] * d[2], d[1] + m[1] * d[2], d[2]];
        }
        let levers = ends
            .iter()
            .zip(&close_steps)
            .map(|(&e, &c)| sum_m(&terms[e.min(c)..c]))
            .collect();
        Self {
            composed: Composed::new(&terms[..used], &ends),
            obs,
            p0: path.start_variances,
            shifts,
            closes,
            levers,
            settings,
            observations,
        }
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
    fn wheel_slip(&self, corr: f64) -> [Vec<GaussMarkovBlock>; 2] {
        [0, 1].map(|j| self.composed.gauss_markov(j, corr))
    }

    /// The opposite-phase Gauss-Markov slip of correlation length `corr` (m) composed.
    fn turning_slip(&self, corr: f64) -> Vec<GaussMarkovBlock> {
        self.composed.gauss_markov(2, corr)
    }

    /// The filter over the composed blocks: one prediction and one update per observation.
    fn filter(&self, slip: SlipModel) -> FilterScore {
        self.filter_tracked(slip, None)
    }

    /// [`Innovations::filter`], pushing the pose error's estimate after each observation to
    /// `track` when given.
    fn filter_tracked(&self, slip: SlipModel, track: Option<&mut Vec<[f64; 3]>>) -> FilterScore {
        if this_thread_cancelled() {
            return FilterScore::cancelled();
        }
        FilterRun {
            composed: &self.composed,
            obs: &self.obs,
            p0: self.p0,
            shifts: &self.shifts,
        }
        .score(slip, track)
    }

    fn nll(
        &self,
        kappa: f64,
        wheels: Option<(f64, &[Vec<GaussMarkovBlock>; 2])>,
        kappa_diff: f64,
        turning: Option<(f64, &[GaussMarkovBlock])>,
    ) -> f64 {
        self.filter(SlipModel {
            kappa,
            wheels,
            kappa_diff,
            turning,
        })
        .nll
    }

    /// The long-range kappa and the slip correlation length (0: white) of the largest
    /// likelihood: the white-slip fit ([`Search::White`]), then the profile over the
    /// correlation grid; the white fit is kept unless correlated slip raises the likelihood by
    /// more than [`EVIDENCE_PER_PARAMETER`] (it has one parameter more). Without that test a
    /// correlation length the data cannot tell won on nearly every run, and its long-range
    /// kappa read q 0.001 slip 15 % high (20 calibrations of the ensemble test). Each search
    /// starts near `log`'s earlier end of it and is recorded there ([`SearchLog`]).
    pub fn fit_correlated(&self, lo: f64, hi: f64, log: &SearchLog) -> (f64, f64) {
        let white = log.largest(Search::White, |k| self.nll(k, None, 0.0, None), lo, hi);
        let white_nll = self.nll(white, None, 0.0, None);
        let (corr, kappa, nll) = best_over_grid(|i, corr| {
            let gm = self.wheel_slip(corr);
            let nll = |k| self.nll(k, Some((corr, &gm)), 0.0, None);
            log.near(Search::Correlated(i), nll, white, lo, hi)
        });
        if nll + EVIDENCE_PER_PARAMETER < white_nll {
            (kappa, corr)
        } else {
            (white, 0.0)
        }
    }

    /// [`Innovations::fit_correlated`], then opposite-phase slip ([`Turning`]): white (a
    /// search over `kappa_diff`) and correlated (the profile over its correlation length),
    /// kept only when it raises the likelihood by more than [`EVIDENCE_PER_PARAMETER`] per
    /// parameter it adds, then kappa and `kappa_diff` fitted in turn, and `kappa_diff` taken as
    /// its mean over the likelihood ([`posterior_mean`]); the searches by `log` as there.
    /// Returns `(kappa, corr, turning)`.
    pub fn fit_with_turning(&self, lo: f64, hi: f64, log: &SearchLog) -> (f64, f64, Turning) {
        let (kappa, corr) = self.fit_correlated(lo, hi, log);
        let gm = (corr > 0.0).then(|| self.wheel_slip(corr));
        let wheels = gm.as_ref().map(|g| (corr, g));
        let without = self.nll(kappa, wheels, 0.0, None);
        let kd = log.largest(
            Search::TurningWhite,
            |d| self.nll(kappa, wheels, d, None),
            lo,
            hi,
        );
        let white = Turning {
            kappa_diff: kd,
            corr: 0.0,
        };
        let mut best = (white, self.nll(kappa, wheels, kd, None), 1.0);
        let (tcorr, tkd, tnll) = best_over_grid(|i, tc| {
            let gt = self.turning_slip(tc);
            let nll = |d| self.nll(kappa, wheels, d, Some((tc, &gt)));
            log.near(Search::Turning(i), nll, kd, lo, hi)
        });
        if tnll + EVIDENCE_PER_PARAMETER < best.1 {
            let t = Turning {
                kappa_diff: tkd,
                corr: tcorr,
            };
            best = (t, tnll, 2.0);
        }
        if best.1 > without - EVIDENCE_PER_PARAMETER * best.2 {
            return (kappa, corr, Turning::NONE);
        }
        let mut turning = best.0;
        let gt = (turning.corr > 0.0).then(|| self.turning_slip(turning.corr));
        let turn = gt.as_deref().map(|g| (turning.corr, g));
        // Kappa took some of the turning slip for wheel slip before `kappa_diff` was there:
        // the two are fitted in turn until they settle.
        let mut kappa = kappa;
        for round in 0..JOINT_ROUNDS {
            let (k, _) = log.near(
                Search::JointKappa(round),
                |k| self.nll(k, wheels, turning.kappa_diff, turn),
                kappa,
                lo,
                hi,
            );
            let (d, _) = log.near(
                Search::JointDiff(round),
                |d| self.nll(k, wheels, d, turn),
                turning.kappa_diff,
                lo,
                hi,
            );
            let settled =
                (k / kappa).ln().abs() < 0.01 && (d / turning.kappa_diff).ln().abs() < 0.01;
            (kappa, turning.kappa_diff) = (k, d);
            if settled {
                break;
            }
        }
        let kd = polish(
            |d| self.nll(kappa, wheels, d, turn),
            turning.kappa_diff,
            lo,
            hi,
        );
        turning.kappa_diff = posterior_mean(|l| self.nll(kappa, wheels, l.exp(), turn), kd, hi);
        (kappa, corr, turning)
    }
}

/// The run's motion merged into steps with the reference's blocks averaged into
/// observations on them ([`StepsTaken::along`]).
struct StepsTaken {
    /// The steps, the observed ones with their observation.
    steps: Vec<Step>,
    /// The odometry's pose at each observed block's end.
    closes: Vec<Pose>,
    /// The number of steps at each observed block's end.
    close_steps: Vec<usize>,
    /// The re-anchorings: the first step after, anchor minus odometry `(x, y, heading)`.
    resets: Vec<(usize, [f64; 3])>,
    /// Observations (positions) taken.
    observations: usize,
}

impl StepsTaken {
    /// The odometry `path` on a track `w` (m), moved to `anchors[b]` at the end of observed
    /// block `b` when given, merged into steps of [`MERGED_STEP`] (never across an
    /// observation); the reference's epochs averaged over blocks of `settings.block_length`
    /// (at most [`BLOCK_TIME`]), every `stride`-th block observed (at most
    /// [`MAX_OBSERVATIONS`]).
    fn along(
        run: &Run,
        w: f64,
        settings: Settings,
        path: &OpenLoop,
        anchors: Option<&[Pose]>,
    ) -> Self {
        let Settings {
            sigmas: (ref_sigma, ref_heading_sigma),
            block_length,
            ..
        } = settings;
        let rh2 = ref_heading_sigma * ref_heading_sigma;
        // Every `stride`-th block's observation is used.
        let distance = run.dist[run.len() - 1] - run.dist[0];
        let stride = (distance / (MAX_OBSERVATIONS * block_length))
            .ceil()
            .max(1.0) as usize;
        let mut blocks = 0usize;
        let (first, last) = (path.first, path.first + path.poses.len() - 1);
        let mut k = 1;
        // This pass's pose of each of the path's (the latest re-anchoring).
        let mut moved = Reanchoring::default();
        // The step being merged: its start pose and what it rolled so far.
        let mut start = path.poses[0];
        let (mut rolled, mut rolled_diff) = ([0.0f64; 2], 0.0f64);
        // A step closes when it rolled MERGED_STEP or its block ends; consecutive blocks
        // start more than a block length or BLOCK_TIME apart.
        let rolled_mean: f64 = path.rolled.iter().map(|r| 0.5 * (r[0] + r[1])).sum();
        let duration = run.reference_at(run.len() - 1).t - run.reference_at(0).t;
        let blocks_most = distance / block_length + duration / BLOCK_TIME + 1.0;
        let mut taken = Self {
            steps: Vec::with_capacity((rolled_mean / MERGED_STEP + blocks_most) as usize + 1),
            closes: Vec::new(),
            close_steps: Vec::new(),
            resets: Vec::new(),
            observations: 0,
        };
        // Observations of one block, averaged: (ref - odo) x, y, noise var, heading, count.
        let mut block = Block::default();
        let mut block_start = 0usize;
        for i in first + 1..=last {
            let open = path.poses[i - first];
            let p = moved.apply(open);
            let [d1, d2, dd] = path.rolled[i - first];
            rolled[0] += d1;
            rolled[1] += d2;
            rolled_diff += dd;
            // A reference epoch joins its block; the block's averaged observation goes on the
            // step holding its middle epoch, which is closed when the block ends.
            let mut block_done = false;
            if k < run.len() && run.matches[k].0 == i {
                let r = run.reference_at(k);
                if block.is_empty() {
                    block_start = k;
                }
                let (ox, oy) = observed_point(&p, run.antenna, path.poses[0].heading);
                block.add(Epoch {
                    dx: r.x - ox,
                    dy: r.y - oy,
                    j: lever_turn(p.heading, run.antenna),
                    r: position_variance(run, k, ref_sigma),
                    dh: r.heading.map(|h| wrap_angle(h - p.heading)),
                    step: taken.steps.len(),
                    dist: run.dist[k],
                });
                block_done = k + 1 >= run.len()
                    || run.dist[k + 1] - run.dist[block_start] > block_length
                    || run.reference_at(k + 1).t - run.reference_at(block_start).t > BLOCK_TIME;
                k += 1;
            }
            if block_done || 0.5 * (rolled[0] + rolled[1]) >= MERGED_STEP || i == last {
                taken
                    .steps
                    .push(Step::between(start, p, w, rolled, rolled_diff));
                start = p;
                (rolled, rolled_diff) = ([0.0; 2], 0.0);
            }
            if block_done {
                let (at, o) = block.take(rh2, settings.span);
                blocks += 1;
                if blocks.is_multiple_of(stride) || k >= run.len() {
                    if let Some(a) = taken.observe(at, o, p, anchors) {
                        moved = Reanchoring::new(open, a);
                        start = a;
                    }
                }
            }
        }
        taken
    }

    /// Puts observation `o` on step `at`, the odometry at `p` at its block's end; returns the
    /// anchor the path moves to there, if any.
    fn observe(&mut self, at: usize, o: Obs, p: Pose, anchors: Option<&[Pose]>) -> Option<Pose> {
        self.steps[at].obs = Some(o);
        self.closes.push(p);
        self.close_steps.push(self.steps.len());
        let anchor = anchors.and_then(|a| a.get(self.observations)).copied();
        if let Some(a) = anchor {
            self.resets.push((
                self.steps.len(),
                [a.x - p.x, a.y - p.y, wrap_angle(a.heading - p.heading)],
            ));
        }
        self.observations += 1;
        anchor
    }
}

/// How a heading error at `heading` moves the point the reference observes at `antenna`
/// (`(forward, left)` m from the axle centre): `R'(h) a`, the lever arm turned by a further
/// quarter turn (m per rad, x and y); zero without a lever arm.
fn lever_turn(heading: f64, antenna: (f64, f64)) -> [f64; 2] {
    if antenna == (0.0, 0.0) {
        return [0.0; 2];
    }
    let (x, y) = antenna_offset(heading + std::f64::consts::FRAC_PI_2, antenna);
    [x, y]
}

/// Share of the slip's along-track variance over one block that the averaged reference noise
/// of an observation may reach when [`position_span`] shortens the averaging.
const SPAN_NOISE_SHARE: f64 = 0.1;

/// The path around a block's middle epoch over which its positions are averaged (m; `None`:
/// the whole block). The along-track error is a random walk (`kappa / 2` per metre, the
/// mean of the wheels'), and the mean of a random walk over a span `s` is smoother than its
/// values: the steps between the means of consecutive blocks of length `d` have `1 - s /
/// (3 d)` of its variance, which the filter, taking the mean for the value at the middle,
/// reads as that much less slip. Against a noisy reference (RTK, SLAM) the whole block's mean
/// is what keeps its noise below the slip and the smoothing is buried in it; against a precise
/// one (motion capture) the span is shortened until the averaged noise `sigma^2 / (rho s)`
/// (per axis; `rho` epochs per metre) reaches [`SPAN_NOISE_SHARE`] of the slip's along-track
/// variance over a block, `kappa d / 2`, and no further than one epoch.
fn position_span(run: &Run, settings: Settings, kappa: f64) -> Option<f64> {
    let d = settings.block_length;
    let distance = run.dist[run.len() - 1] - run.dist[0];
    if !(kappa > 0.0 && distance > 0.0 && d > 0.0) {
        return None;
    }
    let rho = run.len() as f64 / distance;
    let mut variances: Vec<f64> = (0..run.len())
        .map(|k| position_variance(run, k, settings.sigmas.0))
        .collect();
    let sigma2 = median(&mut variances)?;
    let span = sigma2 / (rho * SPAN_NOISE_SHARE * 0.5 * kappa * d);
    (span < d).then(|| span.max(1.0 / rho))
}

/// A reference epoch's noise variance per axis (m^2): its own horizontal sigma, else
/// `ref_sigma`, split over the two axes.
fn position_variance(run: &Run, k: usize, ref_sigma: f64) -> f64 {
    let s = run.reference_at(k).sigma_h.unwrap_or(ref_sigma);
    s * s / 2.0
}

/// The odometry integrated once from the run's start, which every linearisation of
/// [`Innovations`] moves rather than integrates again.
struct OpenLoop {
    /// Sample index of the first match.
    first: usize,
    /// The pose at each sample from the first match's to the last's.
    poses: Vec<Pose>,
    /// Per sample (the first's zero): wheel 1's and wheel 2's distance and `|s_1 - s_2|` (m),
    /// absolute.
    rolled: Vec<[f64; 3]>,
    /// Initial variances of the position (per axis, m^2) and heading (rad^2).
    start_variances: (f64, f64),
}

impl OpenLoop {
    /// Integrates `geometry` from the reference position over the opening standstill and
    /// the reference's heading there (`settings.heading0` without reference headings).
    fn new(run: &Run, geometry: &ChassisParams, settings: Settings) -> Result<Self> {
        let (ref_sigma, ref_heading_sigma) = settings.sigmas;
        let (lo, hi) = run.standstill(0);
        let n0 = (hi - lo + 1) as f64;
        let pos_var0 = (lo..=hi)
            .map(|k| position_variance(run, k, ref_sigma))
            .sum::<f64>()
            / (n0 * n0);
        let (h0, heading_var0) = match run
            .opening_heading(geometry, settings.heading0)
            .map_err(|e| anyhow!("parameters: {e}"))?
        {
            // One epoch's variance: the epochs averaged are observed again in the first block.
            Some((h, _)) => (h, ref_heading_sigma * ref_heading_sigma),
            None => (settings.heading0, 1e-6),
        };
        let mut integ = run
            .start(geometry, 0, h0)
            .map_err(|e| anyhow!("parameters: {e}"))?;
        let first = run.matches[0].0;
        let last = run.matches[run.len() - 1].0;
        let mut poses = Vec::with_capacity(last - first + 1);
        poses.push(integ.pose());
        for s in &run.samples[first + 1..=last] {
            let _ = integ.step_pose(counts(s), index_refs(s));
            poses.push(integ.pose());
        }
        let rolled = rolled_distances(&poses, geometry.track_width);
        Ok(Self {
            first,
            poses,
            rolled,
            start_variances: (pos_var0, heading_var0),
        })
    }
}

/// What each wheel and their difference rolled from each of `poses` to the next on a track
/// `w` (m; zero for the first), [`in_halves`].
fn rolled_distances(poses: &[Pose], w: f64) -> Vec<[f64; 3]> {
    let mut out = Vec::with_capacity(poses.len());
    out.push([0.0; 3]);
    out.extend(in_halves(poses.len().saturating_sub(1), |k| {
        let [s1, s2] = wheel_distances(poses[k], poses[k + 1], w);
        [s1.abs(), s2.abs(), (s1 - s2).abs()]
    }));
    out
}

/// Each of `steps`' terms on a track `w` (m), [`in_halves`].
fn step_terms(steps: &[Step], w: f64) -> Vec<StepTerms> {
    in_halves(steps.len(), |k| steps[k].terms(w))
}

/// `item(k)` for `k` in `0..n`, in order; with two cores and at least [`PARALLEL_STEPS`]
/// items, the second half on another thread (the same results).
fn in_halves<T: Send>(n: usize, item: impl Fn(usize) -> T + Sync) -> Vec<T> {
    if cores() < 2 || n < PARALLEL_STEPS {
        return (0..n).map(item).collect();
    }
    let half = n / 2;
    let item = &item;
    std::thread::scope(|scope| {
        let second = scope.spawn(move || (half..n).map(item).collect::<Vec<_>>());
        let mut out: Vec<T> = Vec::with_capacity(n);
        out.extend((0..half).map(item));
        out.extend(second.join().expect("a half's items panicked"));
        out
    })
}

/// Where a path restarted from `to` at its pose `at` goes: its later poses turned about `at`
/// by `to`'s heading minus `at`'s (clockwise) and moved by `to - at`. The default is no move.
#[derive(Debug, Clone, Copy, Default)]
struct Reanchoring {
    at: Pose,
    to: Pose,
    /// Sine and cosine minus one of the turn (the latter without cancellation).
    sin: f64,
    cos_m1: f64,
}

impl Reanchoring {
    fn new(at: Pose, to: Pose) -> Self {
        let turn = to.heading - at.heading;
        let half = (0.5 * turn).sin();
        Self {
            at,
            to,
            sin: turn.sin(),
            cos_m1: -2.0 * half * half,
        }
    }

    /// The pose `q` of the path moved (exactly `q` when `to` is `at`).
    fn apply(&self, q: Pose) -> Pose {
        let (dx, dy) = (q.x - self.at.x, q.y - self.at.y);
        Pose {
            x: q.x + (self.to.x - self.at.x) + (self.cos_m1 * dx + self.sin * dy),
            y: q.y + (self.to.y - self.at.y) + (self.cos_m1 * dy - self.sin * dx),
            heading: q.heading + (self.to.heading - self.at.heading),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::{default_truth, simulate_path, PathKind, SimSettings};
    use odo_unit::odometry::Integrator;

    /// 40 m of the estimation path with the truth's geometry and 0.2 % slip.
    fn slipping_run(seed: u64) -> crate::simulate::SimRun {
        simulate_path(
            PathKind::Estimation,
            40.0,
            default_truth(),
            SimSettings {
                slip: 0.002,
                seed,
                ..SimSettings::default()
            },
        )
    }

    /// The rolled distances of a long path split between two threads are those of one pass.
    #[test]
    fn rolled_distances_in_halves_are_one_pass() {
        let n = PARALLEL_STEPS + 7;
        let poses: Vec<Pose> = (0..n)
            .map(|k| {
                let t = k as f64 * 1e-3;
                Pose {
                    x: (3.0 * t).sin() * 5.0,
                    y: t * 2.0,
                    heading: (t * 0.7).cos(),
                }
            })
            .collect();
        let w = 0.5656;
        let got = rolled_distances(&poses, w);
        assert_eq!(got.len(), n);
        assert_eq!(got[0], [0.0; 3]);
        for k in 1..n {
            let [s1, s2] = wheel_distances(poses[k - 1], poses[k], w);
            assert_eq!(got[k], [s1.abs(), s2.abs(), (s1 - s2).abs()], "at {k}");
        }
    }

    /// The span of [`position_span`] at the boundaries: the whole block (`None`) where the
    /// averaged noise stays above a tenth of the slip's along-track variance over a block,
    /// one epoch at no noise, the balance between (m).
    #[test]
    fn the_averaging_span_shortens_only_against_a_precise_reference() {
        let sim = slipping_run(3);
        let m = crate::csvio::match_or_fail(&sim.samples, "s", &sim.reference, "r", 10).unwrap();
        let run = Run::new(&sim.samples, &sim.reference, m);
        let rho = run.len() as f64 / (run.dist[run.len() - 1] - run.dist[0]);
        let with = |sigma: f64| Settings {
            sigmas: (sigma, 0.01),
            ..settings(0.0)
        };
        // sigma^2 / 2 / (rho 0.1 kappa / 2) at the default 1 m blocks.
        let balance = |sigma: f64, kappa: f64| sigma * sigma / (rho * 0.1 * kappa);
        let kappa = 2e-7;
        for (sigma, kappa, expected) in [
            (0.008, kappa, None),
            (0.003, kappa, None),
            (0.0005, kappa, Some(balance(0.0005, kappa))),
            (0.0002, kappa, Some(balance(0.0002, kappa).max(1.0 / rho))),
            (0.0, kappa, Some(1.0 / rho)),
            (0.0005, 0.0, None),
            (0.0005, f64::NAN, None),
        ] {
            let got = position_span(&run, with(sigma), kappa);
            match (got, expected) {
                (None, None) => {}
                (Some(g), Some(e)) => assert!((g / e - 1.0).abs() < 1e-9, "{sigma}: {g} {e}"),
                _ => panic!("sigma {sigma}, kappa {kappa}: {got:?} against {expected:?}"),
            }
        }
        assert!(balance(0.0005, kappa) < 1.0 && balance(0.003, kappa) > 1.0);
    }

    /// The BD982's sigmas, 1 m blocks, start heading `heading0` (rad).
    fn settings(heading0: f64) -> Settings {
        Settings {
            heading0,
            sigmas: (0.008, 0.5f64.to_radians()),
            block_length: OBSERVATION_BLOCK,
            span: None,
        }
    }

    /// The path moved to an anchor is the odometry integrated again from that anchor (the
    /// core's arithmetic: to its rounding), and moved onto its own pose it is the path itself.
    #[test]
    fn a_moved_path_is_the_path_integrated_from_the_anchor() {
        let truth = default_truth();
        let sim = slipping_run(5);
        let m = crate::csvio::match_or_fail(&sim.samples, "s", &sim.reference, "r", 10).unwrap();
        let run = Run::new(&sim.samples, &sim.reference, m);
        let settings = settings(0.3);
        let path = OpenLoop::new(&run, &truth, settings).unwrap();
        let n = path.poses.len();
        for (at, dx, dy, turn) in [
            (n / 4, 0.0, 0.0, 0.0),
            (n / 3, 0.02, -0.01, 0.003),
            (n / 2, -0.5, 0.3, -0.2),
            (n - 2, 1.0, 1.0, 3.0),
        ] {
            let open = path.poses[at];
            let anchor = Pose {
                x: open.x + dx,
                y: open.y + dy,
                heading: open.heading + turn,
            };
            let moved = Reanchoring::new(open, anchor);
            // Integrated from the anchor at sample `first + at`.
            let mut again =
                Integrator::new(&truth, counts(&run.samples[path.first + at]), anchor).unwrap();
            for j in at + 1..n {
                let s = &run.samples[path.first + j];
                let _ = again.step_pose(counts(s), index_refs(s));
                let (a, b) = (moved.apply(path.poses[j]), again.pose());
                assert!(
                    (a.x - b.x).abs() < 1e-6 && (a.y - b.y).abs() < 1e-6,
                    "anchor at {at}, sample {j}: {a:?} {b:?}"
                );
                assert!((a.heading - b.heading).abs() < 1e-9, "{a:?} {b:?}");
                if turn == 0.0 && dx == 0.0 {
                    assert_eq!(a, path.poses[j]);
                }
            }
        }
    }

    /// A re-anchoring moves the point of linearisation only: anchored at the odometry's own
    /// poses the filter is the open-loop one; anchored 1 cm off them, the same to rounding;
    /// turned 0.2 mrad off them, the likelihood moves by hundredths (the block's mean position
    /// is taken at its middle step, which turns with the anchor a little differently).
    #[test]
    fn re_anchoring_keeps_the_likelihood() {
        let truth = default_truth();
        let sim = slipping_run(3);
        let m = crate::csvio::match_or_fail(&sim.samples, "s", &sim.reference, "r", 10).unwrap();
        let run = Run::new(&sim.samples, &sim.reference, m);
        let settings = settings(0.0);
        let path = OpenLoop::new(&run, &truth, settings).unwrap();
        let build = |anchors: Option<&[Pose]>| {
            Innovations::anchored(&run, &truth, settings, &path, anchors).unwrap()
        };
        let open = build(None);
        assert!(open.observations > 30);
        let off = |px: f64, ph: f64| -> Vec<Pose> {
            open.closes
                .iter()
                .enumerate()
                .map(|(i, c)| {
                    let s = if i % 2 == 0 { 1.0 } else { -1.0 };
                    Pose {
                        x: c.x + px * s,
                        y: c.y - 0.7 * px * s,
                        heading: c.heading + ph * s,
                    }
                })
                .collect()
        };
        let same = build(Some(&open.closes));
        let moved = build(Some(&off(0.01, 0.0)));
        let turned = build(Some(&off(0.0, 2e-4)));
        for kappa in [1e-7, 1e-6, 1e-5] {
            let a = open.score(kappa).nll;
            let [b, c, d] = [&same, &moved, &turned].map(|i| i.score(kappa).nll);
            assert!((a - b).abs() < 1e-9 * a.abs(), "kappa {kappa}: {a} {b}");
            assert!((a - c).abs() < 1e-5, "kappa {kappa}: {a} {c}");
            assert!((a - d).abs() < 0.05, "kappa {kappa}: {a} {d}");
        }
    }
}
