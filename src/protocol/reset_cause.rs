//! Why the unit last started, as the MCU's reset flags (RCC_CSR, RM0368 sec. 6.3.21) tell it;
//! reported in DeviceInfo and Status so that a host can tell a watchdog reset (a hang, or a
//! panic: the panic handler stops and the watchdog resets) from a power-up.

/// Why the unit last started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ResetCause {
    /// No flag set (QEMU models none), or not read.
    #[default]
    Unknown,
    /// Power-on / power-down reset (POR/PDR; the brown-out flag is set with it).
    PowerOn,
    /// The NRST pin (reset button, debugger), nothing else.
    Pin,
    /// Brown-out (supply below the BOR threshold) without a power-on.
    BrownOut,
    /// Software reset (SYSRESETREQ).
    Software,
    /// The independent watchdog: the firmware hung, or panicked.
    Watchdog,
    /// The window watchdog (unused by the firmware).
    WindowWatchdog,
    /// Low-power management reset (illegal Stop/Standby entry).
    LowPower,
}

/// RCC_CSR flags (RM0368 sec. 6.3.21): BORRSTF 25, PINRSTF 26, PORRSTF 27, SFTRSTF 28,
/// IWDGRSTF 29, WWDGRSTF 30, LPWRRSTF 31. RMVF (bit 24) clears them.
pub const RCC_CSR_RMVF: u32 = 1 << 24;

impl ResetCause {
    /// The cause from RCC_CSR. Every reset also drives NRST low, so PINRSTF is set with any
    /// cause and a power-on sets BORRSTF too: the most specific flag wins (watchdogs, low
    /// power, software, power-on, brown-out, then the pin).
    pub fn from_rcc_csr(csr: u32) -> Self {
        let bit = |n: u32| csr & (1 << n) != 0;
        if bit(29) {
            Self::Watchdog
        } else if bit(30) {
            Self::WindowWatchdog
        } else if bit(31) {
            Self::LowPower
        } else if bit(28) {
            Self::Software
        } else if bit(27) {
            Self::PowerOn
        } else if bit(25) {
            Self::BrownOut
        } else if bit(26) {
            Self::Pin
        } else {
            Self::Unknown
        }
    }

    /// Wire code (u8): 0 unknown, 1 power-on, 2 pin, 3 brown-out, 4 software, 5 watchdog,
    /// 6 window watchdog, 7 low power.
    pub fn code(self) -> u8 {
        self as u8
    }

    /// From the wire code; an unknown code reads as [`ResetCause::Unknown`].
    pub fn from_code(code: u8) -> Self {
        const ALL: [ResetCause; 8] = [
            ResetCause::Unknown,
            ResetCause::PowerOn,
            ResetCause::Pin,
            ResetCause::BrownOut,
            ResetCause::Software,
            ResetCause::Watchdog,
            ResetCause::WindowWatchdog,
            ResetCause::LowPower,
        ];
        ALL.get(usize::from(code)).copied().unwrap_or_default()
    }

    /// The name `status` prints.
    pub fn name(self) -> &'static str {
        match self {
            Self::Unknown => "unknown",
            Self::PowerOn => "power-on",
            Self::Pin => "pin",
            Self::BrownOut => "brown-out",
            Self::Software => "software",
            Self::Watchdog => "watchdog",
            Self::WindowWatchdog => "window-watchdog",
            Self::LowPower => "low-power",
        }
    }
}
