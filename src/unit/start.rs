//! What the unit starts with: the loaded settings and the sampler's discipline, with the
//! fallbacks when they cannot be used.

use super::discipline_config;
use crate::settings::Settings;
use crate::timing::{ClockSource, ConfigError, Discipline, DisciplineConfig, SyncMode};

/// Sample rate of the last-resort sampler configuration, Hz.
pub const FALLBACK_RATE_HZ: u32 = 50;

/// The settings and the discipline the unit starts with.
pub struct Start {
    /// The settings in use.
    pub settings: Settings,
    /// The sampler's discipline, its schedule at tick 0.
    pub discipline: Discipline,
    /// The loaded settings asked for a rate or mode the sampler cannot use: the defaults
    /// are used instead.
    pub settings_replaced: bool,
    /// The discipline rejected the configuration: free-running at [`FALLBACK_RATE_HZ`].
    pub sampler_fallback: bool,
}

/// Starts from the `loaded` settings with the sample timer at `timer_hz`: `clock_now` is the
/// clock running now, `clock_at_start` the one start-up found (they differ once the clock
/// security system switched away from a failed HSE). Fails only when even the fallback
/// configuration is rejected.
pub fn start(
    loaded: Settings,
    timer_hz: u32,
    clock_now: ClockSource,
    clock_at_start: ClockSource,
) -> Result<Start, ConfigError> {
    let mut settings = loaded;
    let mut cfg = discipline_config(&settings, timer_hz, clock_now);
    let settings_replaced = cfg.validate().is_err();
    if settings_replaced {
        settings = Settings::DEFAULT;
        cfg = discipline_config(&settings, timer_hz, clock_now);
    }
    let (discipline, sampler_fallback) = match Discipline::new(cfg, 0) {
        Ok(d) => (d, false),
        Err(_) => {
            let mut c = DisciplineConfig::for_clock(timer_hz, clock_at_start.tolerance_ppm());
            c.mode = SyncMode::Free;
            c.rate_hz = FALLBACK_RATE_HZ;
            (Discipline::new(c, 0)?, true)
        }
    };
    Ok(Start {
        settings,
        discipline,
        settings_replaced,
        sampler_fallback,
    })
}
