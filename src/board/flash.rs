//! The settings flash: sectors 6 and 7 of the STM32F401RE (0x0804_0000 and 0x0806_0000,
//! 128 KiB each, outside the program's FLASH region in `memory.x`), behind the settings
//! store's [`Flash`] trait.
//!
//! Erase and program use 32-bit parallelism (PSIZE = x32, supply 2.7-3.6 V): a 128 KiB
//! sector erase takes 1-2 s (datasheet t_ERASE128KB, max 2 s). The F401 has one flash bank,
//! so the CPU stalls on every flash read (instructions, vector table) while an erase runs:
//! no interrupt is served for up to 2 s. The store erases only when a sector is full (one
//! save in 512), the watchdog ([`super::WATCHDOG_MS`]) outlasts it, and the counters keep
//! counting in hardware; see `docs/HARDWARE.md` for what a stall does to sampling. The data
//! cache is reset after every erase and program so reads see the new contents.
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

#[cfg(not(feature = "qemu"))]
pub use board::SettingsFlash;
#[cfg(feature = "qemu")]
pub use ram::SettingsFlash;

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
    pub const SECTOR_SIZE: usize = 128 * 1024;
    /// Addresses of the two settings sectors (flash sectors 6 and 7).
    const BASE: [usize; 2] = [0x0804_0000, 0x0806_0000];
    /// Flash sector numbers.
    const SNB: [u32; 2] = [6, 7];

    const KEY1: u32 = 0x4567_0123;
    const KEY2: u32 = 0xCDEF_89AB;
    const SR_BSY: u32 = 1 << 16;
    /// OPERR | WRPERR | PGAERR | PGPERR | PGSERR.
    const SR_ERRORS: u32 = 1 << 1 | 0b1111 << 4;
    const CR_PG: u32 = 1 << 0;
    const CR_SER: u32 = 1 << 1;
    const CR_PSIZE_X32: u32 = 0b10 << 8;
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
            self.unlocked(|f| {
                let cr = CR_PSIZE_X32 | CR_SER | SNB[sector] << 3;
                // Note(unsafe): CR = PSIZE x32 | SER | SNB, then STRT (RM0368 sec. 3.5.3).
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
            self.unlocked(|f| {
                // Note(unsafe): CR = PSIZE x32 | PG (RM0368 sec. 3.5.4).
                unsafe { f.flash.cr().write(|w| w.bits(CR_PSIZE_X32 | CR_PG)) };
                for (i, word) in data.chunks_exact(4).enumerate() {
                    let value = u32::from_le_bytes([word[0], word[1], word[2], word[3]]);
                    let addr = (BASE[sector] + offset + 4 * i) as *mut u32;
                    // Note(unsafe): an aligned word inside settings sector `sector` (checked
                    // above), which memory.x keeps out of the program; PG is set.
                    unsafe { core::ptr::write_volatile(addr, value) };
                    f.wait()?;
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
