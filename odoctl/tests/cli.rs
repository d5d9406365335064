//! The command line end to end: simulate, calibrate, validate, replay, plots, bad files.

mod common;

use common::{odoctl, read, scratch, success_stdout};

fn s(p: &std::path::Path) -> &str {
    p.to_str().unwrap()
}

/// The numbers of a CSV text's last row.
fn last_row(csv: &str) -> Vec<f64> {
    csv.lines()
        .last()
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect()
}

#[test]
fn simulate_calibrate_validate_with_plots() {
    let d = scratch("cli_calibrate");
    let (sm, rf, cal, plots) = (
        d.join("s.csv"),
        d.join("r.csv"),
        d.join("cal.toml"),
        d.join("plots"),
    );
    let o = odoctl(&[
        "simulate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--seed",
        "21",
        "--truth-out",
        s(&d.join("truth.toml")),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let initial = d.join("initial.toml");
    std::fs::write(
        &initial,
        "left_diameter = 0.300\nright_diameter = 0.300\ntrack_width = 0.700\n",
    )
    .unwrap();
    let o = odoctl(&[
        "calibrate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--initial",
        s(&initial),
        "--out",
        s(&cal),
        "--plots",
        s(&plots),
        "--windows",
        "8",
        "--windows-out",
        s(&d.join("w.csv")),
        "--quiet",
    ]);
    let out = success_stdout(&o);
    assert!(out.contains("stability study"), "{out}");
    let p = odoctl::config::read_params(&cal, odo_unit::odometry::ChassisParams::DESIGNED).unwrap();
    let t = common::truth();
    assert!((p.left_diameter - t.left_diameter).abs() < 0.5e-3, "{out}");
    assert!(
        (p.right_diameter - t.right_diameter).abs() < 0.5e-3,
        "{out}"
    );
    assert!((p.track_width - t.track_width).abs() < 2e-3, "{out}");
    let text = read(&cal);
    for key in [
        "left_diameter",
        "right_diameter",
        "track_width",
        "ticks_per_rev",
        "delta_left",
        "delta_right",
        "[fit]",
        "initial_heading",
        "eq16_cost",
    ] {
        assert!(text.contains(key), "{key} missing in\n{text}");
    }
    let w = read(&d.join("w.csv"));
    assert!(w.lines().count() >= 8, "{w}");
    assert!(w.lines().next().unwrap().ends_with(",status,reason"), "{w}");
    // Every row is ok or failed with its reason.
    for row in w.lines().skip(1) {
        assert!(
            row.ends_with(",ok,") || (row.contains(",failed,") && !row.ends_with(",failed,")),
            "{row}"
        );
    }
    for f in [
        "calibrate_trajectory",
        "calibrate_horizontal_error",
        "calibrate_heading_error",
        "windows_history",
        "windows_histograms",
    ] {
        let png = std::fs::read(plots.join(format!("{f}.png"))).unwrap();
        assert!(
            png.starts_with(b"\x89PNG\r\n\x1a\n") && png.len() > 10_000,
            "{f}"
        );
    }
    // Validation on another trajectory with the calibrated parameters.
    let (vs, vr) = (d.join("vs.csv"), d.join("vr.csv"));
    let o = odoctl(&[
        "simulate",
        "--samples",
        s(&vs),
        "--reference",
        s(&vr),
        "--path",
        "validation",
        "--length",
        "30",
        "--seed",
        "22",
    ]);
    assert!(o.status.success());
    let o = odoctl(&[
        "validate",
        "--samples",
        s(&vs),
        "--reference",
        s(&vr),
        "--config",
        s(&cal),
        "--errors",
        s(&d.join("e.csv")),
        "--plots",
        s(&plots),
        "--models",
        "all",
    ]);
    let out = success_stdout(&o);
    assert!(
        out.contains("horizontal error [m]") && out.contains("in 1sig"),
        "{out}"
    );
    assert!(plots.join("validate_heading_error.png").exists());
    assert!(plots.join("validate_models.png").exists());
    assert!(out.contains("covariance"), "{out}");
}

#[test]
fn replay_writes_one_row_per_sample() {
    let d = scratch("cli_replay");
    let (sm, rf) = (d.join("s.csv"), d.join("r.csv"));
    assert!(odoctl(&[
        "simulate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--length",
        "5",
        "--no-heading"
    ])
    .status
    .success());
    assert!(read(&rf).starts_with("t,x,y\n"));
    let o = odoctl(&[
        "replay",
        s(&sm),
        "--set",
        "left_diameter=0.2608",
        "--set",
        "right_diameter=0.2607",
        "--set",
        "track_width=0.5656",
        "--heading",
        "0.3",
    ]);
    assert!(o.status.success());
    let out = String::from_utf8(o.stdout).unwrap();
    let mut lines = out.lines();
    assert_eq!(
        lines.next(),
        Some("t,x,y,heading,sigma_x,sigma_y,sigma_heading")
    );
    assert_eq!(out.lines().count(), read(&sm).lines().count());
    // Final pose near the reference's last point.
    let (last, rlast) = (last_row(&out), last_row(&read(&rf)));
    assert!(
        (last[1] - rlast[1]).hypot(last[2] - rlast[2]) < 0.05,
        "{last:?} {rlast:?}"
    );
    let o = odoctl(&["replay", s(&sm), "--set", "track_width=-1"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("track_width"));
    let o = odoctl(&["replay", s(&sm), "--set", "wheel=1"]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown key"));
}

#[test]
fn bad_files_name_the_file_and_line() {
    let d = scratch("cli_bad");
    let good_s = d.join("s.csv");
    let good_r = d.join("r.csv");
    std::fs::write(&good_s, "t,left,right\n0,0,0\n0.02,10,10\n").unwrap();
    std::fs::write(&good_r, "t,x,y\n0,0,0\n0.02,0,0.001\n").unwrap();
    let cases: &[(&str, &str, &str, &str)] = &[
        ("s", "t,left\n0,0\n", ":1:", "missing column `right`"),
        ("s", "t,left,right\n0,0,0\n0.02,abc,0\n", ":3:", "`left`"),
        (
            "s",
            "t,left,right\n0,0,0\n0.02,1.5,0\n",
            ":3:",
            "not an integer",
        ),
        ("s", "t,left,right\n0,0,0\n0,1,1\n", ":3:", "increase"),
        ("r", "t,x,y\n0,0,0\n-1,0,0\n", ":3:", "increase"),
        ("r", "t,x,y\n0,0,zero\n", ":2:", "`y`"),
        ("r", "t,x,y\n100,0,0\n100.02,0,1\n", "common times", "r.csv"),
    ];
    for (which, text, at, what) in cases {
        let bad = d.join(format!("bad_{which}.csv"));
        std::fs::write(&bad, text).unwrap();
        let (sm, rf) = if *which == "s" {
            (&bad, &good_r)
        } else {
            (&good_s, &bad)
        };
        let o = odoctl(&[
            "calibrate",
            "--samples",
            s(sm),
            "--reference",
            s(rf),
            "--quiet",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{text}");
        assert!(
            err.contains(at) && err.contains(what) && err.contains(&format!("bad_{which}.csv")),
            "{text}: {err}"
        );
    }
    let toml = d.join("bad.toml");
    std::fs::write(&toml, "left_diameter = 0.26\n\nright_diameter = \"big\"\n").unwrap();
    let o = odoctl(&["replay", s(&good_s), "--config", s(&toml)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("bad.toml:3") && err.contains("right_diameter"),
        "{err}"
    );
}

#[test]
fn a_replay_from_the_reported_fit_start_reproduces_the_reported_eq16_cost() {
    // The [fit] table's initial_x/initial_y are the start the fit used (the reference
    // averaged over the opening standstill), not the reference's first point: replaying the
    // counts from there with the estimate reproduces eq (16).
    let d = scratch("cli_fit_start");
    let (sm, rf, cal, rep) = (
        d.join("s.csv"),
        d.join("r.csv"),
        d.join("cal.toml"),
        d.join("replay.csv"),
    );
    success_stdout(&odoctl(&[
        "simulate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--length",
        "30",
        "--seed",
        "8",
    ]));
    let out = success_stdout(&odoctl(&[
        "calibrate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--no-delta",
        "--out",
        s(&cal),
    ]));
    assert!(out.contains("std. error"), "{out}");
    let toml: toml::Table = read(&cal).parse().unwrap();
    let fit = toml["fit"].as_table().unwrap();
    let num = |k: &str| fit[k].as_float().unwrap_or_else(|| panic!("[fit] {k}"));
    for k in [
        "left_diameter_se",
        "right_diameter_se",
        "track_width_se",
        "initial_heading_se",
        "residual_sigma",
    ] {
        assert!(num(k) > 0.0 && num(k) < 0.05, "{k} = {}", num(k));
    }
    let (x0, y0, h0, cost) = (
        num("initial_x"),
        num("initial_y"),
        num("initial_heading"),
        num("eq16_cost"),
    );
    let reference = read(&rf);
    let first: Vec<f64> = reference
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert!(
        (x0, y0) != (first[1], first[2]),
        "the standstill mean differs from the first reference point"
    );
    success_stdout(&odoctl(&[
        "replay",
        s(&sm),
        "--config",
        s(&cal),
        "--x",
        &format!("{x0:?}"),
        "--y",
        &format!("{y0:?}"),
        "--heading",
        &format!("{h0:?}"),
        "--out",
        s(&rep),
    ]));
    // Simulated samples and reference share their times row by row; eq (16) sums the
    // distances after the first common time.
    let replayed = read(&rep);
    let mut sum = 0.0;
    let mut rows = 0;
    for (o, r) in replayed.lines().zip(reference.lines()).skip(2) {
        let o: Vec<f64> = o.split(',').map(|v| v.parse().unwrap()).collect();
        let r: Vec<f64> = r.split(',').map(|v| v.parse().unwrap()).collect();
        assert_eq!(o[0], r[0]);
        sum += (o[1] - r[1]).hypot(o[2] - r[2]);
        rows += 1;
    }
    assert_eq!(rows as i64, fit["points"].as_integer().unwrap());
    assert!(
        (sum - cost).abs() <= 1e-9 * cost,
        "replay from the [fit] start: eq (16) {sum} against the reported {cost}"
    );
}

/// `simulate` with an eccentric left wheel (its truth's `left_cos1`), `calibrate
/// --wheel-harmonics 1`: the coefficients and their standard errors in the output TOML,
/// under the shared keys that `config push` sends.
#[test]
fn wheel_harmonics_reach_the_output_and_config_push() {
    let d = scratch("cli_harmonics");
    let (sm, rf, cal) = (d.join("s.csv"), d.join("r.csv"), d.join("cal.toml"));
    let o = odoctl(&[
        "simulate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--path",
        "random",
        "--length",
        "200",
        "--rtk-sigma",
        "0.001",
        "--set",
        "left_cos1=0.003",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = odoctl(&[
        "calibrate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--wheel-harmonics",
        "1",
        "--no-delta",
        "--out",
        s(&cal),
        "--quiet",
    ]);
    let out = success_stdout(&o);
    assert!(
        out.contains("wheel function: 1 harmonic(s) per wheel"),
        "{out}"
    );
    let p = odoctl::config::read_params(&cal, odo_unit::odometry::ChassisParams::DESIGNED).unwrap();
    assert!((p.left_wheel.cos[0] - 0.003).abs() < 3e-4, "{out}");
    assert!(p.right_wheel.cos[0].abs() < 3e-4, "{out}");
    let text = read(&cal);
    for key in [
        "left_cos1 =",
        "left_sin1 =",
        "right_cos1 =",
        "right_sin1 =",
        "left_cos1_se =",
        "wheel_harmonics = 1",
    ] {
        assert!(text.contains(key), "{key} missing in\n{text}");
    }
    let lines = odoctl::config::push_lines(&cal).unwrap().join(" ");
    for key in ["left_cos1 ", "left_sin1 ", "right_cos1 ", "right_sin1 "] {
        assert!(lines.contains(key), "{key} not pushed: {lines}");
    }
    // A run without index latches is refused with the reason.
    let csv = read(&sm);
    let header = csv.lines().next().unwrap().to_string();
    let keep: Vec<usize> = header
        .split(',')
        .enumerate()
        .filter(|(_, c)| !c.ends_with("_index"))
        .map(|(i, _)| i)
        .collect();
    let stripped: String = csv
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            keep.iter().map(|&i| f[i]).collect::<Vec<_>>().join(",") + "\n"
        })
        .collect();
    let bare = d.join("bare.csv");
    std::fs::write(&bare, stripped).unwrap();
    let o = odoctl(&[
        "calibrate",
        "--samples",
        s(&bare),
        "--reference",
        s(&rf),
        "--wheel-harmonics",
        "1",
        "--no-delta",
        "--quiet",
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("index latches"), "{err}");
}

#[test]
fn validate_an_ensemble_of_runs_from_a_list_and_from_repeated_options() {
    let d = scratch("cli_ensemble");
    let mut list = String::from("# samples reference\n");
    for seed in ["31", "32", "33"] {
        let (sm, rf) = (
            d.join(format!("s{seed}.csv")),
            d.join(format!("r{seed}.csv")),
        );
        success_stdout(&odoctl(&[
            "simulate",
            "--samples",
            s(&sm),
            "--reference",
            s(&rf),
            "--seed",
            seed,
            "--length",
            "25",
        ]));
        list += &format!("s{seed}.csv r{seed}.csv\n");
    }
    std::fs::write(d.join("runs.txt"), &list).unwrap();
    let cal = d.join("cal.toml");
    let out = success_stdout(&odoctl(&[
        "calibrate",
        "--samples",
        s(&d.join("s31.csv")),
        "--reference",
        s(&d.join("r31.csv")),
        "--out",
        s(&cal),
    ]));
    assert!(out.contains("covariance model fit: likelihood"), "{out}");
    assert!(read(&cal).contains("uncertainty_model = \"covariance\""));
    let plots = d.join("plots");
    let out = success_stdout(&odoctl(&[
        "validate",
        "--runs",
        s(&d.join("runs.txt")),
        "--config",
        s(&cal),
        "--models",
        "all",
        "--checkpoints",
        "5,10,20,40",
        "--plots",
        s(&plots),
    ]));
    assert!(out.contains("ensemble validation: 3 runs"), "{out}");
    // Every run reaches 5, 10 and 20 m; none 40 m of a 25 m path.
    for m in ["paper", "covariance"] {
        for (dist, runs) in [("5.0", 3), ("10.0", 3), ("20.0", 3), ("40.0", 0)] {
            let row = out
                .lines()
                .find(|l| {
                    let f: Vec<&str> = l.split_whitespace().collect();
                    f.len() > 3 && f[0] == m && f[1] == dist
                })
                .unwrap_or_else(|| panic!("no {m} row at {dist} m:\n{out}"));
            assert_eq!(
                row.split_whitespace().nth(3),
                Some(runs.to_string().as_str()),
                "{row}"
            );
        }
    }
    assert!(out.contains("reliability"));
    for f in [
        "validate_ensemble_coverage.png",
        "validate_ensemble_reliability.png",
    ] {
        let png = std::fs::read(plots.join(f)).unwrap();
        assert_eq!(&png[1..4], b"PNG", "{f}");
    }
    // The same runs by repeated --samples/--reference give the same table.
    let mut args = vec!["validate".to_string()];
    for seed in ["31", "32", "33"] {
        args.extend([
            "--samples".into(),
            s(&d.join(format!("s{seed}.csv"))).to_string(),
            "--reference".into(),
            s(&d.join(format!("r{seed}.csv"))).to_string(),
        ]);
    }
    args.extend(
        [
            "--config",
            s(&cal),
            "--models",
            "all",
            "--checkpoints",
            "5,10,20,40",
        ]
        .map(String::from),
    );
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let again = success_stdout(&odoctl(&args));
    let table = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| l.starts_with("  paper") || l.starts_with("  covariance"))
            .map(String::from)
            .collect()
    };
    assert_eq!(table(&out), table(&again));
    // Unpaired files and a bad list are refused.
    let o = odoctl(&[
        "validate",
        "--samples",
        s(&d.join("s31.csv")),
        "--samples",
        s(&d.join("s32.csv")),
        "--reference",
        s(&d.join("r31.csv")),
        "--config",
        s(&cal),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("in pairs"));
    std::fs::write(d.join("bad.txt"), "only-one-path\n").unwrap();
    let o = odoctl(&[
        "validate",
        "--runs",
        s(&d.join("bad.txt")),
        "--config",
        s(&cal),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("bad.txt:1"));
}

/// The reference's noise: a reference four times noisier than `--reference-sigma` says is
/// named, its scatter recorded in `[fit]`; stated right, no warning; `validate` gives its verdict.
#[test]
fn reference_noise_is_checked_against_its_scatter() {
    let d = scratch("cli_reference_noise");
    let (sm, rf, cal) = (d.join("s.csv"), d.join("r.csv"), d.join("c.toml"));
    let o = odoctl(&[
        "simulate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--rtk-sigma",
        "0.032",
        "--length",
        "40",
        "--seed",
        "9",
    ]);
    assert!(o.status.success());
    let calibrate = |sigma: &str| {
        odoctl(&[
            "calibrate",
            "--samples",
            s(&sm),
            "--reference",
            s(&rf),
            "--reference-sigma",
            sigma,
            "-o",
            s(&cal),
        ])
    };
    let o = calibrate("0.008");
    let out = success_stdout(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("warning: the reference scatters"), "{err}");
    assert!(
        out.contains("inside sigma_h widened by the reference noise"),
        "{out}"
    );
    assert!(
        out.contains("heading change since the start inside sigma_heading widened"),
        "{out}"
    );
    let text = read(&cal);
    let fit: toml::Table = text.parse().unwrap();
    let scatter = fit["fit"]["reference_sigma_scatter"].as_float().unwrap();
    assert!((scatter / 0.032 - 1.0).abs() < 0.1, "{scatter}");
    assert_eq!(fit["fit"]["reference_sigma_stated"].as_float(), Some(0.008));
    let o = calibrate("0.032");
    success_stdout(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("scatters"), "{err}");
    let o = odoctl(&[
        "validate",
        "--samples",
        s(&sm),
        "--reference",
        s(&rf),
        "--config",
        s(&cal),
        "--reference-sigma",
        "0.032",
    ]);
    let out = success_stdout(&o);
    assert!(out.contains("reference noise: stated 0.0320 m"), "{out}");
    assert!(out.lines().any(|l| l.starts_with("verdict: ")), "{out}");
}
