//! Calibration on simulated runs with known truth (the acceptance figures).

mod common;

use std::time::Instant;

use indicatif::ProgressBar;
use odo_unit::odometry::{ChassisParams, Pose};
use odoctl::calib::{self, CalibrationOptions, Run, UncertaintyCriterion, WindowStart};
use odoctl::csvio::match_times;
use odoctl::simulate::PathKind;

fn poor_first_estimate() -> ChassisParams {
    ChassisParams {
        left_diameter: 0.300,
        right_diameter: 0.300,
        track_width: 0.700,
        ..ChassisParams::DESIGNED
    }
}

/// The options with the paper's coverage criterion for the uncertainty coefficients.
fn paper_criterion() -> CalibrationOptions {
    CalibrationOptions {
        criterion: UncertaintyCriterion::Coverage,
        ..CalibrationOptions::default()
    }
}

#[test]
fn calibrate_recovers_the_truth_from_the_papers_poor_first_estimate() {
    let truth = common::truth();
    for seed in [11, 12] {
        let sim = common::sim(PathKind::Estimation, 70.0, seed);
        let started = Instant::now();
        let c = calib::calibrate(
            &sim.samples,
            &sim.reference,
            ("s", "r"),
            &poor_first_estimate(),
            // The paper's coverage criterion (the default is the likelihood).
            &paper_criterion(),
        )
        .unwrap();
        let e = [
            c.params.left_diameter - truth.left_diameter,
            c.params.right_diameter - truth.right_diameter,
            c.params.track_width - truth.track_width,
        ];
        eprintln!(
            "seed {seed}: errors left {:+.4} mm, right {:+.4} mm, track {:+.4} mm; heading0 {:+.5} rad; delta {:e}; {:.2} s",
            e[0] * 1e3,
            e[1] * 1e3,
            e[2] * 1e3,
            c.geometry.heading0 - 0.3,
            c.params.delta_left,
            started.elapsed().as_secs_f64()
        );
        assert!(
            e[0].abs() < 0.5e-3 && e[1].abs() < 0.5e-3,
            "diameters off by {e:?}"
        );
        assert!(e[2].abs() < 2e-3, "track width off by {e:?}");
        assert!((c.geometry.heading0 - 0.3).abs() < 0.01);
        let u = &c.uncertainty[0];
        assert!(
            (u.coverage1 - calib::ONE_SIGMA_COVERAGE).abs() < 0.01,
            "coverage {}",
            u.coverage1
        );
        assert_eq!(c.params.delta_left, c.params.delta_right);
        assert!(c.params.delta_left > 0.0);
        // No slip when turning: the paper's model already covers the heading changes, and
        // delta_diff stays 0.
        let d = u.diff.as_ref().expect("the reference has a heading");
        eprintln!(
            "seed {seed}: delta_diff {:e}, heading coverage {:.3} -> {:.3}",
            d.delta_diff, d.coverage1_before, d.coverage1
        );
        assert_eq!(c.params.delta_diff, 0.0);
        assert!(d.coverage1 >= calib::ONE_SIGMA_COVERAGE && d.coverage3 > 0.99);
    }
}

#[test]
fn delta_diff_is_fitted_when_the_wheels_slip_in_opposite_phase_while_turning() {
    // simulate --slip-turn 0.03: the paper's model, delta fitted on the horizontal errors,
    // under-covers the heading changes; delta_diff brings the heading band to nominal with
    // delta refitted, so the horizontal band stays nominal too.
    let sim = common::sim_turn_slip(PathKind::Estimation, 70.0, 11, 0.03);
    let started = Instant::now();
    let c = calib::calibrate(
        &sim.samples,
        &sim.reference,
        ("s", "r"),
        &common::truth(),
        &paper_criterion(),
    )
    .unwrap();
    let u = &c.uncertainty[0];
    let d = u.diff.as_ref().expect("the reference has a heading");
    eprintln!(
        "delta {:e} -> {:e}, delta_diff {:e}; heading 1-sigma {:.3} -> {:.3}, 3-sigma {:.3} -> {:.3}; horizontal 1-sigma {:.3}; {:.2} s",
        d.delta_before,
        c.params.delta_left,
        d.delta_diff,
        d.coverage1_before,
        d.coverage1,
        d.coverage3_before,
        d.coverage3,
        u.coverage1,
        started.elapsed().as_secs_f64()
    );
    assert!(d.fitted && d.joint && d.warning.is_none());
    assert!(c.params.delta_diff > 1e-7, "{}", c.params.delta_diff);
    assert!(d.coverage1_before < calib::ONE_SIGMA_COVERAGE - 0.03);
    assert!((d.coverage1 - calib::ONE_SIGMA_COVERAGE).abs() < 0.01);
    assert!((u.coverage1 - calib::ONE_SIGMA_COVERAGE).abs() < 0.01);
    assert!(f64::from(c.params.delta_left) < d.delta_before);
    // --no-fit-delta-diff keeps the initial value and reports the same "before" coverage.
    let kept = calib::calibrate(
        &sim.samples,
        &sim.reference,
        ("s", "r"),
        &common::truth(),
        &CalibrationOptions {
            fit_delta_diff: false,
            ..paper_criterion()
        },
    )
    .unwrap();
    let k = kept.uncertainty[0].diff.as_ref().unwrap();
    assert_eq!(kept.params.delta_diff, 0.0);
    assert!(!k.fitted && k.coverage1 == d.coverage1_before);
}

#[test]
fn eq16_at_the_estimate_is_not_above_eq16_at_the_truth() {
    // The optimiser reaches the minimum of eq (16): the truth (with its best heading) cannot
    // do better on the same data.
    let sim = common::sim(PathKind::Estimation, 30.0, 5);
    let run = Run::new(
        &sim.samples,
        &sim.reference,
        match_times(&sim.samples, &sim.reference),
    );
    let last = run.len() - 1;
    let fit = calib::fit_geometry(
        &run,
        &poor_first_estimate(),
        run.heading_guess(0),
        0,
        last,
        Default::default(),
        &ProgressBar::hidden(),
    )
    .unwrap();
    let truth = common::truth();
    let h = calib::fit_heading(&run, &truth, 0, last, 0.3).unwrap();
    let at_truth = run.eq16(&truth, 0, last, h).unwrap();
    assert!(
        fit.cost <= at_truth * (1.0 + 1e-9),
        "fit {} truth {}",
        fit.cost,
        at_truth
    );
    assert!(fit.track_estimated);
}

#[test]
fn replay_with_the_true_parameters_follows_the_reference() {
    let sim = common::sim(PathKind::Estimation, 70.0, 3);
    let (x0, y0, h0) = sim.truth[0];
    let rows = odoctl::replay::replay(
        &common::truth(),
        &sim.samples,
        Pose {
            x: x0,
            y: y0,
            heading: h0,
        },
    )
    .unwrap();
    let err_truth = rows
        .iter()
        .zip(&sim.truth)
        .map(|(r, t)| (r.pose.x - t.0).hypot(r.pose.y - t.1))
        .fold(0.0, f64::max);
    let err_ref = rows
        .iter()
        .zip(&sim.reference)
        .map(|(r, t)| (r.pose.x - t.x).hypot(r.pose.y - t.y))
        .fold(0.0, f64::max);
    eprintln!("replay with the truth: max error {err_truth:.4} m against the true path, {err_ref:.4} m against the reference");
    assert!(err_truth < 0.15, "{err_truth}");
    assert!(err_ref < 0.2, "{err_ref}");
    // Without slip, only encoder quantisation remains.
    let mut rng = odoctl::simulate::Rng::new(1);
    let clean = odoctl::simulate::simulate(&odoctl::simulate::SimOptions {
        truth: common::truth(),
        segments: odoctl::simulate::path(PathKind::Validation, 40.0, &mut rng),
        settings: odoctl::simulate::SimSettings {
            rate: 50.0,
            speed: 0.5,
            slip: 0.0,
            slip_corr: 0.1,
            slip_turn: 0.0,
            slip_turn_corr: 1.0,
            rtk_sigma: 0.0,
            heading_sigma: None,
            start: (0.0, 0.0, 0.0),
            seed: 1,
        },
    });
    let rows = odoctl::replay::replay(&common::truth(), &clean.samples, Pose::default()).unwrap();
    let err = rows
        .iter()
        .zip(&clean.truth)
        .map(|(r, t)| (r.pose.x - t.0).hypot(r.pose.y - t.1))
        .fold(0.0, f64::max);
    assert!(err < 1e-3, "{err}");
}

#[test]
fn stability_study_reports_every_window() {
    let sim = common::sim(PathKind::Estimation, 40.0, 4);
    let run = Run::new(
        &sim.samples,
        &sim.reference,
        match_times(&sim.samples, &sim.reference),
    );
    let full = calib::fit_geometry(
        &run,
        &poor_first_estimate(),
        run.heading_guess(0),
        0,
        run.len() - 1,
        calib::GeomOptions {
            polish: false,
            ..Default::default()
        },
        &ProgressBar::hidden(),
    )
    .unwrap();
    let est = calib::windows_study(
        &run,
        &full,
        &poor_first_estimate(),
        &[4.0, 8.0],
        WindowStart::Full,
        &ProgressBar::hidden(),
    )
    .unwrap();
    let n4 = est.iter().filter(|e| e.length == 4.0).count();
    let n8 = est.iter().filter(|e| e.length == 8.0).count();
    assert!((8..=11).contains(&n4) && (4..=5).contains(&n8), "{n4} {n8}");
    // On 8 m windows the diameters stay within a few millimetres of the truth.
    let t = common::truth();
    let good = est
        .iter()
        .filter(|e| e.length == 8.0)
        .filter_map(|e| e.estimate.as_ref().ok())
        .filter(|v| (v[0] - t.left_diameter).abs() < 3e-3 && (v[1] - t.right_diameter).abs() < 3e-3)
        .count();
    assert!(good * 4 >= n8 * 3, "{good} of {n8}");
}

/// kappa's own standard error (`ln_se`, from the likelihood's curvature) is honest: over 16
/// simulated 70 m drives the fitted `ln kappa` falls about that far from the simulated slip's
/// long-range variance rate (`2 slip^2 slip_corr`, 2e-7 m^2/m for the defaults).
#[test]
fn kappa_standard_error_matches_its_spread_over_drives() {
    let truth_kappa: f64 = 2.0 * 0.001f64.powi(2) * 0.1;
    let z: Vec<f64> = (10..26)
        .map(|seed| {
            let (_, u) =
                common::calibrate_covariance(&common::sim(PathKind::Estimation, 70.0, seed));
            let se = u.ln_se.expect("a likelihood fit has a standard error");
            assert!(se > 0.1 && se < 0.5, "seed {seed}: ln se {se}");
            // The standard error is the most likely value's; the unit is told the mean.
            let most_likely = u
                .most_likely
                .expect("a likelihood fit has its most likely value");
            assert!(f64::from(u.params.kappa_left) >= most_likely as f32 as f64);
            (most_likely.ln() - truth_kappa.ln()) / se
        })
        .collect();
    let n = z.len() as f64;
    let mean = z.iter().sum::<f64>() / n;
    let sd = (z.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    eprintln!("kappa z-scores: mean {mean:.2}, sd {sd:.2}: {z:.2?}");
    // 16 drives: the sd of z within about 2.5 of its standard error (0.18) of 1, the mean
    // within about 3 of its standard error (0.25) of 0.
    assert!(sd > 0.55 && sd < 1.5, "sd {sd}");
    assert!(mean.abs() < 0.75, "mean {mean}");
}
