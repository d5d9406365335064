//! The two settings sectors in the MCU's flash (sectors 1 and 2), behind the settings
//! store's [`Flash`] trait; see `src/board/flash.rs` for the sectors, parallelism and stalls.

use crate::board::flash::{check, FlashError, MAX_ERASE_MS};
use odo_unit::settings::store::Flash;
use stm32f4xx_hal::pac;

/// Bytes per settings sector.
pub const SECTOR_SIZE: usize = 16 * 1024;
/// Addresses of the two settings sectors (flash sectors 1 and 2; `_settings_start` and
/// `_settings_end` in memory.x).
const BASE: [usize; 2] = [0x0800_4000, 0x0800_8000];
/// Flash sector numbers.
const SNB: [u32; 2] = [1, 2];

const KEY1: u32 = 0x4567_0123;
const KEY2: u32 = 0xCDEF_89AB;
const SR_BSY: u32 = 1 << 16;
/// OPERR | WRPERR | PGAERR | PGPERR | PGSERR.
const SR_ERRORS: u32 = 1 << 1 | 0b1111 << 4;
const CR_PG: u32 = 1 << 0;
const CR_SER: u32 = 1 << 1;
/// FLASH_OPTCR BOR_LEV (bits 3:2): 00 level 3 (VDD 2.70-3.60 V), 01 level 2 (2.40-3.60 V),
/// 10 level 1 (2.10-3.60 V), 11 off (down to 1.8 V).
const OPTCR_BOR_LEV_SHIFT: u32 = 2;
const CR_STRT: u32 = 1 << 16;
const CR_LOCK: u32 = 1 << 31;
const ACR_DCEN: u32 = 1 << 10;
const ACR_DCRST: u32 = 1 << 12;

/// Program and erase parallelism (FLASH_CR PSIZE), by the supply voltage the brown-out reset
/// guarantees (RM0368 sec. 3.5.2): x32 needs 2.7-3.6 V, x16 2.1-3.6 V, x8 1.8-3.6 V. Each
/// program operation takes 16 us typical, 100 us at most, whatever its width; a 16 KiB
/// sector erase 250/500 ms (typical/max) at x32, 300/600 ms at x16, 400/800 ms at x8
/// (datasheet DS10086, flash memory programming).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Parallelism {
    X8,
    X16,
    X32,
}

impl Parallelism {
    /// The widest the option bytes' BOR level allows: level 3 x32, levels 1 and 2 x16, off x8.
    fn from_optcr(optcr: u32) -> Self {
        match optcr >> OPTCR_BOR_LEV_SHIFT & 0b11 {
            0b00 => Self::X32,
            0b01 | 0b10 => Self::X16,
            _ => Self::X8,
        }
    }

    /// FLASH_CR PSIZE (bits 9:8).
    fn psize(self) -> u32 {
        (match self {
            Self::X8 => 0b00,
            Self::X16 => 0b01,
            Self::X32 => 0b10,
        }) << 8
    }

    /// Bytes per program operation.
    fn bytes(self) -> usize {
        match self {
            Self::X8 => 1,
            Self::X16 => 2,
            Self::X32 => 4,
        }
    }

    /// Longest 16 KiB sector erase, milliseconds.
    fn max_erase_ms(self) -> u32 {
        match self {
            Self::X8 => MAX_ERASE_MS,
            Self::X16 => 600,
            Self::X32 => 500,
        }
    }
}

/// The two settings sectors in the MCU's flash.
pub struct SettingsFlash {
    flash: pac::FLASH,
}

impl SettingsFlash {
    /// Takes the flash controller.
    pub fn new(flash: pac::FLASH) -> Self {
        Self { flash }
    }

    /// The parallelism the brown-out reset level allows, read at each operation.
    fn parallelism(&self) -> Parallelism {
        Parallelism::from_optcr(self.flash.optcr().read().bits())
    }

    /// Longest CPU stall of one sector erase with the parallelism the BOR level allows,
    /// milliseconds: 500 at x32, 600 at x16, [`MAX_ERASE_MS`] (800) at x8.
    pub fn max_stall_ms(&self) -> u32 {
        self.parallelism().max_erase_ms()
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
        let psize = self.parallelism().psize();
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
        let parallelism = self.parallelism();
        self.unlocked(|f| {
            // Note(unsafe): CR = PSIZE | PG (RM0368 sec. 3.5.4).
            unsafe { f.flash.cr().write(|w| w.bits(parallelism.psize() | CR_PG)) };
            let base = BASE[sector] + offset;
            let unit = parallelism.bytes();
            for (i, chunk) in data.chunks_exact(unit).enumerate() {
                let addr = base + unit * i;
                // Note(unsafe): `unit` aligned bytes (a word, half-word or byte, as PSIZE
                // says; `offset` is word-aligned) inside settings sector `sector` (checked
                // above), which memory.x keeps out of the program; PG is set.
                unsafe {
                    match *chunk {
                        [a, b, c, d] => core::ptr::write_volatile(
                            addr as *mut u32,
                            u32::from_le_bytes([a, b, c, d]),
                        ),
                        [a, b] => {
                            core::ptr::write_volatile(addr as *mut u16, u16::from_le_bytes([a, b]))
                        }
                        [a] => core::ptr::write_volatile(addr as *mut u8, a),
                        _ => {}
                    }
                }
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
