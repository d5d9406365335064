//! A recorded run matched to its reference: the common times, the reference path length,
//! the start of a stretch, and the core integrator run along it.

use anyhow::Result;
use odo_core::odometry::{ChassisParams, Integrator, ParamError, Pose, PoseStep};

use crate::csvio::{RefPoint, Sample};
use crate::replay::{counts, index_refs};
use crate::stats::wrap_angle;

use super::*;

/// Time after a stretch's start over which its reference heading is averaged (s); see
/// [`Run::start_heading`].
pub const START_ALIGN: f64 = 1.0;
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
    /// ([`super::observed_point`]); the centre itself without a lever arm.
    #[inline(always)]
    pub fn observed(&self, pose: &Pose, heading0: f64) -> (f64, f64) {
        super::observed_point(pose, self.antenna, heading0)
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

    /// The core integrator at the start of a stretch beginning at match `a`: the counts of
    /// its sample, the position [`Run::anchor`], heading `heading0`, zero sigmas.
    pub(super) fn start(
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
    pub(super) fn drive(
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
}
