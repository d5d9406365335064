//! The independent watchdog's timing (IWDG, RM0368 sec. 17): the prescaler and reload value
//! for a timeout, and the timeout they give over the LSI's frequency range. The board
//! programs them (`src/board/real/mod.rs`).
//!
//! The IWDG counts a 12-bit down-counter at the LSI's frequency divided by 4 << `PR`
//! (4..256) and resets the MCU at 0; a feed reloads the counter with `RLR`. So a setting
//! times out after (`RLR` + 1) x divider / f_LSI.

/// Nominal LSI frequency, Hz.
pub const LSI_NOMINAL_HZ: u32 = 32_000;
/// Lowest LSI frequency (datasheet DS10086, LSI oscillator characteristics), Hz.
pub const LSI_MIN_HZ: u32 = 17_000;
/// Highest LSI frequency (DS10086), Hz.
pub const LSI_MAX_HZ: u32 = 47_000;

/// Largest reload value (`RLR` has 12 bits); also the counter's value after reset.
pub const MAX_RELOAD: u16 = 0xFFF;
/// Largest prescaler code (`PR` = 6 divides by 256).
pub const MAX_PRESCALER: u8 = 6;

/// An IWDG setting: the prescaler code (`IWDG_PR`) and the reload value (`IWDG_RLR`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IwdgSetting {
    /// `PR`, 0..=[`MAX_PRESCALER`]: the LSI is divided by 4 << `prescaler`.
    pub prescaler: u8,
    /// `RLR`, 0..=[`MAX_RELOAD`]: the counter's value after a feed.
    pub reload: u16,
}

impl IwdgSetting {
    /// The finest setting (smallest prescaler) whose timeout at `lsi_hz` is `timeout_ms`,
    /// rounded down to whole counter steps; `None` when `timeout_ms` is zero, shorter than
    /// one step at /4, or longer than the longest setting (4096 x 256 / `lsi_hz`).
    pub const fn for_timeout(timeout_ms: u32, lsi_hz: u32) -> Option<Self> {
        let lsi_ticks = timeout_ms as u64 * lsi_hz as u64 / 1000;
        let mut prescaler = 0;
        while prescaler <= MAX_PRESCALER {
            let steps = lsi_ticks / (4u64 << prescaler);
            if steps == 0 {
                return None;
            }
            if steps <= MAX_RELOAD as u64 + 1 {
                return Some(Self {
                    prescaler,
                    reload: (steps - 1) as u16,
                });
            }
            prescaler += 1;
        }
        None
    }

    /// The LSI divider, 4..=256.
    pub const fn divider(&self) -> u32 {
        4 << self.prescaler
    }

    /// Time from a feed to the reset with the LSI at `lsi_hz`, microseconds (rounded down).
    pub const fn timeout_us(&self, lsi_hz: u32) -> u32 {
        ((self.reload as u64 + 1) * self.divider() as u64 * 1_000_000 / lsi_hz as u64) as u32
    }
}
