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
//! 2. iteratively reweighted Levenberg-Marquardt on eq (16) itself (weights 1/distance, a
//!    majoriser of the sum of distances, so each accepted step lowers eq (16));
//! 3. optionally a Nelder-Mead polish of eq (16) with restarts; the lowest eq (16) is kept.
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

use anyhow::{anyhow, bail, Result};
use indicatif::ProgressBar;

use crate::core_api::{ChassisParams, Integrator, Pose, UncertaintyModel};
use crate::csvio::{RefPoint, Sample};
use crate::optim::{self, LmOptions, NmOptions, Objective};
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
    /// `k` in `a+1..=b`.
    pub fn integrate(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        mut visit: impl FnMut(usize, &Integrator),
    ) -> Result<(), crate::core_api::ParamError> {
        let (sa, _) = self.matches[a];
        let (x0, y0) = self.anchor(a);
        let mut integ = Integrator::new(
            params,
            counts(&self.samples[sa]),
            Pose {
                x: x0,
                y: y0,
                heading: heading0,
            },
        )?;
        let mut k = a + 1;
        let sb = self.matches[b].0;
        for i in sa + 1..=sb {
            let s = &self.samples[i];
            let _ = integ.step(counts(s), index_refs(s));
            if k <= b && self.matches[k].0 == i {
                visit(k, &integ);
                k += 1;
            }
        }
        Ok(())
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
        self.integrate(params, a, b, heading0, |k, integ| {
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
}

/// Options of [`fit_geometry`].
#[derive(Debug, Clone, Copy)]
pub struct GeomOptions {
    /// Path length of the first continuation stage (m).
    pub first_stage: f64,
    /// Growth of the prefix per stage.
    pub stage_growth: f64,
    /// Run the Nelder-Mead polish of eq (16).
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
            polish: true,
            min_turning: 30f64.to_radians(),
        }
    }
}

/// Total absolute heading change of the odometry over matches `a..=b` (rad), summed over
/// steps of at least 0.25 m of path so that count noise does not add up.
pub fn turning(run: &Run, params: &ChassisParams, a: usize, b: usize, heading0: f64) -> f64 {
    let mut total = 0.0;
    let mut last = (heading0, run.dist[a]);
    let _ = run.integrate(params, a, b, heading0, |k, integ| {
        let h = integ.pose().heading;
        if run.dist[k] - last.1 >= 0.25 || k == b {
            total += (h - last.0).abs();
            last = (h, run.dist[k]);
        }
    });
    total
}

/// Levenberg-Marquardt over the parameters marked free in `free` (the others held).
fn lm_subset<F>(
    mut f: F,
    x: &[f64],
    scale: &[f64],
    free: &[bool],
    kind: Objective,
    opts: LmOptions,
) -> Option<optim::OptResult>
where
    F: FnMut(&[f64], &mut Vec<f64>) -> bool,
{
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
    let mut res =
        optim::levenberg_marquardt(|s, out| f(&full(s), out), &sub0, &sub_scale, kind, opts)?;
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
        ..LmOptions::default()
    };
    progress.set_length((ends.len() + 1 + usize::from(opts.polish)) as u64);
    let mut free = [true, true, false, true];
    for &e in &ends {
        // The track width joins once the stretch has turned enough (it stays free after).
        if !free[2] && turning(run, &with_geometry(start, &x), a, e, x[3]) >= opts.min_turning {
            free[2] = true;
        }
        let f = |x: &[f64], out: &mut Vec<f64>| {
            run.residuals(&with_geometry(start, x), a, e, x[3], out)
        };
        let res = lm_subset(f, &x, &scale, &free, Objective::Squares, lm)
            .ok_or_else(|| anyhow!("the starting parameters are not admissible"))?;
        x = res.x;
        iterations += res.iterations;
        evaluations += res.evaluations;
        if debug {
            eprintln!(
                "stage to {e} ({:.1} m): {x:?} cost {} iterations {} free {free:?}",
                run.dist[e] - run.dist[a],
                res.cost,
                res.iterations
            );
        }
        progress.inc(1);
    }
    let f =
        |x: &[f64], out: &mut Vec<f64>| run.residuals(&with_geometry(start, x), a, b, x[3], out);
    let res = lm_subset(
        f,
        &x,
        &scale,
        &free,
        Objective::SumOfNorms,
        LmOptions {
            max_iter: 200,
            ..lm
        },
    )
    .ok_or_else(|| anyhow!("the fit left the admissible parameter range"))?;
    x = res.x;
    let mut cost = res.cost;
    iterations += res.iterations;
    evaluations += res.evaluations;
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
    Ok(GeomFit {
        params,
        heading0: x[3],
        cost,
        points: b - a,
        iterations,
        evaluations,
        stages: ends.len(),
        track_estimated: free[2],
        turning: turning(run, &params, a, b, x[3]),
    })
}

/// The heading at match `a` minimising eq (16) over `a..=b` with the geometry fixed.
pub fn fit_heading(
    run: &Run,
    params: &ChassisParams,
    a: usize,
    b: usize,
    guess: f64,
) -> Result<f64> {
    let f = |x: &[f64], out: &mut Vec<f64>| run.residuals(params, a, b, x[0], out);
    let res = optim::levenberg_marquardt(
        f,
        &[guess],
        &[1.0],
        Objective::SumOfNorms,
        LmOptions::default(),
    )
    .ok_or_else(|| anyhow!("parameters: not admissible"))?;
    Ok(res.x[0])
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
        self.horizontal.push((odo.0 - r.x).hypot(odo.1 - r.y));
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
}

impl Restarts {
    /// Cuts the run and fits the restart headings (eq 16 over each sub-trajectory, from the
    /// full-run odometry with `heading0`).
    pub fn new(run: &Run, geometry: &ChassisParams, heading0: f64, window: f64) -> Result<Self> {
        let wins = windows(run, window, 3);
        if wins.is_empty() {
            bail!("the run is too short for the uncertainty fit (no sub-trajectory of {window} m with 3 points)");
        }
        let full = evaluate(run, geometry, heading0)?;
        let mut headings = Vec::with_capacity(wins.len());
        for &(a, b) in &wins {
            headings.push(fit_heading(run, geometry, a, b, full.heading[a])?);
        }
        Ok(Self {
            windows: wins,
            headings,
        })
    }

    /// Errors and sigmas at every match after each restart (restart points excluded).
    pub fn evaluate(&self, run: &Run, p: &ChassisParams) -> Result<Evaluation> {
        let mut ev = Evaluation::default();
        for (&(a, b), &h) in self.windows.iter().zip(&self.headings) {
            ev.extend(run, p, a, b, h, false)?;
        }
        Ok(ev)
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
            let band = ev.sigma_heading[i].hypot(ref_heading_sigma * (1.0 + 1.0 / m).sqrt());
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
    let (value, warning) = smallest_covering(
        hi,
        false,
        log_tol,
        |v| {
            Ok(horizontal_coverage(
                &restarts.evaluate(run, &at(v))?,
                ref_sigma,
                1.0,
            ))
        },
        progress,
    )?;
    let warning = warning.map(|w| {
        if w.contains("reference noise") {
            format!("the reference noise alone ({ref_sigma} m) covers 68.3 % of the errors: the coefficient is not identifiable")
        } else {
            w
        }
    });
    let params = at(value);
    let ev = restarts.evaluate(run, &params)?;
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
    let ev = restarts.evaluate(run, &horizontal.params)?;
    let points = heading_points(&ev, 0);
    if points == 0 {
        return Ok(horizontal);
    }
    let cover = |p: &ChassisParams, k: f64| -> Result<f64> {
        Ok(heading_coverage(
            &restarts.evaluate(run, p)?,
            o.ref_heading_sigma,
            k,
            0,
        ))
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
        // delta refitted by the horizontal criterion at a given delta_diff.
        let refit = |v: f64, log_tol: f64| {
            fit_coefficient(
                run,
                restarts,
                &with(&base, v),
                initial,
                o.ref_sigma,
                o.mode,
                log_tol,
                &ProgressBar::hidden(),
            )
        };
        let (dd, w) = smallest_covering(
            hi,
            true,
            DIFF_LOG_TOL,
            |v| cover(&refit(v, DIFF_LOG_TOL)?.params, 1.0),
            progress,
        )?;
        // Joint only when delta stays identifiable (not pushed to zero by delta_diff).
        let joint_fit = match w {
            None => Some(refit(dd, DIFF_LOG_TOL)?).filter(|f| f.warning.is_none()),
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
            let ev = restarts.evaluate(run, &fit.params)?;
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
