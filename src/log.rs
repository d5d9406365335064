//! The unit's log lines (defmt): start-up, and the events of [`odo_unit::unit::Event`].

use odo_unit::settings::store::Loaded;
use odo_unit::settings::SettingsSource;
use odo_unit::timing::{ClockSource, DisciplineConfig, SyncMode, SyncState};
use odo_unit::unit::{Event, Log, Start};

/// What start-up made of the clock (`clock`), the stored settings and the sampler
/// configuration.
pub fn start(clock: ClockSource, loaded: &Loaded, start: &Start) {
    if clock == ClockSource::HsiFallback {
        defmt::error!("HSE did not start or the PLL did not lock on it: running from the HSI");
    }
    if start.settings_replaced {
        defmt::error!("settings: rate/mode unusable by the sampler, using the defaults");
    }
    match loaded.source {
        SettingsSource::Flash => defmt::info!(
            "settings loaded from flash, generation {}",
            loaded.generation
        ),
        SettingsSource::Defaults => {
            defmt::info!("settings: defaults (flash empty or unreadable)")
        }
    }
    if start.sampler_fallback {
        defmt::error!("sampler configuration invalid: free-running at 50 Hz");
    }
}

/// The boot line: version, timer frequency, sample rate and mode.
pub fn booted(timer_hz: u32, cfg: &DisciplineConfig) {
    let mode = if cfg.mode == SyncMode::Pps {
        "pps"
    } else {
        "free"
    };
    defmt::info!(
        "odo-unit {} booted: timer {} Hz, {} Hz {}",
        env!("CARGO_PKG_VERSION"),
        timer_hz,
        cfg.rate_hz,
        mode
    );
}

fn state_name(s: SyncState) -> &'static str {
    match s {
        SyncState::FreeRunning => "free-running",
        SyncState::Locked => "pps-locked",
        SyncState::Holdover => "holdover",
    }
}

/// The defmt log: warnings for lost data and faults, info for state changes.
pub struct Defmt;

impl Log for Defmt {
    /// Inlined, so that each call site keeps only its own line.
    #[inline(always)]
    fn event(&mut self, event: Event) {
        match event {
            Event::SampleLate { latency, merged } => defmt::warn!(
                "sample interrupt late by {} ticks: {} samples merged",
                latency,
                merged
            ),
            Event::PpsOvercapture => defmt::warn!("PPS: over-capture (two edges in one interrupt)"),
            Event::IndexLost { wheel } => {
                defmt::warn!("wheel {}: index pulse lost (over-capture)", wheel)
            }
            Event::FirstIndex { wheel } => defmt::info!("wheel {}: first index pulse", wheel),
            Event::IndexMismatch { wheel, error } => defmt::warn!(
                "wheel {}: index count mismatch of {} increments",
                wheel,
                error
            ),
            Event::ParamsRejected => defmt::error!("chassis parameters rejected by the integrator"),
            Event::IntegratorRejected => {
                defmt::error!("integrator rejected the designed parameters")
            }
            Event::PoseReset => defmt::info!("pose reset"),
            Event::Overrange { sequence } => defmt::warn!(
                "sample {}: motion beyond one sample's limits, not integrated",
                sequence
            ),
            Event::PpsLocked => defmt::info!("PPS: locked"),
            Event::PpsReacquired { missed } => {
                defmt::info!("PPS: reacquired after {} lost pulses", missed)
            }
            Event::PpsGlitch => defmt::warn!("PPS: glitch rejected"),
            Event::SyncChanged { from, to } => {
                defmt::info!("sampling: {} -> {}", state_name(from), state_name(to))
            }
            Event::FaultLines { left, right } => {
                defmt::warn!("encoder fault lines: left {}, right {}", left, right)
            }
        }
    }
}
