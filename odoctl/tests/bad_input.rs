//! Hostile and odd input to odoctl: a link the unit closes, captures across a
//! restart and a GPS week rollover, numeric options out of range, a value of several words,
//! control characters from the unit, TOML values one ulp from the unit's parse.

mod common;

use std::io::Write;
use std::net::TcpListener;

use common::{odoctl, read, scratch};
use odo_unit::protocol::{CommandReply, DeviceInfo, Message, PoseRecord, Status};
use odoctl::simulate::PathKind;

fn s(p: &std::path::Path) -> &str {
    p.to_str().unwrap()
}

/// A "unit" on 127.0.0.1 that accepts `connections` connections, sends `bytes` on each and
/// closes it.
fn closing_unit(connections: usize, bytes: Vec<u8>) -> (String, std::thread::JoinHandle<()>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let h = std::thread::spawn(move || {
        for _ in 0..connections {
            let (mut sock, _) = listener.accept().unwrap();
            let _ = sock.write_all(&bytes);
        }
    });
    (format!("tcp:127.0.0.1:{port}"), h)
}

/// Item 1: a unit that closes the link is an error with a message and exit 1, for every
/// subcommand that talks to it (a BrokenPipe on the link was taken for a closed stdout).
#[test]
fn a_closed_link_is_an_error() {
    let d = scratch("bad_input_closed");
    let push = d.join("cal.toml");
    std::fs::write(&push, "left_diameter = 0.2611\n").unwrap();
    let out = d.join("rec.csv");
    let cases: Vec<Vec<&str>> = vec![
        vec!["config", "save"],
        vec!["config", "get"],
        vec!["config", "get", "rate"],
        vec!["config", "push", s(&push)],
        vec!["record", "--out", s(&out)],
        vec!["record", "--out", s(&out), "--reset-pose"],
        vec!["monitor"],
        vec!["monitor", "--count", "5"],
    ];
    let (port, unit) = closing_unit(cases.len(), Vec::new());
    for args in &cases {
        let mut a = vec![args[0], "--port", &port];
        a.extend(&args[1..]);
        let o = odoctl(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{a:?}: {err}");
        assert!(
            err.contains("odoctl: error:")
                && (err.contains("closed the connection") || err.contains("link to the unit")),
            "{a:?}: {err}"
        );
    }
    unit.join().unwrap();
}

/// Records of a run at 50 Hz with GNSS time from GPS week `week`, time of week `tow_ms`.
fn timed(recs: &[PoseRecord], week: u16, tow_ms: u32) -> Vec<PoseRecord> {
    recs.iter()
        .enumerate()
        .map(|(i, r)| {
            let mut r = *r;
            let ms = u64::from(tow_ms) + i as u64 * 20;
            let weeks = ms / 604_800_000;
            r.flags.time_valid = true;
            r.gnss.week = week + weeks as u16;
            r.gnss.tow_ms = (ms % 604_800_000) as u32 / 1000 * 1000;
            r.gnss.sample_in_second = ((ms % 1000) / 20) as u16;
            r
        })
        .collect()
}

/// Item 2: every record is kept. A capture across a GPS week rollover continues past
/// 604,800 s; a restart of the unit starts a new segment file; exact duplicates are left
/// out and counted; to stdout, a later segment is refused with its count.
#[test]
fn decode_keeps_every_record_across_rollover_and_restart() {
    let d = scratch("bad_input_decode");
    let sim = common::sim(PathKind::Estimation, 3.0, 11);
    let recs = common::records(&common::truth(), &sim.samples[..100]);
    let status = Message::Status(Status {
        rate_hz: 50,
        ..Default::default()
    });
    // 50 records before the unit restarts (1 s before the end of week 2299, so 50 before
    // and 50 after the rollover... of the first run), then 50 records of the restarted unit.
    let first = timed(&recs, 2299, 604_799_000);
    let second = timed(&recs[..50], 2300, 3_000);
    let mut msgs = vec![status.clone()];
    msgs.extend(first.iter().map(|r| Message::Pose(*r)));
    msgs.push(Message::Pose(first[99])); // a duplicate
    msgs.push(status);
    msgs.extend(second.iter().map(|r| Message::Pose(*r)));
    let raw = d.join("capture.bin");
    std::fs::write(&raw, common::encode(msgs)).unwrap();

    let csv = d.join("rec.csv");
    let o = odoctl(&["decode", s(&raw), "--out", s(&csv)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("segment 1 of 2: 100 records")
            && err.contains("segment 2 of 2: 50 records")
            && err.contains("left out: 1 duplicate"),
        "{err}"
    );
    let t: Vec<f64> = read(&csv)
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(t.len(), 100);
    assert!(
        t.windows(2).all(|w| w[1] > w[0]),
        "time increases over the rollover"
    );
    assert!(
        (t[0] - 604_799.0).abs() < 1e-9 && (t[99] - 604_800.98).abs() < 1e-6,
        "{t:?}"
    );
    let t2 = read(&d.join("rec-2.csv"));
    assert_eq!(t2.lines().count(), 51);
    assert!(t2.lines().nth(1).unwrap().starts_with("3."), "{t2}");

    // Free-running (MCU time, which starts again at the restart): the capture of
    // 100 records gave 50 rows.
    let raw = d.join("mcu.bin");
    let msgs = recs.iter().chain(&recs[..50]).map(|r| Message::Pose(*r));
    std::fs::write(&raw, common::encode(msgs)).unwrap();
    let o = odoctl(&["decode", s(&raw), "--out", s(&d.join("mcu.csv"))]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("segment 1 of 2: 100 records") && err.contains("segment 2 of 2: 50 records"),
        "{err}"
    );
    assert_eq!(read(&d.join("mcu-2.csv")).lines().count(), 51);

    // To stdout the restarted segment cannot be written: an error with its count.
    let raw = d.join("capture.bin");
    let o = odoctl(&["decode", s(&raw)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 101);
    assert!(
        err.contains("50 records after a restart not written"),
        "{err}"
    );
}

/// Item 3: every numeric option is checked when parsed; the message names the option and
/// its range (NaN, infinities, negative or endless values were accepted or panicked).
#[test]
fn numeric_options_out_of_range_are_refused() {
    let d = scratch("bad_input_options");
    let f = d.join("x.csv");
    let f = s(&f);
    for (args, option, range) in [
        (
            vec!["monitor", "--port", "tcp:127.0.0.1:1", "--duration", "nan"],
            "--duration",
            "(0, 10000000] s",
        ),
        (
            vec!["monitor", "--port", "tcp:127.0.0.1:1", "--duration", "-1"],
            "--duration",
            "(0, 10000000] s",
        ),
        (
            vec![
                "record",
                "--port",
                "tcp:127.0.0.1:1",
                "--out",
                f,
                "--duration",
                "inf",
            ],
            "--duration",
            "(0, 10000000] s",
        ),
        (
            vec![
                "record",
                "--port",
                "tcp:127.0.0.1:1",
                "--out",
                f,
                "--duration",
                "1e300",
            ],
            "--duration",
            "(0, 10000000] s",
        ),
        (
            vec!["monitor", "--port", "tcp:127.0.0.1:1", "--every", "0"],
            "--every",
            "1..",
        ),
        (
            vec!["bridge", "--port", "tcp:127.0.0.1:1", "--retry", "nan"],
            "--retry",
            "[0.01, 3600] s",
        ),
        (
            vec!["bridge", "--port", "tcp:127.0.0.1:1", "--duration", "-1"],
            "--duration",
            "(0, 10000000] s",
        ),
        (
            vec!["replay", f, "--x", "1e300"],
            "--x",
            "[-1073741824, 1073741824] m",
        ),
        (
            vec!["replay", f, "--x", "nan"],
            "--x",
            "[-1073741824, 1073741824] m",
        ),
        (vec!["replay", f, "--heading", "-6e19"], "--heading", "rad"),
        (
            vec![
                "validate",
                "--samples",
                f,
                "--reference",
                f,
                "--heading",
                "nan",
            ],
            "--heading",
            "rad",
        ),
        (
            vec![
                "simulate",
                "--samples",
                f,
                "--reference",
                f,
                "--length",
                "inf",
            ],
            "--length",
            "(0, 100000] m",
        ),
        (
            vec![
                "simulate",
                "--samples",
                f,
                "--reference",
                f,
                "--speed",
                "1e-300",
            ],
            "--speed",
            "[0.01, 10] m/s",
        ),
        (
            vec!["simulate", "--samples", f, "--reference", f, "--rate", "0"],
            "--rate",
            "Hz",
        ),
        (
            vec![
                "calibrate",
                "--samples",
                f,
                "--reference",
                f,
                "--delta-window",
                "-1",
            ],
            "--delta-window",
            "[0, 1000000] m",
        ),
        (
            vec![
                "calibrate",
                "--samples",
                f,
                "--reference",
                f,
                "--reference-heading-sigma-deg",
                "inf",
            ],
            "--reference-heading-sigma-deg",
            "[0, 180] deg",
        ),
        (
            vec![
                "calibrate",
                "--samples",
                f,
                "--reference",
                f,
                "--windows",
                "1,-2",
            ],
            "--windows",
            "(0, 1000000] m",
        ),
    ] {
        let o = odoctl(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains(option) && err.contains(range),
            "{args:?}: {err}"
        );
    }
}

/// Item 4: `config set` sends one key and one value: a value of several words would be
/// several pairs in one `set` line.
#[test]
fn config_set_value_must_be_one_word() {
    for args in [
        [
            "config",
            "--port",
            "tcp:127.0.0.1:1",
            "set",
            "rate",
            "50 baud 9600",
        ],
        [
            "config",
            "--port",
            "tcp:127.0.0.1:1",
            "set",
            "rate baud",
            "9600",
        ],
        ["config", "--port", "tcp:127.0.0.1:1", "set", "rate", ""],
    ] {
        let o = odoctl(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains("must be one word"), "{args:?}: {err}");
    }
}

/// Item 5: text from the unit (replies, device information) reaches the terminal with its
/// control characters escaped.
#[test]
fn monitor_escapes_control_characters() {
    let mut info = DeviceInfo::default();
    info.firmware_version
        .push_str("1.0\x1b]0;owned\x07")
        .unwrap();
    let reply = CommandReply::chunks(true, "ok\x1b[2J\rrate = 50")
        .next()
        .unwrap();
    let bytes = common::encode([Message::DeviceInfo(info), Message::Reply(reply)]);
    let (port, unit) = closing_unit(1, bytes);
    let o = odoctl(&["monitor", "--port", &port]);
    unit.join().unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        !out.contains('\x1b') && !out.contains('\x07') && !out.contains('\r'),
        "{out:?}"
    );
    assert!(
        out.contains("firmware 1.0\\u{1b}]0;owned\\u{7}")
            && out.contains("# reply: ok\\u{1b}[2J\\rrate = 50"),
        "{out}"
    );
}

/// Item 6: an f32 key in TOML is parsed from its text exactly as the unit parses it (it was
/// read through f64 and rounded twice, one ulp away).
#[test]
fn toml_f32_keys_parse_as_the_unit_does() {
    use odo_unit::settings::{Key, Settings, Value};
    let text = "5.44023805559845641255378723144531250000000000000001e-5";
    let mut unit = Settings::DEFAULT;
    unit.set(Key::DeltaLeft, text).unwrap();
    let Value::F32(expected) = unit.get(Key::DeltaLeft) else {
        panic!("delta_left is an f32 key");
    };
    // Through f64 first: one ulp away (what the reader did before).
    assert_ne!(
        (text.parse::<f64>().unwrap() as f32).to_bits(),
        expected.to_bits()
    );
    let p = odoctl::config::parse_params(
        "t.toml",
        &format!("delta_left = {text}\n"),
        odo_unit::odometry::ChassisParams::DESIGNED,
    )
    .unwrap();
    assert_eq!(p.delta_left.to_bits(), expected.to_bits());
}
