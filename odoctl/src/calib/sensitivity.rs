//! Forward sensitivities of eqs (7)-(15): the pose's derivatives with respect to the
//! diameters, the track width and the initial heading, followed alongside the core integrator.

use odo_unit::odometry::{trig, ChassisParams, PoseStep};

/// The unknowns of the geometry fit, in the order of [`PoseSensitivity`]'s columns and of
/// the fit's parameter vector.
pub const GEOMETRY_UNKNOWNS: [&str; 4] = [
    "left_diameter",
    "right_diameter",
    "track_width",
    "initial_heading",
];

/// `base` with the geometry unknowns of `x` (the first three of [`GEOMETRY_UNKNOWNS`]: the
/// diameters and the track width, m).
pub(crate) fn with_geometry(base: &ChassisParams, x: &[f64]) -> ChassisParams {
    let mut p = *base;
    p.left_diameter = x[0];
    p.right_diameter = x[1];
    p.track_width = x[2];
    p
}

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
///
/// [`Integrator::step_pose`]: odo_unit::odometry::Integrator::step_pose
pub(crate) struct SensitivityTracker {
    model: SensitivityModel,
    pub(crate) sens: PoseSensitivity,
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
    pub(crate) fn new(params: &ChassisParams) -> Self {
        let mut sens = PoseSensitivity::default();
        sens.heading[3] = 1.0;
        Self {
            model: SensitivityModel::new(params),
            sens,
        }
    }

    /// Follows one integrated step of the integrator, from the motion it reports.
    #[inline(always)]
    pub(crate) fn step(&mut self, m: &PoseStep) {
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
