//! The covariance model's kappa by the likelihood of the reference's observations under the
//! error-state Kalman filter ([`Innovations`]): nothing a point is judged on is fitted to it.

use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::filter::innovations::Innovations;
use crate::calib::filter::search::{mean_from_ln_se, polish, slip_rate_range, Search, SearchLog};

use super::coefficients::{set_coefficient, DeltaMode, UncertaintyCriterion, UncertaintyFit};

/// The covariance model's kappa by the filter's likelihood ([`Innovations::fit_with_turning`]):
/// the long-range wheel-distance variance per metre, with the slip's correlation length fitted
/// beside it (the unit's model has white slip; over the tens of metres a sigma is used for,
/// the long-range rate is what it must carry), and the opposite-phase slip. The unit is told
/// kappa's mean over the likelihood ([`mean_from_ln_se`]: `exp(ln_se^2 / 2)` times the most
/// likely value), not the most likely value: its variances are linear in kappa, so the mean is
/// what the errors' spread over kappa's own uncertainty has, and one drive that happened to read
/// kappa low does not leave the unit's bands too narrow. Returns the fit and the wheel slip's
/// correlation length (m; 0: white). The searches start near where an earlier fit's ended
/// (`earlier`, [`SearchLog`]; empty: cold).
pub fn fit_kappa_filter(
    innovations: &Innovations,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    mode: DeltaMode,
    earlier: Vec<(Search, f64)>,
) -> (UncertaintyFit, f64) {
    let (lo, hi) = slip_rate_range();
    let log = SearchLog::after(earlier);
    let (most_likely, corr, turning) = innovations.fit_with_turning(lo, hi, &log);
    let nll = |k: f64| innovations.score_with(k, corr, turning).nll;
    let most_likely = polish(nll, most_likely, lo, hi);
    let ln_se = ln_standard_error(nll, most_likely);
    let kappa = mean_from_ln_se(most_likely, ln_se, hi);
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
    let warning = if most_likely <= lo * 1.01 {
        Some(
            "the errors are explained by the reference noise alone: kappa is not identifiable"
                .to_string(),
        )
    } else if most_likely >= hi * 0.99 {
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
            ln_se,
            most_likely: Some(most_likely),
            searches: log.ended(),
        },
        corr,
    )
}

/// `ln kappa`'s standard error that measures kappa within 20 %: `ln 1.2`.
pub const KAPPA_TARGET_LN_SE: f64 = 0.182_321_556_793_954_6;

/// Step in `ln kappa` of the curvature's finite difference.
const LN_STEP: f64 = 0.3;

/// The standard error of `ln x` at the likelihood's maximum `x`, `nll` the negative
/// log-likelihood: `1 / sqrt` of its second derivative in `ln x` (a central difference
/// [`LN_STEP`] either side); `None` where it is not positive (a maximum at a bound).
pub fn ln_standard_error(nll: impl Fn(f64) -> f64, x: f64) -> Option<f64> {
    let l = x.ln();
    let f = |v: f64| nll(v.exp());
    let curvature = (f(l + LN_STEP) - 2.0 * f(l) + f(l - LN_STEP)) / (LN_STEP * LN_STEP);
    (curvature.is_finite() && curvature > 0.0).then(|| curvature.sqrt().recip())
}

/// Path length (m) that would measure the coefficient within a factor `exp(target)`, from a
/// run of `length` m that measured it within `exp(ln_se)`: the standard error falls as one
/// over the square root of the observations, one per metre of path.
pub fn length_for(ln_se: f64, length: f64, target: f64) -> f64 {
    length * (ln_se / target).powi(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_error_of_a_normal_likelihood_in_ln_scale() {
        // nll = (ln x - ln 2)^2 / (2 s^2): ln x ~ N(ln 2, s^2).
        for s in [0.05, 0.2, 1.0] {
            let nll = |x: f64| (x.ln() - 2f64.ln()).powi(2) / (2.0 * s * s);
            let se = ln_standard_error(nll, 2.0).unwrap();
            assert!((se / s - 1.0).abs() < 1e-9, "{se} vs {s}");
        }
        // A maximum at a bound (nll still falling): none.
        assert_eq!(ln_standard_error(|x: f64| -x.ln(), 1.0), None);
        assert_eq!(ln_standard_error(|_| f64::NAN, 1.0), None);
    }

    #[test]
    fn length_scales_with_the_square_of_the_error() {
        assert_eq!(length_for(0.4, 70.0, 0.2), 280.0);
        assert_eq!(length_for(0.2, 70.0, 0.2), 70.0);
        assert!((length_for(0.1, 70.0, 0.2) - 17.5).abs() < 1e-12);
    }
}
