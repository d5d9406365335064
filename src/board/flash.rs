//! The settings flash: sectors 1 and 2 of the STM32F401RE (0x0800_4000 and 0x0800_8000,
//! 16 KiB each, a hole in the program's FLASH region that `memory.x` keeps empty and checks
//! at link time), behind the settings store's [`Flash`] trait.
//!
//! Parallelism: x32 (PSIZE = 10) needs VDD >= 2.7 V, which only the brown-out reset at level
//! 3 guarantees (option bytes, BOR_LEV = 00). The driver reads BOR_LEV at each operation and
//! falls back to x8, valid down to 1.8 V, on any lower level: slower, never out of spec.
//! A 16 KiB sector erase takes 250 ms typical, 500 ms max at x32 (400 / 800 ms at x8;
//! datasheet DS9716, table "Flash memory programming"): [`MAX_ERASE_MS`].
//!
//! The F401 has one flash bank, so the CPU stalls on every flash read (instructions, the
//! vector table) while an erase runs: no interrupt is served until it ends. The hardware
//! keeps counting meanwhile (encoders, the free-running sample timer, the PPS capture) and
//! the sampler merges the samples the stall passed over (`src/board/sampler.rs`). The store
//! erases only when a sector is full (one save in 64); the watchdog is fed just before the
//! erase, and its shortest timeout (LSI at 47 kHz) outlasts [`MAX_ERASE_MS`] by 5x
//! ([`super::WATCHDOG_MS`]). The data cache is reset after every erase and program so reads
//! see the new contents.
//!
//! The `qemu` build keeps the two sectors in RAM (4 KiB each): QEMU's flash is read-only.

use odo_core::settings::store::Flash;

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
            Self::Status(flags) => write!(f, "Status({flags})"),
        }
    }
}

/// Longest CPU stall of one settings-sector erase, milliseconds: 16 KiB at x8 parallelism
/// (the slower of the two the driver may use; x32 is 500 ms).
pub const MAX_ERASE_MS: u32 = 800;

#[cfg(not(feature = "qemu"))]
pub use board::SettingsFlash;
#[cfg(feature = "qemu")]
pub use ram::SettingsFlash;

impl odo_core::unit::StallingFlash for SettingsFlash {
    fn max_stall_ms(&self) -> u32 {
        SettingsFlash::max_stall_ms(self)
    }
}

fn check(sector: usize, offset: usize, len: usize, size: usize) -> Result<(), FlashError> {
    if sector > 1 || offset.checked_add(len).is_none_or(|end| end > size) {
        return Err(FlashError::Range);
    }
    Ok(())
}

#[cfg(not(feature = "qemu"))]
mod board {
    use super::{check, Flash, FlashError};
    use stm32f4xx_hal::pac;

    /// Bytes per settings sector.
    pub const SECTOR_SIZE: usize = 16 * 1024;
    /// Addresses of the two settings sectors (flash sectors 1 and 2; `_settings_start` and
    /// `_settings_end` in memory.x).
    const BASE: [usize; 2] = [0x0800_4000, 0x0800_8000];
    /// Flash sector numbers.
    const SNB: [u32; 2] = [1, 2];

    /// Longest 16 KiB sector erase at x32 parallelism, milliseconds.
    const MAX_ERASE_X32_MS: u32 = 500;

    const KEY1: u32 = 0x4567_0123;
    const KEY2: u32 = 0xCDEF_89AB;
    const SR_BSY: u32 = 1 << 16;
    /// OPERR | WRPERR | PGAERR | PGPERR | PGSERR.
    const SR_ERRORS: u32 = 1 << 1 | 0b1111 << 4;
    const CR_PG: u32 = 1 << 0;
    const CR_SER: u32 = 1 << 1;
    const CR_PSIZE_X8: u32 = 0b00 << 8;
    const CR_PSIZE_X32: u32 = 0b10 << 8;
    /// FLASH_OPTCR BOR_LEV (bits 3:2): 00 is level 3, VDD 2.70-3.60 V.
    const OPTCR_BOR_LEV: u32 = 0b11 << 2;
    const CR_STRT: u32 = 1 << 16;
    const CR_LOCK: u32 = 1 << 31;
    const ACR_DCEN: u32 = 1 << 10;
    const ACR_DCRST: u32 = 1 << 12;

    /// The two settings sectors in the MCU's flash.
    pub struct SettingsFlash {
        flash: pac::FLASH,
    }

    impl SettingsFlash {
        /// Takes the flash controller.
        pub fn new(flash: pac::FLASH) -> Self {
            Self { flash }
        }

        /// True when the brown-out reset guarantees the 2.7 V that x32 parallelism needs.
        fn x32_allowed(&self) -> bool {
            self.flash.optcr().read().bits() & OPTCR_BOR_LEV == 0
        }

        /// Longest CPU stall of one sector erase with the parallelism the BOR level allows,
        /// milliseconds: 500 at x32, [`super::MAX_ERASE_MS`] (800) at x8.
        pub fn max_stall_ms(&self) -> u32 {
            if self.x32_allowed() {
                MAX_ERASE_X32_MS
            } else {
                super::MAX_ERASE_MS
            }
        }

        fn wait(&self) -> Result<(), FlashError> {
            while self.flash.sr().read().bits() & SR_BSY != 0 {}
            let sr = self.flash.sr().read().bits();
            if sr & SR_ERRORS != 0 {
                return Err(FlashError::Status(sr & SR_ERRORS));
            }
            Ok(())
        }

        /// Unlocks, runs `f`, locks again and resets the data cache, whatever `f` returned.
        fn unlocked(
            &mut self,
            f: impl FnOnce(&Self) -> Result<(), FlashError>,
        ) -> Result<(), FlashError> {
            while self.flash.sr().read().bits() & SR_BSY != 0 {}
            if self.flash.cr().read().bits() & CR_LOCK != 0 {
                self.flash.keyr().write(|w| w.set(KEY1));
                self.flash.keyr().write(|w| w.set(KEY2));
            }
            if self.flash.cr().read().bits() & CR_LOCK != 0 {
                return Err(FlashError::Locked);
            }
            // Note(unsafe): SR error flags are rc_w1: writing them clears stale errors.
            unsafe { self.flash.sr().write(|w| w.bits(SR_ERRORS | 1)) };
            let result = f(self);
            // Note(unsafe): CR = LOCK (clears PG/SER), then a data cache reset (RM0368
            // sec. 3.4.2: DCRST only while DCEN is off).
            unsafe {
                self.flash.cr().write(|w| w.bits(CR_LOCK));
                let acr = self.flash.acr().read().bits();
                self.flash.acr().write(|w| w.bits(acr & !ACR_DCEN));
                self.flash
                    .acr()
                    .write(|w| w.bits((acr & !ACR_DCEN) | ACR_DCRST));
                self.flash.acr().write(|w| w.bits(acr & !ACR_DCRST));
            }
            result
        }
    }

    impl Flash for SettingsFlash {
        type Error = FlashError;

        fn sector_size(&self) -> usize {
            SECTOR_SIZE
        }

        fn erase(&mut self, sector: usize) -> Result<(), FlashError> {
            check(sector, 0, 0, SECTOR_SIZE)?;
            let psize = if self.x32_allowed() {
                CR_PSIZE_X32
            } else {
                CR_PSIZE_X8
            };
            self.unlocked(|f| {
                let cr = psize | CR_SER | SNB[sector] << 3;
                // The CPU stalls from STRT to the end of the erase: give the watchdog its
                // whole period for it.
                super::super::watchdog_feed();
                // Note(unsafe): CR = PSIZE | SER | SNB, then STRT (RM0368 sec. 3.5.3).
                unsafe {
                    f.flash.cr().write(|w| w.bits(cr));
                    f.flash.cr().write(|w| w.bits(cr | CR_STRT));
                }
                f.wait()
            })
        }

        fn program(&mut self, sector: usize, offset: usize, data: &[u8]) -> Result<(), FlashError> {
            check(sector, offset, data.len(), SECTOR_SIZE)?;
            if offset % 4 != 0 || data.len() % 4 != 0 {
                return Err(FlashError::Range);
            }
            let x32 = self.x32_allowed();
            self.unlocked(|f| {
                let psize = if x32 { CR_PSIZE_X32 } else { CR_PSIZE_X8 };
                // Note(unsafe): CR = PSIZE | PG (RM0368 sec. 3.5.4).
                unsafe { f.flash.cr().write(|w| w.bits(psize | CR_PG)) };
                let base = BASE[sector] + offset;
                if x32 {
                    for (i, word) in data.chunks_exact(4).enumerate() {
                        let value = u32::from_le_bytes([word[0], word[1], word[2], word[3]]);
                        let addr = (base + 4 * i) as *mut u32;
                        // Note(unsafe): an aligned word inside settings sector `sector`
                        // (checked above), which memory.x keeps out of the program; PG is set.
                        unsafe { core::ptr::write_volatile(addr, value) };
                        f.wait()?;
                    }
                } else {
                    for (i, byte) in data.iter().enumerate() {
                        let addr = (base + i) as *mut u8;
                        // Note(unsafe): a byte inside settings sector `sector` (checked
                        // above), which memory.x keeps out of the program; PG is set, x8.
                        unsafe { core::ptr::write_volatile(addr, *byte) };
                        f.wait()?;
                    }
                }
                Ok(())
            })
        }

        fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), FlashError> {
            check(sector, offset, buf.len(), SECTOR_SIZE)?;
            for (i, b) in buf.iter_mut().enumerate() {
                let addr = (BASE[sector] + offset + i) as *const u8;
                // Note(unsafe): a byte inside settings sector `sector` (checked above): flash
                // is always readable.
                *b = unsafe { core::ptr::read_volatile(addr) };
            }
            Ok(())
        }
    }
}

#[cfg(feature = "qemu")]
mod ram {
    use super::{check, Flash, FlashError};

    /// Bytes per emulated sector.
    pub const SECTOR_SIZE: usize = 4096;

    /// Two flash sectors emulated in RAM (erased = 0xFF, programming clears bits).
    pub struct SettingsFlash {
        mem: [[u8; SECTOR_SIZE]; 2],
    }

    impl SettingsFlash {
        /// Longest CPU stall of an erase, milliseconds: none, the sectors are RAM.
        pub fn max_stall_ms(&self) -> u32 {
            0
        }

        /// Two erased sectors.
        pub const fn new() -> Self {
            Self {
                mem: [[0xFF; SECTOR_SIZE]; 2],
            }
        }
    }

    impl Flash for SettingsFlash {
        type Error = FlashError;

        fn sector_size(&self) -> usize {
            SECTOR_SIZE
        }

        fn erase(&mut self, sector: usize) -> Result<(), FlashError> {
            check(sector, 0, 0, SECTOR_SIZE)?;
            self.mem[sector] = [0xFF; SECTOR_SIZE];
            Ok(())
        }

        fn program(&mut self, sector: usize, offset: usize, data: &[u8]) -> Result<(), FlashError> {
            check(sector, offset, data.len(), SECTOR_SIZE)?;
            for (m, d) in self.mem[sector][offset..offset + data.len()]
                .iter_mut()
                .zip(data)
            {
                *m &= *d;
            }
            Ok(())
        }

        fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), FlashError> {
            check(sector, offset, buf.len(), SECTOR_SIZE)?;
            buf.copy_from_slice(&self.mem[sector][offset..offset + buf.len()]);
            Ok(())
        }
    }
}
