//! MAVLink 2 output for a flight controller: `ODOMETRY` (#331) per pose record and
//! `HEARTBEAT` (#0), written by hand from the MAVLink `common` dialect (docs/MAVLINK.md).
//!
//! - [`frame`]: the MAVLink 2 frame (header, trailing-zero truncation, CRC-16/MCRF4XX with
//!   the message's `CRC_EXTRA`).
//! - [`odometry`]: our pose record to `ODOMETRY` in the frames ArduPilot and PX4 accept
//!   (`MAV_FRAME_LOCAL_FRD` pose, `MAV_FRAME_BODY_FRD` velocity: x north = our y, y east =
//!   our x, yaw = our heading).
//! - [`rx`]: what the unit does with MAVLink bytes it receives (skips and counts them).
//!
//! The firmware and `odoctl bridge --mavlink` both encode through [`MavlinkOut`].

pub mod frame;
pub mod odometry;
pub mod rx;

pub use frame::{encode_frame, FrameBuf, FrameHeader, MAX_FRAME_LEN};
pub use odometry::{write_odometry, Heartbeat, Twist};
pub use rx::{MavlinkRx, RxCounts};

use crate::odometry::ChassisParams;
use crate::protocol::PoseRecord;
use crate::settings::Settings;

// The settings' baud check counts the frames as sent: 10 bits a byte, with the 0x00 after
// each (`HEARTBEAT`: 10 + 9 + 2 bytes).
const _: () = assert!(crate::settings::MAVLINK_FRAME_BITS == (MAX_FRAME_LEN as u32 + 1) * 10);
const _: () = assert!(crate::settings::MAVLINK_HEARTBEAT_BITS == (10 + 9 + 2 + 1) * 10);

/// System and component id of the unit's frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ids {
    /// `mavlink_sysid`: the vehicle's system id (the flight controller's).
    pub sysid: u8,
    /// `mavlink_compid`: the unit's component id.
    pub compid: u8,
}

impl Ids {
    /// The ids `settings` give (`mavlink_sysid`, `mavlink_compid`; 1..=255 once validated).
    pub fn of(settings: &Settings) -> Self {
        Self {
            sysid: settings.mavlink_sysid as u8,
            compid: settings.mavlink_compid as u8,
        }
    }
}

/// The MAVLink output's state: sequence number, the previous record's counts and time (for
/// the velocity), the reset counter.
#[derive(Debug, Clone, Default)]
pub struct MavlinkOut {
    seq: u8,
    prev: Option<(i64, i64, u64)>,
    resets_seen: u32,
    reset_counter: u8,
}

impl MavlinkOut {
    /// Before the first frame: sequence number 0, no previous record.
    pub const fn new() -> Self {
        Self {
            seq: 0,
            prev: None,
            resets_seen: 0,
            reset_counter: 0,
        }
    }

    /// Forgets the previous record (the output switched away from MAVLink): the next
    /// `ODOMETRY` has no velocity interval, as the first after start.
    pub fn restart(&mut self) {
        self.prev = None;
    }

    /// Sequence number of the next frame.
    pub fn next_seq(&self) -> u8 {
        self.seq
    }

    /// The frame was sent (true: the sequence number steps) or dropped (false: it is used
    /// again, so a receiver counts no loss for a frame never sent).
    pub fn sent(&mut self, sent: bool) {
        if sent {
            self.seq = self.seq.wrapping_add(1);
        }
    }

    /// `ODOMETRY` of `record` as a frame in `out` (bytes used): velocity from the counts
    /// since the previous record given here with `params`; `pose_resets` counts the
    /// `reset_pose` applied since start (each change steps `reset_counter`).
    pub fn odometry(
        &mut self,
        record: &PoseRecord,
        params: &ChassisParams,
        pose_resets: u32,
        ids: Ids,
        out: &mut FrameBuf,
    ) -> usize {
        if pose_resets != self.resets_seen {
            self.resets_seen = pose_resets;
            self.reset_counter = self.reset_counter.wrapping_add(1);
        }
        let now = (record.gamma_left, record.gamma_right, record.mcu_time_us);
        let twist = self.prev.and_then(|(l, r, t)| {
            let dt_us = now.2.wrapping_sub(t);
            Twist::from_counts(params, now.0.wrapping_sub(l), now.1.wrapping_sub(r), dt_us)
        });
        self.prev = Some(now);
        let mut payload = [0u8; odometry::ODOMETRY_LEN];
        write_odometry(record, twist.as_ref(), self.reset_counter, &mut payload);
        encode_frame(&odometry::ODOMETRY_ID, &payload, self.header(ids), out)
    }

    /// `HEARTBEAT` as a frame in `out` (bytes used).
    pub fn heartbeat(&self, ids: Ids, out: &mut FrameBuf) -> usize {
        let payload = Heartbeat::UNIT.payload();
        encode_frame(&odometry::HEARTBEAT_ID, &payload, self.header(ids), out)
    }

    fn header(&self, ids: Ids) -> FrameHeader {
        FrameHeader {
            seq: self.seq,
            sysid: ids.sysid,
            compid: ids.compid,
        }
    }
}
