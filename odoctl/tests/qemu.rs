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

#[test]
fn odoctl_against_the_qemu_image() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let Some(qemu) = qemu_support::boot(&repo, "odoctl_against_the_qemu_image") else {
        return;
    };
    let port = qemu.port;
    let addr = format!("tcp:127.0.0.1:{port}");
    // Wait for QEMU's socket.
    let start = Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "QEMU's USART2 socket did not open"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let d = scratch("qemu");
    let started = Instant::now();
    // Retry connecting once: QEMU may still be dropping the probe connection above.
    let run = |args: &[&str]| {
        for _ in 0..20 {
            let o = odoctl(args);
            if !String::from_utf8_lossy(&o.stderr).contains("cannot connect") {
                return o;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        panic!("cannot connect to {addr}");
    };
    let o = run(&["config", "--port", &addr, "set", "track_width", "0.57"]);
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
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
