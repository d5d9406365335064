//! The settings store under power cuts: from a flash holding up to four records of any
//! generations (the wrap included, and generations more than 2^31 apart, as foreign or
//! damaged flash has them), usable or not, a sequence of saves, each cut at any step with any
//! partial bits, then finished after the reboot.
//!
//! Oracles: no panic; a save that returns Ok loads back bit for bit with the generation it
//! returned, newer than the one loaded before; after a cut the store loads the previous
//! settings or the new ones, from flash once anything was saved (on flash whose records this
//! store could have written: generations within 2^31 of the newest); no word is programmed
//! twice.
#![no_main]

use libfuzzer_sys::fuzz_target;
use odo_unit::settings::store::{encode_record, generation_is_newer, SettingsStore, SLOT_LEN};
use odo_unit::settings::{Settings, SettingsSource};
use odo_fuzz::CutFlash;

/// Distinct valid settings.
fn variant(i: u8) -> Settings {
    let mut s = Settings::DEFAULT;
    s.chassis.track_width = 0.5 + f64::from(i) * 1e-3;
    s.chassis.left_wheel.cos[0] = f32::from(i % 7) * 1e-3;
    s
}

fn load(flash: &CutFlash) -> (Vec<u8>, SettingsSource, u32) {
    let l = SettingsStore::new(flash.clone()).load().expect("load");
    (l.settings.to_bytes().to_vec(), l.source, l.generation)
}

/// Whether records of generations `gens` are in the order this store keeps: one of them
/// newest in serial order, and the one after it newer than all.
fn in_order(gens: &[u32]) -> bool {
    let Some(&top) = gens
        .iter()
        .find(|&&g| gens.iter().all(|&h| h == g || generation_is_newer(g, h)))
    else {
        return gens.is_empty();
    };
    let next = top.wrapping_add(1).max(1);
    gens.iter().all(|&h| generation_is_newer(next, h))
}

fuzz_target!(|data: &[u8]| {
    let Some((head, rest)) = data.split_first_chunk::<2>() else {
        return;
    };
    let slots = usize::from(head[0] % 4) + 1;
    let seeded = usize::from(head[1] % 5);
    let Some((seeds, ops)) = rest.split_at_checked(seeded * 6) else {
        return;
    };
    let mut flash = CutFlash::new(slots);
    let mut gens = Vec::new();
    for seed in seeds.chunks_exact(6) {
        let sector = usize::from(seed[0] & 1);
        let at = usize::from(seed[0] >> 1 & 3) % slots * SLOT_LEN;
        let generation = u32::from_le_bytes([seed[1], seed[2], seed[3], seed[4]]);
        let mut s = variant(seed[5]);
        if seed[0] & 0x80 != 0 {
            s.rate = 0; // well formed, refused on loading
        }
        let slot = &mut flash.mem[sector][at..at + SLOT_LEN];
        if slot.iter().all(|&b| b == 0xFF) {
            let record = encode_record(&s, generation);
            slot[..record.len()].copy_from_slice(&record);
            gens.push(generation);
        }
    }
    // Power-cut safety is promised for flash this store could have written.
    let mut ours = in_order(&gens);
    let mut now = load(&flash);
    for op in ops.chunks_exact(4) {
        let new = variant(op[0]);
        let cut = u32::from(u16::from_le_bytes([op[1], op[2]]));
        let noise = u32::from(op[3]).wrapping_mul(0x0101_0101) ^ cut.rotate_left(11);
        flash.arm(cut, noise);
        let result = SettingsStore::new(&mut flash).save(&new);
        flash.revive();
        let after = load(&flash);
        let is_new = after.0 == new.to_bytes() && after.1 == SettingsSource::Flash;
        match result {
            Ok(generation) => {
                assert!(is_new, "saved but loads {after:?}");
                assert_eq!(after.2, generation);
                if now.1 == SettingsSource::Flash {
                    assert!(
                        generation_is_newer(generation, now.2),
                        "{now:?} -> {after:?}"
                    );
                }
                ours = true;
            }
            Err(_) if ours => {
                assert!(after == now || is_new, "cut at {cut}: {now:?} -> {after:?}");
                if now.1 == SettingsSource::Flash {
                    assert_eq!(after.1, SettingsSource::Flash);
                }
            }
            Err(_) => {}
        }
        assert_eq!(flash.violations, 0, "a word programmed twice");
        now = after;
    }
});
