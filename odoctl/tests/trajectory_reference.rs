//! Trajectory references (TUM, ROS 2 MCAP): simulated motion-capture runs whose reference frame
//! is turned and shifted, whose marker sits off the axle centre with its own yaw, and whose
//! clock is offset; `calibrate --fit-antenna` recovers the geometry and the marker offset
//! within their reported standard errors over several seeds. An MCAP written by
//! `mcap-ros2-support` (a writer we did not write) from the same TUM file reads the same on each
//! of its three topic types.

mod common;

use std::process::Command;

/// `calibrate --fit-antenna` ([`common::calibrate_result`]): the geometry and the marker offset.
fn calibrate(samples: &str, reference: &str, out: &str, extra: &[&str]) -> ([f64; 5], [f64; 5]) {
    let mut args = vec!["--fit-antenna"];
    args.extend_from_slice(extra);
    common::calibrate_result(samples, reference, out, &args)
}

/// Simulates seed `seed` with a TUM reference: marker (0.25, -0.08) m, the frame turned and
/// shifted, the marker's yaw and the clock offset all depending on the seed. Returns the
/// `--time-offset` to give.
fn simulate(dir: &std::path::Path, seed: u64, length: &str, extra: &[&str]) -> String {
    let s = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let frame = format!(
        "{},{},{}",
        seed as f64 * 1.7 - 4.0,
        3.0 - seed as f64,
        seed * 47 % 360
    );
    let yaw = format!("{}", (seed * 83 % 360) as f64 - 180.0);
    let offset = format!("{}", -1.7e9 - seed as f64 * 12.345);
    let seed = seed.to_string();
    let mut args = vec![
        "simulate",
        "--seed",
        &seed,
        "--length",
        length,
        "--rate",
        "100",
        "--samples",
        "",
        "--reference",
        "",
        "--tum",
        "",
        "--antenna",
        "0.25,-0.08",
        "--marker-yaw-deg",
        &yaw,
    ];
    // The seed's frame and clock unless `extra` gives them.
    for (option, value) in [
        ("--trajectory-frame", &frame),
        ("--trajectory-time-offset", &offset),
    ] {
        if !extra.contains(&option) {
            args.extend([option, value.as_str()]);
        }
    }
    let (samples, reference, tum) = (s("run.csv"), s("ref.csv"), s("run.tum"));
    args[8] = &samples;
    args[10] = &reference;
    args[12] = &tum;
    args.extend_from_slice(extra);
    common::success_stdout(&common::odoctl(&args));
    offset
}

#[test]
fn mocap_trajectory_in_a_turned_frame_gives_estimates_within_their_standard_errors() {
    let truth = [0.2608, 0.2607, 0.5656, 0.25, -0.08];
    let mut worst = [0.0f64; 5];
    for seed in 1..=6u64 {
        let d = common::scratch(&format!("trajectory_seed{seed}"));
        let offset = simulate(&d, seed, "150", &[]);
        let s = |n: &str| d.join(n).to_str().unwrap().to_string();
        let (est, se) = calibrate(
            &s("run.csv"),
            &s("run.tum"),
            &s("out.toml"),
            &["--time-offset", &offset],
        );
        let z: Vec<f64> = (0..5).map(|k| (est[k] - truth[k]) / se[k]).collect();
        eprintln!(
            "seed {seed}: errors {:+.1} {:+.1} {:+.1} um, marker {:+.2} {:+.2} mm; z {z:+.2?}",
            (est[0] - truth[0]) * 1e6,
            (est[1] - truth[1]) * 1e6,
            (est[2] - truth[2]) * 1e6,
            (est[3] - truth[3]) * 1e3,
            (est[4] - truth[4]) * 1e3,
        );
        for k in 0..5 {
            assert!(se[k] > 0.0, "seed {seed}: {se:?}");
            worst[k] = worst[k].max(z[k].abs());
            assert!(
                z[k].abs() <= 3.0,
                "seed {seed} parameter {k}: {est:?} se {se:?}"
            );
        }
    }
    eprintln!("largest |error| / standard error: {worst:.2?}");
}

#[test]
fn clock_mismatch_and_bad_topics_are_errors_naming_the_file() {
    let d = common::scratch("trajectory_errors");
    let s = |n: &str| d.join(n).to_str().unwrap().to_string();
    simulate(&d, 2, "30", &["--mcap-reference", &s("run.mcap")]);
    let run = |args: Vec<String>| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = common::odoctl(&args);
        assert!(!o.status.success(), "{args:?}");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let (samples, out) = (s("run.csv"), s("x.toml"));
    let base = ["calibrate", "--samples", &samples, "--out", &out];
    let with = |extra: &[&'static str]| -> Vec<String> {
        base.iter().chain(extra).map(|a| a.to_string()).collect()
    };
    let (tum, mcap) = (s("run.tum"), s("run.mcap"));
    let (tum, mcap): (&'static str, &'static str) = (tum.leak(), mcap.leak());
    let e = run(with(&[
        "--reference",
        tum,
        "--time-offset",
        "5",
        "--clock-ppm",
        "0",
    ]));
    assert!(
        e.contains("run.tum: the trajectory does not overlap") && e.contains("--time-offset"),
        "{e}"
    );
    let e = run(with(&["--reference", tum, "--time-offset", "5"]));
    assert!(
        e.contains("run.tum: the trajectory does not overlap"),
        "{e}"
    );
    let e = run(with(&["--reference", mcap]));
    assert!(e.contains("--reference-topic"), "{e}");
    let e = run(with(&["--reference", mcap, "--reference-topic", "/none"]));
    assert!(e.contains("run.mcap: no topic `/none`"), "{e}");
    let e = run(with(&["--reference", mcap, "--reference-topic", "/tf"]));
    assert!(e.contains("--reference-frames"), "{e}");
    assert!(!d.join("x.toml").exists());
}

/// The clock line of `calibrate`'s stdout: (offset, its se, ppm, its se).
fn clock_line(stdout: &str) -> [f64; 4] {
    let line = stdout
        .lines()
        .find(|l| l.contains("samples' t = stamp"))
        .unwrap_or_else(|| panic!("no clock line in {stdout}"));
    let nums: Vec<f64> = line
        .split("samples' t = stamp")
        .nth(1)
        .unwrap()
        .split(|c: char| c.is_whitespace() || c == '(' || c == ')')
        .filter_map(|w| w.parse::<f64>().ok())
        .collect();
    [nums[0], nums[1], nums[2], nums[3]]
}

#[test]
fn clock_offset_and_rate_estimated_within_their_standard_errors() {
    let (mut zo, mut zr) = (0.0f64, 0.0f64);
    for seed in 1..=5u64 {
        let d = common::scratch(&format!("trajectory_clock{seed}"));
        let s = |n: &str| d.join(n).to_str().unwrap().to_string();
        let offset = -1.7e9 - seed as f64 * 12.345 - 0.0037;
        let ppm = seed as f64 * 17.0 - 50.0;
        let (o, r) = (offset.to_string(), ppm.to_string());
        let clock = ["--trajectory-time-offset", &o, "--trajectory-clock-ppm", &r];
        simulate(&d, seed, "150", &clock);
        let out = s("out.toml");
        let stdout = common::success_stdout(&common::odoctl(&[
            "calibrate",
            "--samples",
            &s("run.csv"),
            "--reference",
            &s("run.tum"),
            "--out",
            &out,
            "--no-delta",
            "--fit-antenna",
        ]));
        let [eo, so, er, sr] = clock_line(&stdout);
        eprintln!(
            "seed {seed}: offset error {:+.3} ms (se {:.3}), rate error {:+.1} ppm (se {:.1})",
            (eo - offset) * 1e3,
            so * 1e3,
            er - ppm,
            sr
        );
        assert!(so > 0.0 && so < 0.005 && sr > 0.0, "seed {seed}: {stdout}");
        zo = zo.max(((eo - offset) / so).abs());
        zr = zr.max(((er - ppm) / sr).abs());
    }
    eprintln!("largest |error| / se: offset {zo:.2}, rate {zr:.2}");
    assert!(zo <= 3.0 && zr <= 3.0, "{zo} {zr}");
}

/// Whether python3 with `mcap` and `mcap-ros2-support` can run; panics when it cannot and CI
/// requires it.
fn python_ready() -> bool {
    common::python_has(
        "trajectory_reference",
        "mcap, mcap_ros2.writer",
        "mcap mcap-ros2-support",
    )
}

#[test]
fn mcap_written_by_mcap_ros2_support_reads_as_the_tum_file() {
    if !python_ready() {
        return;
    }
    let d = common::scratch("trajectory_python");
    let s = |n: &str| d.join(n).to_str().unwrap().to_string();
    let offset = simulate(&d, 4, "60", &[]);
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/ros/write_trajectory.py");
    let o = Command::new("python3")
        .args([script, &s("run.tum"), &s("py.mcap")])
        .output()
        .expect("python3 runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let clock = ["--time-offset", offset.as_str()];
    let (tum, se) = calibrate(&s("run.csv"), &s("run.tum"), &s("tum.toml"), &clock);
    for topic in [
        &["--reference-topic", "/mocap/pose"][..],
        &["--reference-topic", "/slam/odom"],
        &[
            "--reference-topic",
            "/tf",
            "--reference-frames",
            "/map,marker",
        ],
    ] {
        let (est, _) = calibrate(
            &s("run.csv"),
            &s("py.mcap"),
            &s("mcap.toml"),
            &[&clock[..], topic].concat(),
        );
        for k in 0..5 {
            // The stamps as f64 seconds may differ in their last bit (1e-7 s at Unix times).
            assert!(
                (est[k] - tum[k]).abs() <= 1e-4 * se[k],
                "{topic:?} {k}: {est:?} vs TUM {tum:?}"
            );
        }
    }
}

#[test]
fn validate_reads_a_trajectory_in_another_frame_on_another_clock() {
    let d = common::scratch("trajectory_validate");
    let s = |n: &str| d.join(n).to_str().unwrap().to_string();
    let offset = simulate(&d, 3, "100", &[]);
    let (est, _) = calibrate(
        &s("run.csv"),
        &s("run.tum"),
        &s("cal.toml"),
        &["--time-offset", &offset],
    );
    assert!((est[3] - 0.25).abs() < 0.02, "{est:?}");
    let v = common::scratch("trajectory_validate_run");
    let sv = |n: &str| v.join(n).to_str().unwrap().to_string();
    simulate(
        &v,
        7,
        "60",
        &["--path", "validation", "--trajectory-frame", "-1,5,-120"],
    );
    let stdout = common::success_stdout(&common::odoctl(&[
        "validate",
        "--samples",
        &sv("run.csv"),
        "--reference",
        &sv("run.tum"),
        "--config",
        &s("cal.toml"),
    ]));
    assert!(
        stdout.contains("clock (estimated") && stdout.contains("horizontal error"),
        "{stdout}"
    );
}

/// A SLAM-like trajectory (10 Hz, 10 mm, 0.5 degree of yaw noise) determines the clock rate
/// poorly: the clock line says so and names `--clock-ppm 0`; given it, the fit uses rate 0.
#[test]
fn a_poorly_determined_clock_rate_is_named() {
    let d = common::scratch("trajectory_slam_rate");
    let noisy = [
        "--trajectory-every",
        "10",
        "--trajectory-sigma",
        "0.01",
        "--trajectory-yaw-sigma-deg",
        "0.5",
    ];
    simulate(&d, 6, "300", &noisy);
    let s = |n: &str| d.join(n).to_str().unwrap().to_string();
    let run = |extra: &[&str]| {
        let mut args = vec!["calibrate", "--samples"];
        let (samples, tum) = (s("run.csv"), s("run.tum"));
        args.extend([
            samples.as_str(),
            "--reference",
            tum.as_str(),
            "--no-delta",
            "--fit-antenna",
        ]);
        args.extend_from_slice(extra);
        common::success_stdout(&common::odoctl(&args))
    };
    let out = run(&[]);
    assert!(out.contains("the clock rate is poorly determined"), "{out}");
    assert!(out.contains("--clock-ppm 0"), "{out}");
    let fixed = run(&["--clock-ppm", "0"]);
    assert!(!fixed.contains("poorly determined"), "{fixed}");
    assert!(fixed.contains("+0.000 ppm (se 0.000 ppm)"), "{fixed}");
}

/// An estimated clock offset's error is carried into the standard errors: on a SLAM-like
/// trajectory (10 Hz, 10 mm) the lever arm forward's standard error with the offset estimated
/// exceeds the one with the offset given (at the estimate, so the geometry is the same), and
/// `calibrate` prints the share; with the offset given it prints none.
#[test]
fn an_estimated_clock_offset_widens_the_lever_arms_standard_error() {
    let d = common::scratch("trajectory_offset_share");
    let noisy = [
        "--trajectory-every",
        "10",
        "--trajectory-sigma",
        "0.01",
        "--trajectory-yaw-sigma-deg",
        "0.5",
    ];
    simulate(&d, 2, "150", &noisy);
    let s = |n: &str| d.join(n).to_str().unwrap().to_string();
    let run = |out: &str, extra: &[&str]| {
        let (samples, tum, out) = (s("run.csv"), s("run.tum"), s(out));
        let mut args = vec![
            "calibrate",
            "--samples",
            samples.as_str(),
            "--reference",
            tum.as_str(),
            "--out",
            out.as_str(),
            "--no-delta",
            "--fit-antenna",
        ];
        args.extend_from_slice(extra);
        let stdout = common::success_stdout(&common::odoctl(&args));
        let text = std::fs::read_to_string(&out).unwrap();
        let fit: toml::Table = text.parse::<toml::Table>().unwrap()["fit"]
            .as_table()
            .unwrap()
            .clone();
        (stdout, fit["antenna_forward_se"].as_float().unwrap())
    };
    let (estimated, se_estimated) = run("estimated.toml", &[]);
    let share = "the clock offset's share of the standard errors";
    assert!(estimated.contains(share), "{estimated}");
    let [offset, ..] = clock_line(&estimated);
    let (given, se_given) = run("given.toml", &["--time-offset", &offset.to_string()]);
    assert!(!given.contains(share), "{given}");
    eprintln!("lever arm forward se: {se_estimated:.2e} m estimated, {se_given:.2e} m given");
    assert!(se_estimated > 1.05 * se_given, "{se_estimated} {se_given}");
}
