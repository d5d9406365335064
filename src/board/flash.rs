//! The settings flash: sectors 1 and 2 of the STM32F401RE (0x0800_4000 and 0x0800_8000,
//! 16 KiB each, a hole in the program's FLASH region that `memory.x` keeps empty and checks
//! at link time), behind the settings store's `Flash` trait.
//!
//! Parallelism: x32 (PSIZE = 10) needs VDD >= 2.7 V, which only the brown-out reset at level
//! 3 guarantees (option bytes, BOR_LEV = 00); x16 needs 2.1 V, which levels 1 and 2
//! guarantee; x8 is valid down to 1.8 V (BOR off, the factory setting). The driver reads
//! BOR_LEV at each operation and programs and erases with the widest parallelism it allows:
//! never out of spec. A 16 KiB sector erase takes 250/500 ms (typical/max) at x32, 300/600 ms
//! at x16, 400/800 ms at x8 (datasheet DS10086, table "Flash memory programming"):
//! [`MAX_ERASE_MS`].
//!
//! The F401 has one flash bank, so the CPU stalls on every flash read (instructions, the
//! vector table) while an erase or a program operation runs: no interrupt is served until
//! it ends. The hardware keeps counting meanwhile (encoders, the free-running sample timer,
//! the PPS capture) and the sampler merges the samples an erase passed over
//! (`src/board/sampler.rs`). The store erases only when a sector is full (one save in 64);
//! the watchdog is fed just before the erase, and its shortest timeout (LSI at 47 kHz,
//! 2,723 ms) is 3.4 times [`MAX_ERASE_MS`] ([`super::WATCHDOG_MIN_MS`]). Every save also
//! programs its record ([`odo_unit::settings::store::RECORD_LEN`], 176 bytes): one program
//! operation per byte at x8, per half-word at x16, per word at x32, each stalling the CPU
//! for 16 us typical and 100 us at most, with interrupts served between them
//! (docs/HARDWARE.md, Flash and watchdog). The data cache is reset after every erase and
//! program so reads see the new contents.
//!
//! The board's driver is `real/flash.rs`; the `qemu` build keeps the two sectors in RAM
//! (`qemu/flash.rs`, 4 KiB each): QEMU's flash is read-only.

/// Why a flash operation failed.
#[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
#[cfg_attr(feature = "qemu", allow(dead_code))]
pub enum FlashError {
    /// Sector, offset or length outside the settings sectors, or misaligned.
    Range,
    /// The flash controller did not unlock.
    Locked,
    /// Error flags of FLASH_SR after the operation (WRPERR, PGAERR, PGPERR, PGSERR, OPERR).
    Status(u32),
}

/// The text of `#[derive(Debug)]` (it ends up in the `save failed` reply), written by hand:
/// the derived form pulls in core's `{:#?}` machinery (debug builders, `PadAdapter`).
impl core::fmt::Debug for FlashError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Range => f.write_str("Range"),
            Self::Locked => f.write_str("Locked"),
            Self::Status(flags) => {
                write!(f, "Status({})", odo_unit::decimal::Dec(u64::from(*flags)))
            }
        }
    }
}

/// Longest CPU stall of one settings-sector erase, milliseconds: 16 KiB at x8 parallelism
/// (the slowest the driver may use; x16 is 600 ms, x32 500 ms).
pub const MAX_ERASE_MS: u32 = 800;

pub use super::variant::flash::SettingsFlash;

impl odo_unit::unit::StallingFlash for SettingsFlash {
    fn max_stall_ms(&self) -> u32 {
        SettingsFlash::max_stall_ms(self)
    }
}

/// Checks that `len` bytes at `offset` of settings sector `sector` lie inside a sector of
/// `size` bytes.
pub(super) fn check(
    sector: usize,
    offset: usize,
    len: usize,
    size: usize,
) -> Result<(), FlashError> {
    if sector > 1 || offset.checked_add(len).is_none_or(|end| end > size) {
        return Err(FlashError::Range);
    }
    Ok(())
}
