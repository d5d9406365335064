//! The uncertainty coefficients a calibration fits: which model's (delta or kappa), how the
//! two wheels' relate, by which criterion, and the result ([`UncertaintyFit`]).

use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::filter::search::Search;

/// How the two wheels' coefficients are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DeltaMode {
    /// Left and right equal.
    Equal,
    /// Keep the ratio left/right of the initial parameters; fit the common scale.
    KeepRatio,
}

/// How `calibrate` fits the uncertainty coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum UncertaintyCriterion {
    /// The covariance model's kappa by the likelihood of the reference's observations under
    /// an error-state Kalman filter (`calib/filter/innovations.rs`: nothing a point is judged on is fitted
    /// to it); the paper's model by the coverage criterion (the default).
    #[default]
    Likelihood,
    /// The paper's statistical fitting for both models: the smallest coefficient whose
    /// 1-sigma band (widened by the reference noise) covers 68.27 % of the pooled horizontal
    /// errors of restarted sub-trajectories, restart headings fitted by eq (16) on each;
    /// `delta_diff` by the heading-change coverage.
    Coverage,
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
    /// The criterion that fitted the coefficients.
    pub criterion: UncertaintyCriterion,
    /// Heading 1- and 3-sigma coverage of the fit's points (likelihood criterion, reference
    /// with a heading).
    pub heading_coverage: Option<(f64, f64)>,
    /// Standard error of `ln` of the fitted coefficient, from the curvature of the negative
    /// log-likelihood (likelihood criterion): the coefficient is known within a factor of
    /// `exp(ln_se)` (1 sigma).
    pub ln_se: Option<f64>,
    /// The coefficient of the largest likelihood, where the unit is told another: its mean over
    /// the likelihood (likelihood criterion; `fit_kappa_filter`).
    pub most_likely: Option<f64>,
    /// Where the likelihood fit's searches ended, where a later fit of the same drive on more
    /// data starts them (likelihood criterion; else empty).
    pub searches: Vec<(Search, f64)>,
}

/// `base` with the fitted coefficient `v` of its uncertainty model: `delta_left` or
/// `kappa_left` = `v`, the right one `v` or, with [`DeltaMode::KeepRatio`], `v` times the
/// ratio right/left of `initial`'s.
pub(crate) fn set_coefficient(
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

/// `base` with the covariance model's coefficients of `fitted` (the slip and opposite-phase
/// slip; the geometry and the paper model's coefficients stay `base`'s).
pub(crate) fn with_covariance_coefficients(
    base: &ChassisParams,
    fitted: &ChassisParams,
) -> ChassisParams {
    ChassisParams {
        kappa_left: fitted.kappa_left,
        kappa_right: fitted.kappa_right,
        kappa_diff: fitted.kappa_diff,
        kappa_diff_corr: fitted.kappa_diff_corr,
        ..*base
    }
}

/// The `delta_diff` fit of the paper's model (`delta_diff.rs` makes it).
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
    /// (see `delta_diff.rs`).
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
