//! What `calibrate` writes: the stability study's CSV (`--windows-out`), the result TOML
//! (`--out`: the chassis keys, and the fit's figures in `[fit]`) and the figures (`--plots`).

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};

use super::{filter_refined, ErrorSummary};
use crate::calib::{self, Calibration, CalibrationOptions, DeltaMode, Method};
use crate::cli::CalibrateArgs;
use crate::commands::create;
use crate::config::{self as cfg, FitValue};
use crate::csvio;
use crate::reference::clock::ClockFit;

/// The files asked for, in this order: the stability study's CSV, the result, the figures.
pub fn write_result(
    a: &CalibrateArgs,
    reference: &Path,
    c: &Calibration,
    opts: &CalibrationOptions,
    e: &ErrorSummary,
    clock: Option<&ClockFit>,
) -> Result<()> {
    if !c.windows.is_empty() {
        if let Some(p) = &a.windows_out {
            write_windows_csv(p, &c.windows)?;
        }
    }
    if let Some(p) = &a.out {
        write_params(p, a, reference, c, opts, e, clock)?;
    }
    if let Some(dir) = &a.plots {
        write_plots(dir, c)?;
    }
    Ok(())
}

/// The result TOML: the parameters and the fit's figures in `[fit]`.
fn write_params(
    p: &Path,
    a: &CalibrateArgs,
    reference: &Path,
    c: &Calibration,
    opts: &CalibrationOptions,
    e: &ErrorSummary,
    clock: Option<&ClockFit>,
) -> Result<()> {
    let per_model = model_fit(c, opts);
    let mut fit: Vec<(&str, FitValue)> = geometry_fit(a, reference, c, opts);
    fit.extend(clock.map_or_else(Vec::new, clock_fit));
    fit.extend(error_fit(c, e));
    fit.extend(uncertainty_fit(c, opts));
    fit.extend(per_model.iter().map(|(k, v)| (k.as_str(), v.clone())));
    let diff = c.uncertainty.iter().find_map(|u| u.diff.as_ref());
    let mut always: Vec<&str> = c.harmonics.iter().flat_map(|h| h.keys.clone()).collect();
    if diff.is_some_and(|d| d.fitted) {
        always.push("delta_diff");
    }
    let always = always.as_slice();
    let text = cfg::render_params_with(
        &c.params,
        match opts.method {
            Method::Subtrajectory => "odoctl calibrate: chassis parameters estimated on restarted sub-trajectories (beyond eq 16 of Jilek, Burian, Kriz)",
            Method::Paper => "odoctl calibrate: chassis parameters estimated by eq (16) of Jilek, Burian, Kriz",
        },
        &fit,
        always,
    );
    std::fs::write(p, text).with_context(|| format!("{}: cannot write", p.display()))?;
    crate::outln!("wrote {}", p.display());
    Ok(())
}

/// `[fit]`: a trajectory reference's clock, samples' `t` = stamp + `clock_offset` +
/// `clock_ppm` 1e-6 (stamp - `clock_stamp_mid`): offset (s), rate (ppm), their standard errors
/// (0 when given).
fn clock_fit(k: &ClockFit) -> Vec<(&'static str, FitValue)> {
    vec![
        ("clock_offset", FitValue::Num(k.offset)),
        ("clock_offset_se", FitValue::Num(k.offset_se)),
        ("clock_ppm", FitValue::Num(k.ppm)),
        ("clock_ppm_se", FitValue::Num(k.ppm_se)),
        ("clock_stamp_mid", FitValue::Num(k.s_mid)),
    ]
}

/// `[fit]`: the files, the start, the geometry method and its figures.
fn geometry_fit(
    a: &CalibrateArgs,
    reference: &Path,
    c: &Calibration,
    opts: &CalibrationOptions,
) -> Vec<(&'static str, FitValue)> {
    let g = &c.geometry;
    let refined = filter_refined(c);
    let mut fit = vec![
        ("samples", FitValue::Text(a.samples.display().to_string())),
        ("reference", FitValue::Text(reference.display().to_string())),
        ("initial_x", FitValue::Num(g.start.0)),
        ("initial_y", FitValue::Num(g.start.1)),
        ("initial_heading", FitValue::Num(g.heading0)),
        ("eq16_cost", FitValue::Num(g.cost)),
        ("points", FitValue::Int(g.points as i64)),
    ];
    fit.push((
        "method",
        FitValue::Text(
            match opts.method {
                Method::Subtrajectory => "subtrajectory",
                Method::Paper => "paper",
            }
            .into(),
        ),
    ));
    fit.push((
        "subtrajectory_length",
        FitValue::Num(opts.subtrajectory_length),
    ));
    if let Some(s) = &c.subtrajectories {
        fit.push(("subtrajectories", FitValue::Int(s.blocks.len() as i64)));
        fit.push(("subtrajectory_cost", FitValue::Num(s.cost)));
    }
    fit.push((
        "std_error_method",
        FitValue::Text(if refined {
            "the filter's covariance with its linearisation bound".to_string()
        } else {
            format!(
                "cluster-robust sandwich over {} {}",
                g.clusters,
                match opts.method {
                    Method::Subtrajectory => "sub-trajectories",
                    Method::Paper => "consecutive stretches",
                }
            )
        }),
    ));
    if let Some(r) = &c.refinement {
        fit.push((
            "geometry_refine",
            FitValue::Text(match &r.skipped {
                None => "filter".to_string(),
                Some(why) => format!("filter, not applied: {why}"),
            }),
        ));
        if r.skipped.is_none() {
            fit.push(("geometry_refine_kappa", FitValue::Num(r.kappa)));
            let s = c.subtrajectories.as_ref().map(|s| s.params);
            if let Some(p) = s {
                fit.push((
                    "subtrajectory_left_diameter",
                    FitValue::Num(p.left_diameter),
                ));
                fit.push((
                    "subtrajectory_right_diameter",
                    FitValue::Num(p.right_diameter),
                ));
                fit.push(("subtrajectory_track_width", FitValue::Num(p.track_width)));
            }
        }
    }
    for (name, se) in calib::GEOMETRY_UNKNOWNS.iter().zip(g.robust_std_errors) {
        if let Some(v) = se {
            fit.push((se_keys(name), FitValue::Num(v)));
        }
    }
    for (name, se) in calib::GEOMETRY_UNKNOWNS.iter().zip(g.std_errors) {
        if let Some(v) = se {
            fit.push((independent_se_key(name), FitValue::Num(v)));
        }
    }
    if g.antenna != (0.0, 0.0) || g.antenna_std_errors.is_some() {
        fit.push(("antenna_forward", FitValue::Num(g.antenna.0)));
        fit.push(("antenna_left", FitValue::Num(g.antenna.1)));
        if let Some([f, l]) = g.antenna_std_errors {
            fit.push(("antenna_forward_se", FitValue::Num(f)));
            fit.push(("antenna_left_se", FitValue::Num(l)));
        }
    }
    fit.push(("residual_sigma", FitValue::Num(g.residual_sigma)));
    fit.push(("turning", FitValue::Num(g.turning)));
    fit.push((
        "track_width_estimated",
        FitValue::Text(if g.track_estimated { "yes" } else { "no" }.into()),
    ));
    if let Some(w) = &g.track_warning {
        fit.push(("track_width_warning", FitValue::Text(w.clone())));
    }
    fit
}

/// `[fit]`: the errors of the whole run at the result.
fn error_fit(c: &Calibration, e: &ErrorSummary) -> Vec<(&'static str, FitValue)> {
    let ev = &c.evaluation;
    let (h, head, cov1, cov3) = (&e.horizontal, &e.heading, e.coverage1, e.coverage3);
    let he = &e.heading_pairs.0;
    let mut fit = vec![
        (
            "path_length",
            FitValue::Num(*ev.dist.last().unwrap_or(&0.0)),
        ),
        ("horizontal_error_mean", FitValue::Num(h.mean)),
        ("horizontal_error_rms", FitValue::Num(h.rms)),
        ("horizontal_error_p95", FitValue::Num(h.p95)),
        ("horizontal_error_max", FitValue::Num(h.max)),
        ("coverage_1sigma", FitValue::Num(cov1)),
        ("coverage_3sigma", FitValue::Num(cov3)),
        ("coverage_1sigma_widened", FitValue::Num(e.widened.0)),
        ("coverage_3sigma_widened", FitValue::Num(e.widened.1)),
        (
            "reference_sigma_stated",
            FitValue::Num(e.noise.stated_horizontal),
        ),
    ];
    if let Some(s) = e.noise.scatter_horizontal {
        fit.push(("reference_sigma_scatter", FitValue::Num(s)));
    }
    if !he.is_empty() {
        fit.push(("heading_error_rms", FitValue::Num(head.rms)));
        fit.push(("heading_error_max", FitValue::Num(head.max)));
    }
    if let Some((c1, c3)) = e.heading_change {
        fit.push(("heading_change_coverage_1sigma_widened", FitValue::Num(c1)));
        fit.push(("heading_change_coverage_3sigma_widened", FitValue::Num(c3)));
    }
    if let Some(a) = e.noise.scatter_heading {
        fit.push(("reference_heading_sigma_scatter", FitValue::Num(a)));
    }
    fit
}

/// `[fit]`: how the uncertainty coefficients were fitted.
fn uncertainty_fit(c: &Calibration, opts: &CalibrationOptions) -> Vec<(&'static str, FitValue)> {
    let mut fit = Vec::new();
    if !c.uncertainty.is_empty() {
        fit.push((
            "uncertainty_criterion",
            FitValue::Text(format!(
                "1-sigma band sqrt(sigma_h^2 + reference_sigma^2) covers 68.27 % of horizontal errors on sub-trajectories restarted from the reference ({} mode)",
                match opts.delta_mode {
                    DeltaMode::Equal => "equal",
                    DeltaMode::KeepRatio => "keep-ratio",
                }
            )),
        ));
        if opts.criterion == calib::UncertaintyCriterion::Likelihood {
            fit.push((
                "kappa_criterion",
                FitValue::Text("maximum likelihood of the reference's observations (one per metre: the mean over the metre, or over a shorter span about its middle against a precise reference; at most 1000 per run) under an error-state Kalman filter of the odometry, the geometry's relative errors and the wheels' slip (white or Gauss-Markov; kappa = the long-range variance rate)".into()),
            ));
        }
        fit.push(("uncertainty_window", FitValue::Num(opts.delta_window)));
        fit.push(("reference_sigma", FitValue::Num(opts.reference_sigma)));
    }
    fit
}

/// `[fit]`: each uncertainty model's fit, the `delta_diff` fit, the wheel function.
fn model_fit(c: &Calibration, opts: &CalibrationOptions) -> Vec<(String, FitValue)> {
    let mut per_model: Vec<(String, FitValue)> = Vec::new();
    for u in &c.uncertainty {
        let name = cfg::model_name(u.model);
        per_model.push((format!("{name}_points"), FitValue::Int(u.points as i64)));
        per_model.push((
            format!("{name}_coverage_1sigma"),
            FitValue::Num(u.coverage1),
        ));
        per_model.push((
            format!("{name}_coverage_3sigma"),
            FitValue::Num(u.coverage3),
        ));
        if let Some(se) = u.ln_se {
            per_model.push((format!("{name}_ln_se"), FitValue::Num(se)));
        }
        if let Some(ml) = u.most_likely {
            per_model.push((format!("{name}_most_likely"), FitValue::Num(ml)));
        }
    }
    let diff = c.uncertainty.iter().find_map(|u| u.diff.as_ref());
    if let Some(d) = diff {
        if d.fitted {
            per_model.push((
                "delta_diff_criterion".into(),
                FitValue::Text(
                    "smallest delta_diff >= 0 for which, with delta refitted by the horizontal criterion, the 1-sigma heading band sqrt(sigma_heading^2 + (1 + 1/n) reference_heading_sigma^2) covers 68.27 % of the errors of the heading change since each restart (wrapped) on the same sub-trajectories".into(),
                ),
            ));
            per_model.push(("delta_diff_initial".into(), FitValue::Num(d.initial)));
            per_model.push(("delta_before_diff".into(), FitValue::Num(d.delta_before)));
            per_model.push((
                "delta_diff_joint".into(),
                FitValue::Text(
                    if d.joint {
                        "delta refitted"
                    } else {
                        "delta held"
                    }
                    .into(),
                ),
            ));
        }
        per_model.push((
            "reference_heading_sigma".into(),
            FitValue::Num(opts.reference_heading_sigma),
        ));
        per_model.push(("heading_points".into(), FitValue::Int(d.points as i64)));
        for (k, v) in [
            ("heading_coverage_1sigma_before", d.coverage1_before),
            ("heading_coverage_3sigma_before", d.coverage3_before),
            ("heading_coverage_1sigma", d.coverage1),
            ("heading_coverage_3sigma", d.coverage3),
        ] {
            per_model.push((k.into(), FitValue::Num(v)));
        }
    }
    if let Some(hf) = &c.harmonics {
        per_model.extend(harmonics_fit_keys(hf));
    }
    per_model
}

/// The figures of the run (and of the stability study); prints their names.
fn write_plots(dir: &Path, c: &Calibration) -> Result<()> {
    let (g, ev) = (&c.geometry, &c.evaluation);
    let mut files = crate::plots::run_figures(dir, "calibrate", "Estimation run", ev)?;
    if !c.windows.is_empty() {
        let full = [
            g.params.left_diameter,
            g.params.right_diameter,
            g.params.track_width,
        ];
        files.extend(crate::plots::window_figures(dir, &c.windows, full)?);
    }
    for f in files {
        crate::outln!("wrote {}", f.display());
    }
    Ok(())
}

/// The `[fit]` key of an unknown's standard error: `left_diameter_se`, ...
fn se_keys(name: &str) -> &'static str {
    match name {
        "left_diameter" => "left_diameter_se",
        "right_diameter" => "right_diameter_se",
        "track_width" => "track_width_se",
        _ => "initial_heading_se",
    }
}

/// The `[fit]` key of an unknown's standard error for independent residuals.
fn independent_se_key(name: &str) -> &'static str {
    match name {
        "left_diameter" => "left_diameter_se_independent",
        "right_diameter" => "right_diameter_se_independent",
        "track_width" => "track_width_se_independent",
        _ => "initial_heading_se_independent",
    }
}

/// The stability study's per-window estimates (`--windows-out`).
fn write_windows_csv(path: &Path, est: &[calib::WindowEstimate]) -> Result<()> {
    let mut w = create(path)?;
    writeln!(
        w,
        "length,start_dist,t_start,t_end,points,turning,left_diameter,right_diameter,track_width,initial_heading,left_diameter_se,right_diameter_se,track_width_se,initial_heading_se,condition,mean_error,status,reason"
    )?;
    let num = |x: f64| {
        if x.is_finite() {
            format!("{x:?}")
        } else {
            String::new()
        }
    };
    for e in est {
        let v = e
            .fitted
            .map_or_else(|| ",,,".to_string(), |v| v.map(num).join(","));
        let (status, reason) = match &e.estimate {
            Ok(_) => ("ok", String::new()),
            Err(f) => ("failed", f.to_string().replace([',', '\n'], ";")),
        };
        writeln!(
            w,
            "{},{:.3},{},{},{},{:.6},{},{},{},{},{},{}",
            e.length,
            e.start_dist,
            csvio::fmt_t(e.t.0),
            csvio::fmt_t(e.t.1),
            e.points,
            e.turning,
            v,
            e.std_errors.map(num).join(","),
            num(e.condition),
            num(e.mean_error),
            status,
            reason
        )?;
    }
    w.flush()?;
    Ok(())
}

/// The `[fit]` keys of the wheel-function fit.
fn harmonics_fit_keys(hf: &calib::HarmonicsFit) -> Vec<(String, FitValue)> {
    let mut v = vec![
        (
            "wheel_harmonics".to_string(),
            FitValue::Int(hf.order as i64),
        ),
        (
            "harmonics_segments".to_string(),
            FitValue::Int(hf.segments as i64),
        ),
        ("harmonics_window".to_string(), FitValue::Num(hf.segment)),
        (
            "harmonics_residual_sigma".to_string(),
            FitValue::Num(hf.residual_sigma),
        ),
    ];
    for (k, se) in hf.keys.iter().zip(&hf.std_errors) {
        v.push((format!("{k}_se"), FitValue::Num(*se)));
    }
    v
}
