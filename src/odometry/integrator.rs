//! The pose integrator: eqs (7)-(15) in drift-free fixed point, with the uncertainty of
//! eqs (19)-(28) (or the covariance model) alongside.
//!
//! # Numerics
//!
//! The Cortex-M4F has only a single-precision FPU, and an f32 running sum of position loses
//! centimetres per kilometre (at 10 m from the origin an f32 ulp is 1 um, the size of a whole
//! sample's motion at a crawl). So the state is held in integers and f32 is used only for
//! the small per-sample corrections:
//!
//! * Heading: a binary angle (`u64`, 2^64 units per turn, 3.4e-19 rad) plus a turn count.
//!   Each sample adds `k_1 dGamma_1 - k_2 dGamma_2` with `k_i = c_i / (2 pi w)` turns per
//!   increment in 2^-64 units, by wrapping integer arithmetic, which is exact: the heading
//!   is the cumulative count difference times a constant, never a sum of rounded floats
//!   (only the per-angle wheel function's bounded correction comes from f32).
//! * Wheel distances: `c_i dGamma_i` in units of 2^-48 m (exact integer products).
//! * Position: x and y in units of 2^-32 m (2.3e-10 m) in `i64` (range +-2.1e9 m). Each
//!   sample adds `dd sin(theta)`, `dd cos(theta)` with `dd` in fixed point and sin/cos from the
//!   integer kernel of [`trig::sin_cos`] (error < 2e-9), rounded to nearest: the worst-case
//!   systematic error is about 2e-9 of the distance travelled plus 1.2e-10 m per sample,
//!   against 4e-5 m per increment of encoder resolution.
//! * The chord factor of eq (9) is applied as `dd = ds - ds * chord_defect(dalpha/2)`, the
//!   correction in f32: on a straight line it is exactly zero, on a curve its f32 error is
//!   below 1e-7 of an already small term.
//!
//! The host tests compare this against an f64 implementation of the paper's equations over a
//! 10 km drive at 50 Hz (agreement within 1 mm and 1e-6 rad).
//!
//! # Limits of one sample
//!
//! A sample whose increments exceed [`MAX_STEP_COUNTS`] on a wheel, or whose heading change
//! exceeds [`MAX_STEP_DALPHA`] (pi/2), is not integrated: the counts are taken as the new
//! starting point and the step reports [`StepStatus::overrange`]. Such a sample is a fault
//! (a counter misread, or a chassis spinning faster than any sampling rate can follow).

use super::params::{ChassisParams, ParamError};
use super::trig;
use super::uncertainty::{PoseSigma, PoseUncertainty, StepGeometry};
use super::wheel::{WheelModel, DISTANCE_SCALE};
use crate::bytes::Text;
use crate::decimal::Dec;

/// Largest increment count of one wheel in one sample that is integrated (2^18).
pub const MAX_STEP_COUNTS: u64 = 1 << 18;
/// Largest heading change of one sample that is integrated, radians (pi/2).
pub const MAX_STEP_DALPHA: f32 = core::f32::consts::FRAC_PI_2;
/// Largest |x| and |y| a pose may be set to, metres (2^30 m, 1.07e9 m): half the position's
/// fixed-point range, so that the steps after it cannot overflow the `i64` (a further
/// 1.07e9 m of travel).
pub const MAX_POSITION: f64 = 1_073_741_824.0;
/// Largest |heading| a pose may be set to, radians (2^32 rad, 6.8e8 turns): the turn count
/// stays far inside `i64`, and the f64 heading keeps 1e-6 rad.
pub const MAX_HEADING: f64 = 4_294_967_296.0;

/// Position units per metre: 2^32.
const POSITION_SCALE: f64 = 4_294_967_296.0;
/// Binary-angle units per turn: 2^64.
const TURN: f64 = 18_446_744_073_709_551_616.0;
/// 2 pi.
const TAU: f64 = core::f64::consts::TAU;

/// A pose in the plane: x east and y north in metres, heading `alpha` in radians, 0 along
/// +y and growing clockwise. The heading is cumulative (eq 15): it is not wrapped, so a
/// chassis that turned twice on the spot reads 4 pi.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose {
    /// East, metres.
    pub x: f64,
    /// North, metres.
    pub y: f64,
    /// Heading alpha, radians, clockwise from +y, cumulative.
    pub heading: f64,
}

impl Pose {
    /// Whether the integrator can hold this pose: finite, |x|, |y| <= [`MAX_POSITION`] and
    /// |heading| <= [`MAX_HEADING`]; the first coordinate that cannot, otherwise.
    pub fn check_range(&self) -> Result<(), PoseRangeError> {
        let within = |v: f64, max: f64| v.is_finite() && v.abs() <= max;
        if !within(self.x, MAX_POSITION) {
            Err(PoseRangeError::X)
        } else if !within(self.y, MAX_POSITION) {
            Err(PoseRangeError::Y)
        } else if !within(self.heading, MAX_HEADING) {
            Err(PoseRangeError::Heading)
        } else {
            Ok(())
        }
    }
}

/// A pose coordinate the integrator cannot represent (see [`Pose::check_range`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseRangeError {
    /// x is NaN, infinite or beyond +-[`MAX_POSITION`].
    X,
    /// y is NaN, infinite or beyond +-[`MAX_POSITION`].
    Y,
    /// The heading is NaN, infinite or beyond +-[`MAX_HEADING`].
    Heading,
}

impl core::fmt::Display for PoseRangeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            // The limits are whole numbers, written as integers: formatting an f64 would link
            // core's float formatting (about 12 KiB of flash).
            Self::X | Self::Y => write!(
                f,
                "{} must be within -{}..={} m",
                Text(if *self == Self::X { "x" } else { "y" }),
                Dec(MAX_POSITION as u64),
                Dec(MAX_POSITION as u64)
            ),
            Self::Heading => write!(
                f,
                "heading must be within -{}..={} rad",
                Dec(MAX_HEADING as u64),
                Dec(MAX_HEADING as u64)
            ),
        }
    }
}

/// Absolute increment counts `Gamma_1` (left) and `Gamma_2` (right), increments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WheelCounts {
    /// `Gamma_1`, wheel 1 (left).
    pub left: i64,
    /// `Gamma_2`, wheel 2 (right).
    pub right: i64,
}

/// The absolute count latched at each wheel's last index (N) pulse; `None` until the wheel's
/// first index pulse has been seen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IndexRefs {
    /// Wheel 1 (left).
    pub left: Option<i64>,
    /// Wheel 2 (right).
    pub right: Option<i64>,
}

/// What one [`Integrator::step`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StepStatus {
    /// Wheel 1's calibrated per-angle function was applied (its index has been seen and it
    /// has non-zero harmonics).
    pub left_referenced: bool,
    /// The same for wheel 2.
    pub right_referenced: bool,
    /// The sample exceeded [`MAX_STEP_COUNTS`] or [`MAX_STEP_DALPHA`] and was not integrated.
    pub overrange: bool,
}

/// The periodic part of a wheel's function at the previous sample, valid for one index phase.
#[derive(Debug, Clone, Copy, PartialEq)]
struct PeriodicCache {
    /// `(-index) mod P`: which phase origin the value belongs to.
    origin: u32,
    /// `R(theta)` at the previous sample's count, metres.
    value: f32,
}

/// Odometry and uncertainty integrator of a differential-drive chassis.
#[derive(Debug, Clone)]
pub struct Integrator {
    params: ChassisParams,
    wheels: [WheelModel; 2],
    /// Heading change per increment, 2^-64 turn.
    heading_per_count: [u64; 2],
    /// Heading change per metre of wheel-distance difference, 2^-64 turn (f32).
    heading_per_metre: f32,
    /// Transfer constants in f32, metres per increment.
    c: [f32; 2],
    inv_track: f32,
    /// Radians per 2^32 binary-angle units (2^-32 turn), f32.
    rad_per_binary: f32,
    counts: WheelCounts,
    x: i64,
    y: i64,
    heading: u64,
    turns: i64,
    periodic: [Option<PeriodicCache>; 2],
    uncertainty: PoseUncertainty,
}

impl Integrator {
    /// An integrator with parameters `params`, whose first sample is `counts`, at `pose`
    /// with zero uncertainty.
    pub fn new(
        params: &ChassisParams,
        counts: WheelCounts,
        pose: Pose,
    ) -> Result<Self, ParamError> {
        params.validate()?;
        let mut s = Self {
            params: *params,
            wheels: [
                WheelModel::new(
                    params.left_diameter,
                    params.ticks_per_rev,
                    &params.left_wheel,
                ),
                WheelModel::new(
                    params.right_diameter,
                    params.ticks_per_rev,
                    &params.right_wheel,
                ),
            ],
            heading_per_count: [0; 2],
            heading_per_metre: 0.0,
            c: [0.0; 2],
            inv_track: 0.0,
            rad_per_binary: (trig::RAD_PER_BINARY * 4_294_967_296.0) as f32,
            counts,
            x: 0,
            y: 0,
            heading: 0,
            turns: 0,
            periodic: [None; 2],
            uncertainty: PoseUncertainty::new(params),
        };
        s.derive_constants();
        s.reset_pose(pose);
        Ok(s)
    }

    /// Recomputes everything derived from `self.params` (already validated).
    fn derive_constants(&mut self) {
        let p = &self.params;
        self.wheels = [
            WheelModel::new(p.left_diameter, p.ticks_per_rev, &p.left_wheel),
            WheelModel::new(p.right_diameter, p.ticks_per_rev, &p.right_wheel),
        ];
        let per_metre = TURN / (TAU * p.track_width);
        for i in 0..2 {
            let c = self.wheels[i].transfer_constant();
            self.heading_per_count[i] = (c * per_metre + 0.5) as u64;
            self.c[i] = c as f32;
        }
        self.heading_per_metre = per_metre as f32;
        self.inv_track = (1.0 / p.track_width) as f32;
        self.uncertainty.set_params(p);
        self.periodic = [None; 2];
    }

    /// Replaces the parameters, keeping pose, uncertainty and counts. On error nothing changes.
    pub fn set_params(&mut self, params: &ChassisParams) -> Result<(), ParamError> {
        params.validate()?;
        self.params = *params;
        self.derive_constants();
        Ok(())
    }

    /// The parameters in use.
    pub fn params(&self) -> &ChassisParams {
        &self.params
    }

    /// Sets the pose and zeroes the uncertainty (counts are kept). A coordinate outside
    /// [`Pose::check_range`] is clamped to it (NaN to 0), so the steps after it cannot
    /// overflow; callers taking a pose from outside check it first and refuse it.
    pub fn reset_pose(&mut self, pose: Pose) {
        self.x = metres_to_position(pose.x);
        self.y = metres_to_position(pose.y);
        let (turns, frac) = radians_to_binary(pose.heading);
        self.turns = turns;
        self.heading = frac;
        self.uncertainty.reset();
    }

    /// Takes the counts as the new starting point without integrating the motion since the
    /// last sample (after a counter reset, for instance).
    pub fn rebase_counts(&mut self, counts: WheelCounts) {
        self.counts = counts;
        self.periodic = [None; 2];
    }

    /// The absolute counts of the last sample.
    pub fn counts(&self) -> WheelCounts {
        self.counts
    }

    /// The current pose (x east, y north, metres; cumulative heading, radians).
    pub fn pose(&self) -> Pose {
        Pose {
            x: self.x as f64 / POSITION_SCALE,
            y: self.y as f64 / POSITION_SCALE,
            heading: (self.turns as f64 + self.heading as f64 / TURN) * TAU,
        }
    }

    /// Position in fixed point, units of 2^-32 m: `(x, y)`.
    pub fn position_fixed(&self) -> (i64, i64) {
        (self.x, self.y)
    }

    /// Heading as whole turns plus a binary fraction of a turn (2^64 units per turn).
    pub fn heading_binary(&self) -> (i64, u64) {
        (self.turns, self.heading)
    }

    /// The current uncertainty, from the model selected by `uncertainty_model`.
    pub fn sigma(&self) -> PoseSigma {
        self.uncertainty.sigma()
    }

    /// The position-heading covariances `(cov(x, alpha), cov(y, alpha))`, m rad: carried by
    /// the covariance model; zero for the paper's model, which has no correlation terms.
    pub fn heading_covariance(&self) -> (f32, f32) {
        self.uncertainty.heading_covariance()
    }

    /// The change of wheel `i`'s periodic distance term between `before` and `now`, if its
    /// phase is referenced by an index pulse (metres).
    fn periodic_delta(
        &mut self,
        i: usize,
        before: i64,
        now: i64,
        index: Option<i64>,
    ) -> Option<f32> {
        let wheel = &self.wheels[i];
        let Some(index) = index.filter(|_| !wheel.is_round()) else {
            self.periodic[i] = None;
            return None;
        };
        let origin = wheel.phase(0, index);
        let r_before = match self.periodic[i] {
            Some(cache) if cache.origin == origin => cache.value,
            _ => wheel.periodic(wheel.phase(before, index)),
        };
        let r_now = wheel.periodic(wheel.phase(now, index));
        self.periodic[i] = Some(PeriodicCache {
            origin,
            value: r_now,
        });
        Some(r_now - r_before)
    }

    /// Integrates the motion from the previous sample's counts to `counts` (eqs 1-15) and
    /// propagates the uncertainty (eqs 19-28). `index` holds the counts latched at each
    /// wheel's last index pulse, which reference the per-angle wheel functions.
    pub fn step(&mut self, counts: WheelCounts, index: IndexRefs) -> StepStatus {
        let (status, geometry) = self.step_geometry(counts, index);
        // Uncertainty, eqs (19)-(28), or the covariance model.
        if let Some(g) = geometry {
            self.uncertainty.step(&g);
        }
        status
    }

    /// The pose part of [`Integrator::step`] (bit for bit the same pose), with the geometry
    /// its uncertainty step reads, which it leaves to the caller: for host tools that replay
    /// the uncertainty of one integration at other coefficients ([`PoseUncertainty::step`]).
    /// The geometry is `None` when the sample was not integrated.
    #[inline(always)]
    pub fn step_geometry(
        &mut self,
        counts: WheelCounts,
        index: IndexRefs,
    ) -> (StepStatus, Option<StepGeometry>) {
        let (status, motion) = self.advance(counts, index);
        let geometry = motion.map(|m| StepGeometry {
            abs_counts: [
                m.counts[0].unsigned_abs() as f32,
                m.counts[1].unsigned_abs() as f32,
            ],
            abs_count_difference: (m.counts[0] - m.counts[1]).unsigned_abs() as f32,
            wheel_distance: m.wheel_distance,
            ds: m.ds,
            dalpha: m.dalpha,
            chord: m.ds * (1.0 - m.defect),
            sin: trig::q30_to_f32(m.step.sin),
            cos: trig::q30_to_f32(m.step.cos),
            inv_track: self.inv_track,
        });
        (status, geometry)
    }

    /// The pose part of [`Integrator::step`] alone (eqs 1-15, bit for bit the same pose),
    /// without the uncertainty, which it leaves unchanged: for host tools that run the
    /// integrator many times over a recording (the calibration's eq (16) fits). Returns what
    /// the step did, with the step's chord and direction when it was integrated.
    pub fn step_pose(
        &mut self,
        counts: WheelCounts,
        index: IndexRefs,
    ) -> (StepStatus, Option<PoseStep>) {
        let (status, motion) = self.advance(counts, index);
        (status, motion.map(|m| m.step))
    }

    /// Eqs (1)-(15): moves the pose to `counts`; the step's motion, `None` when it was not
    /// integrated (over range).
    #[inline(always)]
    fn advance(&mut self, counts: WheelCounts, index: IndexRefs) -> (StepStatus, Option<Motion>) {
        let before = self.counts;
        self.counts = counts;
        let d = [
            counts.left.wrapping_sub(before.left),
            counts.right.wrapping_sub(before.right),
        ];
        let mut status = StepStatus::default();
        if d[0].unsigned_abs() > MAX_STEP_COUNTS || d[1].unsigned_abs() > MAX_STEP_COUNTS {
            status.overrange = true;
            self.periodic = [None; 2];
            return (status, None);
        }
        let d = [d[0] as i32, d[1] as i32];

        // Wheel distances, eqs (3)-(6): exact linear part plus the periodic correction.
        let mut s = [
            self.wheels[0].transfer_constant_fixed() * i64::from(d[0]),
            self.wheels[1].transfer_constant_fixed() * i64::from(d[1]),
        ];
        let mut s_f = [self.c[0] * d[0] as f32, self.c[1] * d[1] as f32];
        let mut heading_inc = self.heading_per_count[0]
            .wrapping_mul(i64::from(d[0]) as u64)
            .wrapping_sub(self.heading_per_count[1].wrapping_mul(i64::from(d[1]) as u64))
            as i64;
        let r = [
            self.periodic_delta(0, before.left, counts.left, index.left),
            self.periodic_delta(1, before.right, counts.right, index.right),
        ];
        status.left_referenced = r[0].is_some();
        status.right_referenced = r[1].is_some();
        if r[0].is_some() || r[1].is_some() {
            let r = [r[0].unwrap_or(0.0), r[1].unwrap_or(0.0)];
            for i in 0..2 {
                s[i] += trig::f32_to_i64(r[i] * DISTANCE_SCALE as f32);
                s_f[i] += r[i];
            }
            heading_inc =
                heading_inc.wrapping_add(trig::f32_to_i64((r[0] - r[1]) * self.heading_per_metre));
        }

        // Heading change, eq (8), checked against the wrap-safe range of the binary angle.
        if ((s_f[0] - s_f[1]) * self.inv_track).abs() > MAX_STEP_DALPHA {
            status.overrange = true;
            self.periodic = [None; 2];
            return (status, None);
        }
        // |dalpha| < pi/2: the top 32 bits of the increment fit an i32 (2^-32 turn units).
        let dalpha = (heading_inc >> 32) as i32 as f32 * self.rad_per_binary;

        // Centre distance and chord, eqs (7), (9), (10).
        let ds_f = 0.5 * (s_f[0] + s_f[1]);
        let defect = trig::chord_defect(0.5 * dalpha);
        let correction = trig::f32_to_i64(ds_f * defect * DISTANCE_SCALE as f32);
        let chord = ((s[0] + s[1]) >> 1) - correction;

        // Direction of the chord and position update, eqs (11)-(14).
        let theta = self.heading.wrapping_add((heading_inc >> 1) as u64);
        let (sin, cos) = trig::sin_cos(theta);
        self.x += mul_q30_shift16(chord, sin);
        self.y += mul_q30_shift16(chord, cos);

        // Heading, eq (15).
        let (frac, carry) = self.heading.overflowing_add(heading_inc as u64);
        self.heading = frac;
        if heading_inc >= 0 && carry {
            self.turns += 1;
        } else if heading_inc < 0 && !carry {
            self.turns -= 1;
        }
        let step = PoseStep {
            heading_increment: heading_inc,
            direction: theta,
            sin,
            cos,
            chord,
        };
        (
            status,
            Some(Motion {
                counts: d,
                wheel_distance: s_f,
                ds: ds_f,
                dalpha,
                defect,
                step,
            }),
        )
    }
}

/// The motion of one integrated step, as the pose update computed it: exactly the integer
/// quantities that moved the pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PoseStep {
    /// Heading change `dalpha` (eq 8), binary angle: 2^-64 turn, signed.
    pub heading_increment: i64,
    /// Chord direction `theta = alpha + dalpha / 2` (eq 11), binary angle (2^-64 turn).
    pub direction: u64,
    /// `sin(theta)`, Q30 (the kernel of [`trig::sin_cos`]).
    pub sin: i32,
    /// `cos(theta)`, Q30.
    pub cos: i32,
    /// Chord `dd` (eqs 9, 10), units of 2^-48 m: the position moved by
    /// `dd sin(theta)` east and `dd cos(theta)` north, each rounded to 2^-32 m.
    pub chord: i64,
}

/// [`PoseStep`] with the f32 quantities the uncertainty step needs.
#[derive(Debug, Clone, Copy)]
struct Motion {
    /// Increments `dGamma_1`, `dGamma_2`.
    counts: [i32; 2],
    /// Wheel distances `s_1`, `s_2` (m, f32).
    wheel_distance: [f32; 2],
    /// Centre distance `ds` (m, f32).
    ds: f32,
    /// Heading change (rad, f32).
    dalpha: f32,
    /// `1 - sinc(dalpha / 2)`.
    defect: f32,
    step: PoseStep,
}

/// `round(a * b / 2^46)`: a distance in 2^-48 m times a Q30 factor, in 2^-32 m.
#[inline(always)]
fn mul_q30_shift16(a: i64, b: i32) -> i64 {
    ((i128::from(a) * i128::from(b) + (1 << 45)) >> 46) as i64
}

/// Metres to position units (2^-32 m), rounded, clamped to +-[`MAX_POSITION`].
fn metres_to_position(v: f64) -> i64 {
    let scaled = v.clamp(-MAX_POSITION, MAX_POSITION) * POSITION_SCALE;
    if scaled.is_nan() {
        0
    } else if scaled >= 0.0 {
        (scaled + 0.5) as i64
    } else {
        (scaled - 0.5) as i64
    }
}

/// Radians to (whole turns, binary fraction of a turn: 2^64 a turn), clamped to
/// +-[`MAX_HEADING`]; NaN and infinities give (0, 0).
pub fn radians_to_binary(heading: f64) -> (i64, u64) {
    if !heading.is_finite() {
        return (0, 0);
    }
    let t = heading.clamp(-MAX_HEADING, MAX_HEADING) / TAU;
    let mut turns = t as i64;
    if (turns as f64) > t {
        turns -= 1;
    }
    let frac = (t - turns as f64) * TURN;
    (turns, frac as u64)
}
