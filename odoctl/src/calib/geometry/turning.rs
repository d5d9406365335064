//! How much a stretch turned, and what that says of the track width: eq (8), only turning
//! reveals it.

use odo_unit::odometry::ChassisParams;

use crate::calib::run::Run;

/// Total absolute heading change of the odometry over matches `a..=b` (rad), summed over
/// steps of at least 0.25 m of path so that count noise does not add up.
pub fn turning(run: &Run, params: &ChassisParams, a: usize, b: usize, heading0: f64) -> f64 {
    let mut total = 0.0;
    let mut last = (heading0, run.dist[a]);
    let _ = run.integrate_pose(params, a, b, heading0, |k, integ| {
        let h = integ.pose().heading;
        if run.dist[k] - last.1 >= 0.25 || k == b {
            total += (h - last.0).abs();
            last = (h, run.dist[k]);
        }
    });
    total
}

/// Relative standard error of `track_width` above which the fit warns that the trajectory
/// turned too little to determine it (see [`track_width_warning`]).
pub const TRACK_WIDTH_MAX_RELATIVE_SE: f64 = 1e-3;

/// Total absolute turning below which the fit warns that the track width is poorly
/// determined, whatever its standard error says (rad; 90 degrees).
pub const TRACK_WIDTH_WARN_TURNING: f64 = core::f64::consts::FRAC_PI_2;

/// The warning of a geometry fit whose trajectory turned too little to determine the track
/// width: it was held (total absolute turning below `min_turning`), or the turning is below
/// [`TRACK_WIDTH_WARN_TURNING`] (90 deg), or the relative standard error of `track_width`
/// exceeds [`TRACK_WIDTH_MAX_RELATIVE_SE`] (0.1 %, 0.6 mm on a 0.56 m track). Eq (8): only
/// turning reveals the track width, and the formal standard error assumes independent
/// residuals, which odometry drift is not, so both the turning and the error are checked.
pub fn track_width_warning(
    estimated: bool,
    turning: f64,
    min_turning: f64,
    params: &ChassisParams,
    std_errors: &[Option<f64>; 4],
) -> Option<String> {
    let deg = turning.to_degrees();
    if !estimated {
        return Some(format!(
            "the trajectory turned {deg:.0} deg in all (less than {:.0}): track_width not estimated, kept at {}",
            min_turning.to_degrees(),
            params.track_width
        ));
    }
    let rel = std_errors[2].map_or(f64::INFINITY, |se| se / params.track_width);
    if turning < TRACK_WIDTH_WARN_TURNING || rel.is_nan() || rel > TRACK_WIDTH_MAX_RELATIVE_SE {
        return Some(format!(
            "the trajectory turned {deg:.0} deg in all: track_width poorly determined (standard error {:.2} % of it; a fit wants at least {:.0} deg and at most {:.1} %)",
            100.0 * rel,
            TRACK_WIDTH_WARN_TURNING.to_degrees(),
            100.0 * TRACK_WIDTH_MAX_RELATIVE_SE
        ));
    }
    None
}
