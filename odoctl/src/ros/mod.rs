//! Exports to ROS 2 (REP-103/105): MCAP recordings of `/odom`, `/tf`, `/joint_states` and
//! `/diagnostics` as ros2msg/CDR, and the live bridge (DDS, Foxglove). The conversions and
//! their table: docs/ROS.md; every ROS name: [`names`].

pub mod bridge;
pub mod conventions;
pub mod diff_drive;
pub mod discovery;
pub mod export;
pub mod foxglove;
pub mod msgs;
pub mod names;
pub mod recording;
pub mod reset_service;
pub mod spdp_relay;
pub mod stamps;
pub mod stream;
pub mod tracks;
