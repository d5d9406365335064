//! Power-cut-safe settings store on two flash sectors used alternately.
//!
//! Each sector is a log of fixed [`SLOT_LEN`]-byte slots. A save appends one record to the
//! sector that holds the newest usable record; when that sector is full, the *other* sector
//! is erased and the record goes to its first slot. A record carries a generation number
//! (+1 per save, wrapping from 0xFFFF_FFFF to 1) and a CRC-32; loading takes the usable
//! record with the newest generation in serial-number order ([`generation_is_newer`]),
//! which holds when the generations of the records with a valid CRC lie within 2^31 of each
//! other, as this store's always do. Flash of another origin whose generations do not
//! (foreign or damaged records) loads the highest generation, and the next save clears both
//! sectors around its record, so that a save that returns `Ok` always loads back.
//! The sector holding the newest usable record is never erased and a record is never
//! overwritten, so a power cut at any moment of a save (during the erase, or after any
//! programmed word) leaves the previous settings loadable; the new ones are loadable once
//! the record's last word is programmed.
//!
//! Record layout (little-endian, [`RECORD_LEN`] bytes at the start of a slot; the rest of
//! the slot stays erased):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `0x534F444F` (bytes `4F 44 4F 53`, "ODOS") |
//! | 4 | 2 | settings format version ([`super::SETTINGS_FORMAT_VERSION`], 6) |
//! | 6 | 2 | payload length `n` ([`Settings::SERIALIZED_LEN`], 160) |
//! | 8 | 4 | generation, 1 for the first save |
//! | 12 | n | payload ([`Settings::to_bytes`]) |
//! | 12 + n | 4 | CRC-32/ISO-HDLC of bytes 0..12 + n |
//!
//! Saves write format version 6 ([`RECORD_LEN`] = 176 bytes). Loading also accepts the
//! records of format version 5 (payload 156 bytes, 172 bytes in all), written before
//! `gnss_baud` existed, of format version 4 (payload 148 bytes, 164 bytes in all), written before the
//! MAVLink keys existed, of format version 3 (payload 144 bytes, 160 bytes in all), written before
//! `kappa_diff_corr` existed, of format version 2 (payload 116 bytes, 132 bytes), written
//! before the geometry's standard errors existed, and of format version 1 (payload 112 bytes,
//! 128 bytes), written before `max_wheel_speed` existed: keys newer than a record load at
//! their defaults. The version and length must be one of these six pairs, else the record
//! is skipped.

use super::{Settings, SETTINGS_FORMAT_VERSION};
use crate::bytes::Reader;
use crate::crc::crc32;

/// Record magic ("ODOS" in memory order).
pub const MAGIC: u32 = 0x534F_444F;
/// Bytes programmed per save (a record of format version [`SETTINGS_FORMAT_VERSION`]).
pub const RECORD_LEN: usize = CRC_AT + 4;
/// Bytes reserved per record in a sector (room for a larger future layout).
pub const SLOT_LEN: usize = 256;
/// Bytes per flash program unit: offsets and lengths passed to [`Flash::program`] are
/// multiples of this.
pub const WORD: usize = 4;

const CRC_AT: usize = 12 + Settings::SERIALIZED_LEN;

/// The (format version, payload length) pairs a record may carry, bytes.
const FORMATS: [(u16, usize); 6] = [
    (1, Settings::SERIALIZED_LEN_V1),
    (2, Settings::SERIALIZED_LEN_V2),
    (3, Settings::SERIALIZED_LEN_V3),
    (4, Settings::SERIALIZED_LEN_V4),
    (5, Settings::SERIALIZED_LEN_V5),
    (SETTINGS_FORMAT_VERSION, Settings::SERIALIZED_LEN),
];

/// The two settings sectors as the store sees them. Erased flash reads 0xFF; programming
/// can only clear bits.
///
/// On the STM32F401RE, sector index 0 is flash sector 1 (0x0800_4000) and index 1 is
/// sector 2 (0x0800_8000), 16 KiB each (`memory.x`).
pub trait Flash {
    /// The driver's error.
    type Error: core::fmt::Debug;
    /// Bytes per sector (both sectors have this size; a multiple of [`SLOT_LEN`]).
    fn sector_size(&self) -> usize;
    /// Erases sector `sector` (0 or 1) to all 0xFF.
    fn erase(&mut self, sector: usize) -> Result<(), Self::Error>;
    /// Programs `data` at byte `offset` of `sector`, in ascending address order; `offset`
    /// and `data.len()` are multiples of [`WORD`] and the range was erased.
    fn program(&mut self, sector: usize, offset: usize, data: &[u8]) -> Result<(), Self::Error>;
    /// Reads `buf.len()` bytes at `offset` of `sector`.
    fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), Self::Error>;
}

/// Why a load or save failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoreError<E> {
    /// The flash driver failed.
    Flash(E),
    /// The record read back differs from the one written (worn or faulty flash).
    Verify,
    /// The settings do not validate; nothing was written.
    Invalid,
    /// The sector size is not a non-zero multiple of [`SLOT_LEN`].
    Geometry,
}

impl<E: core::fmt::Debug> core::fmt::Display for StoreError<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Flash(e) => write!(f, "flash error {e:?}"),
            Self::Verify => f.write_str("flash verify failed"),
            Self::Invalid => f.write_str("settings invalid, not saved"),
            Self::Geometry => f.write_str("bad flash geometry"),
        }
    }
}

/// Where the settings in use came from (sent in `Status` and `DeviceInfo`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SettingsSource {
    /// No valid settings record in flash: the built-in defaults (code 0).
    #[default]
    Defaults,
    /// Loaded from the flash settings store (code 1).
    Flash,
}

/// What [`SettingsStore::load`] found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Loaded {
    /// The settings to use.
    pub settings: Settings,
    /// `Flash` when they came from a stored record, `Defaults` otherwise.
    pub source: SettingsSource,
    /// Generation of the record used (0 for defaults).
    pub generation: u32,
}

/// Half the generation circle, 2^31.
const HALF: u32 = 1 << 31;

/// How generations compare: as numbers, or rotated by 2^31 (so that a run across the wrap
/// from 0xFFFF_FFFF to 1 is in order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Order {
    Plain,
    Rotated,
}

impl Order {
    /// The key that orders `generation`.
    const fn key(self, generation: u32) -> u32 {
        match self {
            Self::Plain => generation,
            Self::Rotated => generation ^ HALF,
        }
    }
}

/// The generations of the records with a valid CRC: their least and largest key in each
/// [`Order`].
#[derive(Debug, Clone, Copy)]
struct Span {
    plain: (u32, u32),
    rotated: (u32, u32),
}

impl Span {
    fn new(generation: u32) -> Self {
        let r = Order::Rotated.key(generation);
        Self {
            plain: (generation, generation),
            rotated: (r, r),
        }
    }

    fn add(&mut self, generation: u32) {
        let r = Order::Rotated.key(generation);
        self.plain = (self.plain.0.min(generation), self.plain.1.max(generation));
        self.rotated = (self.rotated.0.min(r), self.rotated.1.max(r));
    }

    /// The order in which every generation lies within 2^31 - 1 behind the newest, the
    /// serial-number order of [`generation_is_newer`]; `None` when no half of the circle
    /// holds them all (records not written by this store).
    fn order(&self) -> Option<Order> {
        if self.plain.1 - self.plain.0 < HALF {
            Some(Order::Plain)
        } else if self.rotated.1 - self.rotated.0 < HALF {
            Some(Order::Rotated)
        } else {
            None
        }
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct Scan {
    /// Generations of the records with a valid CRC (usable or not).
    span: Option<Span>,
    /// Newest usable record in each [`Order`] (plain, rotated): (generation, sector,
    /// settings); the first found of equal generations.
    best: [Option<(u32, usize, Settings)>; 2],
    /// Per sector: first slot after the last non-erased slot, if inside the sector.
    next_free: [Option<usize>; 2],
}

impl Scan {
    fn add(&mut self, generation: u32, sector: usize, settings: Option<Settings>) {
        match &mut self.span {
            Some(span) => span.add(generation),
            None => self.span = Some(Span::new(generation)),
        }
        let Some(settings) = settings else {
            return;
        };
        for (best, order) in self.best.iter_mut().zip([Order::Plain, Order::Rotated]) {
            if best.is_none_or(|(g, _, _)| order.key(generation) > order.key(g)) {
                *best = Some((generation, sector, settings));
            }
        }
    }

    /// The order the records follow; plain (the highest generation) when they follow none.
    fn order(&self) -> Order {
        self.span.and_then(|s| s.order()).unwrap_or(Order::Plain)
    }

    /// The newest usable record: (generation, sector, settings).
    fn best(&self) -> Option<(u32, usize, Settings)> {
        self.best[self.order() as usize]
    }

    /// The generation of the next record, and whether it is newer than every record with a
    /// valid CRC. If not (records of another origin), the save clears both sectors for it
    /// to load, and it follows the generation loaded now.
    fn next_generation(&self) -> (u32, bool) {
        // 0 is never written (it stands for the defaults): 0xFFFF_FFFF is followed by 1.
        let after = |g: u32| g.wrapping_add(1).max(1);
        let Some(span) = self.span else {
            return (1, true);
        };
        if let Some(order) = span.order() {
            let (oldest, newest) = match order {
                Order::Plain => span.plain,
                Order::Rotated => (span.rotated.0 ^ HALF, span.rotated.1 ^ HALF),
            };
            let generation = after(newest);
            if generation_is_newer(generation, oldest) {
                return (generation, true);
            }
        }
        (after(self.best().map_or(0, |b| b.0)), false)
    }
}

/// The settings store over a [`Flash`].
#[derive(Debug)]
pub struct SettingsStore<F> {
    flash: F,
}

impl<F: Flash> SettingsStore<F> {
    /// A store over `flash` (nothing is read until [`Self::load`]).
    pub fn new(flash: F) -> Self {
        Self { flash }
    }

    /// The flash driver.
    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// The flash driver, mutably.
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the flash driver back.
    pub fn into_inner(self) -> F {
        self.flash
    }

    fn slots(&self) -> Result<usize, StoreError<F::Error>> {
        let size = self.flash.sector_size();
        if size == 0 || size % SLOT_LEN != 0 {
            return Err(StoreError::Geometry);
        }
        Ok(size / SLOT_LEN)
    }

    fn scan(&mut self) -> Result<Scan, StoreError<F::Error>> {
        let slots = self.slots()?;
        let mut scan = Scan::default();
        let mut buf = [0u8; SLOT_LEN];
        for sector in 0..2 {
            let mut used_end = 0;
            for slot in 0..slots {
                self.flash
                    .read(sector, slot * SLOT_LEN, &mut buf)
                    .map_err(StoreError::Flash)?;
                if buf.iter().all(|&b| b == 0xFF) {
                    continue;
                }
                used_end = slot + 1;
                if let Some((generation, settings)) = parse_record(&buf) {
                    scan.add(generation, sector, settings);
                }
            }
            scan.next_free[sector] = (used_end < slots).then_some(used_end);
        }
        Ok(scan)
    }

    /// Loads the newest usable settings record; without one, the defaults with source
    /// [`SettingsSource::Defaults`]. Fails only when the flash cannot be read.
    pub fn load(&mut self) -> Result<Loaded, StoreError<F::Error>> {
        let scan = self.scan()?;
        Ok(match scan.best() {
            Some((generation, _, settings)) => Loaded {
                settings,
                source: SettingsSource::Flash,
                generation,
            },
            None => Loaded {
                settings: Settings::DEFAULT,
                source: SettingsSource::Defaults,
                generation: 0,
            },
        })
    }

    /// [`Self::load`], falling back to the defaults if the flash cannot be read.
    pub fn load_or_defaults(&mut self) -> Loaded {
        self.load().unwrap_or(Loaded {
            settings: Settings::DEFAULT,
            source: SettingsSource::Defaults,
            generation: 0,
        })
    }

    /// Whether the next [`Self::save`] must erase a sector (the sector holding the newest
    /// usable record is full: every 64th save on the real geometry; or records of another
    /// origin must be cleared). On the STM32F401 an erase stalls the CPU, and the sampling,
    /// for up to 0.8 s; compare that with [`Settings::max_unread_interval`] before saving
    /// while the wheels may turn. Reads the flash, changes nothing.
    pub fn next_save_erases(&mut self) -> Result<bool, StoreError<F::Error>> {
        let scan = self.scan()?;
        let target = scan.best().map_or(0, |(_, sector, _)| sector);
        Ok(!scan.next_generation().1 || scan.next_free[target].is_none())
    }

    /// Saves `settings` (validated first); returns the new record's generation, which the
    /// next [`Self::load`] returns with these settings. One record program and at most one
    /// sector erase, safe against a power cut at any point, on flash this store wrote. On
    /// flash holding records whose generations lie more than 2^31 apart (of another origin
    /// or damaged: no order makes a new record the newest) it erases the other sector,
    /// writes the record there and then erases the sector it came from.
    pub fn save(&mut self, settings: &Settings) -> Result<u32, StoreError<F::Error>> {
        settings.validate().map_err(|_| StoreError::Invalid)?;
        let scan = self.scan()?;
        let (generation, newest) = scan.next_generation();
        let target = scan.best().map_or(0, |(_, sector, _)| sector);
        let (sector, slot) = match scan.next_free[target] {
            Some(slot) if newest => (target, slot),
            _ => {
                let other = 1 - target;
                self.flash.erase(other).map_err(StoreError::Flash)?;
                (other, 0)
            }
        };
        let record = encode_record(settings, generation);
        self.flash
            .program(sector, slot * SLOT_LEN, &record)
            .map_err(StoreError::Flash)?;
        let mut back = [0u8; RECORD_LEN];
        self.flash
            .read(sector, slot * SLOT_LEN, &mut back)
            .map_err(StoreError::Flash)?;
        if back != record {
            return Err(StoreError::Verify);
        }
        if !newest {
            // The record is written: clear the records that could outrank it.
            self.flash.erase(target).map_err(StoreError::Flash)?;
        }
        Ok(generation)
    }
}

/// Whether generation `a` is newer than `b` in serial-number arithmetic (RFC 1982 with 32
/// bits): `a` follows `b` by 1 to 2^31 - 1 saves, across the wrap from 0xFFFF_FFFF to 1.
/// The records in the two sectors span at most a few hundred saves, far inside that window.
/// Records more than 2^31 apart follow no such order: loading then takes the highest
/// generation, and the next save clears them.
pub const fn generation_is_newer(a: u32, b: u32) -> bool {
    let ahead = a.wrapping_sub(b);
    ahead != 0 && ahead < 1 << 31
}

/// The bytes of one record.
pub fn encode_record(settings: &Settings, generation: u32) -> [u8; RECORD_LEN] {
    let mut r = [0xFFu8; RECORD_LEN];
    r[0..4].copy_from_slice(&MAGIC.to_le_bytes());
    r[4..6].copy_from_slice(&SETTINGS_FORMAT_VERSION.to_le_bytes());
    r[6..8].copy_from_slice(&(Settings::SERIALIZED_LEN as u16).to_le_bytes());
    r[8..12].copy_from_slice(&generation.to_le_bytes());
    r[12..CRC_AT].copy_from_slice(&settings.to_bytes());
    let crc = crc32(&r[..CRC_AT]);
    r[CRC_AT..CRC_AT + 4].copy_from_slice(&crc.to_le_bytes());
    r
}

/// Format version and payload length of a record whose magic, version, length pair
/// ([`FORMATS`]) and CRC are right.
fn record_format(r: &[u8]) -> Option<(u16, usize)> {
    let mut h = Reader::new(r);
    if h.u32().ok()? != MAGIC {
        return None;
    }
    let version = h.u16().ok()?;
    let len = usize::from(h.u16().ok()?);
    if !FORMATS.contains(&(version, len)) {
        return None;
    }
    let crc_at = 12 + len;
    let stored = Reader::new(r.get(crc_at..)?).u32().ok()?;
    (crc32(r.get(..crc_at)?) == stored).then_some((version, len))
}

/// A record whose magic, version, length and CRC are right: its generation, and its
/// settings (any format version it accepts) if they decode and validate.
fn parse_record(r: &[u8]) -> Option<(u32, Option<Settings>)> {
    let (version, len) = record_format(r)?;
    let generation = Reader::new(r.get(8..)?).u32().ok()?;
    let settings = r
        .get(12..12 + len)
        .and_then(|payload| Settings::from_bytes_version(version, payload).ok());
    Some((generation, settings))
}
