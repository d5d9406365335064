//! The UBX reader against frames built by independent writers: the Python `pyubx2` and
//! `pyrtcm` packages (tests/ubx/make_ubx.py) write a mixed log of UBX, NMEA and RTCM 3 across a
//! GPS week's end with the flags a reader must follow; every epoch's time, position, fix
//! quality, heading and sigmas must come out as the script says. Skipped with a message when
//! python3 or the packages are missing, unless `ODO_PY_REQUIRED=1` (CI).

mod common;

use std::process::Command;

use common::scratch;
use odoctl::reference::{self, Format, ReferenceOptions};

/// Whether the writer can run; panics when it cannot and CI requires it.
fn python_ready() -> bool {
    common::python_has("reference_ubx", "pyubx2, pyrtcm", "pyubx2")
}

#[test]
fn pyubx2_frames_are_read_by_their_flags() {
    if !python_ready() {
        return;
    }
    let file = scratch("reference_ubx").join("mixed.ubx");
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/ubx/make_ubx.py");
    let out = Command::new("python3")
        .arg(script)
        .arg(&file)
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let want: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let bytes = std::fs::read(&file).expect("the log");
    let log = reference::ubx::parse("mixed.ubx", &bytes, None).expect("read");
    let epochs = want["epochs"].as_array().expect("epochs");
    assert_eq!(log.epochs.len(), epochs.len(), "{}", log.report);
    for (e, w) in log.epochs.iter().zip(epochs) {
        let f = |k: &str| w[k].as_f64().expect(k);
        assert!((e.gps_time - f("gps_time")).abs() < 1e-6, "{e:?} {w}");
        assert!((e.position.lat_deg - f("lat")).abs() < 1e-10, "{e:?} {w}");
        assert!((e.position.lon_deg - f("lon")).abs() < 1e-10, "{e:?} {w}");
        assert!((e.position.height - f("height")).abs() < 1e-7, "{e:?} {w}");
        assert_eq!(format!("{:?}", e.fix), w["fix"].as_str().expect("fix"));
        match w["heading"].as_f64() {
            Some(h) => {
                let got = e.heading.expect("a heading").to_degrees();
                assert!((got - h).abs() < 1e-6, "{got} {h}");
            }
            None => assert_eq!(e.heading, None, "{w}"),
        }
        let s = e.sigma_north_east_up.expect("sigmas");
        assert!((s[0].hypot(s[1]) - f("hacc")).abs() < 1e-9, "{s:?} {w}");
        assert!((s[2] - f("vacc")).abs() < 1e-9, "{s:?} {w}");
    }
    let r = &log.report;
    assert_eq!(
        r.corrupt,
        want["corrupt"].as_u64().expect("corrupt") as usize,
        "{r}"
    );
    for (k, n) in want["other"].as_object().expect("other") {
        assert_eq!(
            r.other.get(k).copied(),
            n.as_u64().map(|n| n as usize),
            "{k}: {r}"
        );
    }
    assert!(r
        .notes
        .iter()
        .any(|n| n.starts_with("1 NAV-RELPOSNED headings with a static base")));
    // Recognised from the content, and the whole path to local metres works.
    let o = ReferenceOptions {
        min_fix: reference::MinFix::Any,
        ..ReferenceOptions::default()
    };
    let r = reference::parse("mixed.ubx", &bytes, &o).expect("reference");
    assert_eq!((r.format, r.report.used), (Format::Ubx, 4));
}
