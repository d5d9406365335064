//! Settings: key access and text round trips, boundary tables, atomic multi-key changes,
//! serialisation, and the flash store under a power cut at every erase/program step.

use odo_core::crc::crc32;
use odo_core::odometry::integrator::MAX_STEP_COUNTS;
use odo_core::odometry::ChassisParams;
use odo_core::settings::store::{
    encode_record, Flash, SettingsStore, MAGIC, RECORD_LEN, SLOT_LEN, WORD,
};
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

/// `next_save_erases` predicts exactly the saves that erase, and reading it changes nothing.
#[test]
fn next_save_erases_predicts_the_erase() {
    let mut store = SettingsStore::new(SimFlash::new(3 * SLOT_LEN));
    for i in 1..=20u32 {
        let predicted = store.next_save_erases().unwrap();
        let before = store.flash().erases;
        let mem = store.flash().mem.clone();
        assert_eq!(store.next_save_erases().unwrap(), predicted);
        assert_eq!(store.flash().mem, mem, "a query changed the flash");
        store.save(&variant(i)).unwrap();
        let erased = store.flash().erases > before;
        assert_eq!(predicted, erased, "save {i}");
        // With 3-slot sectors: saves 1-3 fill sector 0, then every third save erases.
        assert_eq!(erased, i >= 4 && (i - 4) % 3 == 0, "save {i}");
    }
    // A flash that cannot be read is an error, not a guess.
    let mut dead = SimFlash::new(3 * SLOT_LEN);
    dead.dead = true;
    assert!(SettingsStore::new(dead).next_save_erases().is_err());
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
        // At the default 50 Hz and 2 m/s: 669,113 increments per turn keep a sample within
        // 32,767 increments (the largest ticks_per_rev needs a higher rate, see below).
        ("ticks_per_rev", "669113", true),
        ("ticks_per_rev", "669114", false),
        ("ticks_per_rev", "1048576", false),
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
        // 1 Hz: 48,971 increments per sample at the default 2 m/s (see the counts table).
        ("rate", "1", false),
        ("rate", "2", true),
        ("rate", "0", false),
        ("rate", "100", true),
        ("rate", "1001", false), // MAX_RATE_HZ (1000 needs a divider at 115200 baud)
        ("rate", "10000", false),
        ("max_wheel_speed", "2", true),
        ("max_wheel_speed", "0.01", true),
        ("max_wheel_speed", "0.0099", false),
        ("max_wheel_speed", "20", true),
        ("max_wheel_speed", "20.001", false),
        ("max_wheel_speed", "0", false),
        ("max_wheel_speed", "-2", false),
        ("max_wheel_speed", "nan", false),
        ("max_wheel_speed", "inf", false),
        ("max_wheel_speed", "2 m/s", false),
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
    let m = msg(s.set_many([("rate", "1001")]));
    assert!(m.contains("rate: out of range, 1..=1000"), "{m}");
    let m = msg(s.set_many([("rate", "1")]));
    assert_eq!(
        m,
        "rate/max_wheel_speed/ticks_per_rev/left_diameter/right_diameter: up to 48971 \
         increments per sample at max_wheel_speed, above 32767 (the 16-bit right counter \
         would alias; raise rate, or lower max_wheel_speed or ticks_per_rev)"
    );
    let m = msg(s.set_many([("max_wheel_speed", "25")]));
    assert!(
        m.contains("max_wheel_speed: out of range, 0.01..=20"),
        "{m}"
    );
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
    // 1 Hz only for a slower chassis: lowering max_wheel_speed in the same set allows it.
    let mut s = Settings::DEFAULT;
    assert!(s.set_many([("rate", "1")]).is_err());
    assert_eq!(s, Settings::DEFAULT);
    s.set_many([("rate", "1"), ("max_wheel_speed", "1.3")])
        .unwrap();
    // ... and then a finer encoder, or a faster chassis, is refused until the rate rises.
    let before = s;
    assert!(s.set_many([("ticks_per_rev", "40000")]).is_err());
    assert!(s.set_many([("max_wheel_speed", "1.4")]).is_err());
    assert!(
        s.set_many([("right_diameter", "0.2")]).is_err(),
        "smaller wheel"
    );
    assert_eq!(s, before);
    s.set_many([("ticks_per_rev", "40000"), ("rate", "3")])
        .unwrap();
    // The largest ticks_per_rev at 2 m/s from 79 Hz up (32,495 increments per sample).
    let mut s = Settings::DEFAULT;
    assert!(s
        .set_many([("ticks_per_rev", "1048576"), ("rate", "78")])
        .is_err());
    s.set_many([("ticks_per_rev", "1048576"), ("rate", "79")])
        .unwrap();
    // The fastest rate, with a divider for the link.
    let mut s = Settings::DEFAULT;
    s.set_many([("rate", "1000"), ("output_divider", "10"), ("mode", "pps")])
        .unwrap();
    assert!(s.set_many([("rate", "1001"), ("mode", "free")]).is_err());
}

// ---------------------------------------------------------------------------------------
// Counts per sample: the 16-bit right counter (TIM3) must not alias

#[test]
fn counts_limit_constants() {
    assert_eq!(COUNTER16_MAX_UNREAD, 32_767);
    assert_eq!(MAX_STEP_COUNTS, 1 << 18);
    assert_eq!(
        MAX_COUNTS_PER_SAMPLE, 32_767,
        "the 16-bit counter binds first"
    );
    assert_eq!(MAX_RATE_HZ, 1_000);
    assert_eq!(1_000_000 % MAX_RATE_HZ, 0, "usable in pps mode");
    // The documented examples.
    let c = max_counts_per_sample(2.0, 20_000, 0.26, 1);
    assert!((c - 48_970.75).abs() < 0.01, "{c}");
    assert_eq!(Settings::DEFAULT.max_counts_per_sample(), c / 50.0);
    let t = Settings::DEFAULT.max_unread_interval();
    assert!((t - 0.669_1).abs() < 1e-4, "{t}");
    assert_eq!(max_unread_interval(0.0, 20_000, 0.26), f64::INFINITY);
    assert_eq!(max_unread_interval(-1.0, 20_000, 0.26), 0.0);
    assert_eq!(max_unread_interval(f64::NAN, 20_000, 0.26), 0.0);
    assert_eq!(max_counts_per_sample(2.0, 20_000, 0.26, 0), f64::INFINITY);
}

/// The largest diameter `d` (m) for which `max_counts_per_sample(v, tpr, d, rate)` exceeds
/// the limit: the next f64 above it gives at most the limit. Found by bisection on the bits
/// of positive f64 (ordered like the values).
fn boundary_diameter(v: f64, tpr: u32, rate: u32) -> f64 {
    let limit = MAX_COUNTS_PER_SAMPLE as f64;
    let (mut lo, mut hi) = (1e-3f64.to_bits(), 100f64.to_bits());
    assert!(max_counts_per_sample(v, tpr, f64::from_bits(lo), rate) > limit);
    assert!(max_counts_per_sample(v, tpr, f64::from_bits(hi), rate) <= limit);
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if max_counts_per_sample(v, tpr, f64::from_bits(mid), rate) > limit {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    f64::from_bits(lo)
}

/// Boundary table at 1 Hz with a fine encoder: just below, at and just above the limit of
/// 32,767 increments per sample, through `set_many` (which names the keys and leaves the
/// settings intact), on either wheel, and with the smaller wheel deciding.
#[test]
fn counts_per_sample_boundary_table() {
    let tpr = 1_048_576; // the largest ticks_per_rev
    let base = Settings {
        rate: 1,
        max_wheel_speed: 0.05, // m/s
        chassis: ChassisParams {
            ticks_per_rev: tpr,
            ..ChassisParams::DESIGNED
        },
        ..Settings::DEFAULT
    };
    // The f32 value of max_wheel_speed, exactly.
    let v = f64::from(base.max_wheel_speed);
    let d_over = boundary_diameter(v, tpr, 1);
    let d_at = f64::from_bits(d_over.to_bits() + 1);
    // The exact diameter: 0.05 * 2^20 / (pi * 32767) = 0.50931... m.
    assert!((d_at - 0.509_31).abs() < 1e-5, "{d_at}");
    let at = max_counts_per_sample(v, tpr, d_at, 1);
    assert!(at <= 32_767.0 && at > 32_767.0 - 1e-9, "{at}");
    assert!(max_counts_per_sample(v, tpr, d_over, 1) > 32_767.0);
    let rows: &[(f64, f64, bool, &str)] = &[
        // (left_diameter, right_diameter, accepted, what)
        (0.6, 0.6, true, "well below: 27,814 increments"),
        (d_at * 1.000_001, d_at * 1.000_001, true, "just below"),
        (d_at, d_at, true, "at the limit"),
        (d_over, d_over, false, "one ulp above"),
        (d_at * 0.999_999, d_at * 0.999_999, false, "just above"),
        (d_over, 0.6, false, "left wheel smaller"),
        (0.6, d_over, false, "right wheel smaller"),
        (0.6, d_at, true, "right wheel smaller, at the limit"),
        (0.26, 0.26, false, "well above: 64,187 increments"),
    ];
    for &(l, r, ok, what) in rows {
        let mut s = base;
        // Debug form: the shortest text that parses back to the same f64.
        let (lt, rt) = (format!("{l:?}"), format!("{r:?}"));
        let res = s.set_many([
            ("left_diameter", lt.as_str()),
            ("right_diameter", rt.as_str()),
        ]);
        assert_eq!(res.is_ok(), ok, "{what}: {l} {r}: {res:?}");
        if ok {
            assert_eq!((s.chassis.left_diameter, s.chassis.right_diameter), (l, r));
            assert!(s.max_counts_per_sample() <= 32_767.0);
            assert!(
                s.max_unread_interval() >= 1.0,
                "{what}: a whole 1 Hz period"
            );
        } else {
            assert_eq!(s, base, "{what}: changed something");
            let e = res.unwrap_err().to_string();
            assert!(
                e.starts_with("rate/max_wheel_speed/ticks_per_rev/left_diameter/right_diameter")
                    && e.contains("above 32767"),
                "{e}"
            );
            // validate() agrees on the settings as they would have been.
            let mut t = base;
            t.chassis.left_diameter = l;
            t.chassis.right_diameter = r;
            assert!(matches!(
                t.validate(),
                Err(SettingError::CountsPerSample { counts }) if counts >= 32_768
            ));
        }
    }
    // The rate scales it: 64,187 increments at 1 Hz are 32,093 at 2 Hz.
    let mut s = base;
    s.set_many([("left_diameter", "0.26"), ("right_diameter", "0.26")])
        .unwrap_err();
    s.set_many([
        ("left_diameter", "0.26"),
        ("right_diameter", "0.26"),
        ("rate", "2"),
    ])
    .unwrap();
    assert!((s.max_counts_per_sample() - 32_093.47).abs() < 0.01);
}

/// The unread interval is the limit's time at max_wheel_speed, and a sample period of
/// valid settings always fits in it.
#[test]
fn max_unread_interval_matches_counts() {
    for (v, tpr, d) in [(2.0, 20_000, 0.26), (0.5, 1_048_576, 0.4), (20.0, 4, 10.0)] {
        let t = max_unread_interval(v, tpr, d);
        let c = max_counts_per_sample(v, tpr, d, 1) * t;
        assert!((c - 32_767.0).abs() < 1e-6, "{v} {tpr} {d}: {c}");
    }
    for i in 0..50 {
        let s = variant(i);
        assert!(s.max_unread_interval() >= 1.0 / f64::from(s.rate));
    }
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
    // The new key is the last field.
    let mut s = Settings::DEFAULT;
    s.max_wheel_speed = 1.25;
    let b = s.to_bytes();
    assert_eq!(&b[112..116], &1.25f32.to_le_bytes());
    assert_eq!(Settings::from_bytes(&b).unwrap(), s);
    assert!(
        Settings::from_bytes(&b[..116]).is_err(),
        "version 3 needs 144 bytes"
    );
    assert!(Settings::from_bytes_version(4, &b).is_err());
    assert!(Settings::from_bytes_version(0, &b).is_err());
}

// ---------------------------------------------------------------------------------------
// Format version 1 (before max_wheel_speed): still loads

/// A record exactly as the firmware of format version 1 wrote it: 112-byte payload (the
/// version 2 payload without its last 4 bytes), CRC at 124, 128 bytes.
fn v1_record(settings: &Settings, generation: u32) -> Vec<u8> {
    let mut r = Vec::new();
    r.extend_from_slice(&MAGIC.to_le_bytes());
    r.extend_from_slice(&1u16.to_le_bytes());
    r.extend_from_slice(&112u16.to_le_bytes());
    r.extend_from_slice(&generation.to_le_bytes());
    r.extend_from_slice(&settings.to_bytes()[..Settings::SERIALIZED_LEN_V1]);
    let crc = crc32(&r);
    r.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(r.len(), 128);
    r
}

/// A record exactly as the firmware of format version 2 wrote it: 116-byte payload (the
/// version 3 payload without the geometry's standard errors), CRC at 128, 132 bytes.
fn v2_record(settings: &Settings, generation: u32) -> Vec<u8> {
    let mut r = Vec::new();
    r.extend_from_slice(&MAGIC.to_le_bytes());
    r.extend_from_slice(&2u16.to_le_bytes());
    r.extend_from_slice(&116u16.to_le_bytes());
    r.extend_from_slice(&generation.to_le_bytes());
    r.extend_from_slice(&settings.to_bytes()[..Settings::SERIALIZED_LEN_V2]);
    let crc = crc32(&r);
    r.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(r.len(), 132);
    r
}

#[test]
fn record_layout_of_format_version_3() {
    let r = encode_record(&variant(4), 9);
    assert_eq!(RECORD_LEN, 160);
    assert_eq!(r.len(), RECORD_LEN);
    assert_eq!(RECORD_LEN % WORD, 0);
    assert_eq!(&r[4..8], &[3, 0, 144, 0]);
    assert_eq!(&r[12..156], &variant(4).to_bytes());
    assert_eq!(&r[156..160], &crc32(&r[..156]).to_le_bytes());
    // The v1 record is the same bytes up to the payload's end, but its own header and CRC.
    let old = v1_record(&variant(4), 9);
    assert_eq!(&old[12..124], &r[12..124]);
}

#[test]
fn format_version_1_record_loads_with_the_default_max_wheel_speed() {
    let mut old = variant(3);
    old.rate = 100;
    // Whatever the in-memory value, a v1 record cannot carry it.
    old.max_wheel_speed = 7.0;
    let mut f = SimFlash::new(4 * SLOT_LEN);
    f.program(0, 0, &v1_record(&old, 41)).unwrap();
    let expect = Settings {
        max_wheel_speed: Settings::DEFAULT_MAX_WHEEL_SPEED,
        ..old
    };
    assert_eq!(load(&f), (expect, SettingsSource::Flash, 41));
    assert_eq!(
        Settings::from_bytes_version(1, &old.to_bytes()[..112]).unwrap(),
        expect
    );
    // The next save writes version 2 after it, above its generation, and wins.
    let mut store = SettingsStore::new(&mut f);
    assert_eq!(store.save(&variant(5)).unwrap(), 42);
    assert_eq!(load(&f), (variant(5), SettingsSource::Flash, 42));
    assert_eq!(&f.mem[0][SLOT_LEN + 4..SLOT_LEN + 8], &[3, 0, 144, 0]);
    assert_eq!(f.violations, 0);
    // The v1 record is still the fallback if the new one is damaged.
    f.mem[0][SLOT_LEN + 20] ^= 0x10;
    assert_eq!(load(&f), (expect, SettingsSource::Flash, 41));
}

#[test]
fn format_version_2_record_loads_with_an_exact_geometry() {
    let mut old = variant(3);
    old.chassis.geometry_uncertainty.track_width_se = 5e-4;
    old.chassis.kappa_diff = 2e-5;
    let mut f = SimFlash::new(4 * SLOT_LEN);
    f.program(0, 0, &v2_record(&old, 7)).unwrap();
    let expect = Settings {
        chassis: odo_core::odometry::ChassisParams {
            geometry_uncertainty: odo_core::odometry::GeometryUncertainty::EXACT,
            kappa_diff: 0.0,
            ..old.chassis
        },
        ..old
    };
    assert_eq!(load(&f), (expect, SettingsSource::Flash, 7));
    // The next save writes version 3 and wins; the v2 record stays the fallback.
    let mut store = SettingsStore::new(&mut f);
    assert_eq!(store.save(&old).unwrap(), 8);
    assert_eq!(load(&f), (old, SettingsSource::Flash, 8));
    f.mem[0][SLOT_LEN + 20] ^= 0x10;
    assert_eq!(load(&f), (expect, SettingsSource::Flash, 7));
    assert_eq!(f.violations, 0);
}

/// Damaged or mislabelled v1 records are refused like any other, and saving over them
/// keeps the generations increasing and never programs a used word.
#[test]
fn corrupt_or_mislabelled_old_records_are_rejected() {
    let good = v1_record(&variant(2), 10);
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("payload bit", {
            let mut r = good.clone();
            r[40] ^= 1;
            r
        }),
        ("crc bit", {
            let mut r = good.clone();
            r[125] ^= 0x80;
            r
        }),
        ("v1 header with a v2 length", {
            let mut r = good.clone();
            r[6] = 116;
            r
        }),
        ("v2 header on a v1 record", {
            let mut r = good.clone();
            r[4] = 2;
            let crc = crc32(&r[..124]);
            r[124..128].copy_from_slice(&crc.to_le_bytes());
            r
        }),
        ("unknown version 3", {
            let mut r = good.clone();
            r[4] = 3;
            let crc = crc32(&r[..124]);
            r[124..128].copy_from_slice(&crc.to_le_bytes());
            r
        }),
        ("v1 with settings the new rules refuse (rate 1 at 2 m/s)", {
            let mut s = variant(2);
            s.rate = 1;
            v1_record(&s, 10)
        }),
    ];
    for (what, rec) in cases {
        let mut f = SimFlash::new(2 * SLOT_LEN);
        f.program(0, 0, &rec).unwrap();
        let before = f.mem.clone();
        assert_eq!(
            load(&f),
            (Settings::DEFAULT, SettingsSource::Defaults, 0),
            "{what}"
        );
        assert_eq!(f.mem, before, "{what}: loading changed the flash");
        // A save goes after it (never over it), above any CRC-valid generation.
        let mut store = SettingsStore::new(&mut f);
        let g = store.save(&variant(7)).unwrap();
        assert!(g >= 1, "{what}");
        assert_eq!(load(&f).0, variant(7), "{what}");
        assert_eq!(&f.mem[0][..128], &rec[..], "{what}: old slot untouched");
        assert_eq!(f.violations, 0, "{what}");
    }
    // The CRC-valid but refused record still counts for the generation.
    let mut s = variant(2);
    s.rate = 1;
    let mut f = SimFlash::new(2 * SLOT_LEN);
    f.program(0, 0, &v1_record(&s, 10)).unwrap();
    assert_eq!(SettingsStore::new(&mut f).save(&variant(7)).unwrap(), 11);
}

/// The save guard: one sample period plus the erase stall must stay below
/// `max_unread_interval` (0.669 s for the designed chassis at 2 m/s), so at 50 Hz the x32
/// erase (500 ms) is survivable, the x8 erase (800 ms) is not; slower wheels make the x8 erase
/// survivable too, and a stall of zero always is.
#[test]
fn erase_stall_against_the_counter_range() {
    let d = Settings::DEFAULT;
    assert!(d.survives_stall(0));
    assert!(d.survives_stall(500));
    // 669 ms - 20 ms (one period at 50 Hz) = 649 ms.
    assert!(d.survives_stall(648));
    assert!(!d.survives_stall(650));
    assert!(!d.survives_stall(800));
    // Issue 19: at 2 Hz the gap is 500 ms + the stall: the x32 erase (BOR level 3) no longer
    // passes (counts 48,971 > 32,767 would alias TIM3).
    let mut two_hz = d;
    two_hz.rate = 2;
    assert!(!two_hz.survives_stall(500));
    assert!(two_hz.survives_stall(168));
    assert!(!two_hz.survives_stall(170));
    let mut slow = d;
    slow.max_wheel_speed = 1.0;
    assert!(slow.survives_stall(800));
    assert!(!slow.survives_stall(1_400));
}

/// Issue 20 item 9: a valid record of generation 0xFFFF_FFFF made the next save write
/// generation 1, which verified, but every later load returned the old record. Generations
/// are ordered with wrap-around (serial-number arithmetic); go across the wrap through both
/// sectors.
#[test]
fn generation_wraps_around() {
    use odo_core::settings::store::generation_is_newer;
    for (a, b, newer) in [
        (2, 1, true),
        (1, 2, false),
        (1, 1, false),
        (1, u32::MAX, true),
        (u32::MAX, 1, false),
        (5, u32::MAX - 5, true),
        (0x8000_0000, 1, true),
        (0x8000_0001, 1, false),
    ] {
        assert_eq!(generation_is_newer(a, b), newer, "{a:#x} newer than {b:#x}");
    }
    // The input: one record at 0xFFFF_FFFF.
    let mut f = SimFlash::new(3 * SLOT_LEN);
    f.program(0, 0, &encode_record(&variant(1), u32::MAX))
        .unwrap();
    assert_eq!(load(&f), (variant(1), SettingsSource::Flash, u32::MAX));
    let mut store = SettingsStore::new(f);
    assert_eq!(store.save(&variant(2)).unwrap(), 1, "0 is never written");
    assert_eq!(load(store.flash()), (variant(2), SettingsSource::Flash, 1));

    // From 0xFFFF_FFFB over the wrap to 8, around both 3-slot sectors twice.
    let mut f = SimFlash::new(3 * SLOT_LEN);
    f.program(1, 0, &encode_record(&variant(0), u32::MAX - 4))
        .unwrap();
    let mut store = SettingsStore::new(f);
    let mut expected = u32::MAX - 4;
    for i in 1..=12 {
        expected = expected.wrapping_add(1).max(1);
        assert_eq!(store.save(&variant(i)).unwrap(), expected, "save {i}");
        assert_eq!(
            load(store.flash()),
            (variant(i), SettingsSource::Flash, expected),
            "save {i}"
        );
    }
    assert_eq!(expected, 8);
}

// ---------------------------------------------------------------------------------------
// The key table against the format and the docs

/// The version 3 layout written field by field as docs/PROTOCOL.md section 5 lists it (the
/// encoder before the key table): the table's codec must give the same bytes.
fn layout_v3_by_hand(s: &Settings) -> Vec<u8> {
    let c = &s.chassis;
    let mut b = Vec::new();
    for v in [c.left_diameter, c.right_diameter, c.track_width] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&c.ticks_per_rev.to_le_bytes());
    for v in [
        c.delta_left,
        c.delta_right,
        c.delta_diff,
        c.kappa_left,
        c.kappa_right,
    ] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    for w in [&c.left_wheel, &c.right_wheel] {
        for v in w.cos.iter().chain(w.sin.iter()) {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    b.push(match c.uncertainty_model {
        odo_core::odometry::UncertaintyModel::Paper => 0,
        odo_core::odometry::UncertaintyModel::Covariance => 1,
    });
    b.push(match s.mode {
        odo_core::timing::SyncMode::Pps => 0,
        odo_core::timing::SyncMode::Free => 1,
    });
    b.push(match s.time_tag_pps {
        odo_core::timing::TimeTagPps::Previous => 0,
        odo_core::timing::TimeTagPps::Next => 1,
    });
    b.push(0);
    for v in [s.rate, s.output_divider, s.baud] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&s.max_wheel_speed.to_le_bytes());
    let g = &c.geometry_uncertainty;
    for v in [
        g.left_diameter_se,
        g.right_diameter_se,
        g.track_width_se,
        g.diameters_correlation,
        g.left_track_correlation,
        g.right_track_correlation,
        c.kappa_diff,
    ] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

#[test]
fn table_codec_is_the_documented_layout_byte_for_byte() {
    let mut s = variant(9);
    s.chassis.uncertainty_model = odo_core::odometry::UncertaintyModel::Covariance;
    s.chassis.right_wheel.sin[2] = -0.031;
    s.time_tag_pps = odo_core::timing::TimeTagPps::Next;
    s.mode = odo_core::timing::SyncMode::Pps;
    s.max_wheel_speed = 3.25;
    s.chassis.geometry_uncertainty = odo_core::odometry::GeometryUncertainty {
        left_diameter_se: 2.5e-5,
        right_diameter_se: 2.25e-5,
        track_width_se: 4.0e-4,
        diameters_correlation: 0.75,
        left_track_correlation: 0.5,
        right_track_correlation: 0.25,
    };
    s.chassis.kappa_diff = 3.5e-5;
    for s in [Settings::DEFAULT, variant(1), s] {
        assert_eq!(s.to_bytes().to_vec(), layout_v3_by_hand(&s));
        // Version 1 is its first 112 bytes.
        let without_se = Settings {
            chassis: odo_core::odometry::ChassisParams {
                geometry_uncertainty: odo_core::odometry::GeometryUncertainty::EXACT,
                kappa_diff: 0.0,
                ..s.chassis
            },
            ..s
        };
        let v1 = Settings::from_bytes_version(1, &layout_v3_by_hand(&s)[..112]).unwrap();
        assert_eq!(
            v1,
            Settings {
                max_wheel_speed: Settings::DEFAULT_MAX_WHEEL_SPEED,
                ..without_se
            }
        );
        // Version 2 is its first 116 bytes.
        let v2 = Settings::from_bytes_version(2, &layout_v3_by_hand(&s)[..116]).unwrap();
        assert_eq!(v2, without_se);
    }
    // The checksum of the defaults: over the 144 bytes of version 3 (firmware of version 2
    // reported the CRC of the first 116).
    assert_eq!(
        Settings::DEFAULT.checksum(),
        crc32(&layout_v3_by_hand(&Settings::DEFAULT))
    );
    // Every byte belongs to one key, but the reserved byte 99.
    let mut owner = [0u32; Settings::SERIALIZED_LEN];
    for k in Key::ALL {
        let r = k.info().record;
        for o in &mut owner[usize::from(r.offset)..][..k.info().kind.record_size()] {
            *o += 1;
        }
    }
    for (i, n) in owner.iter().enumerate() {
        assert_eq!(*n, u32::from(i != 99), "byte {i}");
    }
    assert_eq!(serialized_len(1), Settings::SERIALIZED_LEN_V1);
    assert_eq!(serialized_len(2), Settings::SERIALIZED_LEN_V2);
    assert_eq!(serialized_len(3), Settings::SERIALIZED_LEN);
}

/// docs/PROTOCOL.md's key table (section 4, "Keys and values") lists the table's keys in its
/// order, with the same type, unit and default.
#[test]
fn docs_list_the_table_keys() {
    let doc =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/PROTOCOL.md")).unwrap();
    let section = doc
        .split("### Keys and values")
        .nth(1)
        .unwrap()
        .split("\n## ")
        .next()
        .unwrap();
    let mut rows: Vec<(String, Vec<String>)> = Vec::new();
    for line in section.lines().filter(|l| l.starts_with("| ")) {
        let cells: Vec<String> = line
            .replace("\\|", "/")
            .trim_matches('|')
            .split('|')
            .map(|c| c.trim().to_string())
            .collect();
        if cells[0] == "key" || cells[0].starts_with("---") {
            continue;
        }
        // `left_cos1..3, left_sin1..3` stands for six keys.
        for name in cells[0].split(", ") {
            match name.strip_suffix("1..3") {
                Some(stem) => {
                    for n in 1..=3 {
                        rows.push((format!("{stem}{n}"), cells.clone()));
                    }
                }
                None => rows.push((name.to_string(), cells.clone())),
            }
        }
    }
    let names: Vec<&str> = rows.iter().map(|(n, _)| n.as_str()).collect();
    let keys: Vec<&str> = Key::ALL.iter().map(|k| k.name()).collect();
    // The docs group each wheel's cosines before its sines, as the table does.
    assert_eq!(names, keys);
    for ((_, cells), k) in rows.iter().zip(Key::ALL) {
        let info = k.info();
        let ty = match info.kind {
            Kind::F64 { .. } => "f64",
            Kind::F32 { .. } => "f32",
            Kind::U32 { .. } | Kind::U32Set(_) => "u32",
            Kind::Word(_) => "word",
        };
        assert_eq!(cells[1], ty, "{}", info.name);
        assert!(
            cells[2].starts_with(info.unit),
            "{}: {}",
            info.name,
            cells[2]
        );
        assert_eq!(
            parse_value(k, &cells[4]),
            Ok(Settings::DEFAULT.get(k)),
            "{}",
            info.name
        );
        assert!(!k.doc().is_empty());
    }
}

/// Errors are values naming the key: callers match on them instead of their text.
#[test]
fn errors_are_values_naming_the_key() {
    let mut s = Settings::DEFAULT;
    let cases: &[(Key, &str, SettingError)] = &[
        (Key::Rate, "abc", SettingError::BadNumber(Key::Rate)),
        (Key::Rate, "-1", SettingError::OutOfRange(Key::Rate)),
        (
            Key::TrackWidth,
            "nan",
            SettingError::NotFinite(Key::TrackWidth),
        ),
        (
            Key::TrackWidth,
            "1e999",
            SettingError::NotFinite(Key::TrackWidth),
        ),
        (
            Key::DeltaRight,
            "1e39",
            SettingError::OutOfRange(Key::DeltaRight),
        ),
        (Key::Mode, "gps", SettingError::BadChoice(Key::Mode)),
        (Key::Baud, "1000", SettingError::OutOfRange(Key::Baud)),
    ];
    for (k, text, e) in cases {
        assert_eq!(s.set(*k, text), Err(*e), "{} {text}", k.name());
        assert_eq!(e.key(), Some(*k));
        assert_eq!(
            parse_value(*k, text).and_then(|v| check_value(*k, v)),
            Err(*e)
        );
    }
    assert_eq!(s, Settings::DEFAULT);
    let relation = |pairs: &[(&'static str, &'static str)]| {
        let mut t = Settings::DEFAULT;
        match t.set_many(pairs.iter().copied()) {
            Err(SetManyError::Value(e)) => e,
            r => panic!("{pairs:?}: {r:?}"),
        }
    };
    assert_eq!(
        relation(&[("ticks_per_rev", "100")]),
        SettingError::Chassis(Key::TicksPerRev)
    );
    assert_eq!(
        relation(&[("mode", "pps"), ("rate", "7")]),
        SettingError::PpsRate
    );
    assert_eq!(relation(&[("rate", "1000")]), SettingError::RecordsOverBaud);
    assert!(matches!(
        relation(&[("rate", "1")]),
        SettingError::CountsPerSample { counts: 48_971 }
    ));
    assert_eq!(
        Settings::from_bytes_version(4, &Settings::DEFAULT.to_bytes()),
        Err(SettingError::UnknownFormatVersion(4))
    );
    assert_eq!(
        relation(&[
            ("diameters_correlation", "0.9"),
            ("left_track_correlation", "0.9"),
        ]),
        SettingError::Correlations
    );
    assert_eq!(
        Settings::from_bytes(&[0; 143]),
        Err(SettingError::BadRecord)
    );
    // Chassis parameters alone, as odoctl checks them.
    let mut c = ChassisParams::DESIGNED;
    assert_eq!(validate_chassis(&c), Ok(()));
    c.left_wheel.sin[1] = 0.06;
    assert_eq!(
        validate_chassis(&c),
        Err(SettingError::OutOfRange(Key::LeftSin2))
    );
    // The default of every key is in its range, and the table's defaults validate.
    for k in Key::ALL {
        check_value(k, Settings::DEFAULT.get(k)).unwrap();
    }
}
