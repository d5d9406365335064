//! What `calibrate` prints: the estimates with their standard errors, how they were found,
//! the uncertainty fits, the errors at the result and the stability study.

use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use super::{filter_refined, ErrorSummary};
use crate::calib::{
    self, Calibration, CalibrationOptions, DiffFit, SubtrajectoryFit, UncertaintyFit,
};
use crate::config as cfg;
use crate::stats::coverage;

/// The result on stdout (warnings on stderr).
pub fn print(
    c: &Calibration,
    initial: &ChassisParams,
    opts: &CalibrationOptions,
    e: &ErrorSummary,
) {
    let g = &c.geometry;
    print_parameters(c, initial);
    match &c.subtrajectories {
        Some(s) => print_subtrajectory_method(c, s, opts),
        None => print_paper_method(c, opts),
    }
    if let Some(w) = &g.track_warning {
        eprintln!("warning: eq (16) fit: {w}");
    }
    if let Some(hf) = &c.harmonics {
        print_harmonics(hf, initial);
    }
    for u in &c.uncertainty {
        print_uncertainty(c, u, initial, opts);
    }
    print_errors(c, e);
    if !c.windows.is_empty() {
        print_window_stats(&c.windows);
    }
}

/// The geometry's estimates against the first estimate, with their standard errors.
fn print_parameters(c: &Calibration, initial: &ChassisParams) {
    let g = &c.geometry;
    let ev = &c.evaluation;
    crate::outln!(
        "calibration: {} common times, {:.1} m of reference path",
        g.points + 1,
        ev.dist.last().unwrap_or(&0.0)
    );
    crate::outln!(
        "  {:<16} {:>14} {:>14} {:>12}",
        "parameter",
        "initial",
        "estimate",
        "std. error"
    );
    let se = |i: usize| {
        g.robust_std_errors[i].map_or_else(|| "held".to_string(), |v| format!("{v:.2e}"))
    };
    for (i, (k, a, b)) in [
        (
            "left_diameter",
            initial.left_diameter,
            c.params.left_diameter,
        ),
        (
            "right_diameter",
            initial.right_diameter,
            c.params.right_diameter,
        ),
        ("track_width", initial.track_width, c.params.track_width),
    ]
    .into_iter()
    .enumerate()
    {
        crate::outln!("  {k:<16} {a:>14.6} {b:>14.6} {:>12}", se(i));
    }
    crate::outln!(
        "  {:<16} {:>14} {:>14.6} {:>12}",
        "initial heading",
        "",
        g.heading0,
        se(3)
    );
}

/// The sub-trajectory method's lever arm, its fit, the filter's refinement and the kind of
/// standard errors.
fn print_subtrajectory_method(c: &Calibration, s: &SubtrajectoryFit, opts: &CalibrationOptions) {
    let refined = filter_refined(c);
    for (k, (v, e)) in ["antenna_forward", "antenna_left"].iter().zip([
        (s.antenna.0, s.std_errors[3]),
        (s.antenna.1, s.std_errors[4]),
    ]) {
        if e.is_some() || s.antenna != (0.0, 0.0) {
            let e = e.map_or_else(|| "held".to_string(), |v| format!("{v:.2e}"));
            crate::outln!("  {k:<16} {:>14} {v:>14.6} {e:>12}", "");
        }
    }
    crate::outln!(
        "  method subtrajectory: {} sub-trajectories of about {} m (cut {}) restarted at their fitted start position and heading, {} points, {} iterations, {} passes; residual sigma {:.4} m",
        s.blocks.len(),
        opts.subtrajectory_length,
        match opts.subtrajectory_cuts {
            calib::Cuts::Straights => "on straights",
            calib::Cuts::Distance => "by distance",
        },
        s.points,
        s.iterations,
        s.evaluations,
        s.residual_sigma
    );
    match &c.refinement {
        Some(r) if r.skipped.is_none() => {
            let e = s.std_errors;
            crate::outln!(
                "  refined by the filter (--geometry-refine filter): white slip kappa {:.3e} m^2/m, kappa_diff {:.3e}, {} observations; the sub-trajectory estimate was {:.6} / {:.6} / {:.6} m (standard errors {})",
                r.kappa,
                r.kappa_diff,
                r.observations,
                s.params.left_diameter,
                s.params.right_diameter,
                s.params.track_width,
                e[..3]
                    .iter()
                    .map(|v| v.map_or("held".to_string(), |v| format!("{v:.2e}")))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
            crate::outln!(
                "  standard errors: the filter's, with its linearisation bound {:.1e} of each length added",
                r.linearisation
            );
        }
        Some(r) => crate::outln!(
            "  filter refinement not applied: {}",
            r.skipped.as_deref().unwrap_or_default()
        ),
        None => {}
    }
    if !refined {
        crate::outln!(
            "  standard errors: cluster-robust over the {} sub-trajectories (with the residuals taken as independent: {})",
            s.blocks.len(),
            s.independent_std_errors[..3]
                .iter()
                .map(|v| v.map_or("held".to_string(), |v| format!("{v:.2e}")))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    crate::outln!(
        "  initial heading: the whole run's eq (16) heading at the estimate, the geometry held (for the evaluation below)"
    );
}

/// The paper method's lever arm, start and standard errors.
fn print_paper_method(c: &Calibration, opts: &CalibrationOptions) {
    let g = &c.geometry;
    if g.antenna != (0.0, 0.0) || g.antenna_std_errors.is_some() {
        let e = |i: usize| {
            g.antenna_std_errors
                .map_or("held".to_string(), |v| format!("{:.2e}", v[i]))
        };
        crate::outln!(
            "  {:<16} {:>14} {:>14.6} {:>12}",
            "antenna_forward",
            "",
            g.antenna.0,
            e(0)
        );
        crate::outln!(
            "  {:<16} {:>14} {:>14.6} {:>12}",
            "antenna_left",
            "",
            g.antenna.1,
            e(1)
        );
    }
    crate::outln!(
        "  method paper (eq 16 over the whole run); start position {:.4} m E, {:.4} m N (the reference, averaged over the standstill there)",
        g.start.0,
        g.start.1
    );
    crate::outln!(
        "  standard errors: cluster-robust over {} stretches of {} m (with the residuals taken as independent, (J^T J)^-1 s^2, s = {:.4} m: {})",
        g.clusters,
        opts.subtrajectory_length,
        g.residual_sigma,
        g.std_errors
            .iter()
            .map(|v| v.map_or("held".to_string(), |v| format!("{v:.2e}")))
            .collect::<Vec<_>>()
            .join(", ")
    );
}

/// One uncertainty model's coefficients and fit.
fn print_uncertainty(
    c: &Calibration,
    u: &UncertaintyFit,
    initial: &ChassisParams,
    opts: &CalibrationOptions,
) {
    let ev = &c.evaluation;
    let (a, b) = match u.model {
        UncertaintyModel::Paper => (
            (initial.delta_left, initial.delta_right),
            (c.params.delta_left, c.params.delta_right),
        ),
        UncertaintyModel::Covariance => (
            (initial.kappa_left, initial.kappa_right),
            (c.params.kappa_left, c.params.kappa_right),
        ),
    };
    crate::outln!("  {:<16} {:>14.4e} {:>14.4e}", u.keys.0, a.0, b.0);
    crate::outln!("  {:<16} {:>14.4e} {:>14.4e}", u.keys.1, a.1, b.1);
    if u.model == UncertaintyModel::Covariance {
        let (i, p) = (&initial, &c.params);
        crate::outln!(
            "  {:<16} {:>14.4e} {:>14.4e}",
            "kappa_diff",
            i.kappa_diff,
            p.kappa_diff
        );
        crate::outln!(
            "  {:<16} {:>14.4e} {:>14.4e}",
            "kappa_diff_corr",
            i.kappa_diff_corr,
            p.kappa_diff_corr
        );
    }
    if u.criterion == calib::UncertaintyCriterion::Likelihood {
        crate::outln!(
            "{} model fit: likelihood of {} reference observations (1 m averages, one per {:.1} m of path: at most {} per run) under a Kalman filter of the odometry's and the geometry's errors; innovations inside 1 and 3 sigma: horizontal {:.1} % / {:.1} %{}",
            cfg::model_name(u.model),
            u.points,
            ev.dist.last().unwrap_or(&0.0) / u.points.max(1) as f64,
            calib::MAX_OBSERVATIONS,
            100.0 * u.coverage1,
            100.0 * u.coverage3,
            u.heading_coverage.map_or(String::new(), |(h1, h3)| format!(
                ", heading {:.1} % / {:.1} %",
                100.0 * h1,
                100.0 * h3
            ))
        );
        if let Some(se) = u.ln_se {
            let length = *ev.dist.last().unwrap_or(&0.0);
            crate::outln!(
                "  kappa is known within a factor of {:.2} (1 sigma, the likelihood's curvature: ln kappa +- {:.2}); about {:.0} m of such driving would measure it within {:.0} %",
                se.exp(),
                se,
                calib::uncertainty::likelihood::length_for(se, length, calib::uncertainty::likelihood::KAPPA_TARGET_LN_SE),
                100.0 * (calib::uncertainty::likelihood::KAPPA_TARGET_LN_SE.exp() - 1.0)
            );
        }
        if let Some(ml) = u.most_likely {
            crate::outln!(
                "  the unit is told kappa's mean over the likelihood, {:.3e} ({:.2} times the most likely {ml:.3e}), and the geometry's covariance at it",
                u.params.kappa_left,
                f64::from(u.params.kappa_left) / ml
            );
        }
    } else {
        crate::outln!(
            "{} model fit: {} sub-trajectories of {} m, {} points; 1-sigma band covers {:.1} % (target 68.3 %), 3-sigma {:.1} %",
            cfg::model_name(u.model),
            u.windows,
            opts.delta_window,
            u.points,
            100.0 * u.coverage1,
            100.0 * u.coverage3
        );
    }
    if let Some(w) = &u.warning {
        eprintln!("warning: uncertainty fit: {w}");
    }
    if let Some(d) = &u.diff {
        print_delta_diff(d, u, opts);
    }
}

/// The `delta_diff` fit (or its kept value) and its heading coverage.
fn print_delta_diff(d: &DiffFit, u: &UncertaintyFit, opts: &CalibrationOptions) {
    crate::outln!(
        "  {:<16} {:>14.4e} {:>14.4e}",
        "delta_diff",
        d.initial,
        d.delta_diff
    );
    let deg = opts.reference_heading_sigma.to_degrees();
    if d.fitted {
        crate::outln!(
            "delta_diff fit: {} heading points, reference heading noise {deg} deg; heading 1-sigma band covers {:.1} % -> {:.1} % (target 68.3 %), 3-sigma {:.1} % -> {:.1} %; delta {} ({:.4e} with the initial delta_diff), horizontal 1-sigma {:.1} %",
            d.points,
            100.0 * d.coverage1_before,
            100.0 * d.coverage1,
            100.0 * d.coverage3_before,
            100.0 * d.coverage3,
            if d.joint { "refitted with it" } else { "held" },
            d.delta_before,
            100.0 * u.coverage1
        );
    } else {
        crate::outln!(
            "delta_diff kept (--no-fit-delta-diff): {} heading points, reference heading noise {deg} deg; heading 1-sigma band covers {:.1} %, 3-sigma {:.1} %",
            d.points,
            100.0 * d.coverage1,
            100.0 * d.coverage3
        );
    }
    if let Some(w) = &d.warning {
        eprintln!("warning: delta_diff fit: {w}");
    }
}

/// The cost of eq (16) and the horizontal and heading errors at the result.
fn print_errors(c: &Calibration, e: &ErrorSummary) {
    let g = &c.geometry;
    let (h, head, cov1, cov3) = (&e.horizontal, &e.heading, e.coverage1, e.coverage3);
    let (he, hs) = (&e.heading_pairs.0, &e.heading_pairs.1);
    if c.subtrajectories.is_some() {
        crate::outln!(
            "eq (16) over the whole run at the estimate: {:.6} m over {} points (mean {:.4} m)",
            g.cost,
            g.points,
            g.cost / g.points as f64
        );
    } else {
        crate::outln!(
            "eq (16): {:.6} m over {} points (mean {:.4} m); {} stages, {} iterations, {} integrator runs",
            g.cost,
            g.points,
            g.cost / g.points as f64,
            g.stages,
            g.iterations,
            g.evaluations
        );
    }
    crate::outln!(
        "horizontal error: mean {:.4} m, rms {:.4} m, p95 {:.4} m, max {:.4} m; inside sigma_h widened by the reference noise: 1 sigma {:.1} %, 3 sigma {:.1} % (sigma_h alone: {:.1} %, {:.1} %)",
        h.mean,
        h.rms,
        h.p95,
        h.max,
        100.0 * e.widened.0,
        100.0 * e.widened.1,
        100.0 * cov1,
        100.0 * cov3
    );
    if !he.is_empty() {
        crate::outln!(
            "heading error: mean |e| {:.3} deg, rms {:.3} deg, max {:.3} deg; sigma_heading alone covers 1 sigma {:.1} %, 3 sigma {:.1} % of it (it predicts the change since the start, not the start heading's error)",
            head.mean.to_degrees(),
            head.rms.to_degrees(),
            head.max.to_degrees(),
            100.0 * coverage(he, hs, 1.0),
            100.0 * coverage(he, hs, 3.0)
        );
    }
    if let Some((c1, c3)) = e.heading_change {
        crate::outln!(
            "heading change since the start inside sigma_heading widened by the reference heading noise: 1 sigma {:.1} %, 3 sigma {:.1} %",
            100.0 * c1,
            100.0 * c3
        );
    }
    crate::outln!("{}", e.noise.describe());
    for w in e.noise.warnings() {
        eprintln!("warning: {w}");
    }
    if let Some(h) = e.noise.hint() {
        crate::outln!("{h}");
    }
}

/// The stability study: per length, the statistics of each parameter and the failed windows.
fn print_window_stats(est: &[calib::WindowEstimate]) {
    crate::outln!(
        "stability study (estimates on consecutive sub-trajectories; failed windows left out):"
    );
    crate::outln!(
        "  {:>6} {:>5} {:>5}  {:<15} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "length",
        "used",
        "fail",
        "parameter",
        "mean",
        "std",
        "median",
        "min",
        "max"
    );
    for w in calib::summarize_windows(est) {
        for (p, name) in calib::WINDOW_PARAMS.iter().enumerate() {
            let s = &w.stats[p];
            let head = if p == 0 {
                format!(
                    "{:>5} m {:>5} {:>5}",
                    w.length,
                    w.accepted,
                    w.windows - w.accepted
                )
            } else {
                format!("{:>7} {:>5} {:>5}", "", "", "")
            };
            crate::outln!(
                "  {head}  {name:<15} {:>10.5} {:>10.5} {:>10.5} {:>10.5} {:>10.5}",
                s.mean,
                s.std,
                s.median,
                s.min,
                s.max
            );
        }
        if !w.failures.is_empty() {
            let why: Vec<String> = w
                .failures
                .iter()
                .map(|(code, n)| format!("{n} {code}"))
                .collect();
            crate::outln!("  {:>7} failed: {}", "", why.join(", "));
        }
    }
    for e in est {
        if let Err(f) = &e.estimate {
            crate::outln!(
                "  FAILED {} m window at {:.1} m ({:.2}-{:.2} s): {f}",
                e.length,
                e.start_dist,
                e.t.0,
                e.t.1
            );
        }
    }
}

/// The wheel-function fit: each harmonic against the first estimate, with its standard errors.
fn print_harmonics(hf: &calib::HarmonicsFit, initial: &ChassisParams) {
    crate::outln!(
        "wheel function: {} harmonic(s) per wheel, referenced to the index, after the geometry fit (its corrections refitted alongside); {} segments of {} m restarted from the reference, {} points, residual {:.4} m",
        hf.order,
        hf.segments,
        hf.segment,
        hf.points,
        hf.residual_sigma
    );
    crate::outln!(
        "  {:<16} {:>14} {:>14} {:>12} {:>12} {:>12}",
        "parameter",
        "initial",
        "estimate",
        "std. error",
        "(iid)",
        "radius [mm]"
    );
    for (i, k) in hf.keys.iter().enumerate() {
        let before = odo_unit::settings::Key::from_name(k)
            .and_then(|key| {
                crate::config::chassis_value_text(initial, key)
                    .parse::<f64>()
                    .ok()
            })
            .unwrap_or(f64::NAN);
        let radius = if k.starts_with("left") {
            hf.params.left_diameter
        } else {
            hf.params.right_diameter
        } / 2.0;
        crate::outln!(
            "  {k:<16} {before:>14.3e} {:>14.3e} {:>12.2e} {:>12.2e} {:>12.4}",
            hf.values[i],
            hf.std_errors[i],
            hf.std_errors_iid[i],
            1e3 * radius * hf.values[i]
        );
    }
    crate::outln!(
        "  standard errors cluster-robust over the segments; (iid): taking the residuals as independent"
    );
}
