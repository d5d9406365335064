//! The reference antenna's lever arm in the calibration model: the reference measures the
//! antenna at `(forward, left)` metres from the axle centre in the chassis frame, so the
//! odometry is compared at `centre + R(heading) (forward, left)`
//! ([`crate::reference::antenna_position`]: heading 0 = north, clockwise; x east, y north),
//! and the derivatives of that point with respect to the fit's unknowns.

use odo_unit::odometry::Pose;

use super::sensitivity::PoseSensitivity;

/// Column of `antenna_forward` in the unknowns of the residual Jacobians (after the four
/// [`GEOMETRY_UNKNOWNS`]).
///
/// [`GEOMETRY_UNKNOWNS`]: super::sensitivity::GEOMETRY_UNKNOWNS
pub const ANTENNA_FORWARD: usize = 4;
/// Column of `antenna_left`.
pub const ANTENNA_LEFT: usize = 5;
/// Number of model unknowns a Jacobian column index may name: [`GEOMETRY_UNKNOWNS`], then
/// `antenna_forward`, `antenna_left`.
///
/// [`GEOMETRY_UNKNOWNS`]: super::sensitivity::GEOMETRY_UNKNOWNS
pub const MODEL_UNKNOWNS: usize = 6;

/// The antenna lever arm of a fit: `(forward, left)` metres from the axle centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LeverArm {
    /// Measured, held.
    Fixed(f64, f64),
    /// Estimated with the geometry, from this first guess.
    Fitted(f64, f64),
}

impl Default for LeverArm {
    /// No lever arm: the reference is the axle centre.
    fn default() -> Self {
        Self::Fixed(0.0, 0.0)
    }
}

impl LeverArm {
    /// The (first) value.
    pub fn value(self) -> (f64, f64) {
        match self {
            Self::Fixed(f, l) | Self::Fitted(f, l) => (f, l),
        }
    }

    /// True when estimated.
    pub fn fitted(self) -> bool {
        matches!(self, Self::Fitted(..))
    }
}

/// The offset of the antenna from the axle centre at `heading` (east, north; m).
#[inline(always)]
pub fn antenna_offset(heading: f64, antenna: (f64, f64)) -> (f64, f64) {
    crate::reference::antenna_position(0.0, 0.0, heading, antenna.0, antenna.1)
}

/// The point the reference measures, for an integrator started with its centre at the
/// stretch's anchor (the reference there) and heading `heading0`: the integrated centre
/// `pose` shifted by the antenna's offset now less its offset at the start,
/// `pose + R(h) a - R(h0) a` (`a` = `(forward, left)`), so that the antenna starts at the
/// anchor. Exactly `pose` when the lever arm is zero.
#[inline(always)]
pub fn observed_point(pose: &Pose, antenna: (f64, f64), heading0: f64) -> (f64, f64) {
    if antenna == (0.0, 0.0) {
        (pose.x, pose.y)
    } else {
        let (ox, oy) = antenna_offset(pose.heading, antenna);
        let (sx, sy) = antenna_offset(heading0, antenna);
        (pose.x + (ox - sx), pose.y + (oy - sy))
    }
}

/// The observed point of `pose` ([`observed_point`]) and its derivatives with respect to the
/// unknowns `cols` (indices below [`MODEL_UNKNOWNS`]) into `jx`, `jy`: the centre's forward
/// sensitivity `d`, plus the lever arm turned with the heading, `R'(h) a dh/dq`, less its
/// turn at the start for the initial heading; for the lever arm itself the columns of
/// `R(h) - R(h0)`.
#[inline(always)]
pub fn observed_with_rows(
    pose: &Pose,
    d: &PoseSensitivity,
    antenna: (f64, f64),
    heading0: f64,
    cols: &[usize],
    jx: &mut [f64],
    jy: &mut [f64],
) -> (f64, f64) {
    let (f, l) = antenna;
    let lever = antenna != (0.0, 0.0);
    if !lever && cols.iter().all(|&k| k < 4) {
        for (j, &k) in cols.iter().enumerate() {
            jx[j] = d.x[k];
            jy[j] = d.y[k];
        }
        return (pose.x, pose.y);
    }
    let (s, c) = pose.heading.sin_cos();
    let (s0, c0) = heading0.sin_cos();
    // d(antenna offset)/d heading, now and at the start.
    let (ax, ay) = (f * c + l * s, -f * s + l * c);
    let (ax0, ay0) = (f * c0 + l * s0, -f * s0 + l * c0);
    for (j, &k) in cols.iter().enumerate() {
        (jx[j], jy[j]) = match k {
            ANTENNA_FORWARD => (s - s0, c - c0),
            ANTENNA_LEFT => (c0 - c, s - s0),
            3 => (
                d.x[3] + ax * d.heading[3] - ax0,
                d.y[3] + ay * d.heading[3] - ay0,
            ),
            _ => (d.x[k] + ax * d.heading[k], d.y[k] + ay * d.heading[k]),
        };
    }
    observed_point(pose, antenna, heading0)
}

/// The lever arm `antenna_forward`, `antenna_left` of a calibration result's `[fit]` table
/// ((0, 0) when it has none): what `calibrate` wrote and `validate` applies.
pub fn read_lever_arm(path: &std::path::Path) -> anyhow::Result<(f64, f64)> {
    use anyhow::{anyhow, Context};
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let table: toml::Table = toml::from_str(&text)
        .map_err(|e| anyhow!("{}: {}", path.display(), e.to_string().trim_end()))?;
    let Some(fit) = table.get("fit").and_then(|f| f.as_table()) else {
        return Ok((0.0, 0.0));
    };
    let num = |k: &str| -> anyhow::Result<f64> {
        match fit.get(k) {
            None => Ok(0.0),
            Some(v) => v
                .as_float()
                .or_else(|| v.as_integer().map(|i| i as f64))
                .filter(|x| x.is_finite() && x.abs() < 100.0)
                .ok_or_else(|| {
                    anyhow!("{}: [fit] {k} must be a distance in metres", path.display())
                }),
        }
    };
    Ok((num("antenna_forward")?, num("antenna_left")?))
}
