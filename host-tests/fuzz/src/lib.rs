//! Support of the fuzz targets: a NOR flash that loses power at a chosen step.

use odo_unit::settings::store::{Flash, WORD};

/// Why a [`CutFlash`] operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CutError {
    /// Power was cut during this operation.
    PowerCut,
    /// No power since the cut (until [`CutFlash::revive`]).
    Dead,
}

/// Two sectors of NOR flash (erased = 0xFF, programming clears bits). One *step* is one
/// programmed word or one erased 256-byte chunk; with [`CutFlash::arm`] the n-th step is
/// interrupted, leaving a word partly programmed or a chunk partly erased (bits from
/// `noise`), and the flash is dead until [`CutFlash::revive`]. Programming a word that is
/// not erased is counted in `violations` (the store must never do it).
#[derive(Debug, Clone)]
pub struct CutFlash {
    /// The sectors' bytes.
    pub mem: [Vec<u8>; 2],
    cut_at: Option<u32>,
    steps: u32,
    dead: bool,
    noise: u32,
    /// Words programmed over non-erased flash.
    pub violations: u32,
}

impl CutFlash {
    /// Erased sectors of `slots` 256-byte slots each.
    pub fn new(slots: usize) -> Self {
        let size = slots * odo_unit::settings::store::SLOT_LEN;
        Self {
            mem: [vec![0xFF; size], vec![0xFF; size]],
            cut_at: None,
            steps: 0,
            dead: false,
            noise: 0,
            violations: 0,
        }
    }

    /// Cuts the power at step `at` from now; the interrupted word or chunk gets `noise`.
    pub fn arm(&mut self, at: u32, noise: u32) {
        self.cut_at = Some(at);
        self.steps = 0;
        self.noise = noise;
    }

    /// Power back (nothing is armed).
    pub fn revive(&mut self) {
        self.dead = false;
        self.cut_at = None;
    }

    fn step(&mut self) -> bool {
        let cut = self.cut_at == Some(self.steps);
        self.steps = self.steps.saturating_add(1);
        self.dead |= cut;
        cut
    }
}

impl Flash for CutFlash {
    type Error = CutError;

    fn sector_size(&self) -> usize {
        self.mem[0].len()
    }

    fn erase(&mut self, sector: usize) -> Result<(), CutError> {
        if self.dead {
            return Err(CutError::Dead);
        }
        let noise = self.noise.to_le_bytes();
        for chunk in 0..self.sector_size() / 256 {
            let bytes = &mut self.mem[sector][chunk * 256..(chunk + 1) * 256];
            if self.cut_at == Some(self.steps) {
                self.dead = true;
                for (i, b) in bytes.iter_mut().enumerate() {
                    *b |= noise[i % 4].rotate_left(i as u32 % 8);
                }
                return Err(CutError::PowerCut);
            }
            self.steps = self.steps.saturating_add(1);
            bytes.fill(0xFF);
        }
        Ok(())
    }

    fn program(&mut self, sector: usize, offset: usize, data: &[u8]) -> Result<(), CutError> {
        if self.dead {
            return Err(CutError::Dead);
        }
        assert_eq!(offset % WORD, 0, "unaligned program");
        assert_eq!(data.len() % WORD, 0, "partial word");
        for (i, w) in data.chunks(WORD).enumerate() {
            let at = offset + i * WORD;
            let cell = &mut self.mem[sector][at..at + WORD];
            let old = u32::from_le_bytes(cell.try_into().unwrap());
            let new = u32::from_le_bytes(w.try_into().unwrap());
            if old != u32::MAX {
                self.violations += 1;
            }
            let noise = self.noise;
            if self.step() {
                let partial = old & (new | noise);
                self.mem[sector][at..at + WORD].copy_from_slice(&partial.to_le_bytes());
                return Err(CutError::PowerCut);
            }
            self.mem[sector][at..at + WORD].copy_from_slice(&(old & new).to_le_bytes());
        }
        Ok(())
    }

    fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), CutError> {
        if self.dead {
            return Err(CutError::Dead);
        }
        buf.copy_from_slice(&self.mem[sector][offset..offset + buf.len()]);
        Ok(())
    }
}

// `&mut CutFlash` as a store's flash, so that the flash outlives the store.
impl Flash for &mut CutFlash {
    type Error = CutError;
    fn sector_size(&self) -> usize {
        (**self).sector_size()
    }
    fn erase(&mut self, sector: usize) -> Result<(), CutError> {
        (**self).erase(sector)
    }
    fn program(&mut self, sector: usize, offset: usize, data: &[u8]) -> Result<(), CutError> {
        (**self).program(sector, offset, data)
    }
    fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), CutError> {
        (**self).read(sector, offset, buf)
    }
}
