//! Tests of the calibration's pieces against each other and against finite differences.

use super::evaluation::*;
use super::geometry::*;
use super::pipeline::*;
use super::restarts::*;
use super::run::*;
use super::sensitivity::*;
use super::uncertainty::*;
use crate::csvio::match_times;
use crate::optim::{self, norm2, LmOptions, NormalAccumulator, Objective};
use crate::simulate::{self, default_truth, PathKind, SimRun, SimSettings};
use indicatif::ProgressBar;
use odo_core::odometry::{ChassisParams, UncertaintyModel};

fn sim(kind: PathKind, length: f64, seed: u64) -> SimRun {
    let settings = SimSettings {
        seed,
        ..Default::default()
    };
    simulate::simulate_path(kind, length, default_truth(), settings)
}

/// The coefficient fits (predicted bracket, then the bisection on known coverages) give
/// the plain bisection's coefficient, every coverage evaluated: paper model without and
/// with `delta_diff` (sigma then not a power of delta), covariance model, on simulated
/// runs; also the refit's coarser width on a memo left by the finer fit.
#[test]
fn fast_coefficient_fit_matches_the_plain_bisection() {
    for seed in [1, 2] {
        let s = sim(PathKind::Random, 150.0, seed);
        let run = Run::new(
            &s.samples,
            &s.reference,
            match_times(&s.samples, &s.reference),
        );
        let geometry = default_truth();
        let h0 = run.heading_guess(0);
        for (model, dd) in [
            (UncertaintyModel::Paper, 0.0f32),
            (UncertaintyModel::Paper, 2e-8),
            (UncertaintyModel::Covariance, 0.0),
        ] {
            let g = ChassisParams {
                uncertainty_model: model,
                delta_diff: dd,
                ..geometry
            };
            let restarts = Restarts::new(&run, &g, h0, 10.0).unwrap();
            let hi = f64::from(match model {
                UncertaintyModel::Paper => ChassisParams::MAX_DELTA,
                UncertaintyModel::Covariance => ChassisParams::MAX_KAPPA,
            });
            let coef = |p: &ChassisParams| match model {
                UncertaintyModel::Paper => p.delta_left,
                UncertaintyModel::Covariance => p.kappa_left,
            };
            for tol in [COEFFICIENT_LOG_TOL, DIFF_LOG_TOL] {
                let mut ev = Evaluation::default();
                let (plain, _) = smallest_covering(
                    hi,
                    false,
                    tol,
                    |v| {
                        let p = set_coefficient(&g, DeltaMode::Equal, &g, v);
                        restarts.evaluate_into(&run, &p, &mut ev)?;
                        Ok(horizontal_coverage(&ev, 0.008, 1.0))
                    },
                    &ProgressBar::hidden(),
                )
                .unwrap();
                let fast = fit_coefficient(
                    &run,
                    &restarts,
                    &g,
                    &g,
                    0.008,
                    DeltaMode::Equal,
                    tol,
                    &ProgressBar::hidden(),
                )
                .unwrap();
                let (a, b) = (f64::from(coef(&fast.params)), f64::from(plain as f32));
                assert!(
                    (a / b).ln().abs() <= tol,
                    "seed {seed} {model:?} delta_diff {dd} width {tol}: fast {a:e}, plain {b:e}"
                );
            }
        }
    }
}

/// The analytic Jacobian of the residuals against central differences of the core
/// integrator's residuals, column by column (relative to the column's norm).
fn check_jacobian(run: &Run, params: &ChassisParams, heading0: f64, a: usize, b: usize) {
    let cols = [0, 1, 2, 3];
    let (mut r, mut jac) = (Vec::new(), Vec::new());
    assert!(run.residuals_with_jacobian(params, a, b, heading0, &mut r, Some(&mut jac), &cols));
    assert_eq!(jac.len(), r.len() * 4);
    let x0 = [
        params.left_diameter,
        params.right_diameter,
        params.track_width,
        heading0,
    ];
    for c in cols {
        // Steps large against the integrator's fixed-point noise (about 1e-8 m on a
        // position), small against the curvature: 1e-4 of a length, 1e-4 rad.
        let h = if c == 3 { 1e-4 } else { 1e-4 * x0[c] };
        let at = |d: f64| {
            let mut x = x0;
            x[c] += d;
            let mut out = Vec::new();
            assert!(run.residuals(&with_geometry(params, &x), a, b, x[3], &mut out));
            out
        };
        let (rp, rm) = (at(h), at(-h));
        let (mut diff, mut norm) = (0.0f64, 0.0f64);
        for i in 0..r.len() {
            let fd = (rp[i] - rm[i]) / (2.0 * h);
            diff = diff.hypot(jac[i * 4 + c] - fd);
            norm = norm.hypot(fd);
        }
        assert!(norm > 0.0, "column {c} is zero");
        // Measured: 4e-7 .. 8e-6, the central differences' own noise.
        assert!(
            diff / norm < 2e-5,
            "column {} ({}): relative difference {:e} (norm {norm:e})",
            c,
            GEOMETRY_UNKNOWNS[c],
            diff / norm
        );
    }
}

#[test]
fn analytic_jacobian_matches_central_differences() {
    // Arcs and straights; spins on the spot (validation path); away from the truth and
    // with a per-angle wheel function (wheel distances not proportional to the counts).
    let est = sim(PathKind::Estimation, 30.0, 3);
    let val = sim(PathKind::Validation, 20.0, 4);
    let mut wavy = default_truth();
    wavy.left_wheel.cos[0] = 2e-3;
    wavy.right_wheel.sin[1] = -1e-3;
    let poor = ChassisParams {
        left_diameter: 0.27,
        right_diameter: 0.25,
        track_width: 0.6,
        ..ChassisParams::DESIGNED
    };
    for s in [&est, &val] {
        let run = Run::new(
            &s.samples,
            &s.reference,
            match_times(&s.samples, &s.reference),
        );
        let last = run.len() - 1;
        for p in [default_truth(), wavy, poor] {
            check_jacobian(&run, &p, 0.31, 0, last);
            check_jacobian(&run, &p, -2.0, last / 3, last);
        }
    }
}

/// The two-core pipeline visits the same matches with the same poses and sensitivities,
/// to the bit, as the one-core loop (through an over-range sample and index latches).
#[test]
fn pipelined_sensitivities_equal_the_one_core_loop() {
    let mut s = sim(PathKind::Random, 300.0, 4);
    assert!(s.samples.len() > PIPELINE_MIN_SAMPLES + 2 * PIPELINE_CHUNK);
    // An over-range jump of both counters midway (the integrator skips that sample).
    for row in &mut s.samples[15_000..] {
        row.left += 1 << 20;
        row.right += 1 << 20;
    }
    let run = Run::new(
        &s.samples,
        &s.reference,
        match_times(&s.samples, &s.reference),
    );
    let last = run.len() - 1;
    let mut p = default_truth();
    p.left_wheel.cos[0] = 0.001;
    for (a, b) in [(0, last), (17, last - 3), (5, PIPELINE_CHUNK + 9)] {
        let mut here = Vec::new();
        run.integrate_with_sensitivity_here(&p, a, b, 0.4, |k, integ, d| {
            here.push((k, integ.pose(), *d));
        })
        .unwrap();
        let mut piped = Vec::new();
        run.integrate_with_sensitivity_pipelined(&p, a, b, 0.4, |k, pose, d| {
            piped.push((k, *pose, *d));
        })
        .unwrap();
        assert_eq!(here.len(), b - a);
        assert!(here == piped, "stretch {a}..{b}");
    }
}

#[test]
fn residuals_with_jacobian_keeps_the_integrators_residuals() {
    let s = sim(PathKind::Estimation, 10.0, 5);
    let run = Run::new(
        &s.samples,
        &s.reference,
        match_times(&s.samples, &s.reference),
    );
    let last = run.len() - 1;
    let p = default_truth();
    let (mut plain, mut with, mut jac) = (Vec::new(), Vec::new(), Vec::new());
    assert!(run.residuals(&p, 0, last, 0.3, &mut plain));
    assert!(run.residuals_with_jacobian(&p, 0, last, 0.3, &mut with, Some(&mut jac), &[2, 0]));
    assert_eq!(plain, with);
    assert_eq!(jac.len(), 2 * with.len());
    assert!(!run.residuals_with_jacobian(&p, 0, last, 0.3, &mut with, Some(&mut jac), &[4]));
    // Streamed into the accumulator: exactly the sums of the stored vectors.
    for (kind, newton) in [
        (Objective::Squares, false),
        (Objective::SumOfNorms, false),
        (Objective::SumOfNorms, true),
    ] {
        let cols = [0, 1, 3];
        assert!(run.residuals_with_jacobian(&p, 0, last, 0.3, &mut with, Some(&mut jac), &cols));
        let mut stored = NormalAccumulator::new(kind, newton, 3);
        stored.add_all(&with, &jac);
        let mut streamed = NormalAccumulator::new(kind, newton, 3);
        assert!(run.accumulate_normal(&p, 0, last, 0.3, &cols, &mut streamed));
        assert_eq!(streamed.cost(), stored.cost());
        assert_eq!(streamed.equations(), stored.equations());
        assert_eq!(streamed.residuals(), with.len());
    }
    let mut acc = NormalAccumulator::new(Objective::Squares, false, 1);
    assert!(!run.accumulate_normal(&p, 0, last, 0.3, &[4], &mut acc));
    let bad = ChassisParams {
        track_width: -1.0,
        ..p
    };
    assert!(!run.accumulate_normal(&bad, 0, last, 0.3, &[0], &mut acc));
}

/// The restarts' heading fit turns one integrated path about its start: the odometry
/// integrated from another start heading is that path turned (to the integrator's
/// rounding), and the heading found is the minimum of eq (16) that a fit re-integrating
/// the odometry at every step finds.
#[test]
fn restart_heading_by_rotation_matches_the_integrating_fit() {
    let s = sim(PathKind::Estimation, 70.0, 9);
    let run = Run::new(
        &s.samples,
        &s.reference,
        match_times(&s.samples, &s.reference),
    );
    let p = default_truth();
    let wins = windows(&run, 10.0, 3);
    assert!(wins.len() >= 6);
    let path = |a: usize, b: usize, h: f64| {
        let mut out = Vec::new();
        run.integrate_pose(&p, a, b, h, |_, integ| {
            let q = integ.pose();
            out.push((q.x, q.y));
        })
        .unwrap();
        out
    };
    for &(a, b) in &wins {
        let (x0, y0) = run.anchor(a);
        let base = path(a, b, 0.3);
        for phi in [0.01, -0.2, 0.5, 3.0] {
            let (sin, cos) = f64::sin_cos(phi);
            for ((x, y), (tx, ty)) in base.iter().zip(path(a, b, 0.3 + phi)) {
                let (dx, dy) = (x - x0, y - y0);
                let (rx, ry) = (x0 + dx * cos + dy * sin, y0 + dy * cos - dx * sin);
                assert!(norm2(rx - tx, ry - ty) < 1e-7, "window {a}..{b}, phi {phi}");
            }
        }
        // Against the fit that re-integrates the odometry at every step, converged as far.
        // That fit's eq (16) carries the fixed-point integrator's arithmetic noise, not
        // smooth in the heading (measured on these windows: +-1e-6 m of a 7.7 m cost
        // between headings 2e-8 rad apart, where the turned path's cost changes by 1e-9 m),
        // and its Newton steps stop on that noise: the two headings agree to about 1e-7
        // rad, and their costs to that noise.
        let integrated = |guess: f64| {
            let res = optim::levenberg_marquardt_streamed(
                |x: &[f64], acc: &mut NormalAccumulator| {
                    run.accumulate_normal(&p, a, b, x[0], &[3], acc)
                },
                &[guess],
                &[1.0],
                Objective::SumOfNorms,
                LmOptions {
                    newton: true,
                    pred_tol: 1e-15,
                    ..LmOptions::default()
                },
            )
            .unwrap();
            res.x[0]
        };
        for guess in [0.3, 0.3 + 0.2, 0.3 - 0.05] {
            let rotated = fit_restart_heading(&run, &p, a, b, guess).unwrap();
            let integrated = integrated(guess);
            let cost = |h: f64| run.eq16(&p, a, b, h).unwrap();
            let (cr, ci) = (cost(rotated), cost(integrated));
            assert!(
                (rotated - integrated).abs() < 2e-7 && (cr - ci).abs() <= 5e-7 * ci,
                "window {a}..{b} from {guess}: {rotated} ({cr}) vs {integrated} ({ci})"
            );
        }
    }
}

#[test]
fn standard_errors_and_the_track_width_warning() {
    let s = sim(PathKind::Estimation, 30.0, 6);
    let run = Run::new(
        &s.samples,
        &s.reference,
        match_times(&s.samples, &s.reference),
    );
    let last = run.len() - 1;
    let fit = fit_geometry(
        &run,
        &default_truth(),
        0.3,
        0,
        last,
        GeomOptions::default(),
        &ProgressBar::hidden(),
    )
    .unwrap();
    assert!(
        fit.track_estimated && fit.track_warning.is_none(),
        "{fit:?}"
    );
    for se in fit.std_errors {
        let se = se.unwrap();
        assert!(se > 0.0 && se < 1e-3, "{se}");
    }
    // The errors scale with the residual sigma: the same fit with all four free again.
    let (se, s) = standard_errors(&run, &fit.params, 0, last, fit.heading0, [true; 4]).unwrap();
    assert_eq!(se, fit.std_errors);
    assert!(
        (s - fit.residual_sigma).abs() < 1e-15 && s > 0.004 && s < 0.02,
        "{s}"
    );
    // Held unknowns have no error; too little turning warns.
    let (se, _) = standard_errors(
        &run,
        &fit.params,
        0,
        last,
        fit.heading0,
        [true, true, false, true],
    )
    .unwrap();
    assert!(se[2].is_none() && se[0].is_some());
    let p = fit.params;
    let held = track_width_warning(false, 0.2, 0.5, &p, &fit.std_errors).unwrap();
    assert!(held.contains("not estimated"), "{held}");
    let little = track_width_warning(true, 1.0, 0.5, &p, &fit.std_errors).unwrap();
    assert!(little.contains("poorly determined"), "{little}");
    let mut loose = fit.std_errors;
    loose[2] = Some(2e-3 * p.track_width);
    assert!(track_width_warning(true, 10.0, 0.5, &p, &loose).is_some());
    assert!(track_width_warning(true, 10.0, 0.5, &p, &fit.std_errors).is_none());
}
