//! `calibrate --export-ros FILE.yaml`: the calibrated geometry as ros2_control
//! `diff_drive_controller` parameters, for users who also drive the chassis with ros2_control.
//!
//! `wheel_separation` = `track_width`; `wheel_radius` = the mean radius `(D_1 + D_2)/4`;
//! `left_wheel_radius_multiplier` = `D_1 / (2 wheel_radius)` and the same for the right, so
//! that `wheel_radius * multiplier` is each wheel's calibrated radius; the separation
//! multiplier stays 1.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result};

use crate::config as cfg;
use odo_unit::odometry::ChassisParams;

/// Node name the parameters are written under (the controller's name in the user's
/// controller manager configuration; rename it there if theirs differs).
pub const CONTROLLER: &str = "diff_drive_controller";

/// The YAML text of the parameters of `p`; `source` is named in a comment.
pub fn diff_drive_yaml(p: &ChassisParams, source: &str) -> String {
    let radius = 0.25 * (p.left_diameter + p.right_diameter);
    let mut y = String::new();
    let _ = writeln!(
        y,
        "# ros2_control diff_drive_controller parameters from odoctl's calibration ({source})."
    );
    let _ = writeln!(
        y,
        "# left_diameter {:?} m, right_diameter {:?} m, track_width {:?} m (docs/ROS.md).",
        p.left_diameter, p.right_diameter, p.track_width
    );
    let _ = writeln!(y, "{CONTROLLER}:");
    let _ = writeln!(y, "  ros__parameters:");
    let _ = writeln!(y, "    wheel_separation: {:?}", p.track_width);
    let _ = writeln!(y, "    wheel_radius: {radius:?}");
    let _ = writeln!(
        y,
        "    left_wheel_radius_multiplier: {:?}",
        p.left_diameter / (2.0 * radius)
    );
    let _ = writeln!(
        y,
        "    right_wheel_radius_multiplier: {:?}",
        p.right_diameter / (2.0 * radius)
    );
    let _ = writeln!(y, "    wheel_separation_multiplier: 1.0");
    y
}

/// The one-call hook of `calibrate --export-ros`: converts the result file `result` that
/// `calibrate --out` wrote into `yaml`.
pub fn export_hook(yaml: &Path, result: &Path) -> Result<()> {
    let p = cfg::read_params(result, ChassisParams::DESIGNED)?;
    std::fs::write(yaml, diff_drive_yaml(&p, &result.display().to_string()))
        .with_context(|| format!("{}: cannot write", yaml.display()))?;
    eprintln!(
        "diff_drive_controller parameters written to {}",
        yaml.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value(y: &str, key: &str) -> f64 {
        y.lines()
            .find_map(|l| l.trim().strip_prefix(&format!("{key}: ")))
            .unwrap_or_else(|| panic!("{key} missing:\n{y}"))
            .parse()
            .unwrap()
    }

    #[test]
    fn radii_and_separation_reproduce_the_calibration() {
        let mut p = ChassisParams::DESIGNED;
        p.left_diameter = 0.2608;
        p.right_diameter = 0.2607;
        p.track_width = 0.5656;
        let y = diff_drive_yaml(&p, "cal.toml");
        assert!(
            y.contains("diff_drive_controller:\n  ros__parameters:\n"),
            "{y}"
        );
        let r = value(&y, "wheel_radius");
        let l = value(&y, "left_wheel_radius_multiplier");
        let rr = value(&y, "right_wheel_radius_multiplier");
        assert!((2.0 * r * l - p.left_diameter).abs() < 1e-15);
        assert!((2.0 * r * rr - p.right_diameter).abs() < 1e-15);
        assert_eq!(value(&y, "wheel_separation"), p.track_width);
        assert_eq!(value(&y, "wheel_separation_multiplier"), 1.0);
        // Equal wheels: multipliers exactly 1.
        let y = diff_drive_yaml(&ChassisParams::DESIGNED, "x");
        assert_eq!(value(&y, "left_wheel_radius_multiplier"), 1.0);
        assert_eq!(value(&y, "right_wheel_radius_multiplier"), 1.0);
    }
}
