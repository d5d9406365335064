//! The settings store under power cuts: from a flash holding one record of any generation
//! (the wrap included), a sequence of saves, each cut at any step with any partial bits,
//! then finished after the reboot.
//!
//! Oracles: no panic; after a cut the store loads the previous settings or the new ones,
//! from flash once anything was saved; a save that returns Ok loads back bit for bit with
//! the generation it returned, newer than the one before; no word is programmed twice.
#![no_main]

use libfuzzer_sys::fuzz_target;
use odo_core::settings::store::{encode_record, generation_is_newer, SettingsStore};
use odo_core::settings::{Settings, SettingsSource};
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

fuzz_target!(|data: &[u8]| {
    let Some((head, ops)) = data.split_first_chunk::<6>() else {
        return;
    };
    let slots = usize::from(head[0] % 4) + 1;
    let mut flash = CutFlash::new(slots);
    if head[1] & 1 == 1 {
        let generation = u32::from_le_bytes([head[2], head[3], head[4], head[5]]);
        let sector = usize::from(head[1] >> 1 & 1);
        flash.mem[sector][..odo_core::settings::store::RECORD_LEN]
            .copy_from_slice(&encode_record(&variant(0), generation));
    }
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
            }
            Err(_) => {
                assert!(after == now || is_new, "cut at {cut}: {now:?} -> {after:?}");
                if now.1 == SettingsSource::Flash {
                    assert_eq!(after.1, SettingsSource::Flash);
                }
            }
        }
        assert_eq!(flash.violations, 0, "a word programmed twice");
        now = after;
    }
});
