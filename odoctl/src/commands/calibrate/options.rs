//! `calibrate`'s options mapped to the library's [`CalibrationOptions`], with the choice of
//! the uncertainty model the result selects.

use anyhow::Result;
use odo_unit::odometry::UncertaintyModel;

use crate::calib::{CalibrationOptions, LeverArm, ReferenceNoise};
use crate::cli::{CalibrateArgs, GeometryArgs, ModelChoice, Models};

/// The calibration's options from the command line's, with the reference's `noise`
/// ([`ReferenceNoise::resolve`]: the options' where given).
pub fn calibration_options(a: &CalibrateArgs, noise: ReferenceNoise) -> Result<CalibrationOptions> {
    let mut o = CalibrationOptions {
        delta_window: a.delta_window,
        reference_sigma: noise.horizontal,
        delta_mode: a.delta_mode,
        fit_delta: !a.no_delta,
        fit_delta_diff: !a.no_fit_delta_diff,
        reference_heading_sigma: noise.heading,
        models: a.models.list(),
        select: selected_model(a.uncertainty_model, a.models),
        criterion: a.uncertainty_criterion,
        polish: a.polish && !a.no_polish,
        windows: a.windows.clone(),
        window_start: a.window_start,
        wheel_harmonics: usize::from(a.wheel_harmonics),
        harmonics_window: a.harmonics_window,
        quiet: a.quiet,
        ..Default::default()
    };
    apply_geometry(&a.geometry, &mut o)?;
    Ok(o)
}

/// The model the result selects (`uncertainty_model`): the one asked for; else `covariance`
/// (the model that holds its coverage against the truth in the ensemble test), `paper` when
/// only the paper's is fitted, or none (the initial estimate's) with `--models config`.
pub fn selected_model(choice: Option<ModelChoice>, models: Models) -> Option<UncertaintyModel> {
    match (choice, models) {
        (Some(ModelChoice::Paper), _) => Some(UncertaintyModel::Paper),
        (Some(ModelChoice::Covariance), _) => Some(UncertaintyModel::Covariance),
        (None, Models::Config) => None,
        (None, Models::Paper) => Some(UncertaintyModel::Paper),
        (None, _) => Some(UncertaintyModel::Covariance),
    }
}

/// Sets the geometry method, its sub-trajectory length and cuts, the refinement and the
/// antenna lever arm of `o`.
pub fn apply_geometry(g: &GeometryArgs, o: &mut CalibrationOptions) -> Result<()> {
    if !(g.subtrajectory_length > 0.0 && g.subtrajectory_length.is_finite()) {
        anyhow::bail!(
            "--subtrajectory-length {}: must be a positive number of metres",
            g.subtrajectory_length
        );
    }
    let (f, l) = match &g.antenna {
        Some(s) => crate::reference::parse_antenna(s)?,
        None => (0.0, 0.0),
    };
    o.method = g.method;
    o.subtrajectory_length = g.subtrajectory_length;
    o.subtrajectory_cuts = g.subtrajectory_cuts;
    o.geometry_refine = g.geometry_refine;
    o.antenna = if g.fit_antenna {
        LeverArm::Fitted(f, l)
    } else {
        LeverArm::Fixed(f, l)
    };
    Ok(())
}
