//! The settings tests' fixtures: an in-memory NOR flash that can lose power at any
//! erase/program step ([`SimFlash`]), distinct valid settings ([`variant`]) and a fresh
//! store's load of a flash ([`load`]).

use odo_unit::settings::store::{Flash, SettingsStore, WORD};
use odo_unit::settings::{Settings, SettingsSource};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimError {
    PowerCut,
    Dead,
}

/// Two sectors of `size` bytes. One *step* is one programmed word or one erased chunk of
/// `erase_chunk` bytes. With `cut_at = Some(n)` the n-th step (0-based) is interrupted: a
/// word is left partially programmed (a random subset of its 0 bits), an erase chunk is
/// left with random bits set; then the device is dead until `revive`.
#[derive(Debug, Clone)]
pub struct SimFlash {
    pub mem: [Vec<u8>; 2],
    erase_chunk: usize,
    cut_at: Option<u64>,
    pub steps: u64,
    pub dead: bool,
    rng: u64,
    /// Words programmed that were not erased (the store must never do that).
    pub violations: u32,
    pub erases: u32,
}

impl SimFlash {
    pub fn new(size: usize) -> Self {
        Self {
            mem: [vec![0xFF; size], vec![0xFF; size]],
            erase_chunk: 256,
            cut_at: None,
            steps: 0,
            dead: false,
            rng: 0x9E37_79B9_7F4A_7C15,
            violations: 0,
            erases: 0,
        }
    }
    pub fn arm(&mut self, cut_at: u64, seed: u64) {
        self.cut_at = Some(cut_at);
        self.steps = 0;
        self.rng = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    }
    pub fn revive(&mut self) {
        self.dead = false;
        self.cut_at = None;
    }
    fn random(&mut self) -> u32 {
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        (self.rng >> 16) as u32
    }
    /// True when this step is the one cut.
    fn step(&mut self) -> bool {
        let cut = self.cut_at == Some(self.steps);
        self.steps += 1;
        if cut {
            self.dead = true;
        }
        cut
    }
}

impl Flash for SimFlash {
    type Error = SimError;
    fn sector_size(&self) -> usize {
        self.mem[0].len()
    }
    fn erase(&mut self, sector: usize) -> Result<(), SimError> {
        if self.dead {
            return Err(SimError::Dead);
        }
        self.erases += 1;
        let size = self.sector_size();
        for start in (0..size).step_by(self.erase_chunk) {
            let end = (start + self.erase_chunk).min(size);
            if self.step() {
                for i in start..end {
                    let r = self.random() as u8;
                    self.mem[sector][i] |= r;
                }
                return Err(SimError::PowerCut);
            }
            self.mem[sector][start..end].fill(0xFF);
        }
        Ok(())
    }
    fn program(&mut self, sector: usize, offset: usize, data: &[u8]) -> Result<(), SimError> {
        if self.dead {
            return Err(SimError::Dead);
        }
        assert_eq!(offset % WORD, 0, "unaligned program");
        assert_eq!(data.len() % WORD, 0, "partial word");
        for (i, w) in data.chunks(WORD).enumerate() {
            let at = offset + i * WORD;
            let old = u32::from_le_bytes(self.mem[sector][at..at + 4].try_into().unwrap());
            let new = u32::from_le_bytes(w.try_into().unwrap());
            if old != u32::MAX {
                self.violations += 1;
            }
            if self.step() {
                let partial = old & (new | self.random());
                self.mem[sector][at..at + 4].copy_from_slice(&partial.to_le_bytes());
                return Err(SimError::PowerCut);
            }
            self.mem[sector][at..at + 4].copy_from_slice(&(old & new).to_le_bytes());
        }
        Ok(())
    }
    fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), SimError> {
        if self.dead {
            return Err(SimError::Dead);
        }
        buf.copy_from_slice(&self.mem[sector][offset..offset + buf.len()]);
        Ok(())
    }
}

/// Distinct valid settings, one per index.
pub fn variant(i: u32) -> Settings {
    let mut s = Settings::DEFAULT;
    s.chassis.track_width = 0.5 + i as f64 * 1e-3;
    s.chassis.left_wheel.cos[0] = (i % 7) as f32 * 1e-3;
    s
}

pub fn load(flash: &SimFlash) -> (Settings, SettingsSource, u32) {
    let mut store = SettingsStore::new(flash.clone());
    let l = store.load().expect("load");
    (l.settings, l.source, l.generation)
}

// `&mut SimFlash` as a Flash, so the tests can keep the flash after the store is dropped.
impl Flash for &mut SimFlash {
    type Error = SimError;
    fn sector_size(&self) -> usize {
        (**self).sector_size()
    }
    fn erase(&mut self, sector: usize) -> Result<(), SimError> {
        (**self).erase(sector)
    }
    fn program(&mut self, sector: usize, offset: usize, data: &[u8]) -> Result<(), SimError> {
        (**self).program(sector, offset, data)
    }
    fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), SimError> {
        (**self).read(sector, offset, buf)
    }
}
