//! `odoctl pool` and the pooling of drives against the truth.

mod common;

use common::scratch;
use odo_unit::odometry::ChassisParams;
use odoctl::calib::pooling::{pool, DriveEstimate};
use odoctl::simulate::{default_truth, PathKind};
use odoctl::stats::chi2_quantile_99;

/// The default calibration of a simulated 70 m drive, as the pooling takes it.
fn drive(seed: u64) -> DriveEstimate {
    let (c, u) = common::calibrate_covariance(&common::sim(PathKind::Estimation, 70.0, seed));
    let p = c.params;
    let g = p.geometry_uncertainty;
    let se = [g.left_diameter_se, g.right_diameter_se, g.track_width_se].map(f64::from);
    let r = [
        [1.0, g.diameters_correlation, g.left_track_correlation],
        [g.diameters_correlation, 1.0, g.right_track_correlation],
        [g.left_track_correlation, g.right_track_correlation, 1.0],
    ];
    DriveEstimate {
        geometry: common::lengths(&p),
        covariance: std::array::from_fn(|i| {
            std::array::from_fn(|j| f64::from(r[i][j]) * se[i] * se[j])
        }),
        kappa_most_likely: u.most_likely.unwrap(),
        kappa_ln_se: u.ln_se.unwrap(),
    }
}

/// Six sets of four simulated 70 m drives: the pooled geometry and kappa fall within their
/// (halved) standard errors of the truth, and the drives agree by the chi-square tests summed
/// over the sets.
#[test]
fn pooled_drives_hold_their_standard_errors() {
    let truth = common::lengths(&default_truth());
    // The simulator's slip: 2 slip^2 corr.
    let truth_kappa: f64 = 2.0 * 0.001f64.powi(2) * 0.1;
    let (mut z, mut zk, mut shrink) = (Vec::new(), Vec::new(), Vec::new());
    let mut chi2 = [(0.0, 0usize); 2];
    for set in 0..6u64 {
        let drives: Vec<_> = (0..4).map(|k| drive(100 + 4 * set + k)).collect();
        let p = pool(&drives).unwrap();
        for (i, t) in truth.iter().enumerate() {
            z.push((p.geometry[i] - t) / p.covariance[i][i].sqrt());
            let single = drives
                .iter()
                .map(|d| d.covariance[i][i].sqrt())
                .sum::<f64>()
                / 4.0;
            shrink.push(p.covariance[i][i].sqrt() / single);
        }
        zk.push((p.kappa_most_likely / truth_kappa).ln() / p.kappa_ln_se);
        for (sum, t) in chi2.iter_mut().zip([p.geometry_chi2, p.kappa_chi2]) {
            sum.0 += t.0;
            sum.1 += t.1;
        }
    }
    eprintln!("pooled z {z:.2?}; ln kappa z {zk:.2?}; SE shrink {shrink:.2?}; chi-square (value, dof) of geometry and ln kappa over the sets {chi2:?}");
    // The drives agree within their standard errors: each chi-square summed over the sets
    // below its 99 % quantile.
    for (v, dof) in chi2 {
        assert!(v < chi2_quantile_99(dof as f64), "{v} on {dof}");
    }
    assert!(z.iter().all(|v| v.abs() < 3.0), "{z:?}");
    assert!(z.iter().filter(|v| v.abs() < 2.0).count() >= 15, "{z:?}");
    assert!(zk.iter().all(|v| v.abs() < 3.0), "{zk:?}");
    // Four drives: the standard errors about halve.
    assert!(shrink.iter().all(|s| (0.4..0.6).contains(s)), "{shrink:?}");
}

/// A drive's result file as `calibrate --out` writes it (the keys pool reads).
fn result_file(d: f64, kappa: f64, fit: &str) -> String {
    format!(
        "left_diameter = {d}\nright_diameter = {d}\ntrack_width = 0.5656\n\
         uncertainty_model = \"covariance\"\nkappa_left = {kappa}\nkappa_right = {kappa}\n\
         left_diameter_se = 0.00002\nright_diameter_se = 0.00002\ntrack_width_se = 0.0003\n\
         \n[fit]\n{fit}"
    )
}

#[test]
fn pool_writes_the_pooled_parameters_and_refuses_what_it_cannot_pool() {
    let dir = scratch("pool_cli");
    let fit = "path_length = 70.0\ncovariance_most_likely = 2e-7\ncovariance_ln_se = 0.25\n";
    let write = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p.to_str().unwrap().to_string()
    };
    let a = write("a.toml", &result_file(0.2608, 2.1e-7, fit));
    let b = write("b.toml", &result_file(0.26082, 2.1e-7, fit));
    let out = dir.join("pooled.toml");
    let out_s = out.to_str().unwrap();
    let o = common::odoctl(&["pool", &a, &b, "--out", out_s]);
    let text = common::success_stdout(&o);
    assert!(
        text.contains("pooled") && text.contains("agreement"),
        "{text}"
    );
    let p = odoctl::config::read_params(&out, ChassisParams::DESIGNED).unwrap();
    assert!(
        (p.left_diameter - 0.26081).abs() < 1e-9,
        "{}",
        p.left_diameter
    );
    let se = f64::from(p.geometry_uncertainty.left_diameter_se);
    assert!((se - 0.00002 / 2f64.sqrt()).abs() < 1e-9, "{se}");
    // kappa: the mean over the pooled likelihood, exp(0.25^2 / 4) times 2e-7.
    let want = 2e-7 * (0.25f64.powi(2) / 4.0).exp();
    assert!(
        (f64::from(p.kappa_left) / want - 1.0).abs() < 1e-6,
        "{}",
        p.kappa_left
    );

    let paper = write(
        "paper.toml",
        &result_file(0.2608, 2e-7, fit).replace("\"covariance\"", "\"paper\""),
    );
    let no_fit = write(
        "no_fit.toml",
        &result_file(0.2608, 2e-7, "").replace("\n[fit]\n", "\n"),
    );
    let no_se = write(
        "no_se.toml",
        &result_file(
            0.2608,
            2e-7,
            "path_length = 70.0\ncovariance_most_likely = 2e-7\n",
        ),
    );
    let other_ticks = write(
        "ticks.toml",
        &format!("ticks_per_rev = 4096\n{}", result_file(0.2608, 2e-7, fit)),
    );
    for (bad, why) in [
        (
            &paper,
            "paper.toml: uncertainty_model is not \"covariance\"",
        ),
        (&no_fit, "no_fit.toml: no [fit] table"),
        (&no_se, "no_se.toml: [fit] has no covariance_ln_se"),
        (&other_ticks, "ticks.toml: ticks_per_rev 4096 differs"),
    ] {
        let _ = std::fs::remove_file(&out);
        let o = common::odoctl(&["pool", &a, bad, "--out", out_s]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains(why), "{why}: {e}");
        assert!(!out.exists(), "{why}: nothing is written");
    }
    // One file is not a pool.
    let o = common::odoctl(&["pool", &a, "--out", out_s]);
    assert!(!o.status.success());
}
