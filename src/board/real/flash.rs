//! The two settings sectors in the MCU's flash (sectors 1 and 2), behind the settings
//! store's [`Flash`] trait; see `src/board/flash.rs` for the sectors, parallelism and stalls.

use crate::board::flash::{check, FlashError, MAX_ERASE_MS};
use odo_core::settings::store::Flash;
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
    /// milliseconds: 500 at x32, [`MAX_ERASE_MS`] (800) at x8.
    pub fn max_stall_ms(&self) -> u32 {
        if self.x32_allowed() {
            MAX_ERASE_X32_MS
        } else {
            MAX_ERASE_MS
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
            super::watchdog_feed();
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
