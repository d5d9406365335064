//! The link subcommands against a fake unit speaking the core's protocol over TCP, and the
//! bit-for-bit replay of pose records made by the core integrator.

mod common;

use std::time::Duration;

use common::{odoctl, read, scratch, success_stdout};
use odo_unit::protocol::Message;
use odoctl::simulate::PathKind;

fn s(p: &std::path::Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn decode_then_replay_matches_the_cores_records_bit_for_bit() {
    let d = scratch("link_decode");
    let sim = common::sim(PathKind::Validation, 15.0, 8);
    // The unit's parameters differ from the designed ones, and one wheel has harmonics
    // (its index count is in the records, so the per-angle function is exercised).
    let mut params = common::truth();
    params.left_wheel.cos[0] = 0.002;
    params.right_wheel.sin[1] = -0.001;
    let recs = common::records(&params, &sim.samples);
    let raw = d.join("capture.bin");
    std::fs::write(&raw, common::encode(recs.iter().map(|r| Message::Pose(*r)))).unwrap();
    let csv = d.join("rec.csv");
    let o = odoctl(&["decode", s(&raw), "--out", s(&csv)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cfg = d.join("unit.toml");
    std::fs::write(&cfg, odoctl::config::render_params(&params, "unit", &[])).unwrap();
    let out = d.join("replay.csv");
    let o = odoctl(&[
        "replay",
        s(&csv),
        "--config",
        s(&cfg),
        "--check",
        "--out",
        s(&out),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success() && err.contains("match the unit's records bit for bit"),
        "{err}"
    );
    // And the CSV itself carries the exact values.
    for (line, r) in read(&out).lines().skip(1).zip(&recs) {
        let v: Vec<&str> = line.split(',').collect();
        assert_eq!(v[1].parse::<f64>().unwrap().to_bits(), r.x.to_bits());
        assert_eq!(v[3].parse::<f64>().unwrap().to_bits(), r.heading.to_bits());
        assert_eq!(
            v[6].parse::<f32>().unwrap().to_bits(),
            r.sigma_heading.to_bits()
        );
    }
    // With other parameters the check fails.
    let o = odoctl(&["replay", s(&csv), "--check", "--out", s(&out)]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("differ"));
}

#[test]
fn decode_counts_corrupted_frames_and_resynchronises() {
    let d = scratch("link_corrupt");
    let sim = common::sim(PathKind::Estimation, 3.0, 9);
    let recs = common::records(&common::truth(), &sim.samples[..100]);
    let mut bytes = common::encode(recs.iter().map(|r| Message::Pose(*r)));
    let frame = bytes.len() / recs.len();
    // Flip a bit inside the 11th frame where it leaves the COBS framing intact, so that only
    // the CRC can catch it.
    let at = (frame * 10 + 5..frame * 11)
        .find(|&i| {
            let mut b = bytes.clone();
            b[i] ^= 0x40;
            let mut dec = odo_unit::protocol::FrameDecoder::new();
            dec.feed(&b, |_| {});
            dec.stats().crc_errors == 1
        })
        .unwrap();
    bytes[at] ^= 0x40;
    let raw = d.join("capture.bin");
    std::fs::write(&raw, &bytes).unwrap();
    let o = odoctl(&["decode", s(&raw), "--out", s(&d.join("rec.csv"))]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("99 pose records")
            && err.contains("CRC errors 1")
            && err.contains("record sequence gaps 1"),
        "{err}"
    );
    let o = odoctl(&["decode", s(&d.join("nothing.bin"))]);
    assert!(!o.status.success());
}

#[test]
fn config_against_a_unit_on_tcp() {
    let (port, unit) = common::fake_unit(Vec::new(), Duration::from_millis(5));
    let d = scratch("link_config");
    let push = d.join("cal.toml");
    std::fs::write(&push, "left_diameter = 0.2611\nright_diameter = 0.2605\ntrack_width = 0.5650\ndelta_left = 2.0e-8\n\n[fit]\neq16_cost = 1.0\n").unwrap();
    let addr = format!("tcp:127.0.0.1:{port}");
    // One connection serves the whole test: use the raw command, then push on a second unit.
    let o = odoctl(&["config", "--port", &addr, "push", s(&push), "--no-save"]);
    let out = success_stdout(&o);
    assert!(
        out.contains(
            // Values in the unit's own text form (what `get` prints).
            "> set left_diameter 0.2611 right_diameter 0.2605 track_width 0.565 delta_left 0.00000002"
        ),
        "{out}"
    );
    let settings = unit.join().unwrap();
    assert_eq!(settings.chassis.left_diameter, 0.2611);
    assert_eq!(settings.chassis.delta_left, 2.0e-8);

    let (port, unit) = common::fake_unit(Vec::new(), Duration::from_millis(5));
    let o = odoctl(&[
        "config",
        "--port",
        &format!("tcp:127.0.0.1:{port}"),
        "set",
        "track_width",
        "99",
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(!o.status.success(), "{out}");
    assert!(out.contains("error"), "{out}");
    assert_eq!(unit.join().unwrap().chassis.track_width, 0.563);

    let (port, unit) = common::fake_unit(Vec::new(), Duration::from_millis(5));
    let o = odoctl(&[
        "config",
        "--port",
        &format!("tcp:127.0.0.1:{port}"),
        "get",
        "ticks_per_rev",
    ]);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("ticks_per_rev = 20000"));
    unit.join().unwrap();

    let o = odoctl(&["config", "--port", "tcp:127.0.0.1:1", "get"]);
    assert!(!o.status.success());
}

#[test]
fn record_and_monitor_against_a_unit_on_tcp() {
    let sim = common::sim(PathKind::Validation, 10.0, 10);
    let samples: Vec<_> = sim.samples[..400].to_vec();
    let d = scratch("link_record");
    let (port, unit) = common::fake_unit(samples.clone(), Duration::from_millis(1));
    let csv = d.join("rec.csv");
    let raw = d.join("rec.bin");
    let o = odoctl(&[
        "record",
        "--port",
        &format!("tcp:127.0.0.1:{port}"),
        "--out",
        s(&csv),
        "--raw",
        s(&raw),
        "--count",
        "200",
        "--reset-pose",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("recorded 200 records") && err.contains("CRC errors 0"),
        "{err}"
    );
    unit.join().unwrap();
    // The recording starts at the reset and replays bit for bit with the unit's parameters.
    let o = odoctl(&[
        "replay",
        s(&csv),
        "--check",
        "--out",
        s(&d.join("replay.csv")),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The raw capture decodes to at least the same records.
    let o = odoctl(&["decode", s(&raw), "--out", s(&d.join("dec.csv"))]);
    assert!(o.status.success());
    assert!(read(&d.join("dec.csv")).lines().count() >= 201);

    let (port, unit) = common::fake_unit(samples, Duration::from_millis(1));
    let o = odoctl(&[
        "monitor",
        "--port",
        &format!("tcp:127.0.0.1:{port}"),
        "--count",
        "20",
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{out}");
    assert!(
        out.lines().filter(|l| !l.starts_with('#')).count() == 21,
        "{out}"
    );
    assert!(
        out.contains("# link: frames") && out.contains("records 20"),
        "{out}"
    );
    // The fake unit's heartbeat, with its loss counters.
    assert!(
        out.contains("# status: ")
            && out.contains("samples lost 1, merged 2")
            && out.contains("GNSS rx lost 3"),
        "{out}"
    );
    unit.join().unwrap();
}

/// A capture whose rate changes inside it (50 Hz, then 10 Hz from a whole
/// second, announced by a Status and the rate switch flag). `decode` turns each record's GNSS
/// sample index into seconds with the rate in use at that record, so the `t` column
/// stays exact and increasing across the switch, and `replay` integrates the file (it uses
/// the counts of each row, whatever the time step) bit for bit.
#[test]
fn decode_and_replay_follow_a_rate_change_inside_a_capture() {
    use odo_unit::protocol::{GnssTime, Status};
    use odo_unit::timing::SyncState;
    let d = scratch("link_rate_change");
    let sim = common::sim(PathKind::Validation, 15.0, 11);
    let params = common::truth();
    // 4 s at 50 Hz, then every 5th simulated sample: 10 Hz.
    let k = 200;
    let used: Vec<_> = sim.samples[..k]
        .iter()
        .chain(sim.samples[k..].iter().step_by(5))
        .cloned()
        .collect();
    let mut recs = common::records(&params, &used);
    let tow0 = 345_600_000u32;
    let status = |rate_hz: u32, div: u32| {
        Message::Status(Status {
            rate_hz,
            output_divider: div,
            ..Default::default()
        })
    };
    let mut msgs = vec![status(50, 1)];
    for (i, r) in recs.iter_mut().enumerate() {
        let (second, index, rate) = if i < k {
            (i / 50, i % 50, 50)
        } else {
            (k / 50 + (i - k) / 10, (i - k) % 10, 10)
        };
        r.flags.sync = SyncState::Locked;
        r.flags.time_valid = true;
        r.flags.rate_switch = i == k;
        r.gnss = GnssTime {
            week: 2400,
            tow_ms: tow0 + 1000 * second as u32,
            sample_in_second: index as u16,
        };
        if index == 0 && i > 0 {
            msgs.push(status(rate, 1));
        }
        msgs.push(Message::Pose(*r));
    }
    let raw = d.join("capture.bin");
    std::fs::write(&raw, common::encode(msgs)).unwrap();
    let csv = d.join("rec.csv");
    let o = odoctl(&["decode", s(&raw), "--out", s(&csv)]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("skipped"), "{err}");
    let text = read(&csv);
    let t: Vec<f64> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(t.len(), recs.len(), "every record is a row");
    for (i, t) in t.iter().enumerate() {
        let want = f64::from(tow0) * 1e-3
            + if i < k {
                i as f64 * 0.02
            } else {
                k as f64 * 0.02 + (i - k) as f64 * 0.1
            };
        assert!((t - want).abs() < 1e-9, "row {i}: t = {t}, want {want}");
    }
    let cfg = d.join("unit.toml");
    std::fs::write(&cfg, odoctl::config::render_params(&params, "unit", &[])).unwrap();
    let o = odoctl(&[
        "replay",
        s(&csv),
        "--config",
        s(&cfg),
        "--check",
        "--out",
        s(&d.join("replay.csv")),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success() && err.contains("match the unit's records bit for bit"),
        "{err}"
    );
}

/// `config pull` writes the unit's settings as TOML that `config push` sends back whole.
#[test]
fn config_pull_writes_what_push_sends_back() {
    let (port, unit) = common::fake_unit(Vec::new(), Duration::from_millis(5));
    let d = scratch("link_pull");
    let file = d.join("unit.toml");
    let o = odoctl(&[
        "config",
        "--port",
        &format!("tcp:127.0.0.1:{port}"),
        "pull",
        s(&file),
    ]);
    let out = success_stdout(&o);
    assert!(out.contains("wrote"), "{out}");
    let unit = unit.join().unwrap();
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(
        text.contains("\nmode = \"free\"\n") && text.contains("\nrate = 50\n"),
        "{text}"
    );
    let lines = odoctl::config::push_lines(&file).unwrap();
    let mut back = odo_unit::settings::Settings::DEFAULT;
    back.chassis.track_width = 0.7;
    back.rate = 100;
    for l in &lines {
        assert!(odo_unit::console::execute(l, &mut back).0.ok, "{l}");
    }
    assert_eq!(back.to_bytes(), unit.to_bytes());
    assert_eq!(
        lines
            .iter()
            .map(|l| l.split_whitespace().count() / 2)
            .sum::<usize>(),
        odo_unit::settings::Key::COUNT
    );
}
