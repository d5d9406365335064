//! `ODOMETRY` (#331) and `HEARTBEAT` (#0) of the MAVLink `common` dialect, and our pose
//! record in their terms (the table in docs/ROS.md, MAVLink column).
//!
//! Frames: pose in `MAV_FRAME_LOCAL_FRD` (x north = our y, y east = our x, z down = 0; the
//! origin where the unit started or was reset), velocity in `MAV_FRAME_BODY_FRD` (x
//! forward, y right, z down). Yaw = our heading alpha (0 north, clockwise), as the rotation
//! body -> local `q = (cos(alpha/2), 0, 0, sin(alpha/2))`, `w >= 0`.

use super::frame::MessageId;
use crate::odometry::integrator::radians_to_binary;
use crate::odometry::trig::{q30_to_f32, sin_cos};
use crate::odometry::{ChassisParams, UncertaintyModel};
use crate::protocol::PoseRecord;

/// `ODOMETRY`: id 331, `CRC_EXTRA` 91.
pub const ODOMETRY_ID: MessageId = MessageId {
    id: 331,
    crc_extra: 91,
};
/// `HEARTBEAT`: id 0, `CRC_EXTRA` 50.
pub const HEARTBEAT_ID: MessageId = MessageId {
    id: 0,
    crc_extra: 50,
};
/// `ODOMETRY` payload with its extensions, bytes.
pub const ODOMETRY_LEN: usize = 233;
/// `MAV_FRAME_LOCAL_FRD`.
pub const MAV_FRAME_LOCAL_FRD: u8 = 20;
/// `MAV_FRAME_BODY_FRD`.
pub const MAV_FRAME_BODY_FRD: u8 = 12;
/// `MAV_ESTIMATOR_TYPE_UNKNOWN`: MAVLink names no wheel odometry estimator; PX4 takes this
/// type as external vision with its covariance (`NAIVE` would drop the covariance).
pub const ESTIMATOR_TYPE: u8 = 0;
/// `quality` when an encoder's fault line is active: -1, odometry failed.
pub const QUALITY_FAILED: i8 = -1;
/// `quality` of a record reporting an index count mismatch (missed or spurious increments).
pub const QUALITY_INDEX_MISMATCH: i8 = 50;
/// `quality` otherwise.
pub const QUALITY_GOOD: i8 = 100;

/// The chassis' motion over one record interval in `MAV_FRAME_BODY_FRD`, from the counts
/// (single precision: what `ODOMETRY` carries).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Twist {
    /// Forward speed `ds/dt`, m/s.
    pub vx: f32,
    /// Yaw rate `dalpha/dt`, rad/s (clockwise seen from above, FRD).
    pub yawspeed: f32,
    /// var(vx), (m/s)^2.
    pub var_vx: f32,
    /// var(yawspeed), (rad/s)^2.
    pub var_yaw: f32,
    /// cov(vx, yawspeed), m rad/s^2.
    pub cov: f32,
}

impl Twist {
    /// The twist of an interval of `dt_us` microseconds in which the wheels turned
    /// `d_left`, `d_right` increments: `s_i = dGamma_i pi D_i / ticks_per_rev`, `ds = (s_1 +
    /// s_2)/2`, `dalpha = (s_1 - s_2)/track_width`; per-wheel variances of the model (paper:
    /// `(delta_i dGamma_i)^2` and `(delta_diff (dGamma_1 - dGamma_2))^2` opposite-phase;
    /// covariance model `kappa_i |s_i|`) plus the quantisation `(pi D_i / ticks_per_rev)^2 /
    /// 6`. `None` when `dt_us` is 0.
    pub fn from_counts(p: &ChassisParams, d_left: i64, d_right: i64, dt_us: u64) -> Option<Self> {
        if dt_us == 0 {
            return None;
        }
        let dt = dt_us as f32 * 1e-6;
        // Through i32, which the FPU converts (i64 needs library code): a record interval's
        // counts are within `MAX_COUNTS_PER_SAMPLE` x `output_divider`, far inside i32.
        let counts = |d: i64| d as i32 as f32;
        let per_tick = core::f32::consts::PI / p.ticks_per_rev as f32;
        let q = [
            p.left_diameter as f32 * per_tick,
            p.right_diameter as f32 * per_tick,
        ];
        let n = [counts(d_left), counts(d_right)];
        let s = [n[0] * q[0], n[1] * q[1]];
        let (var, var_e) = match p.uncertainty_model {
            UncertaintyModel::Paper => {
                let sq = |d: f32, k: f32| (d * k) * (d * k);
                (
                    [sq(p.delta_left, n[0]), sq(p.delta_right, n[1])],
                    sq(p.delta_diff, n[0] - n[1]),
                )
            }
            UncertaintyModel::Covariance => {
                ([p.kappa_left * s[0].abs(), p.kappa_right * s[1].abs()], 0.0)
            }
        };
        let v = [var[0] + q[0] * q[0] / 6.0, var[1] + q[1] * q[1] / 6.0];
        let (w, dt2) = (p.track_width as f32, dt * dt);
        Some(Self {
            vx: 0.5 * (s[0] + s[1]) / dt,
            yawspeed: (s[0] - s[1]) / w / dt,
            var_vx: 0.25 * (v[0] + v[1]) / dt2,
            var_yaw: (v[0] + v[1] + 4.0 * var_e) / (w * w * dt2),
            cov: 0.5 * (v[0] - v[1]) / (w * dt2),
        })
    }
}

/// Index of `(row, col)`, `row <= col`, in a 6x6 upper triangle stored row by row (21).
pub const fn upper(row: usize, col: usize) -> usize {
    row * 6 - row * (row.saturating_sub(1)) / 2 + col - row
}

/// Byte offsets of the `ODOMETRY` fields in the payload (wire order: fields by size,
/// extensions last): time_usec (u64), x, y, z, q[4], vx, vy, vz, rollspeed, pitchspeed,
/// yawspeed, pose_covariance[21], velocity_covariance[21] (f32), frame_id, child_frame_id,
/// then the extensions reset_counter, estimator_type (u8) and quality (i8).
mod at {
    pub const X: usize = 8;
    pub const Q: usize = 20;
    pub const VX: usize = 36;
    pub const YAWSPEED: usize = 56;
    pub const POSE_COVARIANCE: usize = 60;
    pub const VELOCITY_COVARIANCE: usize = 144;
    pub const FRAME_ID: usize = 228;
}

/// `quality` of `record`: [`QUALITY_FAILED`] with an encoder fault, [`QUALITY_INDEX_MISMATCH`]
/// with an index count mismatch, else [`QUALITY_GOOD`].
pub fn quality(record: &PoseRecord) -> i8 {
    let f = record.flags;
    if f.left.fault || f.right.fault {
        QUALITY_FAILED
    } else if f.left.index_mismatch || f.right.index_mismatch {
        QUALITY_INDEX_MISMATCH
    } else {
        QUALITY_GOOD
    }
}

/// The `ODOMETRY` payload (untruncated, into a zeroed `out`) of `record`, with the `twist` since the previous
/// record and the reset counter. Time: the MCU time of the sample. Pose in
/// `MAV_FRAME_LOCAL_FRD`: x = our y (north), y = our x (east), z = 0, `q` of the heading.
/// Pose covariance (upper triangle over x, y, z, roll, pitch, yaw): var(north) = sigma_y^2,
/// cov(north, east) = cov_xy, var(east) = sigma_x^2, var(yaw) = sigma_heading^2, all else 0
/// (z, roll and pitch are not estimated: see docs/MAVLINK.md for why 0, not NaN). Velocity in
/// `MAV_FRAME_BODY_FRD`: vx forward, vy = vz = 0, yawspeed, roll and pitch rates 0; its
/// covariance var(vx) = var(vy), cov(vx, yawspeed), var(yawspeed). Without a twist (the
/// first record) the velocity is 0 and its covariance unknown (NaN first element).
pub fn write_odometry(
    record: &PoseRecord,
    twist: Option<&Twist>,
    reset_counter: u8,
    out: &mut [u8; ODOMETRY_LEN],
) {
    out[..8].copy_from_slice(&record.mcu_time_us.to_le_bytes());
    put_f32s(out, at::X, &[record.y as f32, record.x as f32]);
    put_f32s(out, at::Q, &quaternion_of_heading(record.heading));
    let pose = at::POSE_COVARIANCE;
    let (sx, sy, sh) = (record.sigma_x, record.sigma_y, record.sigma_heading);
    put_f32s(out, pose, &[sy * sy, record.cov_xy]);
    put_f32s(out, pose + 4 * upper(1, 1), &[sx * sx]);
    put_f32s(out, pose + 4 * upper(5, 5), &[sh * sh]);
    let vel = at::VELOCITY_COVARIANCE;
    match twist {
        Some(t) => {
            put_f32s(out, at::VX, &[t.vx]);
            put_f32s(out, at::YAWSPEED, &[t.yawspeed]);
            put_f32s(out, vel, &[t.var_vx]);
            put_f32s(out, vel + 4 * upper(0, 5), &[t.cov, t.var_vx]);
            put_f32s(out, vel + 4 * upper(5, 5), &[t.var_yaw]);
        }
        None => {
            put_f32s(out, vel, &[f32::NAN]);
        }
    }
    out[at::FRAME_ID..].copy_from_slice(&[
        MAV_FRAME_LOCAL_FRD,
        MAV_FRAME_BODY_FRD,
        reset_counter,
        ESTIMATOR_TYPE,
        quality(record) as u8,
    ]);
}

/// Writes `values` little-endian at `at` in `out`; returns the end.
#[inline(never)]
fn put_f32s(out: &mut [u8], at: usize, values: &[f32]) -> usize {
    let end = at + 4 * values.len();
    if let Some(dst) = out.get_mut(at..end) {
        for (chunk, v) in dst.chunks_exact_mut(4).zip(values) {
            chunk.copy_from_slice(&v.to_le_bytes());
        }
    }
    end
}

/// `q = (cos(alpha/2), 0, 0, sin(alpha/2))` of heading `alpha` (rad, any turn), `w >= 0`.
pub fn quaternion_of_heading(alpha: f64) -> [f32; 4] {
    // Half the heading as a binary angle (2^64 a turn): half a turn per whole turn.
    let (turns, frac) = radians_to_binary(alpha);
    let (s, c) = sin_cos(((turns as u64) << 63) | (frac >> 1));
    let sign = if c < 0 { -1.0 } else { 1.0 };
    [sign * q30_to_f32(c), 0.0, 0.0, sign * q30_to_f32(s)]
}

/// The `HEARTBEAT` fields the unit sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Heartbeat {
    /// `MAV_TYPE`.
    pub mav_type: u8,
    /// `MAV_AUTOPILOT`.
    pub autopilot: u8,
    /// `MAV_STATE`.
    pub system_status: u8,
}

impl Heartbeat {
    /// A component that is not a vehicle: `MAV_TYPE_ONBOARD_CONTROLLER` (18),
    /// `MAV_AUTOPILOT_INVALID` (8), `MAV_STATE_ACTIVE` (4); base and custom mode 0.
    pub const UNIT: Self = Self {
        mav_type: 18,
        autopilot: 8,
        system_status: 4,
    };

    /// The payload in wire order: custom_mode (u32), type, autopilot, base_mode,
    /// system_status, mavlink_version (3).
    pub fn payload(&self) -> [u8; 9] {
        [
            0,
            0,
            0,
            0,
            self.mav_type,
            self.autopilot,
            0,
            self.system_status,
            3,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upper_triangle_indices() {
        assert_eq!(upper(0, 0), 0);
        assert_eq!(upper(0, 5), 5);
        assert_eq!(upper(1, 1), 6);
        assert_eq!(upper(2, 2), 11);
        assert_eq!(upper(3, 3), 15);
        assert_eq!(upper(4, 4), 18);
        assert_eq!(upper(5, 5), 20);
    }
}
