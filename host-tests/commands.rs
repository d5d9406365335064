//! Text commands: line assembly, parsing, execution against the settings (atomic, errors
//! change nothing), and fuzz-style proptests of both.

use odo_unit::console::*;
use odo_unit::protocol::{CommandReply, MAX_REPLY_TEXT};
use odo_unit::settings::{Key, Settings};
use proptest::prelude::*;

fn lines(bytes: &[u8]) -> Vec<Result<String, LineError>> {
    let mut a = LineAssembler::new();
    let mut out = Vec::new();
    for &b in bytes {
        if let Some(r) = a.push(b) {
            out.push(r.map(str::to_owned));
        }
    }
    out
}

#[test]
fn line_assembler_terminators_and_editing() {
    assert_eq!(
        lines(b"get\r\nset rate 10\nstatus\r\r\n\n"),
        vec![
            Ok("get".into()),
            Ok("set rate 10".into()),
            Ok("status".into())
        ]
    );
    assert_eq!(lines(b"gxx\x08\x08et\r"), vec![Ok("get".into())]);
    assert_eq!(lines(b"\x7f\x08a\tb\x01\x00c\n"), vec![Ok("a bc".into())]);
    assert_eq!(lines(b"no terminator"), vec![]);
    assert_eq!(lines(b"\xff\xfe\n"), vec![Err(LineError::BadEncoding)]);
}

#[test]
fn line_assembler_overflow_keeps_sync() {
    let mut input = vec![b'x'; MAX_LINE];
    input.extend_from_slice(b"\nversion\n"); // exactly MAX_LINE: accepted
    input.extend(std::iter::repeat_n(b'y', MAX_LINE + 1));
    input.extend_from_slice(b"\x08\x08\r\nhelp\r\n"); // over by one: dropped, even after backspace
    let got = lines(&input);
    assert_eq!(got.len(), 4);
    assert_eq!(got[0].as_ref().unwrap().len(), MAX_LINE);
    assert_eq!(got[1], Ok("version".into()));
    assert_eq!(got[2], Err(LineError::TooLong));
    assert_eq!(got[3], Ok("help".into()));
}

fn run(line: &str, s: &mut Settings) -> (Reply, Action) {
    let before = *s;
    let (r, a) = execute(line, s);
    assert!(
        r.text.starts_with(if r.ok { "ok" } else { "error: " }),
        "{line:?}: {}",
        r.text
    );
    if !r.ok {
        assert_eq!(*s, before, "{line:?} failed but changed the settings");
        assert_eq!(a, Action::None);
    }
    (r, a)
}

/// (line, ok?, text the reply contains)
#[test]
fn command_table() {
    let table: &[(&str, bool, &str)] = &[
        ("help", true, "reset_pose"),
        ("help me", false, "too many arguments"),
        ("version", true, "ok"),
        ("status", true, "ok"),
        ("status now", false, "too many arguments"),
        ("get", true, "track_width = 0.563"),
        ("get left_diameter", true, "left_diameter = 0.26"),
        ("get ticks_per_rev", true, "ticks_per_rev = 20000"),
        ("get delta_left", true, "delta_left = 0.000000039"),
        ("get foo", false, "unknown key 'foo'"),
        ("get rate mode", false, "too many arguments"),
        ("set", false, "missing argument"),
        ("set rate", false, "missing value for 'rate'"),
        ("set bogus", false, "unknown key 'bogus'"),
        ("set rate 20", true, "rate = 20"),
        ("set bogus 1", false, "unknown key 'bogus'"),
        ("set rate 20 bogus 1", false, "unknown key 'bogus'"),
        ("set rate abc", false, "rate: bad number"),
        ("set rate 0", false, "rate: out of range, 1..=1000"),
        ("set rate 2000", false, "rate: out of range, 1..=1000; nothing changed"),
        // Integers beyond 64 bits are out of range too, not a bad number.
        (
            "set rate 99999999999999999999",
            false,
            "error: rate: out of range, 1..=1000; nothing changed",
        ),
        (
            "set rate -99999999999999999999",
            false,
            "error: rate: out of range, 1..=1000; nothing changed",
        ),
        (
            "set baud 184467440737095516160",
            false,
            "error: baud: out of range, 9600|19200",
        ),
        ("set rate 1e3", false, "error: rate: bad number; nothing changed"),
        ("set rate 99999999999999999999x", false, "rate: bad number"),
        // Plain decimals, never an exponent.
        ("set left_cos1 1e-12", true, "left_cos1 = 0.000000000001"),
        ("set delta_left 1e-10", true, "delta_left = 0.0000000001"),
        ("set kappa_left 1e-45", true, "kappa_left = 0.000000000000000000000000000000000000000000001"),
        ("set rate 500", false, "baud"),
        (
            "rate 1",
            false,
            "error: rate/max_wheel_speed/ticks_per_rev/left_diameter/right_diameter: up to 48971 increments per sample",
        ),
        ("set rate 1 max_wheel_speed 1", true, "max_wheel_speed = 1"),
        ("get max_wheel_speed", true, "max_wheel_speed = 2"),
        ("set max_wheel_speed 0.5", true, "max_wheel_speed = 0.5"),
        (
            "set max_wheel_speed 21",
            false,
            "max_wheel_speed: out of range, 0.01..=20; nothing changed",
        ),
        ("get kappa_diff_corr", true, "kappa_diff_corr = 0"),
        (
            "set kappa_diff 0.0004 kappa_diff_corr 2",
            true,
            "kappa_diff_corr = 2",
        ),
        (
            "set kappa_diff_corr 1001",
            false,
            "kappa_diff_corr: out of range, 0..=1000; nothing changed",
        ),
        ("set track_width nan", false, "NaN/inf"),
        ("set track_width -inf", false, "NaN/inf"),
        (
            "set track_width 0.6 left_diameter 0.25",
            true,
            "left_diameter = 0.25",
        ),
        ("mode pps", true, "mode = pps"),
        ("mode gnss", false, "expected pps|free"),
        ("mode", false, "missing argument, usage: mode pps|free"),
        ("mode pps free", false, "too many arguments"),
        ("rate 60", true, "rate = 60"),
        ("rate", false, "missing argument"),
        ("save", true, "ok"),
        ("save now", false, "too many arguments"),
        ("defaults", true, "defaults loaded"),
        ("reset_pose", true, "ok"),
        ("reset_pose 1 2", false, "missing argument"),
        ("reset_pose 1 2 3 4", false, "too many arguments"),
        ("reset_pose 1 x 3", false, "bad number 'x'"),
        ("reset_pose 1 NaN 3", false, "NaN/inf not allowed"),
        ("reset_pose 1 2 1e999", false, "NaN/inf not allowed"),
        ("frobnicate", false, "unknown command 'frobnicate'"),
        ("GET", false, "unknown command"),
        ("   get   rate   ", true, "rate = 50"),
    ];
    for &(line, ok, needle) in table {
        let mut s = Settings::DEFAULT;
        let (r, _) = run(line, &mut s);
        assert_eq!(r.ok, ok, "{line:?}: {}", r.text);
        assert!(
            r.text.contains(needle),
            "{line:?}: {:?} lacks {needle:?}",
            r.text
        );
    }
}

/// What docs/PROTOCOL.md says of the cases a decoder written from it must know: extra
/// spaces, the order of `set`'s checks (a range error is its pair's, before any relation),
/// `reset_pose` with NaN, singular correlation matrices (exact replies).
#[test]
fn documented_edge_cases() {
    let table: &[(&str, Result<&str, &str>)] = &[
        ("  set  rate   20 ", Ok("ok\nrate = 20")),
        ("set rate\t20", Ok("ok\nrate = 20")),
        (
            "set rate 20 output_divider 0",
            Err("error: output_divider: out of range, 1..=10000; nothing changed"),
        ),
        (
            "set output_divider 0 rate 5000",
            Err("error: output_divider: out of range, 1..=10000; nothing changed"),
        ),
        (
            "set rate 5000 output_divider abc",
            Err("error: rate: out of range, 1..=1000; nothing changed"),
        ),
        (
            "set rate 2000 rate 50",
            Err("error: rate: out of range, 1..=1000; nothing changed"),
        ),
        // Each value in range, the relation (records per baud) refused in step 3.
        (
            "set rate 1000 output_divider 1",
            Err("error: rate/output_divider: records need more than the baud rate (raise output_divider or baud; output frames in pps mode also carries GNSS sentences, 44000 bit/s); nothing changed"),
        ),
        ("set rate 20 foo", Err("error: unknown key 'foo' (try help)")),
        ("set foo 1 rate abc", Err("error: unknown key 'foo' (try help)")),
        ("reset_pose nan 0 0", Err("error: NaN/inf not allowed: 'nan'")),
        ("reset_pose 0 0 1e999", Err("error: NaN/inf not allowed: '1e999'")),
        ("reset_pose 0 -inf 0", Err("error: NaN/inf not allowed: '-inf'")),
        (
            "set diameters_correlation 1 left_track_correlation 0.5",
            Err("error: diameters_correlation/left_track_correlation/right_track_correlation: no covariance has these three correlations (set them together in one line); nothing changed"),
        ),
        (
            "set diameters_correlation 1 left_track_correlation 0.5 right_track_correlation 0.5",
            Ok("ok\ndiameters_correlation = 1\nleft_track_correlation = 0.5\nright_track_correlation = 0.5"),
        ),
        (
            "set diameters_correlation -1 left_track_correlation 0.3 right_track_correlation -0.3",
            Ok("ok\ndiameters_correlation = -1\nleft_track_correlation = 0.3\nright_track_correlation = -0.3"),
        ),
        (
            "set diameters_correlation 1 left_track_correlation 1 right_track_correlation 1",
            Ok("ok\ndiameters_correlation = 1\nleft_track_correlation = 1\nright_track_correlation = 1"),
        ),
        (
            "set diameters_correlation 1 left_track_correlation 1 right_track_correlation -1",
            Err("error: diameters_correlation/left_track_correlation/right_track_correlation: no covariance has these three correlations (set them together in one line); nothing changed"),
        ),
    ];
    for (line, want) in table {
        // The line as the assembler hands it on (TAB becomes a space).
        let got = lines(format!("{line}\n").as_bytes());
        let [Ok(got)] = &got[..] else {
            panic!("{line:?}: {got:?}")
        };
        let mut s = Settings::DEFAULT;
        let (r, _) = run(got, &mut s);
        assert_eq!(
            if r.ok {
                Ok(r.text.as_str())
            } else {
                Err(r.text.as_str())
            },
            *want,
            "{line:?}"
        );
    }
}

#[test]
fn actions() {
    let mut s = Settings::DEFAULT;
    assert_eq!(run("save", &mut s).1, Action::Save);
    assert_eq!(run("status", &mut s).1, Action::Status);
    assert_eq!(run("version", &mut s).1, Action::Version);
    assert_eq!(
        run("reset_pose 1.5 -2 2.5", &mut s).1,
        Action::ResetPose {
            x: 1.5,
            y: -2.0,
            heading: 2.5
        }
    );
    assert_eq!(
        run("reset_pose", &mut s).1,
        Action::ResetPose {
            x: 0.0,
            y: 0.0,
            heading: 0.0
        }
    );
    assert_eq!(run("rate 50", &mut s).1, Action::None, "unchanged value");
    assert_eq!(run("rate 60", &mut s).1, Action::SettingsChanged);
    assert_eq!(run("defaults", &mut s).1, Action::SettingsChanged);
    assert_eq!(s, Settings::DEFAULT);
}

#[test]
fn too_many_words() {
    let mut line = String::from("set");
    for _ in 0..=MAX_SET_PAIRS {
        line.push_str(" rate 10");
    }
    let mut s = Settings::DEFAULT;
    let (r, _) = run(&line, &mut s);
    assert!(!r.ok && r.text.contains("too many arguments"), "{}", r.text);
    // Exactly MAX_SET_PAIRS pairs is fine.
    let line: String = std::iter::once("set".to_string())
        .chain((0..MAX_SET_PAIRS).map(|_| " rate 10".to_string()))
        .collect();
    assert!(run(&line, &mut s).0.ok);
}

#[test]
fn atomic_multi_key_set() {
    let mut s = Settings::DEFAULT;
    let (r, _) = run(
        "set left_diameter 0.3 right_diameter 0.3 track_width 20",
        &mut s,
    );
    assert!(!r.ok);
    assert!(
        r.text.contains("track_width") && r.text.contains("nothing changed"),
        "{}",
        r.text
    );
    assert!(!run("rate 1000", &mut s).0.ok);
    assert!(run("set rate 1000 output_divider 20", &mut s).0.ok);
    assert_eq!((s.rate, s.output_divider), (1000, 20));
}

/// `get` prints every key so that feeding its lines back through `set` reproduces the
/// settings exactly.
#[test]
fn get_output_round_trips_through_set() {
    let mut a = Settings::DEFAULT;
    assert!(run(
        "set left_diameter 0.2612345678901234 delta_left 3.123e-8 left_cos2 -0.0123456 kappa_right 1.234567e-9",
        &mut a
    )
    .0
    .ok);
    let (r, _) = run("get", &mut a);
    let body: Vec<&str> = r.text.lines().skip(1).collect();
    assert_eq!(body.len(), Key::COUNT);
    let mut b = Settings::DEFAULT;
    let mut line = String::from("set");
    for l in &body {
        let (k, v) = l.split_once(" = ").unwrap();
        line.push_str(&format!(" {k} {v}"));
        if line.split(' ').count() >= 1 + 2 * MAX_SET_PAIRS - 1 {
            assert!(run(&line, &mut b).0.ok, "{line}");
            line = String::from("set");
        }
    }
    if line != "set" {
        assert!(run(&line, &mut b).0.ok, "{line}");
    }
    assert_eq!(format!("{a:?}"), format!("{b:?}"));
    assert_eq!(a.to_bytes(), b.to_bytes());
}

#[test]
fn long_replies_fit_and_split_into_frames() {
    let mut s = Settings::DEFAULT;
    for line in ["help", "get"] {
        let (r, _) = run(line, &mut s);
        assert!(!r.text.ends_with("..."), "{line} reply truncated");
        let parts: Vec<_> = CommandReply::chunks(r.ok, &r.text).collect();
        assert!(parts.iter().all(|p| p.text.len() <= MAX_REPLY_TEXT));
        let joined: String = parts.iter().map(|p| p.text.as_str()).collect();
        assert_eq!(joined, r.text.as_str());
        println!("{line}: {} bytes, {} frames", r.text.len(), parts.len());
    }
}

/// The longest value texts: every f32 key at a subnormal or near the smallest normal (the
/// longest plain decimals, 47 characters) still fits one `get` reply, whose lines are
/// plain decimals that set back the identical bits.
#[test]
fn get_with_the_longest_values_fits_and_round_trips() {
    let long = [
        -f32::from_bits(0x007F_FFFF), // the largest subnormal, negative
        f32::from_bits(0x0080_0001),  // just above the smallest normal
        f32::from_bits(1),            // the smallest subnormal
    ];
    let mut s = Settings::DEFAULT;
    for k in Key::ALL {
        for v in long {
            let _ = s.set(k, &format!("{v}"));
        }
    }
    let (r, _) = run("get", &mut s);
    assert!(
        !r.text.ends_with("..."),
        "truncated: {} bytes",
        r.text.len()
    );
    assert!(r.text.len() <= MAX_REPLY);
    let mut back = Settings::DEFAULT;
    let mut longest = 0;
    for l in r.text.lines().skip(1) {
        let (k, v) = l.split_once(" = ").expect("key = value");
        assert!(
            !v.contains(['e', 'E']) || v.chars().all(char::is_alphabetic),
            "{l}"
        );
        longest = longest.max(v.len());
        back.set(Key::from_name(k).expect("a key"), v).expect(l);
    }
    assert_eq!(back.to_bytes(), s.to_bytes());
    assert!(
        longest >= 47,
        "the test reaches the longest texts: {longest}"
    );
    println!(
        "get: {} bytes, longest value {longest} characters",
        r.text.len()
    );
}

fn token() -> impl Strategy<Value = String> {
    let words: Vec<String> = [
        "help",
        "version",
        "status",
        "get",
        "set",
        "save",
        "defaults",
        "reset_pose",
        "mode",
        "rate",
        "pps",
        "free",
        "paper",
        "covariance",
        "next",
        "previous",
        "nan",
        "inf",
        "-inf",
        "1e999",
        "0",
        "-1",
        "1",
        "50",
        "1000",
        "115200",
        "9600",
        "0.26",
        "0.563",
        "3.9e-8",
        "0.05",
        "-0.05",
        "20000",
        "x",
        "",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain(Key::ALL.iter().map(|k| k.name().to_string()))
    .collect();
    prop_oneof![
        4 => proptest::sample::select(words),
        1 => any::<f64>().prop_map(|v| v.to_string()),
        1 => any::<i64>().prop_map(|v| v.to_string()),
        1 => "[ -~]{0,12}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(10_000))]

    /// Arbitrary bytes through the line assembler and the executor: no panic, lines never
    /// exceed MAX_LINE, settings always valid, failed commands change nothing.
    #[test]
    fn fuzz_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut a = LineAssembler::new();
        let mut s = Settings::DEFAULT;
        for b in bytes {
            if let Some(Ok(line)) = a.push(b) {
                prop_assert!(line.len() <= MAX_LINE);
                let line = line.to_owned();
                let before = s;
                let (r, _) = execute(&line, &mut s);
                if !r.ok { prop_assert_eq!(s, before); }
                prop_assert!(s.validate().is_ok());
            }
        }
    }

    /// Lines of command-like tokens: the parser reaches deep paths; same invariants.
    #[test]
    fn fuzz_command_lines(tokens in proptest::collection::vec(token(), 0..12)) {
        let line = tokens.join(" ");
        let mut s = Settings::DEFAULT;
        let before = s;
        let (r, _) = execute(&line, &mut s);
        let prefix = if r.ok { "ok" } else { "error: " };
        prop_assert!(r.text.starts_with(prefix), "{}", r.text.as_str());
        if !r.ok { prop_assert_eq!(s, before); }
        prop_assert!(s.validate().is_ok());
    }
}

/// A line of only spaces or tabs is ignored like an empty line, not
/// answered with `error: unknown command ''`.
#[test]
fn blank_lines_are_ignored() {
    assert_eq!(lines(b"   \r\n\t\t\n \t \r"), vec![]);
    assert_eq!(
        lines(b"  \n  status  \n\t\nx\x08 \n"),
        vec![Ok("  status  ".into())]
    );
}

/// `set KEY -0` on a key at 0 changes the stored bytes and checksum, so the
/// unit must be told (`SettingsChanged`), and `defaults` after it must restore +0.
#[test]
fn negative_zero_is_a_change() {
    let mut s = Settings::DEFAULT;
    let before = (s.to_bytes(), s.checksum());
    assert_eq!(run("set left_cos1 -0", &mut s).1, Action::SettingsChanged);
    assert_ne!((s.to_bytes(), s.checksum()), before);
    assert_eq!(run("set left_cos1 -0", &mut s).1, Action::None, "same bits");
    assert_eq!(run("defaults", &mut s).1, Action::SettingsChanged);
    assert_eq!((s.to_bytes(), s.checksum()), before);
    assert_eq!(run("set left_cos1 0", &mut s).1, Action::None);
}

/// `reset_pose` refuses a coordinate the integrator cannot hold (clamped
/// and wrapping before), with an error naming it; in-range extremes are accepted.
#[test]
fn reset_pose_out_of_range_is_refused() {
    use odo_unit::odometry::integrator::{MAX_HEADING, MAX_POSITION};
    let mut s = Settings::DEFAULT;
    for (line, what) in [
        ("reset_pose 3e9 0 0", "x must be within"),
        ("reset_pose 0 -2147483648 0", "y must be within"),
        ("reset_pose 0 0 -6e19", "heading must be within"),
        ("reset_pose 1e300 0 0", "x must be within"),
        ("reset_pose 0 0 1e10", "heading must be within"),
    ] {
        let (r, a) = run(line, &mut s);
        assert!(!r.ok, "{line}: {}", r.text);
        assert!(r.text.contains(what), "{line}: {}", r.text);
        assert!(r.text.contains("pose unchanged"), "{line}: {}", r.text);
        assert_eq!(a, Action::None);
    }
    let line = format!("reset_pose {MAX_POSITION} -{MAX_POSITION} -{MAX_HEADING}");
    assert_eq!(
        run(&line, &mut s).1,
        Action::ResetPose {
            x: MAX_POSITION,
            y: -MAX_POSITION,
            heading: -MAX_HEADING
        }
    );
}

/// The console's UTF-8 decoder accepts exactly what `core::str::from_utf8` accepts and gives
/// the same characters: arbitrary bytes, and the boundaries of RFC 3629 (overlong forms,
/// surrogates, beyond U+10FFFF, truncated sequences).
#[test]
fn utf8_decoder_is_core_from_utf8() {
    use odo_unit::console::line::decode_utf8;
    let check = |bytes: &[u8]| {
        let mut got = String::new();
        let ok = decode_utf8(bytes, |c| {
            got.push(c);
            true
        });
        match std::str::from_utf8(bytes) {
            Ok(s) => assert!(ok && got == s, "{bytes:02x?}"),
            Err(_) => assert!(!ok, "{bytes:02x?} accepted"),
        }
    };
    for case in [
        &b""[..],
        b"set rate 50",
        "ä€𝄞 ok".as_bytes(),
        &[0xC0, 0x80],
        &[0xC1, 0xBF],
        &[0xC2, 0x80],
        &[0xDF, 0xBF],
        &[0xE0, 0x9F, 0xBF],
        &[0xE0, 0xA0, 0x80],
        &[0xED, 0x9F, 0xBF],
        &[0xED, 0xA0, 0x80],
        &[0xEF, 0xBF, 0xBF],
        &[0xF0, 0x8F, 0xBF, 0xBF],
        &[0xF0, 0x90, 0x80, 0x80],
        &[0xF4, 0x8F, 0xBF, 0xBF],
        &[0xF4, 0x90, 0x80, 0x80],
        &[0xF5, 0x80, 0x80, 0x80],
        &[0xE2, 0x82],
        &[0xE2, 0x82, 0x41],
        &[0x80],
        &[0xFF],
    ] {
        check(case);
    }
    let mut rng = 0x1234_5678_9abc_def0u64;
    for _ in 0..200_000 {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        let len = (rng % 6) as usize;
        // Bytes biased to the lead and continuation ranges.
        let bytes: Vec<u8> = (0..len)
            .map(|i| {
                let b = (rng >> (8 * i)) as u8;
                if i == 0 {
                    b | 0x80
                } else {
                    0x80 | (b & 0x3F) | (b & 0x40)
                }
            })
            .collect();
        check(&bytes);
    }
}
