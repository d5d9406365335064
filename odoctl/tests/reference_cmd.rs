//! `odoctl reference` end to end on an NMEA log written by the simulated receiver: the summary
//! names the rate, the gap and the fix qualities; `--to csv` is a REFERENCE CSV again; the
//! GeoJSON and GPX tracks are read back by independent readers (tests/reference_cmd/
//! check_exports.py: Python's `json` with RFC 7946 checks, and `gpxpy`), which compare every
//! point and UTC time. The Python part is skipped with a message when python3 or `gpxpy` is
//! missing, unless `ODO_PY_REQUIRED=1` (CI).

mod common;

use std::process::Command;

use common::{odoctl, scratch, success_stdout};
use odo_unit::timing::nmea::days_from_civil;
use odoctl::reference::geodetic::Geodetic;
use odoctl::reference::{gps_time, simulated, Epoch, FixQuality};

/// Whether the readers can run; panics when they cannot and CI requires them.
fn python_ready() -> bool {
    common::python_has("reference_cmd", "gpxpy", "gpxpy")
}

/// 2 Hz for 60 s from 2026-03-01 10:00:00 UTC, moving north 0.5 m a step; epochs 40..60
/// float; epochs 80..84 missing (a gap of 2.5 s).
fn epochs() -> (Vec<Epoch>, f64) {
    let start = gps_time::utc_to_gps(days_from_civil(2026, 3, 1), 36_000.0, 18).unwrap();
    let e = (0..120)
        .filter(|k| !(80..84).contains(k))
        .map(|k| Epoch {
            gps_time: start + f64::from(k) * 0.5,
            position: Geodetic {
                lat_deg: 49.2 + f64::from(k) * 0.5 / 111_200.0,
                lon_deg: 16.6,
                height: 300.0,
            },
            heading: Some(0.1),
            sigma_north_east_up: Some([0.01, 0.01, 0.02]),
            fix: if (40..60).contains(&k) {
                FixQuality::RtkFloat
            } else {
                FixQuality::RtkFixed
            },
            line: 0,
        })
        .collect();
    (e, start)
}

#[test]
fn summary_exports_and_independent_readers() {
    let dir = scratch("reference_cmd");
    let (epochs, start) = epochs();
    let log = dir.join("run.nmea");
    let mut bytes = Vec::new();
    simulated::write_nmea(&mut bytes, &epochs, 18).unwrap();
    std::fs::write(&log, &bytes).unwrap();
    let path = log.to_str().unwrap();
    let out = success_stdout(&odoctl(&["reference", path]));
    for want in [
        "NMEA 0183",
        "rate: 2.000 Hz",
        "gaps longer than twice the median interval: 1",
        "2.500 s after GPS week",
        "RTK float",
        "116 epochs read, 96 used",
        "heading: NMEA HDT on 116 of 116 epochs",
        "UTC 2026-03-01 10:00:00.000",
    ] {
        assert!(out.contains(want), "{want}:\n{out}");
    }
    // --to csv: a REFERENCE CSV (GPS time of week) the calibration reads.
    let csv = dir.join("track.csv");
    success_stdout(&odoctl(&[
        "reference",
        path,
        "--to",
        "csv",
        "-o",
        csv.to_str().unwrap(),
    ]));
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows = odoctl::csvio::parse_reference("track.csv", &text).unwrap();
    assert_eq!(rows.len(), 96);
    let (_, tow0) = gps_time::week_tow(start);
    assert!((rows[0].t - tow0).abs() < 1e-6, "{:?}", rows[0]);
    assert!((rows[1].y - 0.5).abs() < 0.01, "{:?}", rows[1]);
    // TUM: 8 columns a row.
    let tum = success_stdout(&odoctl(&["reference", path, "--to", "tum"]));
    let data: Vec<&str> = tum.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(data.len(), 96);
    assert!(data.iter().all(|l| l.split(' ').count() == 8), "{tum}");
    // GeoJSON and GPX, read back independently.
    let geojson = dir.join("track.geojson");
    let gpx = dir.join("track.gpx");
    for (f, p) in [("geojson", &geojson), ("gpx", &gpx)] {
        success_stdout(&odoctl(&[
            "reference",
            path,
            "--to",
            f,
            "-o",
            p.to_str().unwrap(),
        ]));
    }
    let expected = dir.join("expected.csv");
    let mut want = String::from("lat,lon,height,utc\n");
    for e in epochs.iter().filter(|e| e.fix == FixQuality::RtkFixed) {
        let s = e.gps_time - start;
        let ms = (s * 1000.0).round() as i64;
        want.push_str(&format!(
            "{:.10},{:.10},{:.4},2026-03-01T10:{:02}:{:02}.{:03}Z\n",
            e.position.lat_deg,
            e.position.lon_deg,
            e.position.height,
            ms / 60_000,
            ms / 1000 % 60,
            ms % 1000
        ));
    }
    std::fs::write(&expected, want).unwrap();
    // A CSV reference has no latitude and longitude: GeoJSON is refused, naming why.
    let o = odoctl(&["reference", csv.to_str().unwrap(), "--to", "geojson"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no latitude and longitude"));
    if !python_ready() {
        return;
    }
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/reference_cmd/check_exports.py"
    );
    let o = Command::new("python3")
        .arg(script)
        .args([&geojson, &gpx, &expected])
        .output()
        .expect("python3 runs");
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}
