//! The covariance model's kappa by the likelihood of the reference's observations under the
//! error-state Kalman filter ([`Innovations`]): nothing a point is judged on is fitted to it.

use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::filter::innovations::Innovations;
use crate::calib::filter::search::slip_rate_range;

use super::coefficients::{set_coefficient, DeltaMode, UncertaintyCriterion, UncertaintyFit};

/// The covariance model's kappa by the filter's likelihood ([`Innovations::fit_with_turning`]):
/// the long-range wheel-distance variance per metre, with the slip's correlation length fitted
/// beside it (the unit's model has white slip; over the tens of metres a sigma is used for,
/// the long-range rate is what it must carry), and the opposite-phase slip. Returns the fit
/// and the wheel slip's correlation length (m; 0: white).
pub fn fit_kappa_filter(
    innovations: &Innovations,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    mode: DeltaMode,
) -> (UncertaintyFit, f64) {
    let (lo, hi) = slip_rate_range();
    let (kappa, corr, turning) = innovations.fit_with_turning(lo, hi);
    let mut params = set_coefficient(
        &ChassisParams {
            uncertainty_model: UncertaintyModel::Covariance,
            ..*geometry
        },
        mode,
        initial,
        kappa,
    );
    params.kappa_diff = turning.kappa_diff as f32;
    // The unit carries the same Gauss-Markov state (`kappa_diff_corr`, metres of
    // `|s_1 - s_2|` as `Turning::corr`); 0 when the white form won.
    params.kappa_diff_corr = turning.corr as f32;
    let score = innovations.score_with(kappa, corr, turning);
    let warning = if kappa <= lo * 1.01 {
        Some(
            "the errors are explained by the reference noise alone: kappa is not identifiable"
                .to_string(),
        )
    } else if kappa >= hi * 0.99 {
        Some(format!("kappa reached its largest admissible value {hi:e}"))
    } else {
        None
    };
    (
        UncertaintyFit {
            model: params.uncertainty_model,
            params,
            keys: ("kappa_left", "kappa_right"),
            windows: 1,
            points: innovations.observations,
            coverage1: score.horizontal.0,
            coverage3: score.horizontal.1,
            warning,
            diff: None,
            criterion: UncertaintyCriterion::Likelihood,
            heading_coverage: (!score.heading.0.is_nan()).then_some(score.heading),
        },
        corr,
    )
}
