//! `ODOMETRY` (#331) and `HEARTBEAT` (#0) of the MAVLink `common` dialect, and our pose
//! record in their terms (the table in docs/ROS.md, MAVLink column).
//!
//! Frames: pose in `MAV_FRAME_LOCAL_FRD` (x north = our y, y east = our x, z down = 0; the
//! origin where the unit started or was reset), velocity in `MAV_FRAME_BODY_FRD` (x
//! forward, y right, z down). Yaw = our heading alpha (0 north, clockwise), as the rotation
//! body -> local `q = (cos(alpha/2), 0, 0, sin(alpha/2))`, `w >= 0`.

use super::frame::MessageId;
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
        let per_tick = core::f32::consts::PI / p.ticks_per_rev as f32;
        let q = [
            p.left_diameter as f32 * per_tick,
            p.right_diameter as f32 * per_tick,
        ];
        let n = [d_left as f32, d_right as f32];
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

/// The `ODOMETRY` fields.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Odometry {
    /// Timestamp, microseconds (ours: the MCU time of the sample, since start).
    pub time_usec: u64,
    /// Pose frame (`MAV_FRAME`).
    pub frame_id: u8,
    /// Velocity frame (`MAV_FRAME`).
    pub child_frame_id: u8,
    /// Position x, y, z in `frame_id`, metres.
    pub position: [f32; 3],
    /// Quaternion w, x, y, z: rotation body -> `frame_id`.
    pub q: [f32; 4],
    /// Velocity vx, vy, vz in `child_frame_id`, m/s.
    pub velocity: [f32; 3],
    /// Roll, pitch and yaw rate, rad/s.
    pub rates: [f32; 3],
    /// Upper triangle of the 6x6 covariance of (x, y, z, roll, pitch, yaw).
    pub pose_covariance: [f32; 21],
    /// Upper triangle of the 6x6 covariance of (vx, vy, vz, roll, pitch, yaw rate).
    pub velocity_covariance: [f32; 21],
    /// Steps at every pose reset.
    pub reset_counter: u8,
    /// `MAV_ESTIMATOR_TYPE`.
    pub estimator_type: u8,
    /// -1 failed, 0 unknown, 1 worst .. 100 best.
    pub quality: i8,
}

impl Odometry {
    /// `record` in MAVLink terms, with the `twist` since the previous record (none for the
    /// first: zero velocity with an unknown covariance, NaN first element) and the reset
    /// counter.
    pub fn from_record(record: &PoseRecord, twist: Option<&Twist>, reset_counter: u8) -> Self {
        let mut pose_covariance = [0.0f32; 21];
        pose_covariance[upper(0, 0)] = record.sigma_y * record.sigma_y;
        pose_covariance[upper(0, 1)] = record.cov_xy;
        pose_covariance[upper(1, 1)] = record.sigma_x * record.sigma_x;
        pose_covariance[upper(5, 5)] = record.sigma_heading * record.sigma_heading;
        // No interval yet (the first record): zero velocity, its covariance unknown (NaN as
        // the first element, as the message defines).
        let t = twist.copied().unwrap_or(Twist {
            vx: 0.0,
            yawspeed: 0.0,
            var_vx: f32::NAN,
            var_yaw: 0.0,
            cov: 0.0,
        });
        let velocity = [t.vx, 0.0, 0.0];
        let rates = [0.0, 0.0, t.yawspeed];
        let mut velocity_covariance = [0.0f32; 21];
        velocity_covariance[upper(0, 0)] = t.var_vx;
        velocity_covariance[upper(1, 1)] = t.var_vx;
        velocity_covariance[upper(0, 5)] = t.cov;
        velocity_covariance[upper(5, 5)] = t.var_yaw;
        let f = record.flags;
        let quality = if f.left.fault || f.right.fault {
            QUALITY_FAILED
        } else if f.left.index_mismatch || f.right.index_mismatch {
            QUALITY_INDEX_MISMATCH
        } else {
            QUALITY_GOOD
        };
        Self {
            time_usec: record.mcu_time_us,
            frame_id: MAV_FRAME_LOCAL_FRD,
            child_frame_id: MAV_FRAME_BODY_FRD,
            position: [record.y as f32, record.x as f32, 0.0],
            q: quaternion_of_heading(record.heading),
            velocity,
            rates,
            pose_covariance,
            velocity_covariance,
            reset_counter,
            estimator_type: ESTIMATOR_TYPE,
            quality,
        }
    }

    /// The payload in wire order (fields by size, extensions last), untruncated.
    pub fn write_payload(&self, out: &mut [u8; ODOMETRY_LEN]) {
        out[..8].copy_from_slice(&self.time_usec.to_le_bytes());
        let mut at = 8;
        for part in [
            &self.position[..],
            &self.q,
            &self.velocity,
            &self.rates,
            &self.pose_covariance,
            &self.velocity_covariance,
        ] {
            at = put_f32s(out, at, part);
        }
        out[228..].copy_from_slice(&[
            self.frame_id,
            self.child_frame_id,
            self.reset_counter,
            self.estimator_type,
            self.quality as u8,
        ]);
    }
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
    // Half the heading as a fraction of a turn in [0, 1), then as a binary angle (2^64 a
    // turn) for the fixed-point sine and cosine.
    let turns = alpha * (0.5 / core::f64::consts::TAU);
    let mut frac = turns - (turns as i64) as f64;
    if frac < 0.0 {
        frac += 1.0;
    }
    let (s, c) = sin_cos((frac * 18_446_744_073_709_551_616.0) as u64);
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
