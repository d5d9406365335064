//! `odoctl replay --mcap` read back by an independent reader: the Python `mcap` and
//! `mcap-ros2-support` packages (tests/ros/read_mcap.py), which decode every message from the
//! file's own schemas and check each field against the replay CSV, the SAMPLES counts and the
//! conventions of docs/ROS.md. Skipped with a message when python3 or the packages are
//! missing, unless `ODO_PY_REQUIRED=1` (CI).

mod common;

use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

use common::{odoctl, scratch, success_stdout};
use odo_unit::odometry::{ChassisParams, Integrator, Pose};
use odoctl::replay::{counts, index_refs};

/// Whether the reader can run; panics when it cannot and CI requires it.
fn python_ready() -> bool {
    common::python_has(
        "ros_mcap",
        "mcap, mcap_ros2.decoder",
        "mcap mcap-ros2-support",
    )
}

/// A parameter file with every key the reader uses written out.
fn params_toml(p: &ChassisParams) -> String {
    let model = match p.uncertainty_model {
        odo_unit::odometry::UncertaintyModel::Paper => "paper",
        odo_unit::odometry::UncertaintyModel::Covariance => "covariance",
    };
    format!(
        "left_diameter = {:?}\nright_diameter = {:?}\ntrack_width = {:?}\nticks_per_rev = {}\n\
         delta_left = {:?}\ndelta_right = {:?}\ndelta_diff = {:?}\nuncertainty_model = \"{model}\"\n\
         kappa_left = {:?}\nkappa_right = {:?}\n",
        p.left_diameter,
        p.right_diameter,
        p.track_width,
        p.ticks_per_rev,
        p.delta_left,
        p.delta_right,
        p.delta_diff,
        p.kappa_left,
        p.kappa_right
    )
}

/// The covariance terms the replay CSV does not carry, straight from the core integrator:
/// `t,cov_xy,cov_x_heading,cov_y_heading` per row.
fn expectations(p: &ChassisParams, samples: &Path) -> String {
    let s = odoctl::csvio::read_samples(samples).unwrap();
    let mut integ = Integrator::new(p, counts(&s[0]), Pose::default()).unwrap();
    let mut out = String::from("t,cov_xy,cov_x_heading,cov_y_heading\n");
    for (i, row) in s.iter().enumerate() {
        if i > 0 {
            integ.step(counts(row), index_refs(row));
        }
        let (xa, ya) = integ.heading_covariance();
        let _ = writeln!(
            out,
            "{},{:?},{:?},{:?}",
            row.t,
            integ.sigma().cov_xy,
            xa,
            ya
        );
    }
    out
}

/// Reads `name.mcap` back; `names` are read_mcap.py's name options (`--ns`, ...).
fn read_back(dir: &Path, name: &str, stamps: &str, fault_at: Option<usize>, names: &[&str]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ros/read_mcap.py");
    let f = |x: &str| dir.join(format!("{name}{x}")).display().to_string();
    let mut cmd = Command::new("python3");
    cmd.arg(&script).args([
        "--mcap",
        &f(".mcap"),
        "--samples",
        &f("_samples.csv"),
        "--replay",
        &f("_replay.csv"),
        "--expect",
        &f("_expect.csv"),
        "--params",
        &f(".toml"),
        "--stamps",
        stamps,
    ]);
    if let Some(k) = fault_at {
        cmd.args(["--fault-at", &k.to_string()]);
    }
    cmd.args(names);
    let o = cmd.output().expect("python3 runs");
    let out = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{name}: {out}\n{err}");
    assert!(out.contains("read_mcap: ok"), "{out}");
    eprintln!("{name}: {}", out.trim());
}

/// Replays `name_samples.csv` with `name.toml` through the CLI into `name.mcap` and
/// `name_replay.csv` (with the name options `names`), and writes the expectations.
fn replay_to_mcap(dir: &Path, name: &str, p: &ChassisParams, names: &[&str]) {
    let f = |x: &str| dir.join(format!("{name}{x}"));
    std::fs::write(f(".toml"), params_toml(p)).unwrap();
    let mut args = vec![
        "replay".to_string(),
        f("_samples.csv").display().to_string(),
        "--config".into(),
        f(".toml").display().to_string(),
        "--out".into(),
        f("_replay.csv").display().to_string(),
        "--mcap".into(),
        f(".mcap").display().to_string(),
    ];
    args.extend(names.iter().map(|s| s.to_string()));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = odoctl(&args);
    success_stdout(&o);
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("/odom"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::write(f("_expect.csv"), expectations(p, &f("_samples.csv"))).unwrap();
}

fn simulated(dir: &Path) -> std::path::PathBuf {
    let s = dir.join("sim_samples.csv");
    success_stdout(&odoctl(&[
        "simulate",
        "--samples",
        s.to_str().unwrap(),
        "--reference",
        dir.join("sim_reference.csv").to_str().unwrap(),
        "--length",
        "15",
        "--seed",
        "7",
    ]));
    s
}

#[test]
fn paper_model_simulated_run_read_back_independently() {
    let dir = scratch("ros_mcap_paper");
    let s = simulated(&dir);
    std::fs::copy(&s, dir.join("paper_samples.csv")).unwrap();
    let mut p = ChassisParams::DESIGNED;
    p.delta_left = 3.0e-6;
    p.delta_right = 2.0e-6;
    p.delta_diff = 1.0e-6;
    replay_to_mcap(&dir, "paper", &p, &[]);
    if python_ready() {
        read_back(&dir, "paper", "samples_t", None, &[]);
    }
}

#[test]
fn covariance_model_recording_with_time_tags_and_a_fault_read_back_independently() {
    let dir = scratch("ros_mcap_cov");
    let s = simulated(&dir);
    // The simulated counts as `record` writes them: GNSS time of week (PPS-locked, time tag
    // valid) from GPS week 2300, day 3, and from sample 300 on the left encoder's fault bit.
    let rows = odoctl::csvio::read_samples(&s).unwrap();
    let fault_at = 300;
    let mut text = String::from("t,left,right,seq,x,y,heading,sigma_x,sigma_y,sigma_heading,flags,mcu_time_us,gps_week,gps_tow_ms\n");
    for (i, r) in rows.iter().enumerate() {
        let ms = 3 * 86_400_000 + 20 * i as u64;
        let t = ms as f64 * 1e-3;
        let flags = 1 | 1 << 2 | if i >= fault_at { 1 << 3 } else { 0 };
        let _ = writeln!(
            text,
            "{t:.3},{},{},{i},0,0,0,0,0,0,{flags},{},2300,{}",
            r.left,
            r.right,
            1_000_000 + 20_000 * i as u64,
            ms / 1000 * 1000
        );
    }
    std::fs::write(dir.join("cov_samples.csv"), text).unwrap();
    let mut p = ChassisParams::DESIGNED;
    p.uncertainty_model = odo_unit::odometry::UncertaintyModel::Covariance;
    p.kappa_left = 2.0e-6;
    p.kappa_right = 1.0e-6;
    // A second robot's names: namespace, frame prefix, its own joints, no TF.
    let names = [
        "--namespace",
        "robot2",
        "--frame-prefix",
        "robot2/",
        "--left-wheel-joint",
        "wheel_l",
        "--right-wheel-joint",
        "wheel_r",
        "--no-tf",
    ];
    replay_to_mcap(&dir, "cov", &p, &names);
    // The position-heading terms are carried (non-zero) by this model.
    let e = std::fs::read_to_string(dir.join("cov_expect.csv")).unwrap();
    let last: Vec<f64> = e
        .lines()
        .last()
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert!(last[2] != 0.0 && last[3] != 0.0, "{last:?}");
    if python_ready() {
        let back = [
            "--ns",
            "robot2",
            "--frame-prefix",
            "robot2/",
            "--joints",
            "wheel_l,wheel_r",
            "--no-tf",
        ];
        read_back(&dir, "cov", "utc", Some(fault_at), &back);
    }
}

#[test]
fn bad_output_path_is_an_error_and_leaves_no_csv_half_written() {
    let dir = scratch("ros_mcap_bad");
    let s = simulated(&dir);
    let o = odoctl(&[
        "replay",
        s.to_str().unwrap(),
        "--out",
        dir.join("r.csv").to_str().unwrap(),
        "--mcap",
        dir.join("no/such/dir/x.mcap").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("x.mcap") && err.contains("cannot create"),
        "{err}"
    );
    assert!(!dir.join("r.csv").exists());
}

#[test]
fn record_mcap_from_a_unit_on_tcp_read_back_independently() {
    let sim = common::sim(odoctl::simulate::PathKind::Validation, 10.0, 11);
    let samples: Vec<_> = sim.samples[..300].to_vec();
    let dir = scratch("ros_mcap_record");
    let (port, unit) = common::fake_unit(samples, std::time::Duration::from_millis(1));
    let f = |x: &str| dir.join(format!("rec{x}"));
    // The unit runs the designed parameters (its defaults): the twist needs them.
    std::fs::write(f(".toml"), params_toml(&ChassisParams::DESIGNED)).unwrap();
    let o = odoctl(&[
        "record",
        "--port",
        &format!("tcp:127.0.0.1:{port}"),
        "--out",
        f("_samples.csv").to_str().unwrap(),
        "--count",
        "200",
        "--reset-pose",
        "--mcap",
        f(".mcap").to_str().unwrap(),
        "--config",
        f(".toml").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("mcap: 200 /odom and /tf"), "{err}");
    assert!(!err.contains("do not look like the unit's"), "{err}");
    unit.join().unwrap();
    // The unit's own pose columns are what /odom must carry; the x-y covariance as sent, no
    // position-heading terms (not on the wire).
    std::fs::copy(f("_samples.csv"), f("_replay.csv")).unwrap();
    let rows = odoctl::csvio::read_samples(&f("_samples.csv")).unwrap();
    let mut e = String::from("t,cov_xy,cov_x_heading,cov_y_heading\n");
    for r in &rows {
        let _ = writeln!(e, "{},{:?},0,0", r.t, r.unit.unwrap().cov_xy);
    }
    std::fs::write(f("_expect.csv"), e).unwrap();
    if python_ready() {
        read_back(&dir, "rec", "mcu_time", None, &[]);
    }
}

#[test]
fn validate_mcap_tracks_read_back_independently() {
    let dir = scratch("ros_mcap_validate");
    let s = simulated(&dir);
    let r = dir.join("sim_reference.csv");
    let (m, e) = (dir.join("val.mcap"), dir.join("errors.csv"));
    let o = odoctl(&[
        "validate",
        "--samples",
        s.to_str().unwrap(),
        "--reference",
        r.to_str().unwrap(),
        "--errors",
        e.to_str().unwrap(),
        "--mcap",
        m.to_str().unwrap(),
    ]);
    success_stdout(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("/reference/path") && err.contains("2 paths"),
        "{err}"
    );
    if python_ready() {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ros/read_tracks.py");
        let o = Command::new("python3")
            .arg(script)
            .args(["--mcap", m.to_str().unwrap()])
            .args(["--reference", r.to_str().unwrap()])
            .args(["--errors", e.to_str().unwrap()])
            .output()
            .unwrap();
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success() && out.contains("read_tracks: ok"),
            "{out}\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        eprintln!("{}", out.trim());
    }
}

#[test]
fn calibrate_export_ros_writes_the_result_as_diff_drive_parameters() {
    let dir = scratch("ros_export_calibrate");
    let s = simulated(&dir);
    let (toml, yaml) = (dir.join("cal.toml"), dir.join("dd.yaml"));
    let o = odoctl(&[
        "calibrate",
        "--samples",
        s.to_str().unwrap(),
        "--reference",
        dir.join("sim_reference.csv").to_str().unwrap(),
        "--no-delta",
        "--quiet",
        "--out",
        toml.to_str().unwrap(),
        "--export-ros",
        yaml.to_str().unwrap(),
        "--mcap",
        dir.join("cal.mcap").to_str().unwrap(),
    ]);
    success_stdout(&o);
    // The calibrated track (Fig. 4) too: the same as `validate --mcap` with the result.
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("/odom/path"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let o = odoctl(&[
        "validate",
        "--samples",
        s.to_str().unwrap(),
        "--reference",
        dir.join("sim_reference.csv").to_str().unwrap(),
        "--config",
        toml.to_str().unwrap(),
        "--mcap",
        dir.join("val.mcap").to_str().unwrap(),
    ]);
    success_stdout(&o);
    let cal = std::fs::read(dir.join("cal.mcap")).unwrap();
    assert!(cal.len() > 1000);
    assert!(cal == std::fs::read(dir.join("val.mcap")).unwrap());
    let p = odoctl::config::read_params(&toml, ChassisParams::DESIGNED).unwrap();
    let y = std::fs::read_to_string(&yaml).unwrap();
    let v = |k: &str| -> f64 {
        y.lines()
            .find_map(|l| l.trim().strip_prefix(&format!("{k}: ")))
            .unwrap_or_else(|| panic!("{k}:\n{y}"))
            .parse()
            .unwrap()
    };
    assert_eq!(v("wheel_separation"), p.track_width);
    let r = v("wheel_radius");
    assert!((2.0 * r * v("left_wheel_radius_multiplier") - p.left_diameter).abs() < 1e-15);
    assert!((2.0 * r * v("right_wheel_radius_multiplier") - p.right_diameter).abs() < 1e-15);
    // The fit moved the designed diameters: the file holds the calibration, not the defaults.
    assert_ne!(p.left_diameter, ChassisParams::DESIGNED.left_diameter);
    // Without --out there is no result to convert: refused by the command line.
    let o = odoctl(&[
        "calibrate",
        "--samples",
        s.to_str().unwrap(),
        "--reference",
        dir.join("sim_reference.csv").to_str().unwrap(),
        "--export-ros",
        yaml.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
}
