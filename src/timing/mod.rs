//! Timing: when samples are taken and what GNSS time they carry.
//!
//! - [`pps`]: the PPS discipline and sample scheduler (locked, holdover, free-running;
//!   glitch rejection; exact integer grid).
//! - [`nmea`]: ZDA/RMC parsing with checksum, UTC to GPS week and time of week.
//! - [`tag`]: which PPS edge a time message names (`time_tag_pps`), and the GNSS second of
//!   each grid second.
//! - [`clock`]: the free-running 32-bit sample timer: counter and capture extension to 64
//!   bits, and the catch-up of the grid after a CPU stall.
//! - [`compare`]: the sample timer's interrupt: the order of its reads, the compare and
//!   re-arm decision, the PPS capture on and off.
//!
//! All of it is pure and host-tested (`host-tests/timing_*.rs`, `host-tests/compare.rs`); the
//! firmware feeds it timer captures and bytes.

pub mod clock;
pub mod compare;
pub mod nmea;
pub mod pps;
pub mod tag;

pub use clock::{catch_up, CatchUp, TimerExtender};
pub use compare::{compare_action, CompareAction, CompareSchedule, CompareTimer, TimerEvent};
pub use nmea::{GpsTime, LineBuffer, NmeaError, TimeMessage, UtcDateTime, GPS_UTC_LEAP_SECONDS};
pub use pps::{
    resolve_capture, ClockSource, ConfigError, Discipline, DisciplineConfig, PpsEvent, PpsStats,
    Sample, SyncMode, SyncState, DIRECT_LOCK_MAX_PPM, HSE_CRYSTAL_TOLERANCE_PPM, HSI_TOLERANCE_PPM,
    MAX_OFFSET_LIMIT_PPM, RATE_RANGE,
};
pub use tag::{TimeTagPps, TimeTagger};
