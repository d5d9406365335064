//! Settings: key access and text round trips, boundary tables, atomic multi-key changes,
//! serialisation, and the flash store under a power cut at every erase/program step.

use odo_core::odometry::ChassisParams;
use odo_core::settings::store::{encode_record, Flash, SettingsStore, SLOT_LEN, WORD};
use odo_core::settings::*;
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------
// In-memory NOR flash that can lose power at any step.

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SimError {
    PowerCut,
    Dead,
}

/// Two sectors of `size` bytes. One *step* is one programmed word or one erased chunk of
/// `erase_chunk` bytes. With `cut_at = Some(n)` the n-th step (0-based) is interrupted: a
/// word is left partially programmed (a random subset of its 0 bits), an erase chunk is
/// left with random bits set; then the device is dead until `revive`.
#[derive(Debug, Clone)]
struct SimFlash {
    mem: [Vec<u8>; 2],
    erase_chunk: usize,
    cut_at: Option<u64>,
    steps: u64,
    dead: bool,
    rng: u64,
    /// Words programmed that were not erased (the store must never do that).
    violations: u32,
    erases: u32,
}

impl SimFlash {
    fn new(size: usize) -> Self {
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
    fn arm(&mut self, cut_at: u64, seed: u64) {
        self.cut_at = Some(cut_at);
        self.steps = 0;
        self.rng = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    }
    fn revive(&mut self) {
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
fn variant(i: u32) -> Settings {
    let mut s = Settings::DEFAULT;
    s.chassis.track_width = 0.5 + i as f64 * 1e-3;
    s.chassis.left_wheel.cos[0] = (i % 7) as f32 * 1e-3;
    s
}

fn load(flash: &SimFlash) -> (Settings, SettingsSource, u32) {
    let mut store = SettingsStore::new(flash.clone());
    let l = store.load().expect("load");
    (l.settings, l.source, l.generation)
}

// ---------------------------------------------------------------------------------------
// Store

#[test]
fn empty_and_garbage_flash_give_defaults() {
    let flash = SimFlash::new(4 * SLOT_LEN);
    assert_eq!(
        load(&flash),
        (Settings::DEFAULT, SettingsSource::Defaults, 0)
    );
    let mut junk = SimFlash::new(4 * SLOT_LEN);
    for s in 0..2 {
        for (i, b) in junk.mem[s].iter_mut().enumerate() {
            *b = (i as u32).wrapping_mul(2_654_435_761).to_le_bytes()[3];
        }
    }
    assert_eq!(
        load(&junk),
        (Settings::DEFAULT, SettingsSource::Defaults, 0)
    );
    // All zero (a programmed-out sector) too.
    let mut zero = SimFlash::new(4 * SLOT_LEN);
    zero.mem[0].fill(0);
    zero.mem[1].fill(0);
    assert_eq!(load(&zero).1, SettingsSource::Defaults);
    // And a save still works on it (erases a sector first).
    let mut store = SettingsStore::new(zero);
    store.save(&variant(1)).expect("save on zeroed flash");
    assert_eq!(store.load().unwrap().settings, variant(1));
}

#[test]
fn save_load_round_trip_and_sector_alternation() {
    let mut store = SettingsStore::new(SimFlash::new(3 * SLOT_LEN));
    for i in 1..=20u32 {
        let g = store.save(&variant(i)).expect("save");
        assert_eq!(g, i);
        let l = store.load().unwrap();
        assert_eq!(
            (l.settings, l.source, l.generation),
            (variant(i), SettingsSource::Flash, i)
        );
    }
    let f = store.into_inner();
    assert_eq!(f.violations, 0, "never programs a non-erased word");
    // 20 saves into 3-slot sectors: 3 in the first, then an erase every 3 saves.
    assert_eq!(f.erases, 6);
}

#[test]
fn invalid_settings_are_not_saved() {
    let mut store = SettingsStore::new(SimFlash::new(2 * SLOT_LEN));
    let mut bad = Settings::DEFAULT;
    bad.chassis.track_width = f64::NAN;
    assert!(store.save(&bad).is_err());
    assert_eq!(store.load().unwrap().source, SettingsSource::Defaults);
    assert_eq!(store.into_inner().steps, 0);
}

#[test]
fn corrupt_newest_record_falls_back_to_previous() {
    let mut store = SettingsStore::new(SimFlash::new(4 * SLOT_LEN));
    store.save(&variant(1)).unwrap();
    store.save(&variant(2)).unwrap();
    let mut f = store.into_inner();
    f.mem[0][SLOT_LEN + 40] ^= 0x01; // a bit of record 2's payload
    assert_eq!(load(&f), (variant(1), SettingsSource::Flash, 1));
    // The next save goes after the damaged slot, with a fresh generation.
    let mut store = SettingsStore::new(f);
    assert_eq!(
        store.save(&variant(3)).unwrap(),
        2,
        "above every valid record"
    );
    assert_eq!(store.load().unwrap().settings, variant(3));
    assert_eq!(store.into_inner().violations, 0);
}

#[test]
fn record_with_valid_crc_but_invalid_settings_is_skipped() {
    let mut f = SimFlash::new(2 * SLOT_LEN);
    let mut bad = Settings::DEFAULT;
    bad.rate = 0; // out of range, but the record itself is well formed
    let rec = encode_record(&bad, 5);
    f.program(0, 0, &rec).unwrap();
    assert_eq!(load(&f).1, SettingsSource::Defaults);
    // A save must still get a generation above it.
    let mut store = SettingsStore::new(f);
    assert_eq!(store.save(&variant(1)).unwrap(), 6);
}

/// Power cut at every step of a save, then (after reboot) at every step of the next save,
/// starting from every number of earlier saves that a 3-slot sector pair goes through in
/// two full rotations. After every cut the loaded settings are the old or the new ones,
/// never defaults or anything else, and generations never go backwards.
#[test]
fn power_cut_at_every_step() {
    let mut checked = 0u64;
    for prior in 0..=12u32 {
        let mut base = SettingsStore::new(SimFlash::new(3 * SLOT_LEN));
        for i in 1..=prior {
            base.save(&variant(i)).unwrap();
        }
        let base = base.into_inner();
        let old = load(&base);
        let new_settings = variant(100 + prior);
        let mut cut = 0u64;
        loop {
            let mut f = base.clone();
            f.arm(cut, cut + 1);
            let done = SettingsStore::new(&mut f).save(&new_settings).is_ok();
            f.revive();
            let after = load(&f);
            if done {
                assert_eq!(after.0, new_settings);
                break;
            }
            let is_old = after == old;
            let is_new = after.0 == new_settings && after.1 == SettingsSource::Flash;
            assert!(is_old || is_new, "prior {prior} cut {cut}: {after:?}");
            if prior > 0 {
                assert_eq!(after.1, SettingsSource::Flash);
            }
            // Second save after the reboot, itself cut at every step.
            let newer = variant(200 + prior);
            let mut cut2 = 0u64;
            loop {
                let mut g = f.clone();
                g.arm(cut2, cut * 1000 + cut2 + 7);
                let done2 = SettingsStore::new(&mut g).save(&newer).is_ok();
                g.revive();
                let after2 = load(&g);
                checked += 1;
                if done2 {
                    assert_eq!(after2.0, newer);
                    assert!(after2.2 > after.2);
                    assert_eq!(g.violations, 0);
                    break;
                }
                assert!(
                    after2 == after || (after2.0 == newer && after2.2 > after.2),
                    "prior {prior} cut {cut} cut2 {cut2}: {after2:?}"
                );
                cut2 += 1;
            }
            cut += 1;
        }
        assert!(cut >= 32, "a save programs at least 32 words");
    }
    assert!(checked > 5_000, "{checked}");
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

/// The real geometry: two 128 KiB sectors, 512 slots each; go once around both.
#[test]
fn full_size_sectors_wrap() {
    let mut store = SettingsStore::new(SimFlash::new(128 * 1024));
    for i in 1..=1100u32 {
        store.save(&variant(i % 50)).unwrap();
    }
    let l = store.load().unwrap();
    assert_eq!((l.settings, l.generation), (variant(1100 % 50), 1100));
    let f = store.into_inner();
    assert_eq!(f.erases, 2);
    assert_eq!(f.violations, 0);
}

// ---------------------------------------------------------------------------------------
// Keys and values

#[test]
fn defaults_are_the_designed_chassis() {
    let s = Settings::default();
    assert_eq!(s.chassis, ChassisParams::DESIGNED);
    assert_eq!(s.chassis.left_diameter, 0.260);
    assert_eq!(s.chassis.track_width, 0.563);
    assert_eq!(s.chassis.ticks_per_rev, 20_000);
    s.validate().unwrap();
}

#[test]
fn every_key_has_a_unique_name_and_round_trips_as_text() {
    let mut names: Vec<&str> = Key::ALL.iter().map(|k| k.name()).collect();
    names.sort();
    names.dedup();
    assert_eq!(names.len(), Key::COUNT);
    for k in Key::ALL {
        assert_eq!(Key::from_name(k.name()), Some(k));
    }
    let s = variant(3);
    for k in Key::ALL {
        let text = s.get(k).to_string();
        let mut u = Settings::DEFAULT;
        u.set(k, &text).unwrap();
        assert_eq!(u.get(k), s.get(k), "{}", k.name());
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]
    /// Any in-range f64/f32 value prints and parses back bit for bit.
    #[test]
    fn float_text_round_trip(bits in any::<u64>(), key_i in 0usize..Key::COUNT) {
        let key = Key::ALL[key_i];
        let mut s = Settings::DEFAULT;
        let text = match key.info().kind {
            Kind::F64 { min, max } => {
                let v = min + (max - min) * (bits as f64 / u64::MAX as f64);
                Value::F64(v).to_string()
            }
            Kind::F32 { min, max } => {
                let v = (min + (max - min) * (bits as f32 / u64::MAX as f32)).clamp(min, max);
                Value::F32(v).to_string()
            }
            _ => return Ok(()),
        };
        s.set(key, &text).unwrap();
        prop_assert_eq!(s.get(key).to_string(), text.clone());
        let mut t = Settings::DEFAULT;
        t.set(key, &s.get(key).to_string()).unwrap();
        prop_assert_eq!(format!("{:?}", t.get(key)), format!("{:?}", s.get(key)));
    }

    /// Arbitrary f64 bit patterns: set either refuses or stores exactly what it printed.
    #[test]
    fn arbitrary_f64_bits(bits in any::<u64>()) {
        let v = f64::from_bits(bits);
        let mut s = Settings::DEFAULT;
        let text = format!("{v}");
        match s.set(Key::TrackWidth, &text) {
            Ok(()) => prop_assert_eq!(s.chassis.track_width.to_bits(), v.to_bits()),
            Err(_) => prop_assert_eq!(s, Settings::DEFAULT),
        }
    }
}

/// Boundary table: (key, value text, accepted?).
#[test]
fn boundary_table() {
    let table: &[(&str, &str, bool)] = &[
        ("left_diameter", "0.01", true),
        ("left_diameter", "0.009999999", false),
        ("left_diameter", "10", true),
        ("left_diameter", "10.000000001", false),
        ("left_diameter", "-0.26", false),
        ("left_diameter", "NaN", false),
        ("left_diameter", "inf", false),
        ("left_diameter", "-Infinity", false),
        ("left_diameter", "1e999", false),
        ("left_diameter", "0.26m", false),
        ("left_diameter", "", false),
        ("left_diameter", "2.6e-1", true),
        ("right_diameter", "0.26", true),
        ("track_width", "0.563", true),
        ("track_width", "0", false),
        ("ticks_per_rev", "3", false),
        ("ticks_per_rev", "146", true), // 0.26 m wheels, 0.563 m track: 0.0056 m/increment
        ("ticks_per_rev", "145", false), // heading step above 0.01 rad per increment
        ("ticks_per_rev", "1048576", true),
        ("ticks_per_rev", "1048577", false),
        ("ticks_per_rev", "-1", false),
        ("ticks_per_rev", "20000.0", false),
        ("ticks_per_rev", "99999999999999999999", false),
        ("delta_left", "0", true),
        ("delta_left", "3.9e-8", true),
        ("delta_left", "0.001", true),
        ("delta_left", "0.0011", false),
        ("delta_left", "-1e-9", false),
        ("delta_right", "1e39", false),
        ("delta_diff", "1e-7", true),
        ("kappa_left", "0.01", true),
        ("kappa_left", "0.0101", false),
        ("kappa_right", "nan", false),
        ("left_cos1", "0.05", true),
        ("left_cos1", "-0.05", true),
        ("left_cos1", "0.0501", false),
        ("right_sin3", "-0.06", false),
        ("uncertainty_model", "paper", true),
        ("uncertainty_model", "covariance", true),
        ("uncertainty_model", "Paper", false),
        ("mode", "pps", true),
        ("mode", "free", true),
        ("mode", "gps", false),
        ("rate", "1", true),
        ("rate", "0", false),
        ("rate", "100", true),
        ("rate", "10001", false),
        ("output_divider", "0", false),
        ("output_divider", "10000", true),
        ("time_tag_pps", "previous", true),
        ("time_tag_pps", "next", true),
        ("time_tag_pps", "last", false),
        ("baud", "115200", true),
        ("baud", "921600", true),
        ("baud", "100000", false),
    ];
    for &(key, text, ok) in table {
        let mut s = Settings::DEFAULT;
        let r = s.set_many([(key, text)]);
        assert_eq!(r.is_ok(), ok, "{key} = {text:?}: {r:?}");
        if !ok {
            assert_eq!(s, Settings::DEFAULT, "{key} = {text:?} changed something");
        }
    }
}

#[test]
fn error_messages_name_the_problem() {
    let mut s = Settings::DEFAULT;
    let msg = |r: Result<(), SetManyError<'_>>| r.unwrap_err().to_string();
    assert_eq!(msg(s.set_many([("foo", "1")])), "unknown key 'foo'");
    assert!(msg(s.set_many([("track_width", "abc")])).contains("track_width: bad number"));
    assert!(msg(s.set_many([("track_width", "nan")])).contains("NaN/inf"));
    let m = msg(s.set_many([("track_width", "11")]));
    assert!(
        m.contains("track_width: out of range") && m.contains("0.01..=10"),
        "{m}"
    );
    assert!(msg(s.set_many([("mode", "x")])).contains("expected pps|free"));
    assert!(msg(s.set_many([("baud", "1")])).contains("one of 9600"));
    let m = msg(s.set_many([("ticks_per_rev", "100")]));
    assert!(
        m.contains("ticks_per_rev: does not fit the other chassis keys"),
        "{m}"
    );
}

#[test]
fn relations_between_keys_are_atomic() {
    let mut s = Settings::DEFAULT;
    // 1000 records/s do not fit 115200 baud ...
    assert!(s.set_many([("rate", "1000")]).is_err());
    assert_eq!(s, Settings::DEFAULT);
    // ... but with a divider (or a faster link) they do, set together.
    s.set_many([("rate", "1000"), ("output_divider", "10")])
        .unwrap();
    assert_eq!((s.rate, s.output_divider), (1000, 10));
    // PPS mode needs a rate dividing one second into whole microseconds.
    let before = s;
    assert!(s.set_many([("mode", "pps"), ("rate", "7")]).is_err());
    assert_eq!(s, before);
    s.set_many([("mode", "pps"), ("rate", "50"), ("output_divider", "1")])
        .unwrap();
    // A bad value late in a list leaves the earlier ones unapplied.
    let before = s;
    assert!(s
        .set_many([
            ("left_diameter", "0.3"),
            ("right_diameter", "0.3"),
            ("track_width", "-1")
        ])
        .is_err());
    assert_eq!(s, before);
    // 9600 baud only with a low output rate.
    assert!(s.set_many([("baud", "9600")]).is_err());
    s.set_many([("baud", "9600"), ("output_divider", "10")])
        .unwrap();
}

#[test]
fn serialisation_round_trip_and_checksum() {
    for i in 0..50 {
        let s = variant(i);
        let b = s.to_bytes();
        assert_eq!(b.len(), Settings::SERIALIZED_LEN);
        assert_eq!(Settings::from_bytes(&b).unwrap(), s);
    }
    assert_ne!(variant(1).checksum(), variant(2).checksum());
    assert!(Settings::from_bytes(&[0u8; 10]).is_err());
    let mut b = Settings::DEFAULT.to_bytes();
    b[96] = 7; // bad uncertainty model code
    assert!(Settings::from_bytes(&b).is_err());
}
