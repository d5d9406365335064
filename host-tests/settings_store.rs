//! The settings flash store (`odo_unit::settings::store`): defaults from empty or garbage
//! flash, the A/B sectors' alternation, fallback past damaged records, generations (with
//! wrap-around), and a power cut at every erase/program step of two saves.

use odo_unit::settings::store::{encode_record, Flash, SettingsStore, SLOT_LEN};
use odo_unit::settings::*;

mod support;
use support::settings::{load, variant, SimFlash};

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

/// A valid record of generation 0xFFFF_FFFF made the next save write
/// generation 1, which verified, but every later load returned the old record. Generations
/// are ordered with wrap-around (serial-number arithmetic); go across the wrap through both
/// sectors.
#[test]
fn generation_wraps_around() {
    use odo_unit::settings::store::generation_is_newer;
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

/// Records of another origin (or damaged flash): valid CRCs, generations anywhere on the
/// circle, usable or not, in any slots of both sectors.
fn foreign_flash(records: &[(usize, usize, u32, bool)], slots: usize) -> SimFlash {
    let mut f = SimFlash::new(slots * SLOT_LEN);
    for (i, &(sector, slot, generation, usable)) in records.iter().enumerate() {
        let mut s = variant(50 + i as u32);
        if !usable {
            s.rate = 0; // well formed, but refused on loading
        }
        let at = (slot % slots) * SLOT_LEN;
        if f.mem[sector][at..at + SLOT_LEN].iter().all(|&b| b == 0xFF) {
            f.program(sector, at, &encode_record(&s, generation))
                .unwrap();
        }
    }
    f
}

/// The newest of `gens` as the store orders them: the serial-number maximum when every
/// generation lies within 2^31 - 1 behind one of them, else the highest.
fn newest(gens: &[u32]) -> u32 {
    use odo_unit::settings::store::generation_is_newer;
    gens.iter()
        .copied()
        .find(|&g| gens.iter().all(|&h| h == g || generation_is_newer(g, h)))
        .unwrap_or_else(|| gens.iter().copied().max().unwrap())
}

/// Generations more than 2^31 apart (three spread around the circle, two exactly 2^31
/// apart): loading takes the highest, and a save that returns Ok loads back with the
/// generation it returned, after clearing the records that would outrank it.
#[test]
fn generations_more_than_half_the_circle_apart() {
    let third = 0x5555_5555u32;
    for gens in [
        vec![1, 1 + third, 1 + 2 * third],
        vec![0x8000_0000, 0],
        vec![0xFFFF_FFFF, 0x7FFF_FFFF],
        vec![5, 0x8000_0005, 0xC000_0000, 0x4000_0000],
    ] {
        for sectors in [[0, 1, 0, 1], [1, 0, 0, 1], [0, 0, 1, 1]] {
            let records: Vec<_> = gens
                .iter()
                .enumerate()
                .map(|(i, &g)| (sectors[i], i, g, true))
                .collect();
            let f = foreign_flash(&records, 3);
            let max = *gens.iter().max().unwrap();
            assert_eq!(load(&f).2, max, "{gens:x?} in sectors {sectors:?}");
            assert_eq!(newest(&gens), max);
            let mut store = SettingsStore::new(f);
            assert!(store.next_save_erases().unwrap(), "it clears");
            let g = store.save(&variant(7)).expect("save");
            assert_eq!(load(store.flash()), (variant(7), SettingsSource::Flash, g));
            // From then on, ordinary saves.
            let g2 = store.save(&variant(8)).expect("save");
            assert_eq!(g2, g.wrapping_add(1).max(1));
            assert_eq!(load(store.flash()), (variant(8), SettingsSource::Flash, g2));
            assert_eq!(store.into_inner().violations, 0);
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(2_000))]

    /// Any records with valid CRCs (generations anywhere, usable or not, in any slots):
    /// loading takes the newest usable one (serial order when the generations allow one,
    /// else the highest), whatever the slots, and every save that returns Ok loads back
    /// with the generation it returned, newer than the one loaded before it.
    #[test]
    fn any_generations_load_the_newest_and_saves_load_back(
        records in proptest::collection::vec(
            (0usize..2, 0usize..3, proptest::prelude::any::<u32>(), proptest::prelude::any::<bool>()),
            0..6,
        ),
        near in proptest::prelude::any::<bool>(),
    ) {
        // Half the cases close to the wrap or to each other, where the orders differ.
        let records: Vec<_> = records
            .into_iter()
            .map(|(s, slot, g, usable)| (s, slot, if near { (g % 8).wrapping_add(u32::MAX - 3) } else { g }, usable))
            .collect();
        let f = foreign_flash(&records, 3);
        // The records as written (a slot taken twice keeps the first).
        let mut written: Vec<(u32, bool)> = Vec::new();
        let mut taken = std::collections::HashSet::new();
        for &(sector, slot, g, usable) in &records {
            if taken.insert((sector, slot)) {
                written.push((g, usable));
            }
        }
        let gens: Vec<u32> = written.iter().map(|w| w.0).collect();
        let usable: Vec<u32> = written.iter().filter(|w| w.1).map(|w| w.0).collect();
        let (_, source, generation) = load(&f);
        if usable.is_empty() {
            proptest::prop_assert_eq!(source, SettingsSource::Defaults);
        } else {
            // The order of all valid records decides; the newest usable one in it is loaded.
            let top = newest(&gens);
            let pick = if gens.iter().all(|&h| h == top || odo_unit::settings::store::generation_is_newer(top, h)) {
                // Serial order: the usable one with the least distance behind `top`.
                *usable.iter().min_by_key(|&&g| top.wrapping_sub(g)).unwrap()
            } else {
                *usable.iter().max().unwrap()
            };
            proptest::prop_assert_eq!((source, generation), (SettingsSource::Flash, pick), "{:x?}", written);
        }
        let mut store = SettingsStore::new(f);
        for i in 0..4 {
            let before = load(store.flash());
            let g = store.save(&variant(i)).expect("save");
            proptest::prop_assert_eq!(load(store.flash()), (variant(i), SettingsSource::Flash, g));
            if before.1 == SettingsSource::Flash {
                proptest::prop_assert!(
                    odo_unit::settings::store::generation_is_newer(g, before.2),
                    "{:#x} after {:#x}", g, before.2
                );
            }
        }
        proptest::prop_assert_eq!(store.into_inner().violations, 0);
    }
}
