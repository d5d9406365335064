//! Chassis and encoder parameters, under the names shared by the firmware commands, the
//! settings store, the CSV/TOML files and the host tool.

use crate::bytes::Text;

/// Number of Fourier harmonics of each wheel's per-angle radius function (eqs 3-5).
pub const WHEEL_HARMONICS: usize = 3;

/// Per-angle wheel function of one wheel: the wheel's effective radius over one turn,
/// relative to its mean, as a short Fourier series referenced to the index (N) pulse.
///
/// With phase `theta` in radians (`2 pi (Gamma - Gamma_index) / ticks_per_rev`), the
/// distance travelled per increment is
/// `c * (1 + sum_h cos[h-1] * cos(h theta) + sin[h-1] * sin(h theta))`, `h = 1..=3`,
/// where `c = pi * diameter / ticks_per_rev`. The coefficients are dimensionless; all zero
/// means a round, centred wheel (eq 6). Keys: `left_cos1`..`left_cos3`, `left_sin1`..`left_sin3`
/// and the same for `right_`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WheelHarmonics {
    /// Cosine coefficients of harmonics 1..=3 (dimensionless).
    pub cos: [f32; WHEEL_HARMONICS],
    /// Sine coefficients of harmonics 1..=3 (dimensionless).
    pub sin: [f32; WHEEL_HARMONICS],
}

impl WheelHarmonics {
    /// A round, centred wheel: the constant transfer constant of eq (6).
    pub const ROUND: Self = Self {
        cos: [0.0; WHEEL_HARMONICS],
        sin: [0.0; WHEEL_HARMONICS],
    };

    /// True when every coefficient is zero (eq 6 applies exactly).
    pub fn is_round(&self) -> bool {
        self.cos.iter().chain(self.sin.iter()).all(|c| *c == 0.0)
    }
}

/// The calibration's own uncertainty of the geometry: standard errors of `left_diameter`,
/// `right_diameter` and `track_width` and their correlations, as the calibration estimated
/// them (keys `left_diameter_se`, `right_diameter_se`, `track_width_se`,
/// `diameters_correlation`, `left_track_correlation`, `right_track_correlation`). The
/// covariance model adds the pose error they cause to its bands; all zero (the default)
/// means a geometry taken as exact.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GeometryUncertainty {
    /// `left_diameter_se`: standard error of `left_diameter`, metres.
    pub left_diameter_se: f32,
    /// `right_diameter_se`: standard error of `right_diameter`, metres.
    pub right_diameter_se: f32,
    /// `track_width_se`: standard error of `track_width`, metres.
    pub track_width_se: f32,
    /// `diameters_correlation`: correlation of the two diameters' errors (-1..=1).
    pub diameters_correlation: f32,
    /// `left_track_correlation`: correlation of `left_diameter`'s and `track_width`'s errors.
    pub left_track_correlation: f32,
    /// `right_track_correlation`: correlation of `right_diameter`'s and `track_width`'s
    /// errors.
    pub right_track_correlation: f32,
}

impl GeometryUncertainty {
    /// An exact geometry (no calibration uncertainty).
    pub const EXACT: Self = Self {
        left_diameter_se: 0.0,
        right_diameter_se: 0.0,
        track_width_se: 0.0,
        diameters_correlation: 0.0,
        left_track_correlation: 0.0,
        right_track_correlation: 0.0,
    };

    /// Largest accepted standard error, metres.
    pub const MAX_SE: f32 = 0.01;

    /// True when the three correlations form a valid (positive semi-definite) correlation
    /// matrix, to within f32 rounding: `1 + 2 r_lr r_lw r_rw - r_lr^2 - r_lw^2 - r_rw^2 >= 0`.
    pub fn correlations_consistent(&self) -> bool {
        let (a, b, c) = (
            self.diameters_correlation,
            self.left_track_correlation,
            self.right_track_correlation,
        );
        1.0 + 2.0 * a * b * c - a * a - b * b - c * c >= -1.0e-6
    }

    /// The covariance of the relative errors `(d left_diameter / left_diameter, d
    /// right_diameter / right_diameter, d track_width / track_width)` of `p`, as the upper
    /// triangle `[ll, rr, ww, lr, lw, rw]` (dimensionless^2).
    pub fn relative_covariance(&self, p: &ChassisParams) -> [f32; 6] {
        let l = self.left_diameter_se / p.left_diameter as f32;
        let r = self.right_diameter_se / p.right_diameter as f32;
        let w = self.track_width_se / p.track_width as f32;
        [
            l * l,
            r * r,
            w * w,
            self.diameters_correlation * l * r,
            self.left_track_correlation * l * w,
            self.right_track_correlation * r * w,
        ]
    }
}

/// Kinematic and uncertainty parameters of the chassis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChassisParams {
    /// `left_diameter`: effective diameter of wheel 1 (left), metres.
    pub left_diameter: f64,
    /// `right_diameter`: effective diameter of wheel 2 (right), metres.
    pub right_diameter: f64,
    /// `track_width`: distance between the wheels' contact points, metres (w of eq 8).
    pub track_width: f64,
    /// `ticks_per_rev`: encoder increments per wheel turn after x4 decoding (P of eq 2).
    pub ticks_per_rev: u32,
    /// `delta_left`: uncertainty coefficient of wheel 1, metres per increment (eq 19):
    /// sigma of the wheel's distance over one sample = `delta_left * |dGamma_1|`.
    pub delta_left: f32,
    /// `delta_right`: uncertainty coefficient of wheel 2, metres per increment.
    pub delta_right: f32,
    /// `delta_diff`: the paper's proposed partial uncertainty of opposite-phase slip when
    /// turning, metres per increment of `|dGamma_1 - dGamma_2|` (0 = the paper's model).
    pub delta_diff: f32,
    /// `uncertainty_model`: which propagation fills the sigmas of a record.
    pub uncertainty_model: UncertaintyModel,
    /// `kappa_left`: for the covariance model, variance of wheel 1's distance per metre it
    /// rolled, m^2/m (Chong & Kleeman).
    pub kappa_left: f32,
    /// `kappa_right`: the same for wheel 2, m^2/m.
    pub kappa_right: f32,
    /// `kappa_diff`: for the covariance model, variance of an opposite-phase error `e`
    /// (`s_1 + e`, `s_2 - e`: slip when turning) per metre of wheel-distance difference
    /// `|ds_1 - ds_2|`, m^2/m (0: none).
    pub kappa_diff: f32,
    /// `kappa_diff_corr`: for the covariance model, correlation length of the opposite-phase
    /// slip, metres of wheel-distance difference `|ds_1 - ds_2|` (0, or below 1 mm: white, `e`
    /// of variance `kappa_diff |ds_1 - ds_2|` per sample). Otherwise the slip rate `eps` (`e` grows by
    /// `eps |ds_1 - ds_2|`) is a Gauss-Markov process of variance `kappa_diff / (2
    /// kappa_diff_corr)`: the same long-range variance `kappa_diff D` over a difference
    /// `D >> kappa_diff_corr`, less over shorter turns. What `odoctl calibrate` fits.
    pub kappa_diff_corr: f32,
    /// Per-angle wheel function of wheel 1 (`left_cos1`.. `left_sin3`).
    pub left_wheel: WheelHarmonics,
    /// Per-angle wheel function of wheel 2 (`right_cos1`.. `right_sin3`).
    pub right_wheel: WheelHarmonics,
    /// The calibration's uncertainty of the geometry (`left_diameter_se`.. ), used by the
    /// covariance model.
    pub geometry_uncertainty: GeometryUncertainty,
}

impl ChassisParams {
    /// The paper's designed values (Table 2, Table 3): 0.260 m wheels, 0.563 m track,
    /// 20,000 increments per turn, delta = 3.90e-8 m per increment, round wheels.
    pub const DESIGNED: Self = Self {
        left_diameter: 0.260,
        right_diameter: 0.260,
        track_width: 0.563,
        ticks_per_rev: 20_000,
        delta_left: 3.90e-8,
        delta_right: 3.90e-8,
        delta_diff: 0.0,
        uncertainty_model: UncertaintyModel::Paper,
        kappa_left: 1.0e-7,
        kappa_right: 1.0e-7,
        kappa_diff: 0.0,
        kappa_diff_corr: 0.0,
        left_wheel: WheelHarmonics::ROUND,
        right_wheel: WheelHarmonics::ROUND,
        geometry_uncertainty: GeometryUncertainty::EXACT,
    };

    /// Smallest accepted wheel diameter or track width, metres.
    pub const MIN_LENGTH: f64 = 0.01;
    /// Largest accepted wheel diameter or track width, metres.
    pub const MAX_LENGTH: f64 = 10.0;
    /// Accepted range of `ticks_per_rev`.
    pub const TICKS_PER_REV_RANGE: core::ops::RangeInclusive<u32> = 4..=1_048_576;
    /// Largest distance one increment may stand for, metres (`pi * diameter / ticks_per_rev`).
    pub const MAX_DISTANCE_PER_COUNT: f64 = 0.03;
    /// Largest heading change one increment may stand for, radians.
    pub const MAX_HEADING_PER_COUNT: f64 = 0.01;
    /// Largest accepted uncertainty coefficient, metres per increment.
    pub const MAX_DELTA: f32 = 1.0e-3;
    /// Largest accepted covariance-model coefficient, m^2/m.
    pub const MAX_KAPPA: f32 = 1.0e-2;
    /// Largest accepted `kappa_diff_corr`, metres of wheel-distance difference.
    pub const MAX_KAPPA_DIFF_CORR: f32 = 1.0e3;
    /// Largest accepted magnitude of one wheel-function coefficient (relative radius).
    pub const MAX_HARMONIC: f32 = 0.05;

    /// These parameters with the uncertainty models' (`delta_*`, `kappa_*`,
    /// `uncertainty_model`, `geometry_uncertainty`) set to the designed ones: two parameter
    /// sets integrate the same poses, bit for bit, when their pose parts are equal.
    pub fn pose_part(&self) -> Self {
        let d = Self::DESIGNED;
        Self {
            delta_left: d.delta_left,
            delta_right: d.delta_right,
            delta_diff: d.delta_diff,
            uncertainty_model: d.uncertainty_model,
            kappa_left: d.kappa_left,
            kappa_right: d.kappa_right,
            kappa_diff: d.kappa_diff,
            kappa_diff_corr: d.kappa_diff_corr,
            geometry_uncertainty: d.geometry_uncertainty,
            ..*self
        }
    }

    /// Checks every parameter against its documented range; the first offending key is
    /// named in the error.
    pub fn validate(&self) -> Result<(), ParamError> {
        let length = (Self::MIN_LENGTH, Self::MAX_LENGTH);
        check("left_diameter", self.left_diameter, length)?;
        check("right_diameter", self.right_diameter, length)?;
        check("track_width", self.track_width, length)?;
        if !Self::TICKS_PER_REV_RANGE.contains(&self.ticks_per_rev) {
            return Err(ParamError::OutOfRange("ticks_per_rev"));
        }
        // Keep one increment's distance and heading change within the fixed-point ranges of
        // the integrator: at most 3 cm and 0.01 rad per increment.
        for diameter in [self.left_diameter, self.right_diameter] {
            let c = core::f64::consts::PI * diameter / f64::from(self.ticks_per_rev);
            if c > Self::MAX_DISTANCE_PER_COUNT
                || c / self.track_width > Self::MAX_HEADING_PER_COUNT
            {
                return Err(ParamError::OutOfRange("ticks_per_rev"));
            }
        }
        for (&(key, lo, hi), value) in F32_RULES.iter().zip(self.f32_values()) {
            check(key, value, (lo, hi))?;
        }
        let g = &self.geometry_uncertainty;
        if !g.correlations_consistent() {
            return Err(ParamError::Inconsistent("right_track_correlation"));
        }
        Ok(())
    }

    /// The single-precision parameters in the order of [`F32_RULES`].
    fn f32_values(&self) -> [f32; F32_RULES.len()] {
        let (l, r, g) = (
            &self.left_wheel,
            &self.right_wheel,
            &self.geometry_uncertainty,
        );
        [
            self.delta_left,
            self.delta_right,
            self.delta_diff,
            self.kappa_left,
            self.kappa_right,
            self.kappa_diff,
            self.kappa_diff_corr,
            l.cos[0],
            l.sin[0],
            l.cos[1],
            l.sin[1],
            l.cos[2],
            l.sin[2],
            r.cos[0],
            r.sin[0],
            r.cos[1],
            r.sin[1],
            r.cos[2],
            r.sin[2],
            g.left_diameter_se,
            g.right_diameter_se,
            g.track_width_se,
            g.diameters_correlation,
            g.left_track_correlation,
            g.right_track_correlation,
        ]
    }
}

/// Key and range (`lo..=hi`) of each single-precision parameter, in the order
/// [`ChassisParams::validate`] checks them: one table and one loop instead of a check per
/// key (cheaper in flash).
const F32_RULES: [(&str, f32, f32); 25] = {
    const DELTA: f32 = ChassisParams::MAX_DELTA;
    const KAPPA: f32 = ChassisParams::MAX_KAPPA;
    const H: f32 = ChassisParams::MAX_HARMONIC;
    const SE: f32 = GeometryUncertainty::MAX_SE;
    [
        ("delta_left", 0.0, DELTA),
        ("delta_right", 0.0, DELTA),
        ("delta_diff", 0.0, DELTA),
        ("kappa_left", 0.0, KAPPA),
        ("kappa_right", 0.0, KAPPA),
        ("kappa_diff", 0.0, KAPPA),
        ("kappa_diff_corr", 0.0, ChassisParams::MAX_KAPPA_DIFF_CORR),
        ("left_cos1", -H, H),
        ("left_sin1", -H, H),
        ("left_cos2", -H, H),
        ("left_sin2", -H, H),
        ("left_cos3", -H, H),
        ("left_sin3", -H, H),
        ("right_cos1", -H, H),
        ("right_sin1", -H, H),
        ("right_cos2", -H, H),
        ("right_sin2", -H, H),
        ("right_cos3", -H, H),
        ("right_sin3", -H, H),
        ("left_diameter_se", 0.0, SE),
        ("right_diameter_se", 0.0, SE),
        ("track_width_se", 0.0, SE),
        ("diameters_correlation", -1.0, 1.0),
        ("left_track_correlation", -1.0, 1.0),
        ("right_track_correlation", -1.0, 1.0),
    ]
};

/// Setting names of the wheel-function coefficients: `[wheel][cos, sin][harmonic - 1]`.
pub const HARMONIC_KEYS: [[[&str; WHEEL_HARMONICS]; 2]; 2] = [
    [
        ["left_cos1", "left_cos2", "left_cos3"],
        ["left_sin1", "left_sin2", "left_sin3"],
    ],
    [
        ["right_cos1", "right_cos2", "right_cos3"],
        ["right_sin1", "right_sin2", "right_sin3"],
    ],
];

/// `v` must be finite and within `lo..=hi`; errors name `key`.
fn check<T: PartialOrd + Into<f64> + Copy>(
    key: &'static str,
    v: T,
    (lo, hi): (T, T),
) -> Result<(), ParamError> {
    if !v.into().is_finite() {
        Err(ParamError::NotFinite(key))
    } else if !(lo..=hi).contains(&v) {
        Err(ParamError::OutOfRange(key))
    } else {
        Ok(())
    }
}

impl Default for ChassisParams {
    fn default() -> Self {
        Self::DESIGNED
    }
}

/// Which uncertainty propagation the integrator runs (`uncertainty_model`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum UncertaintyModel {
    /// The paper's eqs (19)-(28): sigmas summed linearly (plus `delta_diff` when non-zero).
    #[default]
    Paper,
    /// First-order 3x3 covariance propagation of x, y, heading (Chong & Kleeman), with wheel
    /// distance variances `kappa * |ds|`.
    Covariance,
}

/// A parameter set that cannot be used; names the offending key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamError {
    /// The value is NaN or infinite.
    NotFinite(&'static str),
    /// The value is outside its documented range.
    OutOfRange(&'static str),
    /// The value does not fit with the others (three correlations that no covariance has).
    Inconsistent(&'static str),
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NotFinite(k) => write!(f, "{}: not a finite number", Text(k)),
            Self::OutOfRange(k) => write!(f, "{}: out of range", Text(k)),
            Self::Inconsistent(k) => write!(
                f,
                "{}: the three correlations do not form a valid correlation matrix",
                Text(k)
            ),
        }
    }
}
