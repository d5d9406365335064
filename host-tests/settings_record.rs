//! The settings record (`odo_unit::settings::record`): the codec against the layout
//! docs/PROTOCOL.md documents, byte for byte, and the flash records of every format version
//! (v1, v2 and v3 records written by older firmware still load; damaged or mislabelled ones are
//! refused).

use odo_unit::crc::crc32;
use odo_unit::settings::store::{
    encode_record, Flash, SettingsStore, MAGIC, RECORD_LEN, SLOT_LEN, WORD,
};
use odo_unit::settings::*;

mod support;
use support::settings::{load, variant, SimFlash};

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
        "version 6 needs 160 bytes"
    );
    assert!(
        Settings::from_bytes(&b[..156]).is_err(),
        "version 6 needs 160 bytes"
    );
    assert!(Settings::from_bytes_version(7, &b).is_err());
    assert!(Settings::from_bytes_version(0, &b).is_err());
}

/// A record exactly as the firmware of format `version` wrote it: magic, version, payload
/// length, generation, the first `payload` bytes of today's payload, CRC; `len` bytes.
fn old_record(
    settings: &Settings,
    generation: u32,
    version: u16,
    payload: usize,
    len: usize,
) -> Vec<u8> {
    let mut r = Vec::new();
    r.extend_from_slice(&MAGIC.to_le_bytes());
    r.extend_from_slice(&version.to_le_bytes());
    r.extend_from_slice(&(payload as u16).to_le_bytes());
    r.extend_from_slice(&generation.to_le_bytes());
    r.extend_from_slice(&settings.to_bytes()[..payload]);
    let crc = crc32(&r);
    r.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(r.len(), len);
    r
}

/// Format version 1: 112-byte payload (the version 2 payload without its last 4 bytes), CRC
/// at 124, 128 bytes.
fn v1_record(settings: &Settings, generation: u32) -> Vec<u8> {
    assert_eq!(Settings::SERIALIZED_LEN_V1, 112);
    old_record(settings, generation, 1, Settings::SERIALIZED_LEN_V1, 128)
}

/// Format version 2: 116-byte payload (the version 3 payload without the geometry's standard
/// errors), CRC at 128, 132 bytes.
fn v2_record(settings: &Settings, generation: u32) -> Vec<u8> {
    assert_eq!(Settings::SERIALIZED_LEN_V2, 116);
    old_record(settings, generation, 2, Settings::SERIALIZED_LEN_V2, 132)
}

/// Format version 3: 144-byte payload (the version 4 payload without `kappa_diff_corr`), CRC
/// at 156, 160 bytes.
fn v3_record(settings: &Settings, generation: u32) -> Vec<u8> {
    assert_eq!(Settings::SERIALIZED_LEN_V3, 144);
    old_record(settings, generation, 3, Settings::SERIALIZED_LEN_V3, 160)
}

#[test]
fn record_layout_of_format_version_6() {
    let r = encode_record(&variant(4), 9);
    assert_eq!(RECORD_LEN, 176);
    assert_eq!(r.len(), RECORD_LEN);
    assert_eq!(RECORD_LEN % WORD, 0);
    assert_eq!(&r[4..8], &[6, 0, 160, 0]);
    assert_eq!(&r[12..172], &variant(4).to_bytes());
    assert_eq!(&r[172..176], &crc32(&r[..172]).to_le_bytes());
    // The v1 record is the same bytes up to the payload's end, but its own header and CRC.
    let old = v1_record(&variant(4), 9);
    assert_eq!(&old[12..124], &r[12..124]);
}

/// An old record at the start of `f`, of generation `generation`, loads as `expect`; the next
/// save of `new` writes version 6 after it (payload 160) with the next generation and wins;
/// with that record damaged the old one is the fallback again; no used word is programmed.
fn assert_upgrades(f: &mut SimFlash, generation: u32, expect: Settings, new: &Settings) {
    assert_eq!(load(f), (expect, SettingsSource::Flash, generation));
    let mut store = SettingsStore::new(&mut *f);
    assert_eq!(store.save(new).unwrap(), generation + 1);
    assert_eq!(load(f), (*new, SettingsSource::Flash, generation + 1));
    assert_eq!(&f.mem[0][SLOT_LEN + 4..SLOT_LEN + 8], &[6, 0, 160, 0]);
    f.mem[0][SLOT_LEN + 20] ^= 0x10;
    assert_eq!(load(f), (expect, SettingsSource::Flash, generation));
    assert_eq!(f.violations, 0);
}

#[test]
fn format_version_1_record_loads_with_the_default_max_wheel_speed() {
    let mut old = variant(3);
    old.rate = 60;
    // Whatever the in-memory value, a v1 record cannot carry it.
    old.max_wheel_speed = 7.0;
    let mut f = SimFlash::new(4 * SLOT_LEN);
    f.program(0, 0, &v1_record(&old, 41)).unwrap();
    let expect = Settings {
        max_wheel_speed: Settings::DEFAULT_MAX_WHEEL_SPEED,
        ..old
    };
    assert_eq!(
        Settings::from_bytes_version(1, &old.to_bytes()[..112]).unwrap(),
        expect
    );
    assert_upgrades(&mut f, 41, expect, &variant(5));
}

#[test]
fn format_version_2_record_loads_with_an_exact_geometry() {
    let mut old = variant(3);
    old.chassis.geometry_uncertainty.track_width_se = 5e-4;
    old.chassis.kappa_diff = 2e-5;
    old.chassis.kappa_diff_corr = 2.0;
    let mut f = SimFlash::new(4 * SLOT_LEN);
    f.program(0, 0, &v2_record(&old, 7)).unwrap();
    let expect = Settings {
        chassis: odo_unit::odometry::ChassisParams {
            geometry_uncertainty: odo_unit::odometry::GeometryUncertainty::EXACT,
            kappa_diff: 0.0,
            kappa_diff_corr: 0.0,
            ..old.chassis
        },
        ..old
    };
    assert_upgrades(&mut f, 7, expect, &old);
}

#[test]
fn format_version_3_record_loads_with_white_turning_slip() {
    let mut old = variant(3);
    old.chassis.geometry_uncertainty.track_width_se = 5e-4;
    old.chassis.kappa_diff = 2e-5;
    // Whatever the in-memory value, a v3 record cannot carry it.
    old.chassis.kappa_diff_corr = 1.5;
    let mut f = SimFlash::new(4 * SLOT_LEN);
    f.program(0, 0, &v3_record(&old, 12)).unwrap();
    let expect = Settings {
        chassis: odo_unit::odometry::ChassisParams {
            kappa_diff_corr: 0.0,
            ..old.chassis
        },
        ..old
    };
    assert_eq!(
        Settings::from_bytes_version(3, &old.to_bytes()[..144]).unwrap(),
        expect
    );
    assert!(Settings::from_bytes_version(3, &old.to_bytes()[..143]).is_err());
    assert_upgrades(&mut f, 12, expect, &old);
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
        ("v3 header on a v1 record", {
            let mut r = good.clone();
            r[4] = 3;
            let crc = crc32(&r[..124]);
            r[124..128].copy_from_slice(&crc.to_le_bytes());
            r
        }),
        ("unknown version 5", {
            let mut r = good.clone();
            r[4] = 5;
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

/// The version 6 layout written field by field as docs/PROTOCOL.md section 5 lists it (the
/// encoder before the key table): the table's codec must give the same bytes.
fn layout_v6_by_hand(s: &Settings) -> Vec<u8> {
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
        odo_unit::odometry::UncertaintyModel::Paper => 0,
        odo_unit::odometry::UncertaintyModel::Covariance => 1,
    });
    b.push(match s.mode {
        odo_unit::timing::SyncMode::Pps => 0,
        odo_unit::timing::SyncMode::Free => 1,
    });
    b.push(match s.time_tag_pps {
        odo_unit::timing::TimeTagPps::Previous => 0,
        odo_unit::timing::TimeTagPps::Next => 1,
    });
    b.push(match s.output {
        odo_unit::settings::Output::Frames => 0,
        odo_unit::settings::Output::Mavlink => 1,
    });
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
        c.kappa_diff_corr,
    ] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    for v in [s.mavlink_sysid, s.mavlink_compid, s.gnss_baud] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

#[test]
fn table_codec_is_the_documented_layout_byte_for_byte() {
    let mut s = variant(9);
    s.chassis.uncertainty_model = odo_unit::odometry::UncertaintyModel::Covariance;
    s.chassis.right_wheel.sin[2] = -0.031;
    s.time_tag_pps = odo_unit::timing::TimeTagPps::Next;
    s.mode = odo_unit::timing::SyncMode::Pps;
    s.max_wheel_speed = 3.25;
    s.chassis.geometry_uncertainty = odo_unit::odometry::GeometryUncertainty {
        left_diameter_se: 2.5e-5,
        right_diameter_se: 2.25e-5,
        track_width_se: 4.0e-4,
        diameters_correlation: 0.75,
        left_track_correlation: 0.5,
        right_track_correlation: 0.25,
    };
    s.chassis.kappa_diff = 3.5e-5;
    s.chassis.kappa_diff_corr = 2.25;
    s.gnss_baud = 230_400;
    for s in [Settings::DEFAULT, variant(1), s] {
        assert_eq!(s.to_bytes().to_vec(), layout_v6_by_hand(&s));
        // Version 1 is its first 112 bytes.
        let without_se = Settings {
            chassis: odo_unit::odometry::ChassisParams {
                geometry_uncertainty: odo_unit::odometry::GeometryUncertainty::EXACT,
                kappa_diff: 0.0,
                kappa_diff_corr: 0.0,
                ..s.chassis
            },
            gnss_baud: 38_400,
            ..s
        };
        let v1 = Settings::from_bytes_version(1, &layout_v6_by_hand(&s)[..112]).unwrap();
        assert_eq!(
            v1,
            Settings {
                max_wheel_speed: Settings::DEFAULT_MAX_WHEEL_SPEED,
                ..without_se
            }
        );
        // Version 2 is its first 116 bytes.
        let v2 = Settings::from_bytes_version(2, &layout_v6_by_hand(&s)[..116]).unwrap();
        assert_eq!(v2, without_se);
        // Version 4 is its first 148 bytes, with 0 (`frames`) in byte 99.
        let mut v4_bytes = layout_v6_by_hand(&s)[..148].to_vec();
        v4_bytes[99] = 0;
        let v4 = Settings::from_bytes_version(4, &v4_bytes).unwrap();
        assert_eq!(
            v4,
            Settings {
                output: odo_unit::settings::Output::Frames,
                mavlink_sysid: 1,
                mavlink_compid: 197,
                gnss_baud: 38_400,
                ..s
            }
        );
        // Version 5 is its first 156 bytes.
        let v5 = Settings::from_bytes_version(5, &layout_v6_by_hand(&s)[..156]).unwrap();
        assert_eq!(
            v5,
            Settings {
                gnss_baud: 38_400,
                ..s
            }
        );
        // Version 3 is its first 144 bytes.
        let v3 = Settings::from_bytes_version(3, &layout_v6_by_hand(&s)[..144]).unwrap();
        assert_eq!(
            v3,
            Settings {
                chassis: odo_unit::odometry::ChassisParams {
                    kappa_diff_corr: 0.0,
                    ..s.chassis
                },
                gnss_baud: 38_400,
                ..s
            }
        );
    }
    // The checksum of the defaults: over the 160 bytes of version 6 (firmware of version 5
    // reported the CRC of the first 156, of version 4
    // reported the CRC of the first 148, of version 3 of the first 144, of version 2 of the
    // first 116).
    assert_eq!(
        Settings::DEFAULT.checksum(),
        crc32(&layout_v6_by_hand(&Settings::DEFAULT))
    );
    // Every byte belongs to one key (byte 99, reserved before version 5, to `output`).
    let mut owner = [0u32; Settings::SERIALIZED_LEN];
    for k in Key::ALL {
        let r = k.info().record;
        for o in &mut owner[usize::from(r.offset)..][..k.info().kind.record_size()] {
            *o += 1;
        }
    }
    for (i, n) in owner.iter().enumerate() {
        assert_eq!(*n, 1, "byte {i}");
    }
    assert_eq!(serialized_len(1), Settings::SERIALIZED_LEN_V1);
    assert_eq!(serialized_len(2), Settings::SERIALIZED_LEN_V2);
    assert_eq!(serialized_len(3), Settings::SERIALIZED_LEN_V3);
    assert_eq!(serialized_len(4), Settings::SERIALIZED_LEN_V4);
    assert_eq!(serialized_len(5), Settings::SERIALIZED_LEN_V5);
    assert_eq!(serialized_len(6), Settings::SERIALIZED_LEN);
}
