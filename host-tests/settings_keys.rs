//! The settings key table (`odo_unit::settings::keys`): key access and text round trips,
//! boundary tables, error values and messages, atomic multi-key changes, and the table
//! against docs/PROTOCOL.md's list of keys.

use odo_unit::odometry::ChassisParams;
use odo_unit::settings::*;
use proptest::prelude::*;

mod support;
use support::settings::variant;

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
        ("kappa_diff_corr", "0", true),
        ("kappa_diff_corr", "0.0005", true), // below 1 mm: white, its limit
        ("kappa_diff_corr", "2", true),
        ("kappa_diff_corr", "1000", true),
        ("kappa_diff_corr", "1000.001", false),
        ("kappa_diff_corr", "-1e-9", false),
        ("kappa_diff_corr", "nan", false),
        ("kappa_diff_corr", "inf", false),
        ("kappa_diff_corr", "2 m", false),
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
        ("rate", "60", true),
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
    let m = msg(s.set_many([("kappa_diff_corr", "-1")]));
    assert!(m.contains("kappa_diff_corr: out of range, 0..=1000"), "{m}");
    assert!(msg(s.set_many([("baud", "1")])).contains("out of range, 9600|19200"));
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
    s.set_many([("rate", "1000"), ("output_divider", "20")])
        .unwrap();
    assert_eq!((s.rate, s.output_divider), (1000, 20));
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
    // 57600 baud only with a low output rate.
    assert!(s.set_many([("baud", "57600")]).is_err());
    s.set_many([("baud", "57600"), ("output_divider", "5")])
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
    let pairs = |rate| {
        [
            ("ticks_per_rev", "1048576"),
            ("rate", rate),
            ("output_divider", "2"),
        ]
    };
    assert!(s.set_many(pairs("78")).is_err());
    s.set_many(pairs("79")).unwrap();
    // The fastest rate, with a divider for the link.
    let mut s = Settings::DEFAULT;
    s.set_many([("rate", "1000"), ("output_divider", "20"), ("mode", "pps")])
        .unwrap();
    assert!(s.set_many([("rate", "1001"), ("mode", "free")]).is_err());
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
        Settings::from_bytes_version(7, &Settings::DEFAULT.to_bytes()),
        Err(SettingError::UnknownFormatVersion(7))
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
