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
        // Any tenth of a second from GPS week 1000 (1999) to 2560 (2029), any leap count in
        // 13..=18: the times come back exactly (to the NMEA centisecond).
        let t0 = 1000.0 * WEEK + (rng.uniform() * WEEK * 1560.0 * 10.0).floor() / 10.0;
        let leap = 13 + (rng.uniform() * 6.0) as i32;
        let epochs: Vec<reference::Epoch> = enu
            .iter()
            .enumerate()
            .map(|(k, p)| reference::Epoch {
                gps_time: t0 + k as f64 * 0.2,
                position: frame.to_geodetic(*p),
                heading: None,
                sigma_north_east_up: None,
                fix: FixQuality::RtkFixed,
                line: 0,
            })
            .collect();
        let o = ReferenceOptions {
            origin: OriginChoice::Given(origin),
            leap_seconds: Some(leap),
            ..ReferenceOptions::default()
        };
        for (name, bytes) in [
            ("p.nmea", nmea_bytes(&epochs, leap)),
            ("p.pos", pos_bytes(&epochs, PosTime::WeekTow)),
        ] {
            let r = reference::parse(name, &bytes, &o).unwrap();
            assert_eq!(r.epochs.len(), 5, "case {case} {name}");
            for ((e, p), w) in r.epochs.iter().zip(&enu).zip(&epochs) {
                let err = (e.x - p[0]).hypot(e.y - p[1]);
                worst = worst.max(err);
                assert!(err < 1e-3, "case {case} {name}: {origin:?} {p:?}: {err} m");
                assert!(
                    (e.t - w.gps_time).abs() < 1e-6,
                    "case {case} {name}: {} {}",
                    e.t,
                    w.gps_time
                );
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
                sigma_north_east_up: None,
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
            sigma_north_east_up: Some([0.005, 0.005, 0.01]),
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
                odo_unit::timing::nmea::days_from_civil(2026, 12, 31),
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
                leap_seconds: Some(read),
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

/// `calibrate --out` of a run from one reference file: (left, right, track) estimates and
/// their standard errors, and stdout.
fn calibrate_cli(
    samples: &std::path::Path,
    reference: &std::path::Path,
    extra: &[&str],
) -> ([f64; 3], [f64; 3], String) {
    let out = reference.with_extension("toml");
    let mut args = vec![
        "calibrate",
        "--samples",
        samples.to_str().unwrap(),
        "--reference",
        reference.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--no-delta",
        "--quiet",
    ];
    args.extend_from_slice(extra);
    let stdout = common::success_stdout(&common::odoctl(&args));
    let t: toml::Table = common::read(&out).parse().unwrap();
    let fit = t["fit"].as_table().unwrap();
    let num = |tab: &toml::Table, k: &str| tab[k].as_float().unwrap_or_else(|| panic!("{k}"));
    (
        ["left_diameter", "right_diameter", "track_width"].map(|k| num(&t, k)),
        ["left_diameter_se", "right_diameter_se", "track_width_se"].map(|k| num(fit, k)),
        stdout,
    )
}

/// `calibrate_cli` of the run `dir/s.csv` from each receiver log of `dir` (`r.nmea`,
/// `r.pos`) with the options `extra`, against the same run's estimates and standard errors
/// from its CSV reference (`csv`): each summary has `stdout_has`; the log's standard errors
/// are between `se_ratio.0` and `se_ratio.1` times the CSV's; and its estimate is no further
/// from `truth` than the CSV's plus 10 of its standard errors (the run's slip, not the
/// reference noise, dominates the error to the truth; the standard errors, which take the
/// residuals as independent, do not show it). Prints the errors, labelled `label`.
fn check_logs_against_csv(
    dir: &std::path::Path,
    extra: &[&str],
    (csv, csv_se): ([f64; 3], [f64; 3]),
    truth: [f64; 3],
    se_ratio: (f64, f64),
    stdout_has: &str,
    label: &str,
) {
    for file in ["r.nmea", "r.pos"] {
        let (est, se, stdout) = calibrate_cli(&dir.join("s.csv"), &dir.join(file), extra);
        assert!(stdout.contains(stdout_has), "{label}: {stdout}");
        for k in 0..3 {
            assert!(
                se[k] > se_ratio.0 * csv_se[k] && se[k] < se_ratio.1 * csv_se[k],
                "{file} {k} ({label}): {se:?} {csv_se:?}"
            );
            let (e, e_csv) = ((est[k] - truth[k]).abs(), (csv[k] - truth[k]).abs());
            assert!(
                e < e_csv + 10.0 * se[k],
                "{file} {k} ({label}): {est:?} (CSV {csv:?}, se {se:?})"
            );
        }
        eprintln!(
            "{file}, {label}: errors {:.1} {:.1} {:.1} um, standard errors {:.1} {:.1} {:.1} um (CSV {:.1} {:.1} {:.1} um, {:.1} {:.1} {:.1} um)",
            (est[0] - truth[0]) * 1e6,
            (est[1] - truth[1]) * 1e6,
            (est[2] - truth[2]) * 1e6,
            se[0] * 1e6,
            se[1] * 1e6,
            se[2] * 1e6,
            (csv[0] - truth[0]) * 1e6,
            (csv[1] - truth[1]) * 1e6,
            (csv[2] - truth[2]) * 1e6,
            csv_se[0] * 1e6,
            csv_se[1] * 1e6,
            csv_se[2] * 1e6
        );
    }
}

#[test]
fn cli_simulate_logs_then_calibrate_from_each_format() {
    let d = common::scratch("reference_cli");
    let p = |n: &str| d.join(n);
    let s = |n: &str| p(n).to_str().unwrap().to_string();
    let out = common::success_stdout(&common::odoctl(&[
        "simulate",
        "--samples",
        &s("s.csv"),
        "--reference",
        &s("r.csv"),
        "--nmea",
        &s("r.nmea"),
        "--pos",
        &s("r.pos"),
        "--pos-time",
        "week-tow",
        "--seed",
        "8",
    ]));
    assert!(
        out.contains("receiver log: ") && out.contains("RTK float"),
        "{out}"
    );
    // The samples carry GPS time of week (week 2400, 302,400 s by default).
    let samples = common::read(&p("s.csv"));
    assert!(
        samples
            .lines()
            .nth(1)
            .unwrap()
            .starts_with("302400.000000,"),
        "{samples:.200}"
    );
    let truth = [0.2608, 0.2607, 0.5656];
    // The sub-trajectory estimate, whose errors are set by the points it has (the default's
    // filter refinement is limited by the slip instead: below). A fifth of the CSV's points
    // (10 Hz against 50 Hz, float epochs left out): standard errors about sqrt(5) larger.
    let plain = ["--geometry-refine", "none"];
    let (csv, csv_se, _) = calibrate_cli(&p("s.csv"), &p("r.csv"), &plain);
    check_logs_against_csv(
        &d,
        &plain,
        (csv, csv_se),
        truth,
        (1.0, 3.0),
        "left out for their fix quality (--min-fix):",
        "sub-trajectory",
    );
    // The default, refined by the filter: its errors are the slip's during the turns, which a
    // fifth of the points hardly changes.
    let (csv, csv_se, stdout) = calibrate_cli(&p("s.csv"), &p("r.csv"), &[]);
    assert!(stdout.contains("refined by the filter"), "{stdout}");
    check_logs_against_csv(
        &d,
        &[],
        (csv, csv_se),
        truth,
        (0.7, 3.0),
        "refined by the filter",
        "refined",
    );
    // The same log, forced and with float epochs: used counts in the summary.
    let (_, _, stdout) = calibrate_cli(
        &p("s.csv"),
        &p("r.nmea"),
        &[
            "--reference-format",
            "nmea",
            "--min-fix",
            "float",
            "--origin",
            "49.2,16.6,300",
        ],
    );
    assert!(
        stdout.contains("(given)") && !stdout.contains("left out for their fix"),
        "{stdout}"
    );

    // Samples on another time base (the MCU clock, t from 0): refused, naming both ranges.
    common::success_stdout(&common::odoctl(&[
        "simulate",
        "--samples",
        &s("mcu.csv"),
        "--reference",
        &s("mcu_r.csv"),
    ]));
    let o = common::odoctl(&[
        "calibrate",
        "--samples",
        &s("mcu.csv"),
        "--reference",
        &s("r.nmea"),
        "--quiet",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        err.contains("does not overlap")
            && err.contains("TOW 302400.000 s")
            && err.contains("samples t = 0.000 .."),
        "{err}"
    );
    // Bad options.
    for (flag, value) in [
        ("--origin", "91,0,0"),
        ("--leap-seconds", "-3"),
        ("--reference-format", "gpx"),
    ] {
        let o = common::odoctl(&[
            "validate",
            "--samples",
            &s("s.csv"),
            "--reference",
            &s("r.nmea"),
            flag,
            value,
        ]);
        assert_ne!(o.status.code(), Some(0), "{flag} {value}");
    }
}

#[test]
fn cli_simulated_antenna_moves_every_reference() {
    let d = common::scratch("reference_cli_antenna");
    let s = |n: &str| d.join(n).to_str().unwrap().to_string();
    for (name, antenna) in [("a", None), ("b", Some("0.35,-0.1"))] {
        let mut args = vec![
            "simulate".to_string(),
            "--samples".into(),
            s(&format!("{name}.csv")),
            "--reference".into(),
            s(&format!("{name}_r.csv")),
            "--nmea".into(),
            s(&format!("{name}.nmea")),
            "--rtk-sigma".into(),
            "0".into(),
        ];
        if let Some(a) = antenna {
            args.extend(["--antenna".to_string(), a.to_string()]);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        common::success_stdout(&common::odoctl(&args));
    }
    let csv = |n: &str| odoctl::csvio::read_reference(std::path::Path::new(&s(n))).unwrap();
    let (a, b) = (csv("a_r.csv"), csv("b_r.csv"));
    // Same run, same noise-free centre: the offset is R(heading) (0.35, -0.1), 0.364 m long.
    for (p, q) in a.iter().zip(&b) {
        let d = (q.x - p.x).hypot(q.y - p.y);
        assert!((d - 0.35f64.hypot(0.1)).abs() < 1e-9, "{p:?} {q:?}");
        let h = p.heading.unwrap();
        let (ex, ey) = antenna_position(p.x, p.y, h, 0.35, -0.1);
        // The CSV heading carries 0.5 degree noise: 0.36 m x 5 sigma = 16 mm at worst.
        assert!((ex - q.x).hypot(ey - q.y) < 0.02, "{p:?} {q:?}");
    }
    // The NMEA log of b is b's CSV at 10 Hz (to the log's resolution).
    let o = ReferenceOptions {
        min_fix: MinFix::Float,
        origin: OriginChoice::Given(ReceiverSim::default().origin),
        ..ReferenceOptions::default()
    };
    let r = reference::load(std::path::Path::new(&s("b.nmea")), &o).unwrap();
    let pts = r.ref_points((b[0].t, b.last().unwrap().t)).unwrap();
    let mut j = 0;
    let mut worst = 0.0f64;
    for p in pts.iter().filter(|_| true) {
        while (b[j].t - p.t).abs() > 1e-4 {
            j += 1;
        }
        worst = worst.max((b[j].x - p.x).hypot(b[j].y - p.y));
    }
    // Float epochs carry 5 cm noise; fixed ones none (--rtk-sigma 0).
    let fixed_worst = pts
        .iter()
        .zip(&r.epochs)
        .filter(|(_, e)| e.fix == FixQuality::RtkFixed)
        .map(|(p, _)| {
            let q = b.iter().find(|q| (q.t - p.t).abs() < 1e-4).unwrap();
            (q.x - p.x).hypot(q.y - p.y)
        })
        .fold(0.0f64, f64::max);
    assert!(fixed_worst < 2e-4, "{fixed_worst}");
    assert!(worst > 0.01, "{worst}");
}

/// A simulated log's lines, and the log with line `k` replaced by `f(line)` (the checksum
/// recomputed).
fn edit_sentence(text: &str, k: usize, f: impl Fn(&str) -> String) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let body = lines[k][1..lines[k].rfind('*').unwrap()].to_string();
    lines[k] = reference::nmea::with_checksum(&f(&body));
    lines.join("\r\n") + "\r\n"
}

/// One RMC dated 1980-01-01 (before the GPS epoch) in an otherwise good log is counted and
/// skipped like a corrupt sentence: the epochs are dated by the other date sentences, none
/// is lost, and their times are those of the clean log.
#[test]
fn a_date_before_the_gps_epoch_is_counted_and_skipped() {
    let epochs = still_epochs(2300.0 * WEEK + 600.0, 40);
    let clean = String::from_utf8(nmea_bytes(&epochs, 18)).unwrap();
    let o = ReferenceOptions::default();
    let want = reference::parse("c.nmea", clean.as_bytes(), &o).unwrap();
    let rmcs: Vec<usize> = (0..clean.lines().count())
        .filter(|&i| clean.lines().nth(i).unwrap().contains("RMC"))
        .collect();
    for k in [rmcs[0], rmcs[17], *rmcs.last().unwrap()] {
        let bad = edit_sentence(&clean, k, |body| {
            let mut f: Vec<&str> = body.split(',').collect();
            f[9] = "010180";
            f.join(",")
        });
        let r = reference::parse("d.nmea", bad.as_bytes(), &o)
            .unwrap_or_else(|e| panic!("line {}: {e:#}", k + 1));
        let rep = &r.report.read;
        assert_eq!(rep.corrupt, 1, "{rep}");
        assert!(
            rep.problems[0]
                .starts_with(&format!("d.nmea:{}: RMC: date before the GPS epoch", k + 1)),
            "{rep}"
        );
        let t = |r: &reference::Reference| r.epochs.iter().map(|e| e.t).collect::<Vec<_>>();
        assert_eq!(t(&r), t(&want), "line {}", k + 1);
    }
    // A ZDA too.
    let zda = (0..clean.lines().count())
        .find(|&i| clean.lines().nth(i).unwrap().contains("ZDA"))
        .unwrap();
    let bad = edit_sentence(&clean, zda, |body| {
        let mut f: Vec<&str> = body.split(',').collect();
        f[2..5].copy_from_slice(&["05", "01", "1980"]);
        f.join(",")
    });
    let r = reference::parse("z.nmea", bad.as_bytes(), &o).unwrap();
    assert_eq!(r.report.read.corrupt, 1, "{}", r.report.read);
    assert_eq!(r.epochs.len(), want.epochs.len());
}

/// A GGA repeated before its epoch's GST and HDT (the repeat is skipped): the epoch keeps
/// the heading and the sigmas that followed the repeat.
#[test]
fn a_repeated_gga_keeps_the_hdt_and_gst_that_follow_it() {
    let epochs: Vec<reference::Epoch> = still_epochs(2300.0 * WEEK + 600.0, 10)
        .into_iter()
        .enumerate()
        .map(|(k, e)| reference::Epoch {
            heading: Some(0.1 * k as f64),
            ..e
        })
        .collect();
    let clean = String::from_utf8(nmea_bytes(&epochs, 18)).unwrap();
    let mut lines: Vec<&str> = clean.lines().collect();
    let ggas: Vec<usize> = (0..lines.len())
        .filter(|&i| lines[i].contains("GGA"))
        .collect();
    let k = ggas[4];
    lines.insert(k + 1, lines[k]);
    let text = lines.join("\r\n") + "\r\n";
    let r = reference::parse("r.nmea", text.as_bytes(), &ReferenceOptions::default()).unwrap();
    assert_eq!(r.epochs.len(), 10);
    assert_eq!(r.report.read.unusable, 1, "the repeat: {}", r.report.read);
    for (k, e) in r.epochs.iter().enumerate() {
        let h = e
            .heading
            .unwrap_or_else(|| panic!("epoch {k} lost its heading"));
        assert!((h - 0.1 * k as f64).abs() < 1e-4, "epoch {k}: {h}");
        assert!(e.sigma_east_north.is_some(), "epoch {k} lost its sigmas");
    }
}

/// Binary data before an NMEA log whose first byte is `%` (an RTKLIB header's first
/// character) does not make the log RTKLIB: it is detected as NMEA and read.
#[test]
fn a_binary_prefix_starting_with_percent_is_not_rtklib() {
    let epochs = still_epochs(2300.0 * WEEK + 600.0, 10);
    let clean = nmea_bytes(&epochs, 18);
    for prefix in [
        &b"%\xb5\x62\x01\x07\x5c\x00\r\n"[..],
        b"%\x00\x01\x02",
        b"%binary\r\n%\xff\xfe\r\n",
    ] {
        let mut bytes = prefix.to_vec();
        bytes.extend_from_slice(&clean);
        let r = reference::parse("p.nmea", &bytes, &ReferenceOptions::default())
            .unwrap_or_else(|e| panic!("{prefix:?}: {e:#}"));
        assert_eq!(r.format, Format::Nmea, "{prefix:?}");
        assert_eq!(r.epochs.len(), 10, "{prefix:?}");
    }
}
