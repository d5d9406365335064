//! MAVLink output read by pymavlink (ArduPilot's MAVLink library, from the registry;
//! tests/mavlink/read_mavlink.py): the core encoder's frames as the firmware sends them
//! (each followed by 0x00) for simulated records with a pose reset, and `odoctl bridge
//! --mavlink udpout:...` against the fake unit, and the QEMU image's output against the
//! records of a second boot left in frames (QEMU skipped as in host-tests/support/qemu.rs).
//! Every frame's CRC and sequence, the HEARTBEAT, and every ODOMETRY field against our own
//! records. Skipped with a message when python3 or `pymavlink` is missing, unless
//! `ODO_PY_REQUIRED=1` (CI).

mod common;

use std::fmt::Write as FmtWrite;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};

use common::scratch;
use odo_unit::odometry::{ChassisParams, IndexRefs, Integrator, Pose, WheelCounts};
use odo_unit::protocol::PoseRecord;
use odo_unit::settings::Settings;
use odoctl::mavlink::{Converter, Target};
use odoctl::simulate::PathKind;

/// Whether the independent reader can run ([`common::python_has`]).
fn pymavlink_ready() -> bool {
    common::python_has("mavlink", "pymavlink.dialects.v20.common", "pymavlink")
}

fn script() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/mavlink/read_mavlink.py")
}

/// The records as the reader's CSV.
fn expect_csv(records: &[PoseRecord], path: &Path) {
    let mut e = String::from(
        "t_us,x,y,heading,sigma_x,sigma_y,sigma_heading,cov_xy,gamma_left,gamma_right,fault,mismatch\n",
    );
    for r in records {
        let _ = writeln!(
            e,
            "{},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{},{},{},{}",
            r.mcu_time_us,
            r.x,
            r.y,
            r.heading,
            r.sigma_x,
            r.sigma_y,
            r.sigma_heading,
            r.cov_xy,
            r.gamma_left,
            r.gamma_right,
            u8::from(r.flags.left.fault || r.flags.right.fault),
            u8::from(r.flags.left.index_mismatch || r.flags.right.index_mismatch)
        );
    }
    std::fs::write(path, e).unwrap();
}

/// `--params` of the reader: the paper model's constants of `p`.
fn params_args(p: &ChassisParams) -> Vec<String> {
    [
        p.left_diameter,
        p.right_diameter,
        p.track_width,
        f64::from(p.ticks_per_rev),
        f64::from(p.delta_left),
        f64::from(p.delta_right),
        f64::from(p.delta_diff),
    ]
    .iter()
    .map(|v| format!("{v:?}"))
    .collect()
}

fn run_reader(args: &[String]) -> String {
    let o = Command::new("python3")
        .arg(script())
        .args(args)
        .output()
        .unwrap();
    common::success_stdout(&o)
}

#[test]
fn encoder_frames_with_a_pose_reset_read_by_pymavlink() {
    if !pymavlink_ready() {
        return;
    }
    let p = ChassisParams::DESIGNED;
    let sim = common::sim(PathKind::Validation, 10.0, 31);
    // A reset to pose 0 at sample 200: the records start again with zero sigmas, the counts
    // and times go on.
    let mut records = common::records(&p, &sim.samples[..200]);
    records.extend(common::records(&p, &sim.samples[200..400]));
    // An encoder fault and an index count mismatch, as the status word reports them.
    records[100].flags.left.fault = true;
    records[101].flags.right.index_mismatch = true;
    records[102].flags.right.fault = true;
    records[102].flags.left.index_mismatch = true;
    let mut conv = Converter::new(
        p,
        odo_unit::mavlink::Ids {
            sysid: 1,
            compid: 197,
        },
    );
    let mut wire = Vec::new();
    for (i, r) in records.iter().enumerate() {
        if i % 50 == 0 {
            wire.extend(conv.heartbeat());
            wire.push(0);
        }
        wire.extend(conv.odometry(r));
        wire.push(0);
    }
    let dir = scratch("mavlink_encoder");
    let (raw, expect) = (dir.join("link.bin"), dir.join("expect.csv"));
    std::fs::write(&raw, &wire).unwrap();
    expect_csv(&records, &expect);
    let t = |r: &PoseRecord| r.mcu_time_us as f64 * 1e-6;
    let rate = (records.len() - 1) as f64 / (t(&records[records.len() - 1]) - t(&records[0]));
    let mut args: Vec<String> = ["--file", raw.to_str().unwrap()]
        .iter()
        .map(|s| s.to_string())
        .collect();
    args.extend(["--expect".into(), expect.to_str().unwrap().into()]);
    args.push("--params".into());
    args.extend(params_args(&p));
    args.extend(["--rate".into(), format!("{rate}")]);
    args.extend(["--resets".into(), "1".into()]);
    args.extend(["--reset-pose", "0", "0", "0"].map(String::from));
    args.extend(["--qualities", "100", "50", "-1"].map(String::from));
    let out = run_reader(&args);
    assert!(
        out.contains("read_mavlink: ok 400 ODOMETRY (400 matched"),
        "{out}"
    );
    eprintln!("{}", out.trim());
}

#[test]
fn bridge_sends_odometry_over_udp_to_pymavlink() {
    if !pymavlink_ready() {
        return;
    }
    let sim = common::sim(PathKind::Validation, 10.0, 12);
    let samples: Vec<_> = sim.samples[..300].to_vec();
    // The fake unit integrates with its defaults, the designed parameters.
    let p = ChassisParams::DESIGNED;
    let records = common::records(&p, &samples);
    let dir = scratch("mavlink_bridge");
    let expect = dir.join("expect.csv");
    expect_csv(&records, &expect);
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut args: Vec<String> = vec!["--udp".into(), port.to_string()];
    args.extend(["--expect".into(), expect.to_str().unwrap().into()]);
    args.push("--params".into());
    args.extend(params_args(&p));
    args.extend(["--count", "150", "--timeout", "40"].map(String::from));
    let mut reader: Child = Command::new("python3")
        .arg(script())
        .args(&args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(reader.stdout.as_mut().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert_eq!(line.trim(), "ready", "reader did not start");
    let (unit_port, unit) = common::fake_unit(samples, std::time::Duration::from_millis(20));
    let o = Command::new(common::bin())
        .args(["bridge", "--port", &format!("tcp:127.0.0.1:{unit_port}")])
        .args(["--mavlink", &format!("udpout:127.0.0.1:{port}")])
        .args(["--count", "200"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("200 ODOMETRY"), "{err}");
    unit.join().unwrap();
    let o = reader.wait_with_output().unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("read_mavlink: ok"), "{out}");
    eprintln!("{}", out.trim());
}

#[test]
fn targets_parse_or_say_why_not() {
    assert_eq!(
        Target::parse("udpout:127.0.0.1:14550").unwrap(),
        Target::UdpOut("127.0.0.1:14550".into())
    );
    assert_eq!(
        Target::parse("serial:/dev/ttyS1:57600").unwrap(),
        Target::Serial("/dev/ttyS1".into(), 57600)
    );
    for bad in [
        "udpout:host",
        "udpout::1",
        "serial:/dev/x:fast",
        "tcp:1:2",
        "udpout:h:99999",
    ] {
        assert!(Target::parse(bad).is_err(), "{bad}");
    }
}

#[allow(dead_code)]
#[path = "../../host-tests/support/qemu.rs"]
mod qemu_support;

/// Waits until the link has received `more` bytes beyond what it holds now.
fn wait_for_bytes(link: &qemu_support::UnitLink, more: usize, limit: std::time::Duration) {
    let start = std::time::Instant::now();
    let from = link.raw.lock().unwrap().len();
    while link.raw.lock().unwrap().len() < from + more {
        assert!(start.elapsed() < limit, "QEMU sent too little MAVLink");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

#[test]
fn qemu_mavlink_output_read_by_pymavlink() {
    if !pymavlink_ready() {
        return;
    }
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let Some(qemu) = qemu_support::boot(&repo, "qemu_mavlink_output_read_by_pymavlink") else {
        return;
    };
    let limit = std::time::Duration::from_secs(120);
    let mut link = qemu_support::UnitLink::connect(qemu.port, limit);
    while link.records.len() < 3 {
        link.next_frame();
    }
    // 50 Hz, every second sample: 25 ODOMETRY frames a second, 61,720 bit/s of 115,200.
    let from = link.raw.lock().unwrap().len();
    let (ok, text) = link.command("set output mavlink output_divider 2");
    assert!(ok, "{text}");
    // A flight controller flooding the unit: 300 HEARTBEATs at once (6,300 bytes, more than
    // the receive queue holds) while the ODOMETRY stream runs; the rate and sequence checks
    // below cover this stretch.
    // The first frame of `flight_controller_bytes`: a 21-byte HEARTBEAT.
    link.send_bytes(&flight_controller_bytes()[..21].repeat(300));
    // About 3 s, then a reset (its reply, one of our frames, lands among the MAVLink frames
    // and may cost a flight controller's parser the frame after it), then about 2 s more.
    wait_for_bytes(&link, 75 * 246, limit);
    let (ok, text) = link.command("reset_pose 1 2 0.5");
    assert!(ok, "{text}");
    wait_for_bytes(&link, 50 * 246, limit);
    // MAVLink bytes end where the next command is sent.
    let to = link.raw.lock().unwrap().len();
    // A flight controller's bytes: its HEARTBEAT (MAVLink 2), a signed MAVLink 2 frame and a
    // MAVLink 1 HEARTBEAT are skipped and counted; the console answers the line after them.
    link.send_bytes(&flight_controller_bytes());
    let (ok, text) = link.command("status");
    assert!(ok, "{text}");
    assert!(
        text.contains("host_rx_mavlink_ignored = 302, host_rx_mavlink1_ignored = 1"),
        "{text}"
    );
    assert!(
        text.contains("samples_lost = 0, merged_samples = 0"),
        "{text}"
    );
    assert!(text.contains("records_dropped = 0"), "{text}");
    let (ok, text) = link.command("set output frames");
    assert!(ok, "{text}");
    // Records again after `output frames`.
    let n = link.records.len();
    while link.records.len() < n + 3 {
        link.next_frame();
    }
    let bytes = link.raw.lock().unwrap()[from..to].to_vec();
    let sent_as_frames = link.records.clone();
    drop(link);
    drop(qemu);
    // Our records of the same samples: a second boot left in `output frames` (the simulated
    // drive is a function of the sample instant), with the pose reset replayed onto them.
    let odometry = odometry_frames(&bytes);
    let last = odometry.last().expect("ODOMETRY frames").time_usec;
    let until = last.max(sent_as_frames.last().unwrap().mcu_time_us);
    let records = frames_boot_records(&repo, until, limit);
    let params = Settings::DEFAULT.chassis;
    let reset = Pose {
        x: 1.0,
        y: 2.0,
        heading: 0.5,
    };
    let at = reset_sample(&odometry, &records);
    let expected = with_pose_reset(&records, at, reset, &params);
    // The determinism this rests on: what the first boot sent as frames, before the MAVLink
    // stretch and after it (past the reset), equals the expectation bit for bit.
    assert_same_records(&sent_as_frames, &expected);
    let dir = scratch("mavlink_qemu");
    let (raw, expect) = (dir.join("link.bin"), dir.join("expect.csv"));
    std::fs::write(&raw, &bytes).unwrap();
    expect_csv(&expected, &expect);
    let mut args: Vec<String> = ["--file", raw.to_str().unwrap(), "--rate", "25"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    args.extend(["--expect".into(), expect.to_str().unwrap().into()]);
    args.push("--params".into());
    args.extend(params_args(&params));
    args.extend(["--resets", "1", "--reset-pose", "1", "2", "0.5"].map(String::from));
    // The reset may fall on a sample that output_divider 2 skips: the step then comes with the
    // next sample, one 20 ms step (at most 0.021 m, 0.02 rad on the simulated path) later.
    args.extend(["--reset-tolerance", "0.05"].map(String::from));
    args.extend(["--allow-gaps", "2"].map(String::from));
    // The simulated drive flags a right index mismatch and raises the right fault line once a
    // lap (src/board/qemu/drive.rs): quality 50 and -1 besides 100.
    args.extend(["--qualities", "100", "50", "-1"].map(String::from));
    let out = run_reader(&args);
    assert!(
        out.contains(&format!(
            "read_mavlink: ok {0} ODOMETRY ({0} matched",
            odometry.len()
        )),
        "{out}"
    );
    let sent = odometry.iter().any(|o| o.time_usec == at);
    eprintln!(
        "{} (reset at t = {at} us, a sample {}; {} records of the second boot)",
        out.trim(),
        if sent { "sent" } else { "skipped" },
        records.len()
    );
}

/// What the test needs of an `ODOMETRY` frame: its time and reset counter, and whether its
/// pose covariance is all zero (the reset sample's).
struct OdometryFrame {
    time_usec: u64,
    reset_counter: u8,
    zero_covariance: bool,
}

/// The `ODOMETRY` frames (MAVLink 2, CRC valid) in `bytes`, in order; other bytes skipped.
fn odometry_frames(bytes: &[u8]) -> Vec<OdometryFrame> {
    use odo_unit::mavlink::frame::{crc16, crc_accumulate, STX_V2};
    use odo_unit::mavlink::odometry::{ODOMETRY_ID, ODOMETRY_LEN};
    let mut out = Vec::new();
    let mut i = 0;
    while i + 12 <= bytes.len() {
        let len = usize::from(bytes[i + 1]);
        let end = i + 12 + len;
        let id = u32::from_le_bytes([bytes[i + 7], bytes[i + 8], bytes[i + 9], 0]);
        let valid = bytes[i] == STX_V2
            && bytes[i + 2] == 0
            && id == ODOMETRY_ID.id
            && len <= ODOMETRY_LEN
            && end <= bytes.len()
            && crc_accumulate(crc16(&bytes[i + 1..end - 2]), ODOMETRY_ID.crc_extra).to_le_bytes()
                == bytes[end - 2..end];
        if !valid {
            i += 1;
            continue;
        }
        // The payload with its trailing zeros back.
        let mut p = [0u8; ODOMETRY_LEN];
        p[..len].copy_from_slice(&bytes[i + 10..end - 2]);
        let f = |at: usize| f32::from_le_bytes(p[at..at + 4].try_into().unwrap());
        // pose_covariance at byte 60: elements 0 (north), 1 (north-east), 6 (east), 20 (yaw).
        out.push(OdometryFrame {
            time_usec: u64::from_le_bytes(p[..8].try_into().unwrap()),
            reset_counter: p[230],
            zero_covariance: [0, 1, 6, 20].iter().all(|k| f(60 + 4 * k) == 0.0),
        });
        i = end;
    }
    out
}

/// The pose records of a boot left in `output frames`, from its first sample until MCU time
/// `until_us`, with no sequence gap.
fn frames_boot_records(repo: &Path, until_us: u64, limit: std::time::Duration) -> Vec<PoseRecord> {
    let qemu = qemu_support::boot(repo, "qemu_mavlink_output_read_by_pymavlink (frames)")
        .expect("the image booted once already");
    let mut link = qemu_support::UnitLink::connect(qemu.port, limit);
    while link.records.last().is_none_or(|r| r.mcu_time_us < until_us) {
        link.next_frame();
    }
    for (a, b) in link.records.iter().zip(&link.records[1..]) {
        assert_eq!(b.sequence, a.sequence + 1, "a record lost");
    }
    link.records.clone()
}

/// MCU time of the sample the pose reset fell on: the first `ODOMETRY` of the next
/// `reset_counter`, or (when it carries a covariance already, one step on) the sample before
/// it, which `output_divider` skipped.
fn reset_sample(odometry: &[OdometryFrame], records: &[PoseRecord]) -> u64 {
    let first = odometry
        .iter()
        .find(|o| o.reset_counter != odometry[0].reset_counter)
        .expect("a reset_counter step");
    if first.zero_covariance {
        return first.time_usec;
    }
    let k = records
        .iter()
        .position(|r| r.mcu_time_us == first.time_usec)
        .expect("a record at the reset step");
    records[k - 1].mcu_time_us
}

/// `records` with the pose reset to `pose` at the sample of MCU time `at_us` and replayed
/// from there through the core integrator (as the firmware does: the counts rebased, the
/// uncertainty zeroed); counts, index references and flags as recorded.
fn with_pose_reset(
    records: &[PoseRecord],
    at_us: u64,
    pose: Pose,
    params: &ChassisParams,
) -> Vec<PoseRecord> {
    let counts = |r: &PoseRecord| WheelCounts {
        left: r.gamma_left,
        right: r.gamma_right,
    };
    let k = records
        .iter()
        .position(|r| r.mcu_time_us == at_us)
        .expect("a record at the reset sample");
    let mut out = records.to_vec();
    let mut integ = Integrator::new(params, counts(&records[k]), pose).unwrap();
    for (i, r) in out.iter_mut().enumerate().skip(k) {
        if i > k {
            let refs = IndexRefs {
                left: r.flags.left.index_seen.then_some(r.index_left),
                right: r.flags.right.index_seen.then_some(r.index_right),
            };
            assert!(!integ.step(counts(r), refs).overrange);
        }
        let (p, s) = (integ.pose(), integ.sigma());
        (r.x, r.y, r.heading) = (p.x, p.y, p.heading);
        (r.sigma_x, r.sigma_y, r.sigma_heading, r.cov_xy) = (s.x, s.y, s.heading, s.cov_xy);
    }
    out
}

/// Every record of `got` equals the one of `want` at the same MCU time: pose, sigmas and
/// counts bit for bit.
fn assert_same_records(got: &[PoseRecord], want: &[PoseRecord]) {
    let key = |r: &PoseRecord| {
        (
            [r.x, r.y, r.heading].map(f64::to_bits),
            [r.sigma_x, r.sigma_y, r.sigma_heading, r.cov_xy].map(f32::to_bits),
            (r.gamma_left, r.gamma_right),
        )
    };
    for g in got {
        let w = want
            .iter()
            .find(|w| w.mcu_time_us == g.mcu_time_us)
            .expect("a record of the same sample");
        assert_eq!(key(g), key(w), "record at {} us", g.mcu_time_us);
    }
}

/// A flight controller's HEARTBEAT (system 1, component 1) in MAVLink 2, a signed MAVLink 2
/// frame (13 signature bytes) and a MAVLink 1 HEARTBEAT.
fn flight_controller_bytes() -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; odo_unit::mavlink::MAX_FRAME_LEN + 1];
    let hb = [0, 0, 0, 0, 2, 3, 81, 4, 3];
    let header = odo_unit::mavlink::FrameHeader {
        seq: 7,
        sysid: 1,
        compid: 1,
    };
    let id = odo_unit::mavlink::frame::MessageId {
        id: 0,
        crc_extra: 50,
    };
    let n = odo_unit::mavlink::encode_frame(&id, &hb, header, &mut buf);
    out.extend_from_slice(&buf[..n]);
    let n = odo_unit::mavlink::encode_frame(&id, &hb, header, &mut buf);
    buf[2] = 0x01; // signed: the CRC no longer matches; the unit skips it by its length
    out.extend_from_slice(&buf[..n]);
    out.extend_from_slice(&[0x5A; 13]);
    out.extend_from_slice(&[0xFE, 9, 8, 1, 1, 0]);
    out.extend_from_slice(&hb);
    out.extend_from_slice(&[0x12, 0x34]);
    out
}
