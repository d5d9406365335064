//! A recorded run matched to its reference: the common times, the reference path length,
//! the start of a stretch, and the core integrator run along it.

use anyhow::Result;
use odo_unit::odometry::uncertainty::StepGeometry;
use odo_unit::odometry::{ChassisParams, Integrator, ParamError, Pose, PoseStep, PoseUncertainty};

use crate::csvio::{RefPoint, Sample};
use crate::optim::{self, NormalAccumulator, Objective};
use crate::replay::{counts, index_refs};
use crate::stats::wrap_angle;

use super::antenna::{observed_point, observed_with_rows, MODEL_UNKNOWNS};
use super::pipeline::{cores, follow_sensitivities, PIPELINE_MIN_SAMPLES};
use super::sensitivity::{PoseSensitivity, SensitivityTracker, GEOMETRY_UNKNOWNS};

/// Time after a stretch's start over which its reference heading is averaged (s); see
/// [`Run::start_heading`].
pub const START_ALIGN: f64 = 1.0;
/// Reference points closer than this to the last anchor do not add to the path length (m):
/// keeps the RTK noise from inflating the distance travelled.
pub(crate) const PATH_STEP: f64 = 0.05;

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
    /// Where the reference antenna sits on the chassis, `(forward, left)` metres from the
    /// axle centre ((0, 0) by default): the reference is compared with
    /// [`Run::observed`], the odometry's antenna position.
    pub antenna: (f64, f64),
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
            antenna: (0.0, 0.0),
        }
    }

    /// This run with the reference antenna at `(forward, left)` metres from the axle centre.
    pub fn with_antenna(mut self, antenna: (f64, f64)) -> Self {
        self.antenna = antenna;
        self
    }

    /// The point of the chassis at `pose` that the reference measures (x east, y north, m),
    /// for a stretch integrated from its anchor with heading `heading0`: the antenna
    /// ([`observed_point`]); the centre itself without a lever arm.
    #[inline(always)]
    pub fn observed(&self, pose: &Pose, heading0: f64) -> (f64, f64) {
        observed_point(pose, self.antenna, heading0)
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

    /// [`Run::start_heading`] at the run's start with the odometry's own heading change:
    /// the reference headings of the opening standstill and of the first [`START_ALIGN`]
    /// seconds, each less the heading `params` turned since match 0 (integrated from
    /// `heading0`). `None` without a reference heading at match 0. One heading alone carries
    /// its full noise (0.5 deg for an RTK pair) into the start of a whole-run integration,
    /// whose positions are off by its square over two times the distance (4e-4 of the path
    /// at 3 sigma): an average of 50 does not.
    pub fn opening_heading(
        &self,
        params: &ChassisParams,
        heading0: f64,
    ) -> Result<Option<(f64, usize)>, ParamError> {
        if self.is_empty() || self.reference_at(0).heading.is_none() {
            return Ok(None);
        }
        let t_end = self.reference_at(0).t + START_ALIGN;
        let (_, still) = self.standstill(0);
        let b = (still + 1..self.len())
            .find(|&k| self.reference_at(k).t > t_end)
            .unwrap_or(self.len() - 1);
        let mut changes = Vec::with_capacity(b);
        self.integrate_pose(params, 0, b, heading0, |_, integ| {
            changes.push(integ.pose().heading - heading0)
        })?;
        Ok(self.start_heading(0, |k| changes.get(k - 1).copied()))
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
    ) -> Result<(), ParamError> {
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
    ) -> Result<(), ParamError> {
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
    ) -> Result<(), ParamError> {
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

    /// [`Run::integrate`] with the uncertainty stepped beside the integrator (a
    /// [`PoseUncertainty`] of `params`: the integrator's own sigmas, bit for bit) and each
    /// integrated sample's step geometry appended to `geometries`: `visit(k, &integrator,
    /// &uncertainty, geometries.len())` at every match `k` in `a+1..=b`.
    pub fn integrate_geometry(
        &self,
        params: &ChassisParams,
        (a, b): (usize, usize),
        heading0: f64,
        geometries: &mut Vec<StepGeometry>,
        mut visit: impl FnMut(usize, &Integrator, &PoseUncertainty, usize),
    ) -> Result<(), ParamError> {
        let mut integ = self.start(params, a, heading0)?;
        let mut uncertainty = PoseUncertainty::new(params);
        let mut k = a + 1;
        for i in self.matches[a].0 + 1..=self.matches[b].0 {
            let s = &self.samples[i];
            if let (_, Some(g)) = integ.step_geometry(counts(s), index_refs(s)) {
                uncertainty.step(&g);
                geometries.push(g);
            }
            if k <= b && self.matches[k].0 == i {
                visit(k, &integ, &uncertainty, geometries.len());
                k += 1;
            }
        }
        Ok(())
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
    ) -> Result<(), ParamError> {
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
    ) -> Result<(), ParamError> {
        self.drive(
            params,
            a,
            b,
            heading0,
            |integ, s| integ.step_pose(counts(s), index_refs(s)).1,
            visit,
        )
    }

    /// [`Run::integrate_with_sensitivity`] on two cores: the core integrator on a second
    /// thread, the sensitivities and `visit` on this one (`pipeline::follow_sensitivities`).
    pub fn integrate_with_sensitivity_pipelined(
        &self,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        visit: impl FnMut(usize, &Pose, &PoseSensitivity),
    ) -> Result<(), ParamError> {
        let integ = self.start(params, a, heading0)?;
        follow_sensitivities(integ, params, self.samples, &self.matches, (a, b), visit);
        Ok(())
    }

    /// The core integrator at the start of a stretch beginning at match `a`: the counts of
    /// its sample, the position [`Run::anchor`], heading `heading0`, zero sigmas.
    pub(crate) fn start(
        &self,
        params: &ChassisParams,
        a: usize,
        heading0: f64,
    ) -> Result<Integrator, ParamError> {
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
    ) -> Result<(), ParamError> {
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
            let (px, py) = self.observed(&integ.pose(), heading0);
            let r = self.reference_at(k);
            out.push(px - r.x);
            out.push(py - r.y);
        })
        .is_ok()
            && out.iter().all(|v| v.is_finite())
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
        let n = cols.len();
        let (mut jx, mut jy) = ([0.0; MODEL_UNKNOWNS], [0.0; MODEL_UNKNOWNS]);
        self.integrate_with_sensitivity(params, a, b, heading0, |k, p, d| {
            let r = self.reference_at(k);
            let (ox, oy) = observed_with_rows(p, d, self.antenna, heading0, cols, &mut jx, &mut jy);
            out.push(ox - r.x);
            out.push(oy - r.y);
            jac.extend_from_slice(&jx[..n]);
            jac.extend_from_slice(&jy[..n]);
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
        self.accumulate_normal_with(params, self.antenna, a, b, heading0, cols, acc)
    }

    /// [`Run::accumulate_normal`] with the lever arm `antenna` instead of the run's own (for
    /// fits that estimate it; its columns are [`ANTENNA_FORWARD`], [`ANTENNA_LEFT`]).
    ///
    /// [`ANTENNA_FORWARD`]: super::antenna::ANTENNA_FORWARD
    /// [`ANTENNA_LEFT`]: super::antenna::ANTENNA_LEFT
    #[allow(clippy::too_many_arguments)]
    pub fn accumulate_normal_with(
        &self,
        params: &ChassisParams,
        antenna: (f64, f64),
        a: usize,
        b: usize,
        heading0: f64,
        cols: &[usize],
        acc: &mut NormalAccumulator,
    ) -> bool {
        if cols.iter().any(|&c| c >= MODEL_UNKNOWNS) || cols.len() > MODEL_UNKNOWNS {
            return false;
        }
        let mut finite = true;
        let (mut jx, mut jy) = ([0.0; MODEL_UNKNOWNS], [0.0; MODEL_UNKNOWNS]);
        let ok = self
            .integrate_with_sensitivity(params, a, b, heading0, |k, p, d| {
                let r = self.reference_at(k);
                let (ox, oy) = observed_with_rows(p, d, antenna, heading0, cols, &mut jx, &mut jy);
                let (rx, ry) = (ox - r.x, oy - r.y);
                finite &= rx.is_finite() && ry.is_finite();
                acc.add_pair(rx, ry, &jx, &jy);
            })
            .is_ok();
        ok && finite && acc.cost().is_finite()
    }

    /// Eq (16) over matches `a..=b`.
    pub fn eq16(&self, params: &ChassisParams, a: usize, b: usize, heading0: f64) -> Option<f64> {
        let mut r = Vec::new();
        self.residuals(params, a, b, heading0, &mut r)
            .then(|| optim::objective(Objective::SumOfNorms, &r))
    }
}

/// Cuts matches `0..len` into consecutive stretches of `window` metres of reference path (the
/// whole run when `window <= 0`); each is `(start, end)` with at least `min_points` after the
/// start.
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::pipeline::PIPELINE_CHUNK;
    use crate::calib::sensitivity::with_geometry;
    use crate::calib::testing::{run_of, sim};
    use crate::simulate::{default_truth, PathKind};

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
            let run = run_of(s);
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
        let run = run_of(&s);
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
        let run = run_of(&s);
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
}
