//! The command console with the settings: bytes from the host link through the line
//! assembler into `execute`, saves going to a flash store.
//!
//! Oracles: no panic; a reply starts with `ok` or `error: ` and fits [`MAX_REPLY`]; an error
//! changes nothing; `SettingsChanged` exactly when the stored bytes changed; the working
//! settings always validate; a `reset_pose` pose is inside the integrator's range; a save
//! loads back bit for bit; every key's `get` text is a plain decimal (never an exponent) and
//! set back is no change (exact text form); an integer of any size beyond a key's range is
//! out of range, not a bad number.
#![no_main]

use libfuzzer_sys::fuzz_target;
use odo_unit::console::{execute, Action, LineAssembler, MAX_REPLY};
use odo_unit::odometry::Pose;
use odo_unit::settings::store::SettingsStore;
use odo_unit::settings::{Key, Kind, Settings};
use odo_fuzz::CutFlash;

fuzz_target!(|data: &[u8]| {
    let mut settings = Settings::DEFAULT;
    let mut store = SettingsStore::new(CutFlash::new(2));
    let mut lines = LineAssembler::new();
    for &b in data {
        let Some(Ok(line)) = lines.push(b) else {
            continue;
        };
        let line = line.to_owned();
        let before = settings;
        let (reply, action) = execute(&line, &mut settings);
        assert!(reply.text.len() <= MAX_REPLY);
        let head = if reply.ok { "ok" } else { "error: " };
        assert!(reply.text.starts_with(head), "{line:?}: {}", reply.text);
        let changed = settings.to_bytes() != before.to_bytes();
        if !reply.ok {
            assert_eq!(action, Action::None, "{line:?}");
        }
        assert_eq!(
            changed,
            action == Action::SettingsChanged,
            "{line:?}: {action:?}"
        );
        assert!(settings.validate().is_ok(), "{line:?}");
        match action {
            Action::ResetPose { x, y, heading } => {
                assert!(Pose { x, y, heading }.check_range().is_ok(), "{line:?}");
            }
            Action::Save => {
                store.save(&settings).expect("valid settings save");
                let loaded = store.load().expect("load").settings;
                assert_eq!(loaded.to_bytes(), settings.to_bytes(), "{line:?}");
            }
            _ => {}
        }
    }
    for k in Key::ALL {
        let value = settings.get(k).to_string();
        let word = value.bytes().all(|b| b.is_ascii_lowercase());
        assert!(word || !value.contains(['e', 'E']), "{}: {value}", k.name());
        let line = format!("set {} {value}", k.name());
        let (reply, action) = execute(&line, &mut settings);
        assert!(reply.ok, "{line:?}: {}", reply.text);
        assert_eq!(action, Action::None, "{line:?}: the text form is not exact");
        if matches!(k.kind(), Kind::U32 { .. } | Kind::U32Set(_)) {
            for digits in [
                "99999999999999999999",
                "-99999999999999999999",
                "4294967296",
            ] {
                let line = format!("set {} {digits}", k.name());
                let (reply, _) = execute(&line, &mut settings);
                assert!(
                    reply.text.contains("out of range"),
                    "{line:?}: {}",
                    reply.text
                );
            }
        }
    }
});
