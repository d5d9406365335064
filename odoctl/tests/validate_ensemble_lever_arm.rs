//! `validate` with several runs applies the calibration result's antenna lever arm as
//! `validate` of one run does: runs simulated with an antenna 0.5 m ahead of and 0.25 m left
//! of the axle centre, judged with a result whose `[fit]` holds that lever arm, cover the
//! truth as their twins without an antenna (same seeds, same counts) judged with the same
//! result without it; judged without the lever arm they do not.

mod common;

use common::{odoctl, read, scratch, success_stdout};

const SEEDS: [&str; 4] = ["41", "42", "43", "44"];
const ANTENNA: (f64, f64) = (0.5, 0.25);

/// One row of the ensemble coverage table: (model, distance, runs, horizontal 1 and 3 sigma
/// shares in %, NaN where no run reached the checkpoint).
type Row = (String, String, usize, f64, f64);

fn table(out: &str) -> Vec<Row> {
    let pct = |s: &str| s.parse::<f64>().unwrap_or(f64::NAN);
    out.lines()
        .filter(|l| l.starts_with("  paper ") || l.starts_with("  covariance "))
        .filter(|l| l.contains(" m "))
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            // model, distance, "m", runs, h1 "%", h3 "%", ...
            (
                f[0].to_string(),
                f[1].to_string(),
                f[3].parse().unwrap(),
                pct(f[4]),
                pct(if f[4] == "-" { f[5] } else { f[6] }),
            )
        })
        .collect()
}

#[test]
fn ensemble_validation_applies_the_lever_arm_as_validate_does() {
    let d = scratch("validate_ensemble_lever_arm");
    let p = |n: &str| d.join(n).to_str().unwrap().to_string();
    let antenna = format!("{},{}", ANTENNA.0, ANTENNA.1);
    let (mut plain_list, mut antenna_list) = (String::new(), String::new());
    for seed in SEEDS {
        for (kind, extra) in [("plain", None), ("antenna", Some(antenna.as_str()))] {
            let (s, r) = (
                p(&format!("{kind}{seed}.csv")),
                p(&format!("{kind}{seed}_ref.csv")),
            );
            let mut args = vec![
                "simulate",
                "--seed",
                seed,
                "--length",
                "30",
                "--samples",
                s.as_str(),
                "--reference",
                r.as_str(),
            ];
            if let Some(a) = extra {
                args.extend(["--antenna", a]);
            }
            success_stdout(&odoctl(&args));
        }
        plain_list += &format!("plain{seed}.csv plain{seed}_ref.csv\n");
        antenna_list += &format!("antenna{seed}.csv antenna{seed}_ref.csv\n");
        // Twins: the same counts, the reference moved to the antenna.
        assert_eq!(
            read(&d.join(format!("plain{seed}.csv"))),
            read(&d.join(format!("antenna{seed}.csv")))
        );
    }
    std::fs::write(d.join("plain.txt"), plain_list).unwrap();
    std::fs::write(d.join("antenna.txt"), antenna_list).unwrap();
    // The calibration result of a plain run, and the same with the lever arm in its [fit].
    success_stdout(&odoctl(&[
        "calibrate",
        "--samples",
        &p("plain41.csv"),
        "--reference",
        &p("plain41_ref.csv"),
        "--out",
        &p("cal.toml"),
        "--quiet",
    ]));
    let mut with_arm: toml::Table = read(&d.join("cal.toml")).parse().unwrap();
    let fit = with_arm["fit"].as_table_mut().unwrap();
    fit.insert("antenna_forward".into(), ANTENNA.0.into());
    fit.insert("antenna_left".into(), ANTENNA.1.into());
    std::fs::write(d.join("cal_arm.toml"), toml::to_string(&with_arm).unwrap()).unwrap();

    let ensemble = |list: &str, config: &str| {
        success_stdout(&odoctl(&[
            "validate",
            "--runs",
            &p(list),
            "--config",
            &p(config),
            "--models",
            "all",
        ]))
    };
    let plain = ensemble("plain.txt", "cal.toml");
    let with = ensemble("antenna.txt", "cal_arm.toml");
    let without = ensemble("antenna.txt", "cal.toml");
    assert!(
        with.contains("antenna lever arm from") && with.contains("0.5000 m forward, 0.2500 m left"),
        "{with}"
    );
    assert!(!without.contains("antenna lever arm"), "{without}");
    let (plain_t, with_t, without_t) = (table(&plain), table(&with), table(&without));
    assert_eq!(plain_t.len(), with_t.len(), "{plain}\n{with}");
    let reached: Vec<usize> = (0..plain_t.len()).filter(|&i| plain_t[i].2 > 0).collect();
    assert!(reached.len() >= 4, "{plain}");
    for &i in &reached {
        let (a, b) = (&plain_t[i], &with_t[i]);
        assert_eq!((&a.0, &a.1, a.2), (&b.0, &b.1, b.2), "{plain}\n{with}");
        // The same horizontal coverage within one run of the four (the checkpoints fall on
        // the antenna's path, a little longer than the centre's in turns).
        for (x, y) in [(a.3, b.3), (a.4, b.4)] {
            assert!(
                (x - y).abs() <= 25.0 + 1e-9,
                "{a:?} vs {b:?}\n{plain}\n{with}"
            );
        }
        assert!(b.4 >= 75.0, "{b:?}\n{with}");
        // Without the lever arm, the 0.56 m offset turning with the chassis is far outside
        // the millimetre bands.
        assert!(without_t[i].4 <= 25.0, "{:?}\n{without}", without_t[i]);
    }
    // Repeated --samples/--reference give the list's table.
    let mut args = vec!["validate".to_string()];
    for seed in SEEDS {
        args.extend([
            "--samples".into(),
            p(&format!("antenna{seed}.csv")),
            "--reference".into(),
            p(&format!("antenna{seed}_ref.csv")),
        ]);
    }
    args.extend([
        "--config".into(),
        p("cal_arm.toml"),
        "--models".into(),
        "all".into(),
    ]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let rows = |out: &str| -> Vec<String> {
        out.lines()
            .filter(|l| l.starts_with("  paper ") || l.starts_with("  covariance "))
            .map(String::from)
            .collect()
    };
    assert_eq!(rows(&success_stdout(&odoctl(&args))), rows(&with));
    // validate of one run: the antenna run with the lever arm covers as its plain twin.
    let single = |samples: &str, config: &str| {
        let out = success_stdout(&odoctl(&[
            "validate",
            "--samples",
            &p(&format!("{samples}.csv")),
            "--reference",
            &p(&format!("{samples}_ref.csv")),
            "--config",
            &p(config),
        ]));
        let line = out
            .lines()
            .find(|l| l.contains("added to the horizontal bands"))
            .unwrap_or_else(|| panic!("{out}"))
            .to_string();
        // "... bands: A % in 1 sigma, B % in 3 sigma"
        let words: Vec<&str> = line.split_whitespace().collect();
        let nums: Vec<f64> = words
            .windows(2)
            .filter(|w| w[1] == "%")
            .map(|w| w[0].parse().unwrap())
            .collect();
        assert_eq!(nums.len(), 2, "{line}");
        (nums[0], nums[1])
    };
    let (p1, p3) = single("plain41", "cal.toml");
    let (a1, a3) = single("antenna41", "cal_arm.toml");
    assert!(
        (p1 - a1).abs() < 2.0 && (p3 - a3).abs() < 2.0,
        "{p1} {p3} vs {a1} {a3}"
    );
}
