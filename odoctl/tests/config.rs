//! The settings key table across the unit and odoctl: the unit's `get` text, odoctl's TOML
//! and its `config push` lines carry every key bit for bit, and both sides know the same
//! keys.

use odo_unit::console::{execute, LineAssembler, MAX_LINE, MAX_SET_PAIRS};
use odo_unit::settings::{Key, Kind, Settings, Value};
use odo_unit::timing::{SyncMode, TimeTagPps};
use odoctl::config::{self, ConfigError};

/// xorshift64*: deterministic test values.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in `lo..=hi` (f64, full mantissa).
    fn f64_in(&mut self, lo: f64, hi: f64) -> f64 {
        (lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64).clamp(lo, hi)
    }
    /// Any f32 bit pattern from 0 to `max` (so every exponent, subnormals included), with a
    /// random sign when `signed`.
    fn f32_bits_to(&mut self, max: f32, signed: bool) -> f32 {
        let v = f32::from_bits((self.next() % (u64::from(max.to_bits()) + 1)) as u32);
        if signed && self.next() & 1 == 1 {
            -v
        } else {
            v
        }
    }
}

/// Valid settings in which every key differs from its default, with awkward values: f64
/// with full mantissas, f32 of any exponent down to subnormals, negative zero.
fn every_key_changed(rng: &mut Rng) -> Settings {
    let mut s = Settings::DEFAULT;
    let c = &mut s.chassis;
    c.left_diameter = rng.f64_in(0.2, 0.4);
    c.right_diameter = rng.f64_in(0.2, 0.4);
    c.track_width = rng.f64_in(0.4, 0.8);
    c.ticks_per_rev = 1_000 + (rng.next() % 39_000) as u32;
    c.delta_left = rng.f32_bits_to(1e-3, false);
    c.delta_right = rng.f32_bits_to(1e-3, false);
    c.delta_diff = rng.f32_bits_to(1e-3, false).max(f32::from_bits(1));
    c.uncertainty_model = odo_unit::odometry::UncertaintyModel::Covariance;
    c.kappa_left = rng.f32_bits_to(1e-2, false);
    c.kappa_right = rng.f32_bits_to(1e-2, false);
    c.kappa_diff = rng.f32_bits_to(1e-2, false).max(f32::from_bits(1));
    c.kappa_diff_corr = rng.f32_bits_to(1e3, false).max(f32::from_bits(1));
    let g = &mut c.geometry_uncertainty;
    for v in [
        &mut g.left_diameter_se,
        &mut g.right_diameter_se,
        &mut g.track_width_se,
    ] {
        *v = rng.f32_bits_to(0.01, false).max(f32::from_bits(1));
    }
    // Correlations of at most 0.4 in magnitude always form a valid correlation matrix.
    for v in [
        &mut g.diameters_correlation,
        &mut g.left_track_correlation,
        &mut g.right_track_correlation,
    ] {
        *v = rng.f32_bits_to(0.4, true);
        if *v == 0.0 {
            *v = -0.0;
        }
    }
    for wheel in [&mut c.left_wheel, &mut c.right_wheel] {
        for v in wheel.cos.iter_mut().chain(wheel.sin.iter_mut()) {
            *v = rng.f32_bits_to(0.05, true);
            if *v == 0.0 {
                *v = -0.0; // differs from the default +0 in its bits
            }
        }
    }
    s.mode = SyncMode::Pps;
    s.rate = [100, 125, 200, 250, 400, 500, 1000][(rng.next() % 7) as usize];
    // At least 3: at 1000 Hz the MAVLink output carries at most 374 frames a second at
    // 921,600 baud.
    s.output_divider = 3 + (rng.next() % 9_998) as u32;
    s.time_tag_pps = TimeTagPps::Next;
    s.baud = 921_600;
    s.max_wheel_speed = rng.f32_bits_to(20.0, false).max(0.01);
    s.output = odo_unit::settings::Output::Mavlink;
    s.mavlink_sysid = 2 + (rng.next() % 254) as u32;
    s.mavlink_compid = 1 + (rng.next() % 196) as u32;
    s.gnss_baud = 230_400;
    s.validate().expect("valid test settings");
    s
}

fn bits(v: Value) -> (u64, String) {
    match v {
        Value::F64(x) => (x.to_bits(), String::new()),
        Value::F32(x) => (u64::from(x.to_bits()), String::new()),
        Value::U32(x) => (u64::from(x), String::new()),
        Value::Word(w) => (0, w.to_string()),
    }
}

/// unit text (`get`) -> TOML -> `config push` lines -> unit settings, bit for bit, for every
/// key, over many random settings.
#[test]
fn every_key_round_trips_unit_text_toml_push_unit() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    for case in 0..500 {
        let mut unit = every_key_changed(&mut rng);
        for k in Key::ALL {
            assert_ne!(
                bits(unit.get(k)),
                bits(Settings::DEFAULT.get(k)),
                "case {case}: {} keeps its default",
                k.name()
            );
        }
        let original = unit;
        // The unit's text.
        let (reply, _) = execute("get", &mut unit);
        assert!(reply.ok, "{}", reply.text);
        // -> TOML.
        let (pulled, keys) = config::parse_get_reply(&reply.text).unwrap();
        assert_eq!(keys, Key::ALL);
        let toml = config::render_settings(&pulled, &keys, "pulled from the unit");
        // -> `config push` lines.
        let lines = config::push_lines_of("unit.toml", &toml).unwrap();
        // -> another unit, through its line assembler: every line within its limits.
        let mut other = Settings::DEFAULT;
        let mut assembler = LineAssembler::new();
        for line in &lines {
            assert!(
                line.len() <= MAX_LINE,
                "case {case}: {} bytes: {line}",
                line.len()
            );
            assert!(line.split_whitespace().count() <= 1 + 2 * MAX_SET_PAIRS);
            let mut got = None;
            for &b in line.as_bytes().iter().chain(b"\n") {
                if let Some(r) = assembler.push(b) {
                    got = Some(r.map(str::to_string));
                }
            }
            let received = got.expect("a line").expect("within the unit's line");
            let (r, _) = execute(&received, &mut other);
            assert!(r.ok, "case {case}: {line}: {}", r.text);
        }
        for k in Key::ALL {
            assert_eq!(
                bits(other.get(k)),
                bits(original.get(k)),
                "case {case}: {} through\n{toml}",
                k.name()
            );
        }
        assert_eq!(other.to_bytes(), original.to_bytes());
    }
}

/// The keys the unit lists in `help` and `get`, the keys odoctl reads from TOML and sends,
/// and the chassis keys of parameter files are one set: the table's.
#[test]
fn odoctl_and_the_unit_know_the_same_keys() {
    let mut unit = Settings::DEFAULT;
    let (help, _) = execute("help", &mut unit);
    let in_help: Vec<&str> = help
        .text
        .lines()
        .skip_while(|l| !l.starts_with("keys"))
        .skip(1)
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    let names: Vec<&str> = Key::ALL.iter().map(|k| k.name()).collect();
    assert_eq!(in_help, names);
    let (get, _) = execute("get", &mut unit);
    let in_get: Vec<&str> = get
        .text
        .lines()
        .skip(1)
        .filter_map(|l| l.split(" = ").next())
        .collect();
    assert_eq!(in_get, names);
    // odoctl reads every one of them from TOML and sends every one of them.
    let toml: String = Key::ALL
        .iter()
        .map(|k| match k.info().kind {
            Kind::Word(_) => format!("{} = \"{}\"\n", k.name(), Settings::DEFAULT.get(*k)),
            _ => format!("{} = {}\n", k.name(), Settings::DEFAULT.get(*k)),
        })
        .collect();
    let (_, read) = config::parse_settings("all.toml", &toml, Settings::DEFAULT).unwrap();
    assert_eq!(read, Key::ALL);
    let sent: Vec<String> = config::push_lines_of("all.toml", &toml)
        .unwrap()
        .iter()
        .flat_map(|l| {
            l.split_whitespace()
                .skip(1)
                .step_by(2)
                .map(str::to_string)
                .collect::<Vec<_>>()
        })
        .collect();
    let mut sent_sorted = sent.clone();
    sent_sorted.sort();
    let mut names_sorted: Vec<String> = names.iter().map(|n| n.to_string()).collect();
    names_sorted.sort();
    assert_eq!(sent_sorted, names_sorted);
    // Parameter files: exactly the chassis keys, the unit options refused by name.
    let chassis: Vec<Key> = config::chassis_keys().collect();
    assert_eq!(chassis.len(), 30);
    for k in Key::ALL {
        let line = format!("{} = {}\n", k.name(), Settings::DEFAULT.get(k));
        let line = match k.info().kind {
            Kind::Word(_) => format!("{} = \"{}\"\n", k.name(), Settings::DEFAULT.get(k)),
            _ => line,
        };
        let r = config::parse_params("p.toml", &line, Settings::DEFAULT.chassis);
        if chassis.contains(&k) {
            assert!(r.is_ok(), "{}: {r:?}", k.name());
        } else {
            let e = r.unwrap_err();
            assert!(
                matches!(e.downcast_ref(), Some(ConfigError::NotChassis { key, .. }) if *key == k),
                "{}: {e}",
                k.name()
            );
        }
    }
}

/// `config push` refuses what the unit would refuse, before sending anything, naming the
/// line; a file without keys is an error too.
#[test]
fn push_refuses_bad_files() {
    let e = config::push_lines_of("u.toml", "rate = 100\nbaud = 1234\n").unwrap_err();
    assert_eq!(
        e.downcast_ref::<ConfigError>(),
        Some(&ConfigError::Setting {
            origin: "u.toml".into(),
            line: 2,
            error: odo_unit::settings::SettingError::OutOfRange(Key::Baud)
        })
    );
    assert!(
        e.to_string()
            .starts_with("u.toml:2: baud: out of range, 9600|19200"),
        "{e}"
    );
    let e = config::push_lines_of("u.toml", "mode = \"gnss\"\n").unwrap_err();
    assert!(e.to_string().contains("mode: expected pps|free"), "{e}");
    let e = config::push_lines_of("u.toml", "# nothing\n[fit]\na = 1\n").unwrap_err();
    assert!(
        matches!(e.downcast_ref(), Some(ConfigError::NothingToSend(_))),
        "{e}"
    );
}

/// Keys that are only valid together reach the unit in one atomic `set`: the finest encoder
/// needs 79 Hz; pushed onto a unit at 50 Hz, `ticks_per_rev` and `rate` must arrive together.
#[test]
fn related_keys_share_one_set() {
    let mut a = Settings::DEFAULT;
    let (r, _) = execute("set ticks_per_rev 1048576 rate 79 output_divider 2", &mut a);
    assert!(r.ok, "{}", r.text);
    let (get, _) = execute("get", &mut a);
    let (s, keys) = config::parse_get_reply(&get.text).unwrap();
    let lines = config::push_lines_of("a.toml", &config::render_settings(&s, &keys, "")).unwrap();
    let mut b = Settings::DEFAULT;
    for l in &lines {
        let (r, _) = execute(l, &mut b);
        assert!(r.ok, "{l}: {}", r.text);
    }
    assert_eq!(b, a);
    // The opposite direction: back to the defaults from there.
    let mut d = Settings::DEFAULT;
    let (get, _) = execute("get", &mut d);
    let (s, keys) = config::parse_get_reply(&get.text).unwrap();
    for l in &config::push_lines_of("d.toml", &config::render_settings(&s, &keys, "")).unwrap() {
        let (r, _) = execute(l, &mut b);
        assert!(r.ok, "{l}: {}", r.text);
    }
    assert_eq!(b, Settings::DEFAULT);
}
