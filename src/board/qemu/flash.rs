//! The settings sectors kept in RAM (4 KiB each): QEMU's flash is read-only.

use crate::board::flash::{check, FlashError};
use odo_unit::settings::store::Flash;

/// Bytes per emulated sector.
pub const SECTOR_SIZE: usize = 4096;

/// The RAM of the two sectors, in `.bss`: held by reference, so the settings store and the
/// command task's state that owns it stay small when start-up moves them.
static mut SECTORS: [[u8; SECTOR_SIZE]; 2] = [[0; SECTOR_SIZE]; 2];

/// Two flash sectors emulated in RAM (erased = 0xFF, programming clears bits).
pub struct SettingsFlash {
    mem: &'static mut [[u8; SECTOR_SIZE]; 2],
}

impl SettingsFlash {
    /// Longest CPU stall of an erase, milliseconds: none, the sectors are RAM.
    pub fn max_stall_ms(&self) -> u32 {
        0
    }

    /// Two erased sectors.
    pub fn new(_flash: stm32f4xx_hal::pac::FLASH) -> Self {
        // Note(unsafe): FLASH is a singleton peripheral moved in here, so this runs once and
        // this is the only reference to SECTORS.
        let mem = unsafe { &mut *core::ptr::addr_of_mut!(SECTORS) };
        for sector in mem.iter_mut() {
            sector.fill(0xFF);
        }
        Self { mem }
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
