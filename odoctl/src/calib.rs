//! Calibration against a reference trajectory (RTK GNSS): eq (16) of the paper for the wheel
//! diameters and the track width, the uncertainty coefficients by a coverage criterion, the
//! stability study on sub-trajectories (the paper's Figs. 7-9), and the error evaluation used
//! by `validate`.
//!
//! All odometry goes through the core integrator, so a calibrated run is bit-consistent with
//! what the unit computes.
//!
//! # Geometry (eq 16)
//! The unknowns are `left_diameter`, `right_diameter`, `track_width` and the initial heading;
//! the initial position is the reference point at the first common time (when the counts
//! show the chassis standing still there, the mean of the reference points over that
//! standstill: the same position with the RTK noise averaged out). The cost is
//! `e = sum_i |p_odo(i) - p_ref(i)|` over all common times. The minimisation:
//! 1. continuation: Levenberg-Marquardt on the squared distances over a growing prefix of the
//!    trajectory (2 m of reference path, then x1.5 per stage up to the whole run), each stage
//!    starting from the previous one's result; a poor first estimate (0.300/0.300/0.700 m)
//!    would otherwise wind the odometry around the reference and trap the fit;
//! 2. damped Newton on eq (16) itself: gradient `sum J_k^T u_k`, Hessian
//!    `sum J_k^T (I - u_k u_k^T) J_k / |r_k|` (`u_k` the unit residual), Levenberg-Marquardt
//!    damping, steps accepted only when eq (16) falls;
//! 3. optionally a Nelder-Mead polish of eq (16) with restarts; the lowest eq (16) is kept.
//!
//! Every Jacobian is analytic: the forward sensitivities of eqs (7)-(15) with respect to the
//! diameters, the track width and the initial heading are propagated in f64 in the same
//! pass as the core integrator ([`Run::integrate_with_sensitivity`]), which stays the one
//! source of the poses. At the estimate, [`standard_errors`] gives the unknowns' standard
//! errors and [`track_width_warning`] says when the run turned too little for the track
//! width.
//!
//! # Uncertainty coefficients
//! The trajectory is cut into consecutive sub-trajectories of `window` metres of reference
//! path. Each is restarted from the reference: position = the reference point, heading = the
//! heading minimising eq (16) over that sub-trajectory (a noisy reference heading would swamp
//! the odometry error), sigmas = 0. At every later common time of the sub-trajectory the
//! horizontal error `e` and the predicted `sigma_h` are taken. The coefficient (`delta_left =
//! delta_right` for the paper's model, `kappa_left = kappa_right` for the covariance model;
//! equal by default, or their initial ratio kept) is the smallest value for which
//! `e <= sqrt(sigma_h^2 + sigma_ref^2)` holds at 68.27 % of those points (the 1-sigma band
//! covers the errors as often as a normal 1-sigma interval would); `sigma_ref` is the
//! reference's own horizontal noise (8 mm RMS for the BD982; 0 to ignore it).
//!
//! For the paper's model with a reference heading, [`fit_delta_diff`] then fits `delta_diff`
//! on the same sub-trajectories by the heading-change coverage, with delta refitted jointly.

use std::cell::RefCell;
use std::rc::Rc;

use anyhow::{anyhow, bail, Result};
use indicatif::ProgressBar;

use crate::core_api::{trig, ChassisParams, Integrator, Pose, PoseStep, UncertaintyModel};
use crate::csvio::{RefPoint, Sample};
use crate::optim::{self, norm2, LmOptions, NmOptions, NormalAccumulator, Objective};
use crate::replay::{counts, index_refs};
use crate::stats::wrap_angle;

/// Time after a stretch's start over which its reference heading is averaged (s); see
/// [`Run::start_heading`].
pub const START_ALIGN: f64 = 1.0;

/// Nominal coverage of a 1-sigma band of a normal distribution.
pub const ONE_SIGMA_COVERAGE: f64 = 0.682_689_492;

/// Reference points closer than this to the last anchor do not add to the path length (m):
/// keeps the RTK noise from inflating the distance travelled.
const PATH_STEP: f64 = 0.05;

/// A recorded run matched to its reference.
pub struct Run<'a> {
    /// SAMPLES rows.
    pub samples: &'a [Sample],
    /// REFERENCE rows.
    pub reference: &'a [RefPoint],
    /// (sample index, reference index) at common times, increasing.
    pub matches: Vec<(usize, usize)>,
    /// Reference path length from the first match to each match (m).
    pub dist: Vec<f64>,
}

/// The unknowns of the geometry fit, in the order of [`PoseSensitivity`]'s columns and of
/// the fit's parameter vector.
pub const GEOMETRY_UNKNOWNS: [&str; 4] = [
    "left_diameter",
    "right_diameter",
    "track_width",
    "initial_heading",
];

/// Derivatives of an odometry pose with respect to the geometry fit's unknowns, in the order
/// of [`GEOMETRY_UNKNOWNS`]: `left_diameter` (m), `right_diameter` (m), `track_width` (m) and
/// the initial heading (rad). Position rows are in m per unit of the unknown (x east, y
/// north), the heading row in rad per unit (clockwise positive).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PoseSensitivity {
    /// `d x / d unknown`.
    pub x: [f64; 4],
    /// `d y / d unknown`.
    pub y: [f64; 4],
    /// `d heading / d unknown`.
    pub heading: [f64; 4],
}

/// Q30 one.
const Q30: f64 = 1_073_741_824.0;

/// `sin(h)/h` and its derivative, by their Taylor series (|h| <= pi/4 in a step: truncation
/// below 1e-10; no branch at 0).
fn sinc_and_derivative(h: f64) -> (f64, f64) {
    let h2 = h * h;
    let sinc = 1.0
        - h2 / 6.0 * (1.0 - h2 / 20.0 * (1.0 - h2 / 42.0 * (1.0 - h2 / 72.0 * (1.0 - h2 / 110.0))));
    let d =
        -h / 3.0 * (1.0 - h2 / 10.0 * (1.0 - h2 / 28.0 * (1.0 - h2 / 54.0 * (1.0 - h2 / 88.0))));
    (sinc, d)
}

/// Forward sensitivities of eqs (7)-(15), propagated in f64 beside the core integrator, which
/// stays the one source of the poses: each step's heading change `dalpha`, chord direction
/// `theta = alpha + dalpha/2` (its sine and cosine) and chord `dd` are the ones the integrator
/// moved the pose with ([`PoseStep`], from [`Integrator::step_pose`]), the wheel
/// distances recovered from them as `s_1,2 = ds +- w dalpha/2`, `ds = dd / sinc(dalpha/2)`,
/// and the derivatives of
/// `dalpha = (s_1 - s_2)/w`, `dd = ds sinc(dalpha/2)`, `x += dd sin(theta)`,
/// `y += dd cos(theta)`, `alpha += dalpha` accumulated with `d s_i / d D_i = s_i / D_i` (the
/// wheel distance, including the per-angle wheel function, is proportional to its diameter).
struct SensitivityTracker {
    model: SensitivityModel,
    sens: PoseSensitivity,
}

/// The chassis constants of [`SensitivityTracker`]'s update.
#[derive(Debug, Clone, Copy)]
struct SensitivityModel {
    /// `1 / D_1`, `1 / D_2` (1/m).
    inv_diameters: [f64; 2],
    /// `w` (m).
    track: f64,
    /// `1 / w` (1/m).
    inv_track: f64,
}

/// The part of one step's sensitivity update that depends on the step alone, not on the
/// sensitivities so far.
#[derive(Debug, Clone, Copy)]
struct StepTerms {
    /// `sin(theta)`, `cos(theta)`.
    sin: f64,
    cos: f64,
    /// Chord `dd` (m).
    dd: f64,
    /// `d dd / d unknown` at fixed heading.
    d_dd: [f64; 4],
    /// `d dalpha / d unknown`.
    d_dalpha: [f64; 4],
}

/// Chord units of [`PoseStep::chord`] per metre (2^48).
const CHORD_SCALE: f64 = 281_474_976_710_656.0;

impl SensitivityModel {
    fn new(params: &ChassisParams) -> Self {
        Self {
            inv_diameters: [1.0 / params.left_diameter, 1.0 / params.right_diameter],
            track: params.track_width,
            inv_track: 1.0 / params.track_width,
        }
    }

    /// The terms of the integrator's step `m`; `None` when it did not move.
    #[inline(always)]
    fn terms(&self, m: &PoseStep) -> Option<StepTerms> {
        if m.heading_increment == 0 && m.chord == 0 {
            return None;
        }
        let (sin, cos) = (f64::from(m.sin) / Q30, f64::from(m.cos) / Q30);
        let dalpha = m.heading_increment as f64 * trig::RAD_PER_BINARY;
        let half = 0.5 * dalpha;
        let (sinc, dsinc) = sinc_and_derivative(half);
        let dd = m.chord as f64 / CHORD_SCALE;
        let ds = dd / sinc;
        let [i1, i2] = self.inv_diameters;
        let (w, iw) = (self.track, self.inv_track);
        let (s1, s2) = (ds + w * half, ds - w * half);
        let (e1, e2) = (s1 * i1, s2 * i2);
        let d_dalpha = [e1 * iw, -e2 * iw, -dalpha * iw, 0.0];
        let d_ds = [0.5 * e1, 0.5 * e2, 0.0, 0.0];
        let d_dd = std::array::from_fn(|p| d_ds[p] * sinc + ds * dsinc * 0.5 * d_dalpha[p]);
        Some(StepTerms {
            sin,
            cos,
            dd,
            d_dd,
            d_dalpha,
        })
    }
}

impl SensitivityTracker {
    /// At the start: zero derivatives except `d heading / d heading0 = 1`.
    fn new(params: &ChassisParams) -> Self {
        let mut sens = PoseSensitivity::default();
        sens.heading[3] = 1.0;
        Self {
            model: SensitivityModel::new(params),
            sens,
        }
    }

    /// Follows one integrated step of the integrator, from the motion it reports.
    #[inline(always)]
    fn step(&mut self, m: &PoseStep) {
        if let Some(t) = self.model.terms(m) {
            self.apply(&t);
        }
    }

    /// Follows a step from its terms.
    #[inline(always)]
    fn apply(&mut self, t: &StepTerms) {
        let s = &mut self.sens;
        for p in 0..4 {
            let d_theta = s.heading[p] + 0.5 * t.d_dalpha[p];
            s.x[p] += t.d_dd[p] * t.sin + t.dd * t.cos * d_theta;
            s.y[p] += t.d_dd[p] * t.cos - t.dd * t.sin * d_theta;
            s.heading[p] += t.d_dalpha[p];
        }
    }
}

/// The cores this process may run on, asked once (the question reads the scheduler's
/// affinity and cgroup limits: too slow to ask at every integration).
pub fn cores() -> usize {
    static CORES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// Shortest stretch (samples) that [`Run::integrate_with_sensitivity`] spreads over two
/// cores: below it, the thread costs more than it saves.
pub const PIPELINE_MIN_SAMPLES: usize = 20_000;

/// Samples per chunk handed from the integrating thread to the sensitivity thread (80 bytes
/// each: 320 KiB, in the caches).
const PIPELINE_CHUNK: usize = 4096;

/// Chunks in flight between the two threads at most.
const PIPELINE_DEPTH: usize = 4;

/// One sample as the integrating thread hands it on: the step's motion, when integrated, and
/// at a match its index and the pose there.
struct PipelineItem {
    motion: Option<PoseStep>,
    at: Option<(usize, Pose)>,
}

impl<'a> Run<'a> {
    /// Matches the files (see `csvio::match_times`) and measures the reference path.
    pub fn new(
        samples: &'a [Sample],
        reference: &'a [RefPoint],
        matches: Vec<(usize, usize)>,
    ) -> Self {
        let mut dist = Vec::with_capacity(matches.len());
        let mut total = 0.0;
        let mut anchor: Option<(f64, f64)> = None;
        for &(_, r) in &matches {
            let p = &reference[r];
            match anchor {
                None => anchor = Some((p.x, p.y)),
                Some((ax, ay)) => {
                    let d = (p.x - ax).hypot(p.y - ay);
                    if d >= PATH_STEP {
                        total += d;
                        anchor = Some((p.x, p.y));
                    }
                }
            }
            dist.push(total);
        }
        Self {
            samples,
            reference,
            matches,
            dist,
        }
    }

    /// Number of common times.
    pub fn len(&self) -> usize {
        self.matches.len()
    }

    /// True when there is no common time.
    pub fn is_empty(&self) -> bool {
        self.matches.is_empty()
    }

    /// Reference point of match `k`.
    pub fn reference_at(&self, k: usize) -> &RefPoint {
        &self.reference[self.matches[k].1]
    }

    /// The start position of a stretch beginning at match `a`: the reference point there, or,
    /// when the counts show the chassis standing still around it, the mean of the reference
    /// points of that standstill (the same true position, with the RTK noise averaged out).
    pub fn anchor(&self, a: usize) -> (f64, f64) {
        let (lo, hi) = self.standstill(a);
        let n = (hi - lo + 1) as f64;
        let (sx, sy) = (lo..=hi).fold((0.0, 0.0), |(sx, sy), k| {
            let r = self.reference_at(k);
            (sx + r.x, sy + r.y)
        });
        (sx / n, sy / n)
    }

    /// The matches `lo..=hi` around `a` at which the counts equal those at `a` (the chassis
    /// standing still there; `(a, a)` when it moves).
    pub fn standstill(&self, a: usize) -> (usize, usize) {
        let c = counts(&self.samples[self.matches[a].0]);
        let still = |k: usize| counts(&self.samples[self.matches[k].0]) == c;
        let mut lo = a;
        while lo > 0 && still(lo - 1) {
            lo -= 1;
        }
        let mut hi = a;
        while hi + 1 < self.len() && still(hi + 1) {
            hi += 1;
        }
        (lo, hi)
    }

    /// The reference heading at the start of a stretch beginning at match `a`, with the
    /// number of reference headings averaged for it; `None` when the reference has no heading
    /// at `a`. The circular mean of `reference heading - odometry heading change since a`
    /// (`change(k)`, `None` where unknown) over the standstill before `a` (change 0) and the
    /// matches within [`START_ALIGN`] seconds after it: one reference heading carries its
    /// full noise into every later heading-change error, an average a fraction of it.
    pub fn start_heading(
        &self,
        a: usize,
        change: impl Fn(usize) -> Option<f64>,
    ) -> Option<(f64, usize)> {
        let h0 = self.reference_at(a).heading?;
        let (lo, _) = self.standstill(a);
        let t_end = self.reference_at(a).t + START_ALIGN;
        let (mut sum, mut n) = (0.0, 0usize);
        for k in lo..self.len() {
            let r = self.reference_at(k);
            if k > a && r.t > t_end {
                break;
            }
            let c = if k <= a { Some(0.0) } else { change(k) };
            if let (Some(h), Some(c)) = (r.heading, c) {
                sum += wrap_angle(h - c - h0);
                n += 1;
            }
        }
        Some((h0 + sum / n.max(1) as f64, n.max(1)))
    }

    /// Last match `b >= a` whose path distance from match `a` is at most `length`.
    pub fn last_within(&self, a: usize, length: f64) -> usize {
        let limit = self.dist[a] + length;
        let mut b = a;
        while b + 1 < self.len() && self.dist[b + 1] <= limit {
            b += 1;
        }
        b
    }

    /// Runs the core integrator from match `a` (position = the reference point there, heading
    /// `heading0`, zero sigmas) to match `b`, calling `visit(k, &integrator)` at every match
    /// `k` in `a+1..=b`. The uncertainty is propagated too (see [`Run::integrate_pose`]).
    pub fn integrate(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        visit: impl FnMut(usize, &Integrator),
    ) -> Result<(), crate::core_api::ParamError> {
        self.integrate_steps(params, a, b, heading0, true, visit)
    }

    /// [`Run::integrate`] with the pose alone ([`Integrator::step_pose`]: the same poses, bit
    /// for bit, without the uncertainty, whose sigmas stay zero): for the eq (16) fits.
    pub fn integrate_pose(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        visit: impl FnMut(usize, &Integrator),
    ) -> Result<(), crate::core_api::ParamError> {
        self.integrate_steps(params, a, b, heading0, false, visit)
    }

    /// [`Run::integrate`] (`uncertainty`) or [`Run::integrate_pose`].
    #[inline(always)]
    fn integrate_steps(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        uncertainty: bool,
        mut visit: impl FnMut(usize, &Integrator),
    ) -> Result<(), crate::core_api::ParamError> {
        self.drive(
            params,
            a,
            b,
            heading0,
            |integ, s| {
                if uncertainty {
                    let _ = integ.step(counts(s), index_refs(s));
                } else {
                    let _ = integ.step_pose(counts(s), index_refs(s));
                }
                None
            },
            |k, integ, _| visit(k, integ),
        )
    }

    /// [`Run::integrate_pose`] with the pose's derivatives with respect to the geometry
    /// unknowns (see [`PoseSensitivity`]) propagated alongside: `visit(k, &pose,
    /// &sensitivity)` at every match `k` in `a+1..=b`. A stretch of at least
    /// [`PIPELINE_MIN_SAMPLES`] samples is integrated on a second core while this one follows
    /// the sensitivities and visits: the same arithmetic in the same order, so the same
    /// results to the bit.
    pub fn integrate_with_sensitivity(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        mut visit: impl FnMut(usize, &Pose, &PoseSensitivity),
    ) -> Result<(), crate::core_api::ParamError> {
        let samples = self.matches[b].0 - self.matches[a].0;
        if samples >= PIPELINE_MIN_SAMPLES && cores() > 1 {
            self.integrate_with_sensitivity_pipelined(params, a, b, heading0, visit)
        } else {
            self.integrate_with_sensitivity_here(params, a, b, heading0, |k, integ, d| {
                visit(k, &integ.pose(), d)
            })
        }
    }

    /// [`Run::integrate_with_sensitivity`] on this core alone.
    pub fn integrate_with_sensitivity_here(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        visit: impl FnMut(usize, &Integrator, &PoseSensitivity),
    ) -> Result<(), crate::core_api::ParamError> {
        self.drive(
            params,
            a,
            b,
            heading0,
            |integ, s| integ.step_pose(counts(s), index_refs(s)).1,
            visit,
        )
    }

    /// [`Run::integrate_with_sensitivity`] as a pipeline: a scoped thread runs the core
    /// integrator and hands each sample's motion ([`PoseStep`]) and, at the matches, the pose
    /// on, in chunks of [`PIPELINE_CHUNK`] samples (recycled); this thread follows the
    /// sensitivities and calls `visit`.
    pub fn integrate_with_sensitivity_pipelined(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        mut visit: impl FnMut(usize, &Pose, &PoseSensitivity),
    ) -> Result<(), crate::core_api::ParamError> {
        let mut integ = self.start(params, a, heading0)?;
        let (sa, sb) = (self.matches[a].0, self.matches[b].0);
        let (full, chunks) = std::sync::mpsc::sync_channel::<Vec<PipelineItem>>(PIPELINE_DEPTH);
        let (recycle, empty) = std::sync::mpsc::channel::<Vec<PipelineItem>>();
        let mut tracker = SensitivityTracker::new(params);
        std::thread::scope(|scope| {
            scope.spawn(move || {
                let mut k = a + 1;
                let mut chunk = Vec::with_capacity(PIPELINE_CHUNK);
                for i in sa + 1..=sb {
                    let s = &self.samples[i];
                    let motion = integ.step_pose(counts(s), index_refs(s)).1;
                    let at = (k <= b && self.matches[k].0 == i).then(|| {
                        k += 1;
                        (k - 1, integ.pose())
                    });
                    chunk.push(PipelineItem { motion, at });
                    if chunk.len() == PIPELINE_CHUNK {
                        if full.send(chunk).is_err() {
                            return;
                        }
                        chunk = empty
                            .try_recv()
                            .unwrap_or_else(|_| Vec::with_capacity(PIPELINE_CHUNK));
                    }
                }
                if !chunk.is_empty() {
                    let _ = full.send(chunk);
                }
            });
            for mut chunk in chunks {
                for item in &chunk {
                    if let Some(m) = &item.motion {
                        tracker.step(m);
                    }
                    if let Some((k, pose)) = &item.at {
                        visit(*k, pose, &tracker.sens);
                    }
                }
                chunk.clear();
                let _ = recycle.send(chunk);
            }
        });
        Ok(())
    }

    /// The core integrator at the start of a stretch beginning at match `a`: the counts of
    /// its sample, the position [`Run::anchor`], heading `heading0`, zero sigmas.
    fn start(
        &self,
        params: &ChassisParams,
        a: usize,
        heading0: f64,
    ) -> Result<Integrator, crate::core_api::ParamError> {
        let (x0, y0) = self.anchor(a);
        Integrator::new(
            params,
            counts(&self.samples[self.matches[a].0]),
            Pose {
                x: x0,
                y: y0,
                heading: heading0,
            },
        )
    }

    /// The loop of the `integrate` functions: `step` advances the integrator by one sample
    /// and returns the step's motion when the sensitivities should follow it.
    #[inline(always)]
    fn drive(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        mut step: impl FnMut(&mut Integrator, &Sample) -> Option<PoseStep>,
        mut visit: impl FnMut(usize, &Integrator, &PoseSensitivity),
    ) -> Result<(), crate::core_api::ParamError> {
        let mut integ = self.start(params, a, heading0)?;
        let sa = self.matches[a].0;
        let mut tracker = SensitivityTracker::new(params);
        let mut k = a + 1;
        let sb = self.matches[b].0;
        for i in sa + 1..=sb {
            if let Some(m) = step(&mut integ, &self.samples[i]) {
                tracker.step(&m);
            }
            if k <= b && self.matches[k].0 == i {
                visit(k, &integ, &tracker.sens);
                k += 1;
            }
        }
        Ok(())
    }

    /// [`Run::residuals`] and, with `jac`, their derivatives with respect to the geometry
    /// unknowns `cols` (indices into [`GEOMETRY_UNKNOWNS`]; row-major: one row per residual,
    /// one column per entry of `cols`), in the same pass.
    #[allow(clippy::too_many_arguments)]
    pub fn residuals_with_jacobian(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        out: &mut Vec<f64>,
        jac: Option<&mut Vec<f64>>,
        cols: &[usize],
    ) -> bool {
        let Some(jac) = jac else {
            return self.residuals(params, a, b, heading0, out);
        };
        if cols.iter().any(|&c| c >= GEOMETRY_UNKNOWNS.len()) {
            return false;
        }
        out.clear();
        jac.clear();
        // Room for every row at once: no regrowth (and copy) of the large Jacobian.
        out.reserve(2 * (b - a));
        jac.reserve(2 * (b - a) * cols.len());
        self.integrate_with_sensitivity(params, a, b, heading0, |k, p, d| {
            let r = self.reference_at(k);
            out.push(p.x - r.x);
            out.push(p.y - r.y);
            jac.extend(cols.iter().map(|&c| d.x[c]));
            jac.extend(cols.iter().map(|&c| d.y[c]));
        })
        .is_ok()
            && out.iter().chain(jac.iter()).all(|v| v.is_finite())
    }

    /// [`Run::residuals_with_jacobian`] fed straight into `acc` (pair by pair, in match order:
    /// the same sums as of the stored vectors) instead of stored: the objective and normal
    /// equations of the eq (16) fits without a pass over tens of megabytes of Jacobian.
    /// False when the parameters are not admissible or a residual is not finite.
    pub fn accumulate_normal(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        cols: &[usize],
        acc: &mut NormalAccumulator,
    ) -> bool {
        if cols.iter().any(|&c| c >= GEOMETRY_UNKNOWNS.len()) {
            return false;
        }
        let mut finite = true;
        let (mut jx, mut jy) = ([0.0; 4], [0.0; 4]);
        let ok = self
            .integrate_with_sensitivity(params, a, b, heading0, |k, p, d| {
                let r = self.reference_at(k);
                for (j, &c) in cols.iter().enumerate() {
                    jx[j] = d.x[c];
                    jy[j] = d.y[c];
                }
                let (rx, ry) = (p.x - r.x, p.y - r.y);
                finite &= rx.is_finite() && ry.is_finite();
                acc.add_pair(rx, ry, &jx, &jy);
            })
            .is_ok();
        ok && finite && acc.cost().is_finite()
    }

    /// The x and y differences odometry - reference at matches `a+1..=b`, into `out`;
    /// false when the parameters are not admissible.
    pub fn residuals(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        out: &mut Vec<f64>,
    ) -> bool {
        out.clear();
        out.reserve(2 * (b - a));
        self.integrate_pose(params, a, b, heading0, |k, integ| {
            let p = integ.pose();
            let r = self.reference_at(k);
            out.push(p.x - r.x);
            out.push(p.y - r.y);
        })
        .is_ok()
            && out.iter().all(|v| v.is_finite())
    }

    /// Eq (16) over matches `a..=b`.
    pub fn eq16(&self, params: &ChassisParams, a: usize, b: usize, heading0: f64) -> Option<f64> {
        let mut r = Vec::new();
        self.residuals(params, a, b, heading0, &mut r)
            .then(|| optim::objective(Objective::SumOfNorms, &r))
    }

    /// A first guess of the heading at match `a`: the reference's heading there when it has
    /// one, else the direction from the reference point at `a` to the first one at least
    /// 0.3 m away (0 when the reference never moves that far).
    pub fn heading_guess(&self, a: usize) -> f64 {
        let r0 = self.reference_at(a);
        if let Some(h) = r0.heading {
            return h;
        }
        for k in a + 1..self.len() {
            let r = self.reference_at(k);
            let (dx, dy) = (r.x - r0.x, r.y - r0.y);
            if dx.hypot(dy) >= 0.3 {
                return dx.atan2(dy);
            }
        }
        0.0
    }
}

/// Which parameters the geometry fit estimates.
fn with_geometry(base: &ChassisParams, x: &[f64]) -> ChassisParams {
    let mut p = *base;
    p.left_diameter = x[0];
    p.right_diameter = x[1];
    p.track_width = x[2];
    p
}

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
    /// Standard errors of [`GEOMETRY_UNKNOWNS`] (m, m, m, rad; `None` for an unknown that was
    /// held); see [`standard_errors`].
    pub std_errors: [Option<f64>; 4],
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
}

impl Default for GeomOptions {
    fn default() -> Self {
        Self {
            first_stage: 2.0,
            stage_growth: 1.5,
            polish: false,
            min_turning: 30f64.to_radians(),
        }
    }
}

/// Total absolute heading change of the odometry over matches `a..=b` (rad), summed over
/// steps of at least 0.25 m of path so that count noise does not add up.
pub fn turning(run: &Run, params: &ChassisParams, a: usize, b: usize, heading0: f64) -> f64 {
    let mut total = 0.0;
    let mut last = (heading0, run.dist[a]);
    let _ = run.integrate_pose(params, a, b, heading0, |k, integ| {
        let h = integ.pose().heading;
        if run.dist[k] - last.1 >= 0.25 || k == b {
            total += (h - last.0).abs();
            last = (h, run.dist[k]);
        }
    });
    total
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
        run.accumulate_normal(&with_geometry(base, &v), a, b, v[3], &idx, acc)
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
    let scale = [
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
    let debug = std::env::var_os("ODOCTL_DEBUG").is_some();
    let (mut iterations, mut evaluations) = (0, 0);
    let lm = LmOptions {
        max_iter: 60,
        pred_tol: STAGE_PRED_TOL,
        // Light damping from the start: the trust region (max_step) bounds the first steps
        // from a poor estimate, and each stage starts near its minimum.
        lambda0: 1e-9,
        ..LmOptions::default()
    };
    progress.set_length((ends.len() + 1 + usize::from(opts.polish)) as u64);
    let mut free = [true, true, false, true];
    for &e in &ends {
        // The track width joins once the stretch has turned enough (it stays free after).
        if !free[2] && turning(run, &with_geometry(start, &x), a, e, x[3]) >= opts.min_turning {
            free[2] = true;
        }
        let res = lm_subset(run, start, a, e, &x, &scale, &free, Objective::Squares, lm)
            .ok_or_else(|| anyhow!("the starting parameters are not admissible"))?;
        x = res.x;
        iterations += res.iterations;
        evaluations += res.evaluations;
        if debug {
            eprintln!(
                "stage to {e} ({:.1} m): {x:?} cost {} iterations {} runs {} free {free:?}",
                run.dist[e] - run.dist[a],
                res.cost,
                res.iterations,
                res.evaluations
            );
        }
        progress.inc(1);
    }
    let res = lm_subset(
        run,
        start,
        a,
        b,
        &x,
        &scale,
        &free,
        Objective::SumOfNorms,
        LmOptions {
            max_iter: 200,
            pred_tol: FINAL_PRED_TOL,
            newton: true,
            ..lm
        },
    )
    .ok_or_else(|| anyhow!("the fit left the admissible parameter range"))?;
    x = res.x;
    let mut cost = res.cost;
    iterations += res.iterations;
    evaluations += res.evaluations;
    if debug {
        eprintln!(
            "final fit: {x:?} cost {} iterations {} runs {}",
            res.cost, res.iterations, res.evaluations
        );
    }
    progress.inc(1);
    if opts.polish {
        let idx: Vec<usize> = (0..4).filter(|&i| free[i]).collect();
        let full = |sub: &[f64]| {
            let mut v = x.clone();
            for (j, &i) in idx.iter().enumerate() {
                v[i] = sub[j];
            }
            v
        };
        let sub0: Vec<f64> = idx.iter().map(|&i| x[i]).collect();
        let step: Vec<f64> = idx.iter().map(|&i| scale[i] * 1e-4).collect();
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
        evaluations += nm.evaluations;
        iterations += nm.iterations;
        if nm.cost < cost {
            x = full(&nm.x);
            cost = nm.cost;
        }
        progress.inc(1);
    }
    let params = with_geometry(start, &x);
    let turned = turning(run, &params, a, b, x[3]);
    let (std_errors, residual_sigma) = standard_errors(run, &params, a, b, x[3], free)
        .ok_or_else(|| anyhow!("the fit left the admissible parameter range"))?;
    evaluations += 2;
    let track_warning =
        track_width_warning(free[2], turned, opts.min_turning, &params, &std_errors);
    Ok(GeomFit {
        params,
        heading0: x[3],
        start: run.anchor(a),
        cost,
        points: b - a,
        iterations,
        evaluations,
        stages: ends.len(),
        track_estimated: free[2],
        turning: turned,
        std_errors,
        residual_sigma,
        track_warning,
    })
}

/// Relative standard error of `track_width` above which the fit warns that the trajectory
/// turned too little to determine it (see [`track_width_warning`]).
pub const TRACK_WIDTH_MAX_RELATIVE_SE: f64 = 1e-3;

/// Total absolute turning below which the fit warns that the track width is poorly
/// determined, whatever its standard error says (rad; 90 degrees).
pub const TRACK_WIDTH_WARN_TURNING: f64 = core::f64::consts::FRAC_PI_2;

/// The warning of a geometry fit whose trajectory turned too little to determine the track
/// width: it was held (total absolute turning below `min_turning`), or the turning is below
/// [`TRACK_WIDTH_WARN_TURNING`] (90 deg), or the relative standard error of `track_width`
/// exceeds [`TRACK_WIDTH_MAX_RELATIVE_SE`] (0.1 %, 0.6 mm on a 0.56 m track). Eq (8): only
/// turning reveals the track width, and the formal standard error assumes independent
/// residuals, which odometry drift is not, so both the turning and the error are checked.
pub fn track_width_warning(
    estimated: bool,
    turning: f64,
    min_turning: f64,
    params: &ChassisParams,
    std_errors: &[Option<f64>; 4],
) -> Option<String> {
    let deg = turning.to_degrees();
    if !estimated {
        return Some(format!(
            "the trajectory turned {deg:.0} deg in all (less than {:.0}): track_width not estimated, kept at {}",
            min_turning.to_degrees(),
            params.track_width
        ));
    }
    let rel = std_errors[2].map_or(f64::INFINITY, |se| se / params.track_width);
    if turning < TRACK_WIDTH_WARN_TURNING || rel.is_nan() || rel > TRACK_WIDTH_MAX_RELATIVE_SE {
        return Some(format!(
            "the trajectory turned {deg:.0} deg in all: track_width poorly determined (standard error {:.2} % of it; a fit wants at least {:.0} deg and at most {:.1} %)",
            100.0 * rel,
            TRACK_WIDTH_WARN_TURNING.to_degrees(),
            100.0 * TRACK_WIDTH_MAX_RELATIVE_SE
        ));
    }
    None
}

/// Standard errors of the geometry unknowns ([`GEOMETRY_UNKNOWNS`]) at an eq (16) estimate
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
    let idx: Vec<usize> = (0..4).filter(|&i| free[i]).collect();
    let p = idx.len();
    let mut acc = NormalAccumulator::new(Objective::Squares, false, p);
    if !run.accumulate_normal(params, a, b, heading0, &idx, &mut acc) {
        return None;
    }
    let (jtj, _) = acc.equations();
    let m = acc.residuals();
    let s2 = acc.cost() / (m.saturating_sub(p).max(1)) as f64;
    let mut se = [None; 4];
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
    Some((se, s2.sqrt()))
}

/// The heading at match `a` minimising eq (16) over `a..=b` with the geometry fixed.
pub fn fit_heading(
    run: &Run,
    params: &ChassisParams,
    a: usize,
    b: usize,
    guess: f64,
) -> Result<f64> {
    let f = |x: &[f64], acc: &mut NormalAccumulator| {
        run.accumulate_normal(params, a, b, x[0], &[3], acc)
    };
    let res = optim::levenberg_marquardt_streamed(
        f,
        &[guess],
        &[1.0],
        Objective::SumOfNorms,
        LmOptions::default(),
    )
    .ok_or_else(|| anyhow!("parameters: not admissible"))?;
    Ok(res.x[0])
}

/// Stop a restart heading fit when the predicted relative reduction of eq (16) falls below
/// this (the heading is then the minimum within about 1e-10 rad).
const RESTART_PRED_TOL: f64 = 1e-14;

/// A path turned by up to this (rad) is the re-integrated path to within the integrator's
/// own arithmetic noise; a restart heading found further from the heading the path was
/// integrated at is refined from a path integrated at it (the turned path's error grows
/// with the angle: about 1e-7 m at 0.5 rad over 10 m, 1e-7 rad on the heading found).
const RESTART_TURN_EXACT: f64 = 0.01;

/// Integrations of one restart heading fit at most (the second from the first's heading).
const RESTART_PASSES: usize = 2;

/// [`fit_heading`] for the restarts of the uncertainty fits, integrating once (twice when the
/// heading found is more than [`RESTART_TURN_EXACT`] from `guess`). A change of
/// the start heading by `phi` turns the whole path about its start by `phi` (clockwise):
/// the odometry is integrated once at `guess`, and eq (16) is minimised over the rotation of
/// those positions, `x - x0 = dx cos(phi) + dy sin(phi)`, `y - y0 = -dx sin(phi) + dy cos(phi)`
/// (`dx`, `dy` the positions at `guess` relative to the start), with the derivative
/// `d x / d heading0 = y - y0`, `d y / d heading0 = -(x - x0)` (what the forward sensitivity
/// of [`Run::residuals_with_jacobian`] sums). The core integrator turns the same path by
/// the same angle up to its rounding (the sine/cosine kernel, 2e-9 of the distance), so the
/// heading is the one a fit re-integrating at every step would find.
fn fit_restart_heading(
    run: &Run,
    params: &ChassisParams,
    a: usize,
    b: usize,
    guess: f64,
) -> Result<f64> {
    let (x0, y0) = run.anchor(a);
    let mut path = Vec::with_capacity(b - a);
    let mut heading = guess;
    for _ in 0..RESTART_PASSES {
        path.clear();
        run.integrate_pose(params, a, b, heading, |k, integ| {
            let p = integ.pose();
            let r = run.reference_at(k);
            path.push([p.x - x0, p.y - y0, r.x - x0, r.y - y0]);
        })
        .map_err(|e| anyhow!("parameters: {e}"))?;
        let at = heading;
        let f = |x: &[f64], acc: &mut NormalAccumulator| {
            let (sin, cos) = (x[0] - at).sin_cos();
            for &[dx, dy, rx, ry] in &path {
                let (px, py) = (dx * cos + dy * sin, dy * cos - dx * sin);
                acc.add_pair(px - rx, py - ry, &[py], &[-px]);
            }
            acc.cost().is_finite()
        };
        let res = optim::levenberg_marquardt_streamed(
            f,
            &[at],
            &[1.0],
            Objective::SumOfNorms,
            LmOptions {
                // The Newton model of the norms converges quadratically: the heading is the
                // minimum of the turned path's eq (16) to 1e-10 rad, not where the IRLS
                // majoriser's linear convergence happens to stop (iterations cost no
                // integration here).
                newton: true,
                pred_tol: RESTART_PRED_TOL,
                ..LmOptions::default()
            },
        )
        .ok_or_else(|| anyhow!("parameters: not admissible"))?;
        heading = res.x[0];
        if (heading - at).abs() <= RESTART_TURN_EXACT {
            break;
        }
    }
    Ok(heading)
}

/// Errors and predicted uncertainty along a run.
#[derive(Debug, Clone, Default)]
pub struct Evaluation {
    /// Match indices evaluated.
    pub k: Vec<usize>,
    /// Times (s).
    pub t: Vec<f64>,
    /// Reference path length from the start (m).
    pub dist: Vec<f64>,
    /// Odometry position (m).
    pub odo: Vec<(f64, f64)>,
    /// Reference position (m).
    pub reference: Vec<(f64, f64)>,
    /// Horizontal error |odometry - reference| (m).
    pub horizontal: Vec<f64>,
    /// Predicted horizontal sigma (m).
    pub sigma_h: Vec<f64>,
    /// Odometry heading (rad, cumulative).
    pub heading: Vec<f64>,
    /// Heading error odometry - reference, wrapped to (-pi, pi] (rad), where the reference
    /// has a heading.
    pub heading_err: Vec<Option<f64>>,
    /// Predicted heading sigma (rad).
    pub sigma_heading: Vec<f64>,
    /// Error of the heading change since the stretch's start (rad): `(heading - heading at
    /// the start) - (reference heading - reference heading at the start)`, wrapped to (-pi, pi],
    /// where the reference has a heading; the start's reference heading is averaged over a
    /// standstill there ([`Run::start_heading`]). `sigma_heading` (zero at the start)
    /// predicts exactly this error; the absolute heading error also carries the error of
    /// the fitted start heading.
    pub heading_change_err: Vec<Option<f64>>,
    /// Number of reference headings averaged at the stretch's start.
    pub start_headings: Vec<usize>,
}

impl Evaluation {
    /// Empties every column, keeping the allocations.
    pub fn clear(&mut self) {
        let Self {
            k,
            t,
            dist,
            odo,
            reference,
            horizontal,
            sigma_h,
            heading,
            heading_err,
            sigma_heading,
            heading_change_err,
            start_headings,
        } = self;
        k.clear();
        t.clear();
        dist.clear();
        odo.clear();
        reference.clear();
        horizontal.clear();
        sigma_h.clear();
        heading.clear();
        heading_err.clear();
        sigma_heading.clear();
        heading_change_err.clear();
        start_headings.clear();
    }

    /// Reserves room for `n` more rows in every column.
    fn reserve(&mut self, n: usize) {
        self.k.reserve(n);
        self.t.reserve(n);
        self.dist.reserve(n);
        self.odo.reserve(n);
        self.reference.reserve(n);
        self.horizontal.reserve(n);
        self.sigma_h.reserve(n);
        self.heading.reserve(n);
        self.heading_err.reserve(n);
        self.sigma_heading.reserve(n);
        self.heading_change_err.reserve(n);
        self.start_headings.reserve(n);
    }

    /// Moves the rows of `other` to the end of `self`.
    fn append(&mut self, other: &mut Self) {
        let Self {
            k,
            t,
            dist,
            odo,
            reference,
            horizontal,
            sigma_h,
            heading,
            heading_err,
            sigma_heading,
            heading_change_err,
            start_headings,
        } = other;
        self.k.append(k);
        self.t.append(t);
        self.dist.append(dist);
        self.odo.append(odo);
        self.reference.append(reference);
        self.horizontal.append(horizontal);
        self.sigma_h.append(sigma_h);
        self.heading.append(heading);
        self.heading_err.append(heading_err);
        self.sigma_heading.append(sigma_heading);
        self.heading_change_err.append(heading_change_err);
        self.start_headings.append(start_headings);
    }

    /// Appends the evaluation of matches `a+1..=b` from a restart at `a` (see
    /// [`Run::integrate`]); with `include_start`, the start point itself too (zero error
    /// by construction, zero sigma).
    pub fn extend(
        &mut self,
        run: &Run,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        include_start: bool,
    ) -> Result<()> {
        let mut rows = Vec::with_capacity(b - a);
        run.integrate(params, a, b, heading0, |k, integ| {
            let p = integ.pose();
            let s = integ.sigma();
            rows.push((
                k,
                (p.x, p.y),
                p.heading,
                f64::from(s.horizontal()),
                f64::from(s.heading),
            ));
        })
        .map_err(|e| anyhow!("parameters: {e}"))?;
        let start = run
            .start_heading(a, |k| rows.get(k - a - 1).map(|r| r.2 - heading0))
            .map(|(h, n)| (heading0, h, n));
        self.reserve(rows.len() + 1);
        if include_start {
            self.push(run, a, run.anchor(a), heading0, 0.0, 0.0, start);
        }
        for (k, xy, h, sh, sa) in rows {
            self.push(run, k, xy, h, sh, sa, start);
        }
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        run: &Run,
        k: usize,
        odo: (f64, f64),
        heading: f64,
        sigma_h: f64,
        sigma_heading: f64,
        start: Option<(f64, f64, usize)>,
    ) {
        let r = run.reference_at(k);
        let change = match (start, r.heading) {
            (Some((h0, r0, n)), Some(rh)) => {
                self.start_headings.push(n);
                Some(wrap_angle((heading - h0) - wrap_angle(rh - r0)))
            }
            _ => {
                self.start_headings.push(0);
                None
            }
        };
        self.heading_change_err.push(change);
        self.k.push(k);
        self.t.push(r.t);
        self.dist.push(run.dist[k]);
        self.odo.push(odo);
        self.reference.push((r.x, r.y));
        self.horizontal.push(norm2(odo.0 - r.x, odo.1 - r.y));
        self.sigma_h.push(sigma_h);
        self.heading.push(heading);
        self.heading_err
            .push(r.heading.map(|h| wrap_angle(heading - h)));
        self.sigma_heading.push(sigma_heading);
    }

    /// The heading errors and sigmas where the reference has a heading.
    pub fn heading_pairs(&self) -> (Vec<f64>, Vec<f64>) {
        self.heading_err
            .iter()
            .zip(&self.sigma_heading)
            .filter_map(|(e, s)| e.map(|e| (e, *s)))
            .unzip()
    }
}

/// Evaluation of the whole run from match 0.
pub fn evaluate(run: &Run, params: &ChassisParams, heading0: f64) -> Result<Evaluation> {
    let mut ev = Evaluation::default();
    ev.extend(run, params, 0, run.len() - 1, heading0, true)?;
    Ok(ev)
}

/// How the two wheels' coefficients are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DeltaMode {
    /// Left and right equal.
    Equal,
    /// Keep the ratio left/right of the initial parameters; fit the common scale.
    KeepRatio,
}

/// Result of the uncertainty fit.
#[derive(Debug, Clone)]
pub struct UncertaintyFit {
    /// The model whose coefficients were fitted.
    pub model: UncertaintyModel,
    /// The parameters with the fitted coefficients.
    pub params: ChassisParams,
    /// Which keys were fitted (`delta_left`/`delta_right` or `kappa_left`/`kappa_right`).
    pub keys: (&'static str, &'static str),
    /// Sub-trajectories used.
    pub windows: usize,
    /// Points used (common times after each restart).
    pub points: usize,
    /// Achieved coverage of the 1-sigma band (with the reference noise).
    pub coverage1: f64,
    /// Achieved coverage of the 3-sigma band (with the reference noise).
    pub coverage3: f64,
    /// Set when the criterion could not be met inside the admissible range.
    pub warning: Option<String>,
    /// The `delta_diff` fit and heading coverage (paper model, reference with a heading).
    pub diff: Option<DiffFit>,
}

/// Cuts matches `0..len` into consecutive sub-trajectories of `window` metres (the whole run
/// when `window <= 0`); each is `(start, end)` with at least `min_points` after the start.
pub fn windows(run: &Run, window: f64, min_points: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    if run.is_empty() {
        return out;
    }
    let last = run.len() - 1;
    if window <= 0.0 {
        if last >= min_points {
            out.push((0, last));
        }
        return out;
    }
    let mut a = 0;
    while a < last {
        let b = run.last_within(a, window).max(a + 1);
        if b - a >= min_points && run.dist[b] - run.dist[a] >= 0.5 * window {
            out.push((a, b));
        }
        a = b;
    }
    out
}

fn set_coefficient(
    base: &ChassisParams,
    mode: DeltaMode,
    initial: &ChassisParams,
    v: f64,
) -> ChassisParams {
    let mut p = *base;
    let ratio = |l: f32, r: f32| {
        if l > 0.0 && r > 0.0 && mode == DeltaMode::KeepRatio {
            f64::from(r / l)
        } else {
            1.0
        }
    };
    match p.uncertainty_model {
        UncertaintyModel::Paper => {
            let q = ratio(initial.delta_left, initial.delta_right);
            p.delta_left = v as f32;
            p.delta_right = (v * q) as f32;
        }
        UncertaintyModel::Covariance => {
            let q = ratio(initial.kappa_left, initial.kappa_right);
            p.kappa_left = v as f32;
            p.kappa_right = (v * q) as f32;
        }
    }
    p
}

/// The restarted sub-trajectories of the uncertainty fits: consecutive stretches of `window`
/// metres, each started from the reference position with the heading minimising eq (16) over
/// it. They depend on the geometry only, so every coefficient fit shares them.
#[derive(Debug, Clone)]
pub struct Restarts {
    /// `(start, end)` match indices.
    pub windows: Vec<(usize, usize)>,
    /// Restart headings (rad).
    pub headings: Vec<f64>,
    /// The last evaluations (see [`Restarts::evaluate_memo`]).
    memo: RefCell<Vec<(ChassisParams, bool, Rc<Evaluation>)>>,
}

/// Evaluations kept by [`Restarts::evaluate_memo`]: the two latest of a coefficient search
/// (its predictor) and the fit's result.
const MEMO_EVALUATIONS: usize = 4;

impl Restarts {
    /// Cuts the run and fits the restart headings (eq 16 over each sub-trajectory, from the
    /// full-run odometry with `heading0`).
    pub fn new(run: &Run, geometry: &ChassisParams, heading0: f64, window: f64) -> Result<Self> {
        let wins = windows(run, window, 3);
        if wins.is_empty() {
            bail!("the run is too short for the uncertainty fit (no sub-trajectory of {window} m with 3 points)");
        }
        // The full-run odometry headings (the pose does not depend on the uncertainty model).
        let mut full = Vec::with_capacity(run.len());
        full.push(heading0);
        run.integrate_pose(geometry, 0, run.len() - 1, heading0, |_, integ| {
            full.push(integ.pose().heading)
        })
        .map_err(|e| anyhow!("parameters: {e}"))?;
        // The sub-trajectories' fits are independent: spread over the cores (the same fits,
        // in the same order of results, as one after the other).
        let threads = cores().min(wins.len());
        let chunk = wins.len().div_ceil(threads.max(1));
        let headings = std::thread::scope(|scope| {
            let jobs: Vec<_> = wins
                .chunks(chunk)
                .map(|part| {
                    let full = &full;
                    scope.spawn(move || {
                        part.iter()
                            .map(|&(a, b)| fit_restart_heading(run, geometry, a, b, full[a]))
                            .collect::<Result<Vec<f64>>>()
                    })
                })
                .collect();
            jobs.into_iter()
                .map(|j| j.join().expect("restart heading fit panicked"))
                .collect::<Result<Vec<_>>>()
        })?
        .concat();
        Ok(Self {
            windows: wins,
            headings,
            memo: RefCell::default(),
        })
    }

    /// [`Restarts::evaluate`], remembered: the last [`MEMO_EVALUATIONS`] evaluations are kept
    /// and returned again for the same parameters (the fits of the coefficients evaluate the
    /// same parameters several times: the result, its coverages, the refits of delta).
    pub fn evaluate_memo(&self, run: &Run, p: &ChassisParams) -> Result<Rc<Evaluation>> {
        self.memo_eval(run, p, true)
    }

    /// The horizontal errors and sigmas only (`horizontal`, `sigma_h`; the other columns
    /// may be empty), remembered with [`Restarts::evaluate_memo`]'s evaluations.
    fn horizontal_memo(&self, run: &Run, p: &ChassisParams) -> Result<Rc<Evaluation>> {
        self.memo_eval(run, p, false)
    }

    fn memo_eval(&self, run: &Run, p: &ChassisParams, full: bool) -> Result<Rc<Evaluation>> {
        let mut memo = self.memo.borrow_mut();
        if let Some(i) = memo.iter().position(|(q, f, _)| q == p && (*f || !full)) {
            let hit = memo.remove(i);
            let ev = Rc::clone(&hit.2);
            memo.push(hit);
            return Ok(ev);
        }
        // Reuse the buffers of the oldest evaluation when nobody holds it any more.
        let mut ev = if memo.len() >= MEMO_EVALUATIONS {
            Rc::try_unwrap(memo.remove(0).2).unwrap_or_default()
        } else {
            Evaluation::default()
        };
        drop(memo);
        self.evaluate_parts(run, p, &mut ev, full)?;
        let ev = Rc::new(ev);
        let mut memo = self.memo.borrow_mut();
        // A full evaluation replaces a horizontal one of the same parameters.
        memo.retain(|(q, _, _)| q != p);
        memo.push((*p, full, Rc::clone(&ev)));
        Ok(ev)
    }

    /// The remembered evaluations whose parameters satisfy `family`, newest first.
    fn memo_where(
        &self,
        family: impl Fn(&ChassisParams) -> bool,
    ) -> Vec<(ChassisParams, Rc<Evaluation>)> {
        self.memo
            .borrow()
            .iter()
            .rev()
            .filter(|(q, _, _)| family(q))
            .map(|(q, _, ev)| (*q, Rc::clone(ev)))
            .collect()
    }

    /// Errors and sigmas at every match after each restart (restart points excluded).
    pub fn evaluate(&self, run: &Run, p: &ChassisParams) -> Result<Evaluation> {
        let mut ev = Evaluation::default();
        self.evaluate_into(run, p, &mut ev)?;
        Ok(ev)
    }

    /// [`Restarts::evaluate`] into `ev` (cleared first, its buffers reused: the coverage
    /// bisections evaluate the same sub-trajectories dozens of times).
    /// The sub-trajectories are evaluated on all cores (independent, appended in order: the
    /// same evaluation as one after the other).
    pub fn evaluate_into(&self, run: &Run, p: &ChassisParams, ev: &mut Evaluation) -> Result<()> {
        self.evaluate_parts(run, p, ev, true)
    }

    /// [`Restarts::evaluate_into`], with only `horizontal` and `sigma_h` filled when not
    /// `full` (what the coefficient searches need: a fraction of the memory traffic).
    fn evaluate_parts(
        &self,
        run: &Run,
        p: &ChassisParams,
        ev: &mut Evaluation,
        full: bool,
    ) -> Result<()> {
        ev.clear();
        let threads = cores().min(self.windows.len()).max(1);
        let chunk = self.windows.len().div_ceil(threads);
        let jobs: Vec<_> = self
            .windows
            .chunks(chunk)
            .zip(self.headings.chunks(chunk))
            .collect();
        let (first, rest) = jobs.split_first().expect("at least one sub-trajectory");
        let evaluate = |ev: &mut Evaluation, (wins, heads): (&[(usize, usize)], &[f64])| {
            let n = wins.iter().map(|(a, b)| b - a).sum();
            if full {
                ev.reserve(n);
            } else {
                ev.horizontal.reserve(n);
                ev.sigma_h.reserve(n);
            }
            for (&(a, b), &h) in wins.iter().zip(heads) {
                if full {
                    ev.extend(run, p, a, b, h, false)?;
                } else {
                    run.integrate(p, a, b, h, |k, integ| {
                        let o = integ.pose();
                        let r = run.reference_at(k);
                        ev.horizontal.push(norm2(o.x - r.x, o.y - r.y));
                        ev.sigma_h.push(f64::from(integ.sigma().horizontal()));
                    })
                    .map_err(|e| anyhow!("parameters: {e}"))?;
                }
            }
            Ok::<_, anyhow::Error>(())
        };
        let parts = std::thread::scope(|scope| {
            let spawned: Vec<_> = rest
                .iter()
                .map(|&job| {
                    scope.spawn(move || {
                        let mut part = Evaluation::default();
                        evaluate(&mut part, job).map(|()| part)
                    })
                })
                .collect();
            let own = evaluate(ev, *first);
            let parts = spawned
                .into_iter()
                .map(|j| j.join().expect("evaluation panicked"))
                .collect::<Result<Vec<_>>>();
            own.and(parts)
        })?;
        for mut part in parts {
            ev.append(&mut part);
        }
        Ok(())
    }
}

/// Coverage of the horizontal `k`-sigma band widened by the reference noise:
/// the fraction of points with `e <= k sqrt(sigma_h^2 + ref_sigma^2)`.
pub fn horizontal_coverage(ev: &Evaluation, ref_sigma: f64, k: f64) -> f64 {
    let inside = ev
        .horizontal
        .iter()
        .zip(&ev.sigma_h)
        .filter(|(e, s)| **e <= k * s.hypot(ref_sigma))
        .count();
    inside as f64 / ev.horizontal.len().max(1) as f64
}

/// Coverage of the heading-change `k`-sigma band widened by the reference heading noise, over
/// the points `from..` where the reference has a heading: the fraction with `|e| <= k
/// sqrt(sigma_heading^2 + (1 + 1/n) ref_heading_sigma^2)`, `e` the error of the heading change
/// since the stretch's start ([`Evaluation::heading_change_err`]; the reference noise enters
/// at the point and, averaged over `n` headings, at the start); NaN without any.
pub fn heading_coverage(ev: &Evaluation, ref_heading_sigma: f64, k: f64, from: usize) -> f64 {
    let (mut n, mut inside) = (0usize, 0usize);
    for i in from..ev.heading_change_err.len() {
        if let Some(e) = ev.heading_change_err[i] {
            let m = ev.start_headings[i].max(1) as f64;
            let band = norm2(
                ev.sigma_heading[i],
                ref_heading_sigma * (1.0 + 1.0 / m).sqrt(),
            );
            n += 1;
            if e.abs() <= k * band {
                inside += 1;
            }
        }
    }
    if n == 0 {
        f64::NAN
    } else {
        inside as f64 / n as f64
    }
}

/// Number of points `from..` with a heading-change error.
pub fn heading_points(ev: &Evaluation, from: usize) -> usize {
    ev.heading_change_err
        .get(from..)
        .map_or(0, |v| v.iter().filter(|e| e.is_some()).count())
}

/// The smallest `v` in `[0, hi]` with `cover(v) >= ONE_SIGMA_COVERAGE`, for a coverage that is
/// non-decreasing in `v`: 0 when it already holds there, else a bisection in log scale down
/// to a relative width `rel_tol`. Returns the value and a warning when `hi` is not enough or
/// the criterion is not identifiable.
fn smallest_covering(
    hi: f64,
    zero_allowed: bool,
    rel_tol: f64,
    mut cover: impl FnMut(f64) -> Result<f64>,
    progress: &ProgressBar,
) -> Result<(f64, Option<String>)> {
    let lo = hi * 1e-12;
    if zero_allowed && cover(0.0)? >= ONE_SIGMA_COVERAGE {
        return Ok((0.0, None));
    }
    let c_hi = cover(hi)?;
    if c_hi < ONE_SIGMA_COVERAGE {
        return Ok((
            hi,
            Some(format!(
                "even {hi:e} (the largest admissible) covers only {:.1} % of the errors",
                100.0 * c_hi
            )),
        ));
    }
    if cover(lo)? >= ONE_SIGMA_COVERAGE {
        return Ok((
            lo,
            Some("the reference noise alone covers 68.3 % of the errors: the coefficient is not identifiable".into()),
        ));
    }
    let (mut l, mut h) = (lo.ln(), hi.ln());
    while h - l > rel_tol {
        let m = 0.5 * (l + h);
        if cover(m.exp())? >= ONE_SIGMA_COVERAGE {
            h = m;
        } else {
            l = m;
        }
        progress.inc(1);
    }
    Ok((h.exp(), None))
}

/// Fits the uncertainty coefficients by the coverage criterion of the module documentation.
#[allow(clippy::too_many_arguments)]
pub fn fit_uncertainty(
    run: &Run,
    geometry: &ChassisParams,
    heading0: f64,
    initial: &ChassisParams,
    window: f64,
    ref_sigma: f64,
    mode: DeltaMode,
    progress: &ProgressBar,
) -> Result<UncertaintyFit> {
    let restarts = Restarts::new(run, geometry, heading0, window)?;
    fit_uncertainty_on(run, &restarts, geometry, initial, ref_sigma, mode, progress)
}

/// Bisection width (natural log of the coefficient) of the horizontal fit.
const COEFFICIENT_LOG_TOL: f64 = 1e-7;
/// Bisection width of `delta_diff`, and of delta when refitted inside its fit (0.01 %).
const DIFF_LOG_TOL: f64 = 1e-4;

/// [`fit_uncertainty`] on given restarted sub-trajectories; the other coefficients (e.g.
/// `delta_diff`) are those of `geometry`.
pub fn fit_uncertainty_on(
    run: &Run,
    restarts: &Restarts,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    ref_sigma: f64,
    mode: DeltaMode,
    progress: &ProgressBar,
) -> Result<UncertaintyFit> {
    progress.set_length(48);
    fit_coefficient(
        run,
        restarts,
        geometry,
        initial,
        ref_sigma,
        mode,
        COEFFICIENT_LOG_TOL,
        progress,
    )
}

#[allow(clippy::too_many_arguments)]
fn fit_coefficient(
    run: &Run,
    restarts: &Restarts,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    ref_sigma: f64,
    mode: DeltaMode,
    log_tol: f64,
    progress: &ProgressBar,
) -> Result<UncertaintyFit> {
    let (keys, hi) = match geometry.uncertainty_model {
        UncertaintyModel::Paper => (
            ("delta_left", "delta_right"),
            f64::from(ChassisParams::MAX_DELTA),
        ),
        UncertaintyModel::Covariance => (
            ("kappa_left", "kappa_right"),
            f64::from(ChassisParams::MAX_KAPPA),
        ),
    };
    // With the ratio kept, the larger coefficient must stay in range too.
    let q = match (mode, geometry.uncertainty_model) {
        (DeltaMode::KeepRatio, UncertaintyModel::Paper) if initial.delta_left > 0.0 => {
            f64::from(initial.delta_right / initial.delta_left)
        }
        (DeltaMode::KeepRatio, UncertaintyModel::Covariance) if initial.kappa_left > 0.0 => {
            f64::from(initial.kappa_right / initial.kappa_left)
        }
        _ => 1.0,
    };
    let hi = hi / q.max(1.0);
    let at = |v: f64| set_coefficient(geometry, mode, initial, v);
    let coefficient = |p: &ChassisParams| match p.uncertainty_model {
        UncertaintyModel::Paper => f64::from(p.delta_left),
        UncertaintyModel::Covariance => f64::from(p.kappa_left),
    };
    // The evaluations of this family (these parameters but the coefficient) already made,
    // e.g. by the horizontal fit before a refit of delta: (coefficient, coverage).
    let family = |p: &ChassisParams| at(coefficient(p)) == *p;
    let facts = RefCell::new(
        restarts
            .memo_where(family)
            .iter()
            .map(|(p, ev)| (coefficient(p), horizontal_coverage(ev, ref_sigma, 1.0)))
            .collect::<Vec<_>>(),
    );
    let real = |v: f64| -> Result<f64> {
        let ev = restarts.horizontal_memo(run, &at(v))?;
        let c = horizontal_coverage(&ev, ref_sigma, 1.0);
        facts.borrow_mut().push((v, c));
        Ok(c)
    };
    // The coverage is non-decreasing in the coefficient (what the bisection assumes): a
    // value at or above one known to cover, or at or below one known not to, is decided
    // without an evaluation; the bisection then takes exactly the steps it would take with
    // every coverage evaluated, and only the midpoints between those are evaluated.
    let cover = |v: f64| -> Result<f64> {
        let known = known_coverage(&facts.borrow(), v);
        match known {
            Some(c) => Ok(c),
            None => real(v),
        }
    };
    bracket_threshold(
        restarts,
        hi,
        log_tol,
        family,
        ref_sigma,
        match geometry.uncertainty_model {
            // sigma proportional to delta (with delta_diff = 0), variance to kappa.
            UncertaintyModel::Paper => 1.0,
            UncertaintyModel::Covariance => 0.5,
        },
        coefficient(geometry),
        &facts,
        &real,
    )?;
    let (value, warning) = smallest_covering(hi, false, log_tol, cover, progress)?;
    let warning = warning.map(|w| {
        if w.contains("reference noise") {
            format!("the reference noise alone ({ref_sigma} m) covers 68.3 % of the errors: the coefficient is not identifiable")
        } else {
            w
        }
    });
    let params = at(value);
    let ev = restarts.evaluate_memo(run, &params)?;
    Ok(UncertaintyFit {
        model: geometry.uncertainty_model,
        params,
        keys,
        windows: restarts.windows.len(),
        points: ev.horizontal.len(),
        coverage1: horizontal_coverage(&ev, ref_sigma, 1.0),
        coverage3: horizontal_coverage(&ev, ref_sigma, 3.0),
        warning,
        diff: None,
    })
}

/// The coverage at `v` implied by the coverages `facts` (coefficient, coverage) of a
/// non-decreasing coverage: the one at `v` itself, else one `>= ONE_SIGMA_COVERAGE` at or
/// below `v`, else one below it at or above `v` (the caller only compares it with
/// [`ONE_SIGMA_COVERAGE`]); `None` when they do not decide.
fn known_coverage(facts: &[(f64, f64)], v: f64) -> Option<f64> {
    if let Some(&(_, c)) = facts.iter().find(|(u, _)| *u == v) {
        return Some(c);
    }
    facts
        .iter()
        .find(|(u, c)| *u <= v && *c >= ONE_SIGMA_COVERAGE)
        .or_else(|| {
            facts
                .iter()
                .find(|(u, c)| *u >= v && *c < ONE_SIGMA_COVERAGE)
        })
        .map(|&(_, c)| c)
}

/// Predicts, from evaluations of one family at coefficients `a` and `b` (`sigma_h` of each,
/// the horizontal errors being the same), the smallest coefficient whose horizontal 1-sigma
/// band covers [`ONE_SIGMA_COVERAGE`] of the errors: per point, `sigma_h` is taken as a power
/// of the coefficient through the two evaluations (exact for the covariance model, `sigma_h^2`
/// linear in kappa, and for the paper model without `delta_diff`, `sigma_h` linear in delta;
/// to f32 rounding), which gives the coefficient at which the point becomes covered; the
/// prediction is their 68.27 % quantile. With one evaluation (`b` = `None`) the power is
/// `exponent`.
fn predict_threshold(
    e: &[f64],
    ref_sigma: f64,
    a: (f64, &[f64]),
    b: Option<(f64, &[f64])>,
    exponent: f64,
) -> Option<f64> {
    let n = e.len();
    if n == 0 || a.0 <= 0.0 {
        return None;
    }
    let mut need = ONE_SIGMA_COVERAGE * n as f64;
    need = need.ceil().min(n as f64);
    let mut k = need as usize;
    while k > 0 && (k - 1) as f64 / n as f64 >= ONE_SIGMA_COVERAGE {
        k -= 1;
    }
    while k <= n && (k as f64 / n as f64) < ONE_SIGMA_COVERAGE {
        k += 1;
    }
    if k == 0 || k > n {
        return None;
    }
    let (la, sa) = (a.0.ln(), a.1);
    let mut t: Vec<f64> = (0..n)
        .map(|i| {
            let target2 = e[i] * e[i] - ref_sigma * ref_sigma;
            if target2 <= 0.0 {
                return 0.0;
            }
            let ls = 0.5 * target2.ln();
            let s0 = sa[i];
            let p = match b {
                Some((vb, sb)) if sb[i] > 0.0 && s0 > 0.0 && vb != a.0 => {
                    (sb[i].ln() - s0.ln()) / (vb.ln() - la)
                }
                _ => exponent,
            };
            if !(s0 > 0.0 && p > 0.0 && p.is_finite()) {
                return f64::INFINITY;
            }
            (la + (ls - s0.ln()) / p).exp()
        })
        .collect();
    let (_, &mut th, _) = t.select_nth_unstable_by(k - 1, f64::total_cmp);
    (th.is_finite() && th > 0.0).then_some(th)
}

/// Brackets the threshold of the coverage criterion before the bisection: evaluations
/// (`real`, which records its results in `facts`) on either side of the predicted threshold
/// ([`predict_threshold`], from the latest two evaluations of the family), at a distance of
/// the bisection's width, widened when a prediction misses. The bisection then finds every
/// step outside the bracket decided (see [`known_coverage`]): the result is the bisection's,
/// with a handful of evaluations instead of dozens. Evaluations only; never decides anything.
#[allow(clippy::too_many_arguments)]
fn bracket_threshold(
    restarts: &Restarts,
    hi: f64,
    log_tol: f64,
    family: impl Fn(&ChassisParams) -> bool,
    ref_sigma: f64,
    exponent: f64,
    start: f64,
    facts: &RefCell<Vec<(f64, f64)>>,
    real: &dyn Fn(f64) -> Result<f64>,
) -> Result<()> {
    let lo = hi * 1e-12;
    let coefficient = |p: &ChassisParams| match p.uncertainty_model {
        UncertaintyModel::Paper => f64::from(p.delta_left),
        UncertaintyModel::Covariance => f64::from(p.kappa_left),
    };
    let mut width = log_tol;
    for _ in 0..8 {
        let (below, above) = {
            let f = facts.borrow();
            let below = f
                .iter()
                .filter(|(_, c)| *c < ONE_SIGMA_COVERAGE)
                .map(|p| p.0)
                .fold(f64::NEG_INFINITY, f64::max);
            let above = f
                .iter()
                .filter(|(_, c)| *c >= ONE_SIGMA_COVERAGE)
                .map(|p| p.0)
                .fold(f64::INFINITY, f64::min);
            (below, above)
        };
        if below > 0.0 && above.is_finite() && (above / below).ln() <= 2.5 * log_tol {
            return Ok(());
        }
        if above <= lo || below >= hi {
            return Ok(());
        }
        let evs = restarts.memo_where(&family);
        let Some((pa, ea)) = evs.first() else {
            let v0 = if start > lo && start < hi {
                start
            } else {
                (lo * hi).sqrt()
            };
            real(v0)?;
            continue;
        };
        let b = evs
            .get(1)
            .map(|(pb, eb)| (coefficient(pb), eb.sigma_h.as_slice()));
        let Some(pred) = predict_threshold(
            &ea.horizontal,
            ref_sigma,
            (coefficient(pa), &ea.sigma_h),
            b,
            exponent,
        ) else {
            return Ok(());
        };
        // Inside what is known, else bisect what is known.
        let pred = if pred > below && pred < above {
            pred
        } else if below > 0.0 && above.is_finite() {
            (below * above).sqrt()
        } else if pred >= above {
            above * (-width).exp()
        } else {
            below * width.exp()
        };
        let (l, h) = (
            (pred * (-width).exp()).clamp(lo, hi),
            (pred * width.exp()).clamp(lo, hi),
        );
        let c_h = known_coverage(&facts.borrow(), h);
        let c_h = match c_h {
            Some(c) => c,
            None => real(h)?,
        };
        if c_h >= ONE_SIGMA_COVERAGE && known_coverage(&facts.borrow(), l).is_none() {
            real(l)?;
        }
        width *= 4.0;
    }
    Ok(())
}

/// The `delta_diff` fit of the paper's model (see [`fit_delta_diff`]).
#[derive(Debug, Clone)]
pub struct DiffFit {
    /// The initial `delta_diff` (from the first estimate).
    pub initial: f64,
    /// The fitted (or, when not fitted, the kept) `delta_diff`.
    pub delta_diff: f64,
    /// Whether it was fitted.
    pub fitted: bool,
    /// delta (`delta_left`) of the horizontal fit with the initial `delta_diff`.
    pub delta_before: f64,
    /// Whether delta was refitted with it (both criteria hold); false when delta was held
    /// (see [`fit_delta_diff`]).
    pub joint: bool,
    /// Heading points used (common times after each restart with a reference heading).
    pub points: usize,
    /// Heading 1-sigma coverage (band widened by the reference heading noise) with the
    /// horizontally fitted delta and the initial `delta_diff`.
    pub coverage1_before: f64,
    /// The same 3-sigma coverage.
    pub coverage3_before: f64,
    /// Heading 1-sigma coverage with the final coefficients.
    pub coverage1: f64,
    /// Heading 3-sigma coverage with the final coefficients.
    pub coverage3: f64,
    /// Set when the criterion could not be met inside the admissible range.
    pub warning: Option<String>,
}

/// Options of [`fit_delta_diff`].
#[derive(Debug, Clone, Copy)]
pub struct DiffOptions {
    /// Fit `delta_diff` (else keep the initial one and only report the heading coverage).
    pub fit: bool,
    /// Reference heading noise (rad), added to `sigma_heading` in the criterion.
    pub ref_heading_sigma: f64,
    /// Reference horizontal noise (m), for the refits of delta.
    pub ref_sigma: f64,
    /// Left/right relation of delta in its refits.
    pub mode: DeltaMode,
}

/// Fits `delta_diff` of the paper's model jointly with delta, on the restarted
/// sub-trajectories of the horizontal fit `horizontal`.
///
/// Criterion: delta stays the horizontal criterion's (the 1-sigma band widened by the
/// reference noise covers 68.27 % of the horizontal errors), refitted at every trial
/// `delta_diff` (which widens `sigma_x`, `sigma_y` too, so delta comes down as it goes up);
/// `delta_diff` is the smallest value `>= 0` for which the 1-sigma heading band
/// `sqrt(sigma_heading^2 + (1 + 1/n) ref_heading_sigma^2)` covers 68.27 % of the errors of the
/// heading change since each restart ([`heading_coverage`]): 0 when the paper's model already
/// covers them. Both criteria then hold. The heading coverage along that curve is taken as
/// non-decreasing in `delta_diff` (bisection in log scale). When no admissible `delta_diff`
/// meets both (delta would have to fall to zero), delta is held at its horizontal fit and
/// `delta_diff` alone meets the heading criterion (a warning says so; the horizontal band
/// then covers more than 68.27 %). Returns the updated fit (with `diff` set), or `horizontal`
/// unchanged for the covariance model or a reference without heading.
pub fn fit_delta_diff(
    run: &Run,
    restarts: &Restarts,
    horizontal: UncertaintyFit,
    initial: &ChassisParams,
    o: DiffOptions,
    progress: &ProgressBar,
) -> Result<UncertaintyFit> {
    if horizontal.model != UncertaintyModel::Paper {
        return Ok(horizontal);
    }
    let ev = restarts.evaluate_memo(run, &horizontal.params)?;
    let points = heading_points(&ev, 0);
    if points == 0 {
        return Ok(horizontal);
    }
    let cover = |p: &ChassisParams, k: f64| -> Result<f64> {
        let ev = restarts.evaluate_memo(run, p)?;
        Ok(heading_coverage(&ev, o.ref_heading_sigma, k, 0))
    };
    let with = |p: &ChassisParams, v: f64| ChassisParams {
        delta_diff: v as f32,
        ..*p
    };
    let initial_dd = f64::from(horizontal.params.delta_diff);
    let delta_before = f64::from(horizontal.params.delta_left);
    let before = (
        heading_coverage(&ev, o.ref_heading_sigma, 1.0, 0),
        heading_coverage(&ev, o.ref_heading_sigma, 3.0, 0),
    );
    let mut fit = horizontal;
    let mut warning = None;
    let mut joint = true;
    if o.fit {
        progress.set_length(40);
        let base = fit.params;
        let hi = f64::from(ChassisParams::MAX_DELTA);
        // delta refitted by the horizontal criterion at a given delta_diff (remembered: the
        // result is refitted again at the end).
        let refits: RefCell<Vec<(f64, UncertaintyFit)>> = RefCell::default();
        let refit = |v: f64| -> Result<UncertaintyFit> {
            if let Some((_, f)) = refits.borrow().iter().find(|(u, _)| *u == v) {
                return Ok(f.clone());
            }
            let f = fit_coefficient(
                run,
                restarts,
                &with(&base, v),
                initial,
                o.ref_sigma,
                o.mode,
                DIFF_LOG_TOL,
                &ProgressBar::hidden(),
            )?;
            refits.borrow_mut().push((v, f.clone()));
            Ok(f)
        };
        let (dd, w) = smallest_covering(
            hi,
            true,
            DIFF_LOG_TOL,
            |v| cover(&refit(v)?.params, 1.0),
            progress,
        )?;
        // Joint only when delta stays identifiable (not pushed to zero by delta_diff).
        let joint_fit = match w {
            None => Some(refit(dd)?).filter(|f| f.warning.is_none()),
            Some(_) => None,
        };
        if let Some(f) = joint_fit {
            fit = f;
        } else {
            joint = false;
            let (dd, w2) = smallest_covering(
                hi,
                true,
                DIFF_LOG_TOL,
                |v| cover(&with(&base, v), 1.0),
                progress,
            )?;
            fit.params = with(&base, dd);
            let ev = restarts.evaluate_memo(run, &fit.params)?;
            fit.coverage1 = horizontal_coverage(&ev, o.ref_sigma, 1.0);
            fit.coverage3 = horizontal_coverage(&ev, o.ref_sigma, 3.0);
            warning = Some(match w2 {
                Some(w2) => w2,
                None => format!(
                    "no delta_diff meets the heading and the horizontal criterion together; delta held at its horizontal fit, which now covers {:.1} % of the horizontal errors",
                    100.0 * fit.coverage1
                ),
            });
        }
    }
    fit.diff = Some(DiffFit {
        initial: initial_dd,
        delta_diff: f64::from(fit.params.delta_diff),
        fitted: o.fit,
        joint,
        delta_before,
        points,
        coverage1_before: before.0,
        coverage3_before: before.1,
        coverage1: cover(&fit.params, 1.0)?,
        coverage3: cover(&fit.params, 3.0)?,
        warning,
    });
    Ok(fit)
}

/// Where the stability study's fits start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WindowStart {
    /// From the initial estimate, as the paper did (Fig. 7).
    Initial,
    /// From the full-trajectory estimate.
    Full,
}

/// One sub-trajectory estimate of the stability study.
#[derive(Debug, Clone)]
pub struct WindowEstimate {
    /// Nominal sub-trajectory length (m).
    pub length: f64,
    /// Path distance of its start from the run's start (m).
    pub start_dist: f64,
    /// Start and end time (s).
    pub t: (f64, f64),
    /// Total absolute heading change along it (rad, from the full-run odometry).
    pub turning: f64,
    /// Common times used.
    pub points: usize,
    /// The estimate (left_diameter, right_diameter, track_width, heading0), or why it failed;
    /// the track width is NaN where the sub-trajectory turned too little to determine it.
    pub estimate: Result<[f64; 4], String>,
    /// Eq (16) per point at the estimate (m).
    pub mean_error: f64,
}

/// The paper's stability study: estimates on consecutive sub-trajectories of each length.
pub fn windows_study(
    run: &Run,
    full: &GeomFit,
    initial: &ChassisParams,
    lengths: &[f64],
    start: WindowStart,
    progress: &ProgressBar,
) -> Result<Vec<WindowEstimate>> {
    let ev = evaluate(run, &full.params, full.heading0)?;
    let plan: Vec<(f64, usize, usize)> = lengths
        .iter()
        .flat_map(|&l| windows(run, l, 10).into_iter().map(move |(a, b)| (l, a, b)))
        .collect();
    progress.set_length(plan.len() as u64);
    let from = match start {
        WindowStart::Initial => *initial,
        WindowStart::Full => full.params,
    };
    let opts = GeomOptions {
        polish: false,
        ..GeomOptions::default()
    };
    let mut out = Vec::with_capacity(plan.len());
    for (length, a, b) in plan {
        let turning: f64 = ev.heading[a..=b]
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .sum();
        let fit = fit_geometry(
            run,
            &from,
            ev.heading[a],
            a,
            b,
            opts,
            &ProgressBar::hidden(),
        );
        let (estimate, mean_error) = match fit {
            Ok(f) => (
                Ok([
                    f.params.left_diameter,
                    f.params.right_diameter,
                    if f.track_estimated {
                        f.params.track_width
                    } else {
                        f64::NAN
                    },
                    f.heading0,
                ]),
                f.cost / f.points as f64,
            ),
            Err(e) => (Err(e.to_string()), f64::NAN),
        };
        out.push(WindowEstimate {
            length,
            start_dist: run.dist[a],
            t: (run.reference_at(a).t, run.reference_at(b).t),
            turning,
            points: b - a,
            estimate,
            mean_error,
        });
        progress.inc(1);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::commands::default_truth;
    use crate::csvio::match_times;
    use crate::simulate::{self, PathKind, SimOptions, SimRun, SimSettings};

    fn sim(kind: PathKind, length: f64, seed: u64) -> SimRun {
        let settings = SimSettings {
            rate: 50.0,
            speed: 0.5,
            slip: 0.001,
            slip_corr: 0.1,
            slip_turn: 0.0,
            slip_turn_corr: 1.0,
            rtk_sigma: 0.008,
            heading_sigma: Some(0.5f64.to_radians()),
            start: (0.0, 0.0, 0.3),
            seed,
        };
        let mut rng = simulate::Rng::new(seed ^ 0x5EED);
        simulate::simulate(&SimOptions {
            truth: default_truth(),
            segments: simulate::path(kind, length, &mut rng),
            settings,
        })
    }

    /// The coefficient fits (predicted bracket, then the bisection on known coverages) give
    /// the plain bisection's coefficient, every coverage evaluated: paper model without and
    /// with `delta_diff` (sigma then not a power of delta), covariance model, on simulated
    /// runs; also the refit's coarser width on a memo left by the finer fit.
    #[test]
    fn fast_coefficient_fit_matches_the_plain_bisection() {
        for seed in [1, 2] {
            let s = sim(PathKind::Random, 150.0, seed);
            let run = Run::new(
                &s.samples,
                &s.reference,
                match_times(&s.samples, &s.reference),
            );
            let geometry = default_truth();
            let h0 = run.heading_guess(0);
            for (model, dd) in [
                (UncertaintyModel::Paper, 0.0f32),
                (UncertaintyModel::Paper, 2e-8),
                (UncertaintyModel::Covariance, 0.0),
            ] {
                let g = ChassisParams {
                    uncertainty_model: model,
                    delta_diff: dd,
                    ..geometry
                };
                let restarts = Restarts::new(&run, &g, h0, 10.0).unwrap();
                let hi = f64::from(match model {
                    UncertaintyModel::Paper => ChassisParams::MAX_DELTA,
                    UncertaintyModel::Covariance => ChassisParams::MAX_KAPPA,
                });
                let coef = |p: &ChassisParams| match model {
                    UncertaintyModel::Paper => p.delta_left,
                    UncertaintyModel::Covariance => p.kappa_left,
                };
                for tol in [COEFFICIENT_LOG_TOL, DIFF_LOG_TOL] {
                    let mut ev = Evaluation::default();
                    let (plain, _) = smallest_covering(
                        hi,
                        false,
                        tol,
                        |v| {
                            let p = set_coefficient(&g, DeltaMode::Equal, &g, v);
                            restarts.evaluate_into(&run, &p, &mut ev)?;
                            Ok(horizontal_coverage(&ev, 0.008, 1.0))
                        },
                        &ProgressBar::hidden(),
                    )
                    .unwrap();
                    let fast = fit_coefficient(
                        &run,
                        &restarts,
                        &g,
                        &g,
                        0.008,
                        DeltaMode::Equal,
                        tol,
                        &ProgressBar::hidden(),
                    )
                    .unwrap();
                    let (a, b) = (f64::from(coef(&fast.params)), f64::from(plain as f32));
                    assert!(
                        (a / b).ln().abs() <= tol,
                        "seed {seed} {model:?} delta_diff {dd} width {tol}: fast {a:e}, plain {b:e}"
                    );
                }
            }
        }
    }

    /// The analytic Jacobian of the residuals against central differences of the core
    /// integrator's residuals, column by column (relative to the column's norm).
    fn check_jacobian(run: &Run, params: &ChassisParams, heading0: f64, a: usize, b: usize) {
        let cols = [0, 1, 2, 3];
        let (mut r, mut jac) = (Vec::new(), Vec::new());
        assert!(run.residuals_with_jacobian(params, a, b, heading0, &mut r, Some(&mut jac), &cols));
        assert_eq!(jac.len(), r.len() * 4);
        let x0 = [
            params.left_diameter,
            params.right_diameter,
            params.track_width,
            heading0,
        ];
        for c in cols {
            // Steps large against the integrator's fixed-point noise (about 1e-8 m on a
            // position), small against the curvature: 1e-4 of a length, 1e-4 rad.
            let h = if c == 3 { 1e-4 } else { 1e-4 * x0[c] };
            let at = |d: f64| {
                let mut x = x0;
                x[c] += d;
                let mut out = Vec::new();
                assert!(run.residuals(&with_geometry(params, &x), a, b, x[3], &mut out));
                out
            };
            let (rp, rm) = (at(h), at(-h));
            let (mut diff, mut norm) = (0.0f64, 0.0f64);
            for i in 0..r.len() {
                let fd = (rp[i] - rm[i]) / (2.0 * h);
                diff = diff.hypot(jac[i * 4 + c] - fd);
                norm = norm.hypot(fd);
            }
            assert!(norm > 0.0, "column {c} is zero");
            // Measured: 4e-7 .. 8e-6, the central differences' own noise.
            assert!(
                diff / norm < 2e-5,
                "column {} ({}): relative difference {:e} (norm {norm:e})",
                c,
                GEOMETRY_UNKNOWNS[c],
                diff / norm
            );
        }
    }

    #[test]
    fn analytic_jacobian_matches_central_differences() {
        // Arcs and straights; spins on the spot (validation path); away from the truth and
        // with a per-angle wheel function (wheel distances not proportional to the counts).
        let est = sim(PathKind::Estimation, 30.0, 3);
        let val = sim(PathKind::Validation, 20.0, 4);
        let mut wavy = default_truth();
        wavy.left_wheel.cos[0] = 2e-3;
        wavy.right_wheel.sin[1] = -1e-3;
        let poor = ChassisParams {
            left_diameter: 0.27,
            right_diameter: 0.25,
            track_width: 0.6,
            ..ChassisParams::DESIGNED
        };
        for s in [&est, &val] {
            let run = Run::new(
                &s.samples,
                &s.reference,
                match_times(&s.samples, &s.reference),
            );
            let last = run.len() - 1;
            for p in [default_truth(), wavy, poor] {
                check_jacobian(&run, &p, 0.31, 0, last);
                check_jacobian(&run, &p, -2.0, last / 3, last);
            }
        }
    }

    /// The two-core pipeline visits the same matches with the same poses and sensitivities,
    /// to the bit, as the one-core loop (through an over-range sample and index latches).
    #[test]
    fn pipelined_sensitivities_equal_the_one_core_loop() {
        let mut s = sim(PathKind::Random, 300.0, 4);
        assert!(s.samples.len() > PIPELINE_MIN_SAMPLES + 2 * PIPELINE_CHUNK);
        // An over-range jump of both counters midway (the integrator skips that sample).
        for row in &mut s.samples[15_000..] {
            row.left += 1 << 20;
            row.right += 1 << 20;
        }
        let run = Run::new(
            &s.samples,
            &s.reference,
            match_times(&s.samples, &s.reference),
        );
        let last = run.len() - 1;
        let mut p = default_truth();
        p.left_wheel.cos[0] = 0.001;
        for (a, b) in [(0, last), (17, last - 3), (5, PIPELINE_CHUNK + 9)] {
            let mut here = Vec::new();
            run.integrate_with_sensitivity_here(&p, a, b, 0.4, |k, integ, d| {
                here.push((k, integ.pose(), *d));
            })
            .unwrap();
            let mut piped = Vec::new();
            run.integrate_with_sensitivity_pipelined(&p, a, b, 0.4, |k, pose, d| {
                piped.push((k, *pose, *d));
            })
            .unwrap();
            assert_eq!(here.len(), b - a);
            assert!(here == piped, "stretch {a}..{b}");
        }
    }

    #[test]
    fn residuals_with_jacobian_keeps_the_integrators_residuals() {
        let s = sim(PathKind::Estimation, 10.0, 5);
        let run = Run::new(
            &s.samples,
            &s.reference,
            match_times(&s.samples, &s.reference),
        );
        let last = run.len() - 1;
        let p = default_truth();
        let (mut plain, mut with, mut jac) = (Vec::new(), Vec::new(), Vec::new());
        assert!(run.residuals(&p, 0, last, 0.3, &mut plain));
        assert!(run.residuals_with_jacobian(&p, 0, last, 0.3, &mut with, Some(&mut jac), &[2, 0]));
        assert_eq!(plain, with);
        assert_eq!(jac.len(), 2 * with.len());
        assert!(!run.residuals_with_jacobian(&p, 0, last, 0.3, &mut with, Some(&mut jac), &[4]));
        // Streamed into the accumulator: exactly the sums of the stored vectors.
        for (kind, newton) in [
            (Objective::Squares, false),
            (Objective::SumOfNorms, false),
            (Objective::SumOfNorms, true),
        ] {
            let cols = [0, 1, 3];
            assert!(run.residuals_with_jacobian(
                &p,
                0,
                last,
                0.3,
                &mut with,
                Some(&mut jac),
                &cols
            ));
            let mut stored = NormalAccumulator::new(kind, newton, 3);
            stored.add_all(&with, &jac);
            let mut streamed = NormalAccumulator::new(kind, newton, 3);
            assert!(run.accumulate_normal(&p, 0, last, 0.3, &cols, &mut streamed));
            assert_eq!(streamed.cost(), stored.cost());
            assert_eq!(streamed.equations(), stored.equations());
            assert_eq!(streamed.residuals(), with.len());
        }
        let mut acc = NormalAccumulator::new(Objective::Squares, false, 1);
        assert!(!run.accumulate_normal(&p, 0, last, 0.3, &[4], &mut acc));
        let bad = ChassisParams {
            track_width: -1.0,
            ..p
        };
        assert!(!run.accumulate_normal(&bad, 0, last, 0.3, &[0], &mut acc));
    }

    /// The restarts' heading fit turns one integrated path about its start: the odometry
    /// integrated from another start heading is that path turned (to the integrator's
    /// rounding), and the heading found is the minimum of eq (16) that a fit re-integrating
    /// the odometry at every step finds.
    #[test]
    fn restart_heading_by_rotation_matches_the_integrating_fit() {
        let s = sim(PathKind::Estimation, 70.0, 9);
        let run = Run::new(
            &s.samples,
            &s.reference,
            match_times(&s.samples, &s.reference),
        );
        let p = default_truth();
        let wins = windows(&run, 10.0, 3);
        assert!(wins.len() >= 6);
        let path = |a: usize, b: usize, h: f64| {
            let mut out = Vec::new();
            run.integrate_pose(&p, a, b, h, |_, integ| {
                let q = integ.pose();
                out.push((q.x, q.y));
            })
            .unwrap();
            out
        };
        for &(a, b) in &wins {
            let (x0, y0) = run.anchor(a);
            let base = path(a, b, 0.3);
            for phi in [0.01, -0.2, 0.5, 3.0] {
                let (sin, cos) = f64::sin_cos(phi);
                for ((x, y), (tx, ty)) in base.iter().zip(path(a, b, 0.3 + phi)) {
                    let (dx, dy) = (x - x0, y - y0);
                    let (rx, ry) = (x0 + dx * cos + dy * sin, y0 + dy * cos - dx * sin);
                    assert!(norm2(rx - tx, ry - ty) < 1e-7, "window {a}..{b}, phi {phi}");
                }
            }
            // Against the fit that re-integrates the odometry at every step, converged as far.
            // That fit's eq (16) carries the fixed-point integrator's arithmetic noise, not
            // smooth in the heading (measured on these windows: +-1e-6 m of a 7.7 m cost
            // between headings 2e-8 rad apart, where the turned path's cost changes by 1e-9 m),
            // and its Newton steps stop on that noise: the two headings agree to about 1e-7
            // rad, and their costs to that noise.
            let integrated = |guess: f64| {
                let res = optim::levenberg_marquardt_streamed(
                    |x: &[f64], acc: &mut NormalAccumulator| {
                        run.accumulate_normal(&p, a, b, x[0], &[3], acc)
                    },
                    &[guess],
                    &[1.0],
                    Objective::SumOfNorms,
                    LmOptions {
                        newton: true,
                        pred_tol: 1e-15,
                        ..LmOptions::default()
                    },
                )
                .unwrap();
                res.x[0]
            };
            for guess in [0.3, 0.3 + 0.2, 0.3 - 0.05] {
                let rotated = fit_restart_heading(&run, &p, a, b, guess).unwrap();
                let integrated = integrated(guess);
                let cost = |h: f64| run.eq16(&p, a, b, h).unwrap();
                let (cr, ci) = (cost(rotated), cost(integrated));
                assert!(
                    (rotated - integrated).abs() < 2e-7 && (cr - ci).abs() <= 5e-7 * ci,
                    "window {a}..{b} from {guess}: {rotated} ({cr}) vs {integrated} ({ci})"
                );
            }
        }
    }

    #[test]
    fn standard_errors_and_the_track_width_warning() {
        let s = sim(PathKind::Estimation, 30.0, 6);
        let run = Run::new(
            &s.samples,
            &s.reference,
            match_times(&s.samples, &s.reference),
        );
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
