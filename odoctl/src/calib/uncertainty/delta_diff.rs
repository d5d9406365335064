//! The `delta_diff` fit of the paper's model by the heading-change coverage.

use std::cell::RefCell;

use anyhow::Result;
use indicatif::ProgressBar;
use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::run::Run;

use super::coefficients::{DeltaMode, DiffFit, UncertaintyFit};
use super::coverage::{
    fit_coefficient, heading_coverage, heading_points, horizontal_coverage, smallest_covering,
    DIFF_LOG_TOL,
};
use super::restarts::Restarts;

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
            fit.coverage1 = horizontal_coverage(&ev, o.ref_sigma, 1.0, 0);
            fit.coverage3 = horizontal_coverage(&ev, o.ref_sigma, 3.0, 0);
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
