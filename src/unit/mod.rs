//! The unit's behaviour, hardware-free: what the firmware's RTIC tasks do with what the
//! interrupts hand them.
//!
//! - [`sample`]: what the sample interrupt hands on ([`RawSample`]).
//! - [`processor`]: one sample to a pose record and the Status heartbeat ([`Processor`]).
//! - [`commands`]: command lines to settings changes, saves, pose resets ([`Commands`]).
//! - [`status`]: the text of the `status` command.
//! - [`rx_errors`]: a UART's receive errors ([`RxErrors`]).
//! - [`start`](mod@start): the settings and sampler configuration the unit starts with.
//! - [`event`]: what the unit logs ([`Event`]).
//! - [`forward`]: which GNSS sentences go to the host link, and the room they must leave.
//! - [`watchdog`]: the independent watchdog's prescaler, reload value and timeouts.
//!
//! `src/main.rs` holds the tasks, resources and queues around these; host tests in
//! `host-tests/unit.rs`.

pub mod commands;
pub mod event;
pub mod forward;
pub mod processor;
pub mod rx_errors;
pub mod sample;
pub mod start;
pub mod status;
pub mod watchdog;

pub use commands::{Commands, Effect, StallingFlash};
pub use event::{Event, Log};
pub use forward::{Forwarder, GnssCounters};
pub use processor::{HeartbeatInputs, Live, Processor, Requests, SampleOutcome, StoreState};
pub use rx_errors::{RxByte, RxErrors};
pub use sample::{IndexCapture, PpsLatch, RawCounts, RawSample};
pub use start::{start, Start};
pub use status::BoardReport;

use crate::settings::Settings;
use crate::timing::{ClockSource, DisciplineConfig, TimeTagPps};

/// The discipline configuration that `settings` ask for, with the PPS lock range of the
/// clock running now (`clock`), the sample timer at `timer_hz`.
pub fn discipline_config(
    settings: &Settings,
    timer_hz: u32,
    clock: ClockSource,
) -> DisciplineConfig {
    let mut cfg = DisciplineConfig::for_clock(timer_hz, clock.tolerance_ppm());
    cfg.rate_hz = settings.rate;
    cfg.mode = settings.mode;
    cfg
}

/// Which PPS edge a time message names, as `settings` say.
pub fn time_tag(settings: &Settings) -> TimeTagPps {
    settings.time_tag_pps
}
