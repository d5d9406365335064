//! The antenna lever arm in the calibration: from simulated NMEA and RTKLIB logs of
//! an antenna 0.35 m ahead of the axle, `calibrate --fit-antenna` recovers the geometry and the
//! lever arm, in both methods, as accurately as the CSV of the same run without an antenna;
//! `validate` reads the lever arm back from the result and applies it.

mod common;

use common::calibrate_result as calibrate;

#[test]
fn lever_arm_recovered_from_nmea_and_pos_as_well_as_from_the_csv_without_it() {
    let d = common::scratch("lever_arm");
    let s = |n: &str| d.join(n).to_str().unwrap().to_string();
    for (name, antenna) in [("plain", None), ("antenna", Some("0.35,0"))] {
        let mut args = vec![
            "simulate".to_string(),
            "--seed".into(),
            "8".into(),
            "--samples".into(),
            s(&format!("{name}.csv")),
            "--reference".into(),
            s(&format!("{name}_ref.csv")),
        ];
        if let Some(a) = antenna {
            args.extend([
                "--antenna".into(),
                a.into(),
                "--nmea".into(),
                s("antenna.nmea"),
                "--pos".into(),
                s("antenna.pos"),
            ]);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        common::success_stdout(&common::odoctl(&args));
    }
    let truth = [0.2608, 0.2607, 0.5656, 0.35, 0.0];
    for method in ["subtrajectory", "paper"] {
        let (csv, _) = calibrate(
            &s("plain.csv"),
            &s("plain_ref.csv"),
            &s("plain.toml"),
            &["--method", method],
        );
        for log in ["antenna.nmea", "antenna.pos"] {
            let out = s(&format!("{log}.{method}.toml"));
            let (est, se) = calibrate(
                &s("antenna.csv"),
                &s(log),
                &out,
                &["--method", method, "--fit-antenna"],
            );
            eprintln!(
                "{method} {log}: errors {:+.1} {:+.1} {:+.1} um, antenna {:+.2} {:+.2} mm (se {:.1} {:.1} {:.1} um, {:.2} {:.2} mm); CSV without antenna {:+.1} {:+.1} {:+.1} um",
                (est[0] - truth[0]) * 1e6,
                (est[1] - truth[1]) * 1e6,
                (est[2] - truth[2]) * 1e6,
                (est[3] - truth[3]) * 1e3,
                (est[4] - truth[4]) * 1e3,
                se[0] * 1e6,
                se[1] * 1e6,
                se[2] * 1e6,
                se[3] * 1e3,
                se[4] * 1e3,
                (csv[0] - truth[0]) * 1e6,
                (csv[1] - truth[1]) * 1e6,
                (csv[2] - truth[2]) * 1e6
            );
            for k in 0..3 {
                // The accuracy reached from the CSV without an antenna, within 3 of the log's
                // standard errors (a fifth of the points: 10 Hz, float epochs left out).
                let (e, e_csv) = ((est[k] - truth[k]).abs(), (csv[k] - truth[k]).abs());
                assert!(
                    e <= e_csv + 3.0 * se[k],
                    "{method} {log} {k}: {est:?} (CSV {csv:?}, se {se:?})"
                );
            }
            for k in 3..5 {
                assert!(se[k] > 0.0 && se[k] < 0.01, "{method} {log}: {se:?}");
                assert!(
                    (est[k] - truth[k]).abs() <= 3.0 * se[k],
                    "{method} {log} antenna {k}: {est:?} se {se:?}"
                );
            }
        }
    }
    // Ignoring the lever arm biases the geometry far beyond that (prototype: 1.6 mm, 8 mm).
    let (naive, _) = calibrate(&s("antenna.csv"), &s("antenna.nmea"), &s("naive.toml"), &[]);
    assert!((naive[2] - truth[2]).abs() > 5e-3, "{naive:?}");
    // validate reads the lever arm from the result: the errors on the same run are those of
    // the centre model (the whole run's drift, centimetres); without it, several times more.
    let validate = |config: &str| {
        common::success_stdout(&common::odoctl(&[
            "validate",
            "--samples",
            &s("antenna.csv"),
            "--reference",
            &s("antenna.nmea"),
            "--config",
            config,
        ]))
    };
    let with = validate(&s("antenna.nmea.subtrajectory.toml"));
    assert!(with.contains("antenna lever arm from"), "{with}");
    let rms = |out: &str| -> f64 {
        let line = out
            .lines()
            .find(|l| l.trim_start().starts_with("horizontal error [m]"))
            .unwrap_or_else(|| panic!("{out}"));
        line.split_whitespace().nth(4).unwrap().parse().unwrap()
    };
    let mut bare: toml::Table = common::read(&d.join("antenna.nmea.subtrajectory.toml"))
        .parse()
        .unwrap();
    bare.remove("fit");
    std::fs::write(d.join("bare.toml"), toml::to_string(&bare).unwrap()).unwrap();
    let without = validate(&s("bare.toml"));
    eprintln!(
        "validate rms: {} m with the lever arm, {} m without",
        rms(&with),
        rms(&without)
    );
    assert!(
        rms(&with) < 0.1 && rms(&without) > 3.0 * rms(&with),
        "{with}\n{without}"
    );
}

/// The covariance model's kappa against an antenna on a lever arm is the axle centre's: the
/// filter observes the antenna, its position turned with the heading error. Same run with
/// the reference at the axle centre and at an antenna 0.3 m ahead and 0.1 m left, the lever
/// arm given and fitted.
#[test]
fn kappa_through_a_lever_arm_is_the_kappa_at_the_axle_centre() {
    let d = common::scratch("lever_arm_kappa");
    let s = |n: &str| d.join(n).to_str().unwrap().to_string();
    let kappa = |name: &str, extra: &[&str]| -> f64 {
        let out = s(&format!("{name}{}.toml", extra.len()));
        let mut args = vec!["calibrate", "--quiet", "--samples"];
        let (samples, reference) = (s(&format!("{name}.csv")), s(&format!("{name}_ref.csv")));
        args.extend([samples.as_str(), "--reference", &reference, "--out", &out]);
        args.extend_from_slice(extra);
        common::success_stdout(&common::odoctl(&args));
        let t: toml::Table = common::read(std::path::Path::new(&out)).parse().unwrap();
        t["kappa_left"].as_float().unwrap()
    };
    for (name, antenna) in [("centre", None), ("antenna", Some("0.3,0.1"))] {
        let (samples, reference) = (s(&format!("{name}.csv")), s(&format!("{name}_ref.csv")));
        let mut args = vec![
            "simulate",
            "--seed",
            "3",
            "--length",
            "150",
            "--samples",
            &samples,
            "--reference",
            &reference,
        ];
        args.extend(antenna.map(|a| ["--antenna", a]).into_iter().flatten());
        common::success_stdout(&common::odoctl(&args));
    }
    let centre = kappa("centre", &[]);
    for extra in [&["--antenna", "0.3,0.1"][..], &["--fit-antenna"][..]] {
        let k = kappa("antenna", extra);
        eprintln!("kappa {k:e} with {extra:?}, {centre:e} at the axle centre");
        assert!(
            (k / centre).ln().abs() < 0.3,
            "{extra:?}: {k:e} vs {centre:e}"
        );
    }
}
