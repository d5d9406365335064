//! The reference input end to end: a simulated receiver logs the simulated run (NMEA and
//! RTKLIB `.pos`), the loader reads the files back, and the local reference it hands to the
//! calibration is the antenna's true path; boundary tables over hemispheres, day and week
//! rollover, leap seconds, corrupt sentences, missing dates and float epochs.

mod common;

use std::f64::consts::PI;

use odoctl::csvio::{RefPoint, Sample};
use odoctl::reference::geodetic::{Geodetic, LocalFrame};
use odoctl::reference::gps_time::{self, WEEK};
use odoctl::reference::simulated::{self, PosTime, ReceiverSim};
use odoctl::reference::{
    self, antenna_position, FixQuality, Format, MinFix, OriginChoice, ReferenceOptions,
};
use odoctl::simulate::{PathKind, Rng};

fn nmea_bytes(epochs: &[reference::Epoch], leap: i32) -> Vec<u8> {
    let mut v = Vec::new();
    simulated::write_nmea(&mut v, epochs, leap).unwrap();
    v
}

fn pos_bytes(epochs: &[reference::Epoch], t: PosTime) -> Vec<u8> {
    let mut v = Vec::new();
    simulated::write_pos(&mut v, epochs, t).unwrap();
    v
}

/// The samples' time range when `record` stamps them with GPS time of week from `gps_start`.
fn tow_range(samples: &[Sample], gps_start: f64) -> (f64, f64) {
    let (_, tow0) = gps_time::week_tow(gps_start);
    (tow0 + samples[0].t, tow0 + samples.last().unwrap().t)
}

/// The largest horizontal distance between reference rows and the antenna's true path at the
/// same sample instants (`tow0` + sample time), and how many rows were compared.
fn worst_error(
    points: &[RefPoint],
    samples: &[Sample],
    truth: &[(f64, f64, f64)],
    tow0: f64,
    antenna: (f64, f64),
) -> (f64, usize) {
    let mut worst = 0.0f64;
    let mut n = 0;
    let mut i = 0;
    for p in points {
        while i < samples.len() && samples[i].t + tow0 < p.t - 1e-4 {
            i += 1;
        }
        assert!(
            i < samples.len() && (samples[i].t + tow0 - p.t).abs() < 1e-4,
            "{p:?}"
        );
        let (x, y, h) = truth[i];
        let (ax, ay) = antenna_position(x, y, h, antenna.0, antenna.1);
        worst = worst.max((p.x - ax).hypot(p.y - ay));
        n += 1;
    }
    (worst, n)
}

#[test]
fn nmea_and_pos_of_a_simulated_run_give_the_antenna_path() {
    let run = common::sim(PathKind::Estimation, 70.0, 3);
    let sim = ReceiverSim {
        antenna: (0.35, -0.12),
        rtk_sigma: 0.0,
        float_sigma: 0.05,
        float_fraction: 0.15,
        heading_sigma: Some(0.0),
        // Near the end of GPS week 2301, so that the run crosses into week 2302 (and, at 18
        // leap seconds, UTC Saturday 23:59:42 is the week's end: no day change there).
        gps_start: 2302.0 * WEEK - 40.0,
        ..ReceiverSim::default()
    };
    let times: Vec<f64> = run.samples.iter().map(|s| s.t).collect();
    let epochs = simulated::receiver_epochs(&times, &run.truth, &sim);
    let floats = epochs
        .iter()
        .filter(|e| e.fix == FixQuality::RtkFloat)
        .count();
    assert!(
        floats > 0 && epochs.len() > 1000,
        "{floats} of {}",
        epochs.len()
    );
    let (_, tow0) = gps_time::week_tow(sim.gps_start);
    let range = tow_range(&run.samples, sim.gps_start);
    let o = ReferenceOptions {
        origin: OriginChoice::Given(sim.origin),
        ..ReferenceOptions::default()
    };
    let files = [
        ("run.nmea", nmea_bytes(&epochs, 18), Format::Nmea),
        (
            "run.pos",
            pos_bytes(&epochs, PosTime::Calendar),
            Format::Rtklib,
        ),
        (
            "run-wt.pos",
            pos_bytes(&epochs, PosTime::WeekTow),
            Format::Rtklib,
        ),
    ];
    for (name, bytes, format) in &files {
        let r = reference::parse(name, bytes, &o).unwrap();
        assert_eq!(r.format, *format);
        assert_eq!(r.report.epochs, epochs.len(), "{name}");
        assert_eq!(r.report.used, epochs.len() - floats, "{name}");
        assert_eq!(r.report.below_min_fix[&FixQuality::RtkFloat], floats);
        let points = r.ref_points(range).unwrap();
        // Strictly increasing across the week's end (time of week past 604,800 s).
        assert!(points.windows(2).all(|w| w[1].t > w[0].t));
        assert!(points.last().unwrap().t > WEEK, "{name}");
        let (worst, n) = worst_error(&points, &run.samples, &run.truth, tow0, sim.antenna);
        assert_eq!(n, epochs.len() - floats);
        // The files' resolution: 1e-8 arc minute (NMEA), 1e-9 degree (.pos): 0.1 mm.
        eprintln!(
            "{name}: {n} epochs used, worst horizontal error {:.3} mm",
            worst * 1e3
        );
        assert!(worst < 2e-4, "{name}: worst {worst} m");
        if *format == Format::Nmea {
            // HDT: 0.001 degree.
            let r0 = &r.epochs[5];
            let i = run
                .samples
                .iter()
                .position(|s| (s.t + tow0 - (r0.t - (2301.0 * WEEK))).abs() < 1e-4)
                .unwrap();
            let dh = odoctl::stats::wrap_angle(r0.heading.unwrap() - run.truth[i].2);
            assert!(dh.abs() < 1e-5, "{dh}");
        }
    }
    // --min-fix float uses every epoch; the float ones carry their noise (5 cm RMS).
    let all = reference::parse(
        "run.nmea",
        &files[0].1,
        &ReferenceOptions {
            min_fix: MinFix::Float,
            ..o
        },
    )
    .unwrap();
    assert_eq!(all.report.used, epochs.len());
    let (worst, _) = worst_error(
        &all.ref_points(range).unwrap(),
        &run.samples,
        &run.truth,
        tow0,
        sim.antenna,
    );
    eprintln!("--min-fix float: worst error {:.1} mm", worst * 1e3);
    assert!(worst > 0.02, "{worst}");
}

#[test]
fn property_enu_through_nmea_and_pos_within_a_millimetre_anywhere() {
    let mut rng = Rng::new(17);
    let mut worst = 0.0f64;
    for case in 0..200 {
        let origin = Geodetic {
            lat_deg: (rng.uniform() * 2.0 - 1.0) * 80.0,
            lon_deg: (rng.uniform() * 2.0 - 1.0) * 180.0,
            height: rng.uniform() * 3000.0 - 100.0,
        };
        let frame = LocalFrame::new(origin);
        // Points up to 1 km away, in every direction, 0..1 s apart.
        let enu: Vec<[f64; 3]> = (0..5)
            .map(|_| {
                let a = rng.uniform() * 2.0 * PI;
                let d = rng.uniform() * 1000.0;
                [d * a.sin(), d * a.cos(), rng.uniform() * 20.0 - 10.0]
            })
            .collect();
        let t0 = 2200.0 * WEEK + (rng.uniform() * WEEK * 100.0).floor() / 10.0;
        let epochs: Vec<reference::Epoch> = enu
            .iter()
            .enumerate()
            .map(|(k, p)| reference::Epoch {
                gps_time: t0 + k as f64 * 0.2,
                position: frame.to_geodetic(*p),
                heading: None,
                sigma: None,
                fix: FixQuality::RtkFixed,
                line: 0,
            })
            .collect();
        let o = ReferenceOptions {
            origin: OriginChoice::Given(origin),
            ..ReferenceOptions::default()
        };
        for (name, bytes) in [
            ("p.nmea", nmea_bytes(&epochs, 18)),
            ("p.pos", pos_bytes(&epochs, PosTime::WeekTow)),
        ] {
            let r = reference::parse(name, &bytes, &o).unwrap();
            assert_eq!(r.epochs.len(), 5, "case {case} {name}");
            for (e, p) in r.epochs.iter().zip(&enu) {
                let err = (e.x - p[0]).hypot(e.y - p[1]);
                worst = worst.max(err);
                assert!(err < 1e-3, "case {case} {name}: {origin:?} {p:?}: {err} m");
                assert!((e.t - epochs[0].gps_time).abs() < 1.0 + 1e-6);
            }
        }
    }
    eprintln!(
        "1,000 points up to 1 km, both files: worst horizontal error {:.4} mm",
        worst * 1e3
    );
}

#[test]
fn hemisphere_sign_table() {
    // (origin, step north m, step east m): the local signs follow the step, whatever the
    // hemisphere's letters.
    for (lat, lon) in [
        (49.2, 16.6),
        (-33.9, 151.2),
        (40.7, -74.0),
        (-34.6, -58.4),
        (0.0, 0.0),
        (0.01, 179.999),
    ] {
        let origin = Geodetic {
            lat_deg: lat,
            lon_deg: lon,
            height: 50.0,
        };
        let frame = LocalFrame::new(origin);
        let steps = [(10.0, 0.0), (0.0, 10.0), (-10.0, 0.0), (0.0, -10.0)];
        let epochs: Vec<reference::Epoch> = steps
            .iter()
            .enumerate()
            .map(|(k, (n, e))| reference::Epoch {
                gps_time: 2350.0 * WEEK + 1000.0 + k as f64,
                position: frame.to_geodetic([*e, *n, 0.0]),
                heading: None,
                sigma: None,
                fix: FixQuality::RtkFixed,
                line: 0,
            })
            .collect();
        let text = String::from_utf8(nmea_bytes(&epochs, 18)).unwrap();
        let ns = if lat < 0.0 { ",S," } else { ",N," };
        let ew = if lon < 0.0 { ",W," } else { ",E," };
        assert!(text.contains(ns) && text.contains(ew), "{text}");
        let r = reference::parse(
            "h.nmea",
            text.as_bytes(),
            &ReferenceOptions {
                origin: OriginChoice::Given(origin),
                ..ReferenceOptions::default()
            },
        )
        .unwrap();
        for (e, (n, ea)) in r.epochs.iter().zip(steps) {
            assert!(
                (e.y - n).abs() < 1e-4 && (e.x - ea).abs() < 1e-4,
                "{lat},{lon}: {e:?}"
            );
        }
    }
}

/// A short log: `n` fixed epochs at 10 Hz from `gps_start`, standing at the origin.
fn still_epochs(gps_start: f64, n: usize) -> Vec<reference::Epoch> {
    let origin = ReceiverSim::default().origin;
    (0..n)
        .map(|k| reference::Epoch {
            gps_time: gps_start + k as f64 * 0.1,
            position: origin,
            heading: None,
            sigma: Some([0.005, 0.005, 0.01]),
            fix: FixQuality::RtkFixed,
            line: 0,
        })
        .collect()
}

#[test]
fn day_week_and_leap_second_table() {
    // (GPS start, leap seconds written, leap seconds read, GPS shift expected on reading).
    let table = [
        // UTC midnight (day rollover) in the middle of a week.
        (2300.0 * WEEK + 86_400.0 * 3.0 + 18.0 - 1.0, 18, 18, 0.0),
        // GPS week rollover (Saturday 23:59:42 UTC).
        (2301.0 * WEEK - 1.0, 18, 18, 0.0),
        // The end of the year.
        (
            gps_time::utc_to_gps(
                odo_core::timing::nmea::days_from_civil(2026, 12, 31),
                86_399.0,
                18,
            )
            .unwrap(),
            18,
            18,
            0.0,
        ),
        // Read with one leap second too many: everything one second later.
        (2300.0 * WEEK + 5000.0, 18, 19, 1.0),
        // Before 2017's leap second: a log of 2016 read with 17.
        (1_167_264_000.0, 17, 17, 0.0),
    ];
    for (start, written, read, shift) in table {
        let epochs = still_epochs(start, 20);
        let r = reference::parse(
            "t.nmea",
            &nmea_bytes(&epochs, written),
            &ReferenceOptions {
                leap_seconds: read,
                ..ReferenceOptions::default()
            },
        )
        .unwrap();
        assert_eq!(r.epochs.len(), 20, "{start}");
        for (a, b) in r.epochs.iter().zip(&epochs) {
            assert!(
                (a.t - b.gps_time - shift).abs() < 1e-6,
                "{start}: {} {}",
                a.t,
                b.gps_time
            );
        }
    }
}

#[test]
fn a_log_that_misses_the_samples_is_refused_naming_both_ranges() {
    let start = 2300.0 * WEEK + 7200.0;
    let epochs = still_epochs(start, 50);
    let r = reference::parse(
        "x.nmea",
        &nmea_bytes(&epochs, 18),
        &ReferenceOptions::default(),
    )
    .unwrap();
    assert_eq!(r.ref_points((7200.0, 7205.0)).unwrap().len(), 50);
    let e = r.ref_points((9000.0, 9100.0)).unwrap_err().to_string();
    assert!(
        e.contains("x.nmea: the reference does not overlap")
            && e.contains("GPS week 2300 TOW 7200.000 s (UTC 2024-02-04 01:59:42.000)")
            && e.contains("9000.000 .. 9100.000"),
        "{e}"
    );
    // The MCU clock of an unsynchronised run (t from 0) does not overlap either.
    assert!(r.ref_points((0.0, 60.0)).is_err());
}

#[test]
fn corrupted_bytes_are_skipped_and_counted() {
    let epochs = still_epochs(2300.0 * WEEK + 600.0, 200);
    let clean = nmea_bytes(&epochs, 18);
    let mut rng = Rng::new(5);
    let mut bytes = clean.clone();
    // Change one character inside 30 different sentences (between `$` and `*`).
    let starts: Vec<usize> = (0..bytes.len()).filter(|&i| bytes[i] == b'$').collect();
    let mut hit = std::collections::BTreeSet::new();
    while hit.len() < 30 {
        let s = starts[(rng.uniform() * starts.len() as f64) as usize];
        if !hit.insert(s) {
            continue;
        }
        let star = s + bytes[s..].iter().position(|b| *b == b'*').unwrap();
        let k = s + 1 + (rng.uniform() * (star - s - 1) as f64) as usize;
        bytes[k] = if bytes[k] == b'7' { b'8' } else { b'7' };
    }
    let name = "c.nmea";
    let r = reference::parse(name, &bytes, &ReferenceOptions::default()).unwrap();
    let rep = &r.report.read;
    assert_eq!(rep.corrupt, 30, "{rep}");
    assert!(
        rep.problems.iter().all(|p| p.starts_with("c.nmea:")),
        "{rep}"
    );
    // At most 30 epochs lost (a corrupt GGA), the rest used.
    assert!(
        r.epochs.len() >= 170 && r.epochs.len() <= 200,
        "{}",
        r.epochs.len()
    );
    let clean_r = reference::parse(name, &clean, &ReferenceOptions::default()).unwrap();
    assert_eq!(clean_r.report.read.corrupt, 0);
    assert_eq!(clean_r.report.read.other["GSV"], 20);
}

#[test]
fn missing_date_and_nothing_usable_are_errors_with_the_file() {
    let epochs = still_epochs(2300.0 * WEEK + 600.0, 10);
    let text = String::from_utf8(nmea_bytes(&epochs, 18)).unwrap();
    let undated: String = text
        .lines()
        .filter(|l| !l.contains("RMC") && !l.contains("ZDA"))
        .map(|l| format!("{l}\n"))
        .collect();
    let e = reference::parse("u.nmea", undated.as_bytes(), &ReferenceOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("u.nmea: no date"), "{e}");
    // Only float epochs and the default --min-fix fixed.
    let floats: Vec<reference::Epoch> = epochs
        .iter()
        .map(|e| reference::Epoch {
            fix: FixQuality::RtkFloat,
            ..*e
        })
        .collect();
    let e = reference::parse(
        "f.pos",
        &pos_bytes(&floats, PosTime::Calendar),
        &ReferenceOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("f.pos: no epoch has the required fix quality") && e.contains("10 RTK float"),
        "{e}"
    );
    // A forced format that does not fit the content.
    let e = reference::parse(
        "f.pos",
        &pos_bytes(&floats, PosTime::Calendar),
        &ReferenceOptions {
            format: Some(Format::Nmea),
            ..ReferenceOptions::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("f.pos: no usable position"), "{e}");
}

#[test]
fn load_detects_the_format_from_the_content() {
    let d = common::scratch("reference_load");
    let epochs = still_epochs(2300.0 * WEEK + 600.0, 10);
    let files = [
        ("a.txt", nmea_bytes(&epochs, 18), Format::Nmea),
        (
            "b.txt",
            pos_bytes(&epochs, PosTime::WeekTow),
            Format::Rtklib,
        ),
        ("c.txt", b"t,x,y\n0,0,0\n1,1,1\n".to_vec(), Format::Csv),
    ];
    for (name, bytes, f) in files {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        let r = reference::load(&p, &ReferenceOptions::default()).unwrap();
        assert_eq!(r.format, f);
        assert_eq!(r.file, p.display().to_string());
    }
    let e = reference::load(&d.join("missing.nmea"), &ReferenceOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.nmea: cannot read"), "{e}");
}
