//! End to end through the firmware's QEMU image: `odoctl config`, `record` and
//! `replay --check` against the real firmware on QEMU's `netduinoplus2`, its USART2 on a TCP
//! socket. Skipped (with a message) without `qemu-system-arm` or without the image
//! (`target/qemu/thumbv7em-none-eabihf/release/odo-unit`, built by
//! `cargo build --release --features qemu --target-dir target/qemu`, or `$ODO_QEMU_IMAGE`);
//! `ODO_QEMU_REQUIRED=1` turns a skip into a failure.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::{odoctl, read, scratch};

// odoctl talks to the unit itself; only the launcher of this module is used here.
#[allow(dead_code)]
#[path = "../../host-tests/support/qemu.rs"]
mod qemu_support;

/// Boots the image for `test` and waits for its USART2 socket: QEMU (killed when dropped)
/// and the link's address; `None` when the test is skipped.
fn boot(test: &str) -> Option<(qemu_support::Qemu, String)> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let qemu = qemu_support::boot(&repo, test)?;
    let port = qemu.port;
    let start = Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "QEMU's USART2 socket did not open"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    Some((qemu, format!("tcp:127.0.0.1:{port}")))
}

/// `odoctl ARGS`, retried while it cannot connect: QEMU may still be dropping the probe
/// connection of [`boot`].
fn run_retrying(addr: &str, args: &[&str]) -> std::process::Output {
    for _ in 0..20 {
        let o = odoctl(args);
        if !String::from_utf8_lossy(&o.stderr).contains("cannot connect") {
            return o;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("cannot connect to {addr}");
}

#[test]
fn odoctl_against_the_qemu_image() {
    let Some((_qemu, addr)) = boot("odoctl_against_the_qemu_image") else {
        return;
    };
    let run = |args: &[&str]| run_retrying(&addr, args);
    let d = scratch("qemu");
    let started = Instant::now();
    let o = run(&["config", "--port", &addr, "set", "track_width", "0.57"]);
    common::success_stdout(&o);
    let o = run(&["config", "--port", &addr, "set", "track_width", "nan"]);
    assert!(
        !o.status.success(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("error"));
    let o = run(&["config", "--port", &addr, "get", "track_width"]);
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("track_width = 0.57"),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let csv = d.join("rec.csv");
    let o = run(&[
        "record",
        "--port",
        &addr,
        "--out",
        csv.to_str().unwrap(),
        "--count",
        "600",
        "--reset-pose",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("recorded 600 records") && err.contains("CRC errors 0"),
        "{err}"
    );
    assert!(read(&csv).lines().count() == 601);
    let o = odoctl(&[
        "replay",
        csv.to_str().unwrap(),
        "--set",
        "track_width=0.57",
        "--check",
        "--out",
        d.join("replay.csv").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    eprintln!(
        "odoctl against QEMU: {:.1} s, {}",
        started.elapsed().as_secs_f64(),
        String::from_utf8_lossy(&o.stderr).trim()
    );
}

/// A `pub const NAME: f64 = VALUE;` of the QEMU drive's source: its simulated truth.
fn qemu_truth(name: &str) -> f64 {
    let src = include_str!("../../src/board/qemu/drive.rs");
    let line = src
        .lines()
        .find(|l| l.starts_with(&format!("pub const {name}: f64 = ")))
        .unwrap_or_else(|| panic!("{name} in src/board/qemu/drive.rs"));
    line.split('=')
        .nth(1)
        .unwrap()
        .trim()
        .trim_end_matches(';')
        .parse()
        .unwrap()
}

/// The calibration drive in one command against the firmware: locked to the simulated
/// receiver's PPS, the unit forwards its GGA/GST/RMC/HDT; `record --calibrate` shows the live
/// estimate, ends with the batch calibration of the recording and its NMEA log, which recovers
/// the simulated chassis; `calibrate` takes the recording alone and `config push` sends the
/// result.
#[test]
fn calibration_drive_in_one_command_against_the_qemu_image() {
    let Some((_qemu, addr)) = boot("calibration_drive_in_one_command") else {
        return;
    };
    let run = |args: &[&str]| run_retrying(&addr, args);
    let d = scratch("qemu_calibration_drive");
    let o = run(&["config", "--port", &addr, "set", "mode", "pps"]);
    common::success_stdout(&o);
    let csv = d.join("drive.csv");
    let result = d.join("chassis.toml");
    let started = Instant::now();
    // Nine laps of the simulated path (20 s each) at 50 Hz.
    let o = run(&[
        "record",
        "--port",
        &addr,
        "--out",
        csv.to_str().unwrap(),
        "--count",
        "9000",
        "--calibrate",
        "--result",
        result.to_str().unwrap(),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{out}\n{err}");
    eprintln!(
        "record --calibrate: {:.1} s\n{out}\n{err}",
        started.elapsed().as_secs_f64()
    );
    assert!(d.join("drive.nmea").is_file(), "{err}");
    let truth = [
        qemu_truth("TRUE_LEFT_DIAMETER"),
        qemu_truth("TRUE_RIGHT_DIAMETER"),
        qemu_truth("TRUE_TRACK_WIDTH"),
    ];
    let p = odoctl::config::read_params(&result, odo_unit::odometry::ChassisParams::DESIGNED)
        .expect("the drive's result");
    let g = p.geometry_uncertainty;
    let se = [g.left_diameter_se, g.right_diameter_se, g.track_width_se].map(f64::from);
    let est = common::lengths(&p);
    for k in 0..3 {
        assert!(
            (est[k] - truth[k]).abs() <= 4.0 * se[k],
            "parameter {k}: {} against the truth {} (standard error {})",
            est[k],
            truth[k],
            se[k]
        );
    }
    // The recording alone calibrates as well (the log is found beside it), to within a
    // hundredth of the standard errors of the final, which started warm from the last batch.
    let again = d.join("again.toml");
    let o = odoctl(&[
        "calibrate",
        "--samples",
        csv.to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    common::success_stdout(&o);
    let files = common::lengths(
        &odoctl::config::read_params(&again, odo_unit::odometry::ChassisParams::DESIGNED).unwrap(),
    );
    for k in 0..3 {
        assert!(
            (files[k] - est[k]).abs() <= 0.01 * se[k],
            "parameter {k}: {} from the files against {} recorded (standard error {})",
            files[k],
            est[k],
            se[k]
        );
    }
    let o = run(&[
        "config",
        "--port",
        &addr,
        "push",
        result.to_str().unwrap(),
        "--no-save",
    ]);
    common::success_stdout(&o);
}
