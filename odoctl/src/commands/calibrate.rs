//! `odoctl calibrate`: reads the files, runs [`calib::calibrate`], prints and writes the result.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use odo_core::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::{self, CalibrationOptions, DeltaMode, LeverArm, Method};
use crate::config::{self as cfg, FitValue};
use crate::csvio;
use crate::reference::cli::{read_reference, reference_for_samples, ReferenceArgs};
use crate::stats::{coverage, summarize};

use super::create;

/// Options of `odoctl calibrate`: the files, and the fitting options.
#[derive(Debug, Clone, Default)]
pub struct CalibrateOptions {
    /// SAMPLES CSV.
    pub samples: PathBuf,
    /// REFERENCE CSV.
    pub reference: PathBuf,
    /// First-estimate file.
    pub initial: Option<PathBuf>,
    /// `KEY=VALUE` overrides of the first estimate.
    pub sets: Vec<String>,
    /// Result file.
    pub out: Option<PathBuf>,
    /// Study CSV.
    pub windows_out: Option<PathBuf>,
    /// Figure directory.
    pub plots: Option<PathBuf>,
    /// The fitting options.
    pub calibration: CalibrationOptions,
    /// The geometry method and lever arm options (applied over `calibration`).
    pub geometry: GeometryArgs,
}

/// How `calibrate` estimates the geometry: the method, its sub-trajectory length, the antenna
/// lever arm.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct GeometryArgs {
    /// Geometry estimator: `subtrajectory` (restarted every --subtrajectory-length metres, the
    /// default) or `paper` (eq 16 over the whole run).
    #[arg(long, value_enum, default_value_t = Method::Subtrajectory)]
    pub method: Method,
    /// Sub-trajectory length of the default method, and the stretches of the paper method's
    /// cluster-robust standard errors (m of reference path).
    #[arg(long, default_value_t = calib::SUBTRAJECTORY_LENGTH)]
    pub subtrajectory_length: f64,
    /// Where the default method cuts the run: `distance` (exactly every
    /// --subtrajectory-length metres, the default) or `straights` (near every
    /// --subtrajectory-length metres, at the point farthest from any turning, so that no arc
    /// or spin is split: better on short runs' track width, see odoctl/README.md).
    #[arg(long, value_enum, default_value_t = calib::Cuts::Distance)]
    pub subtrajectory_cuts: calib::Cuts,
    /// After the default method: `filter` (the default) refines the geometry by the Kalman
    /// filter of the kappa likelihood, which weights the turns by the slip's heading noise,
    /// where its linearisation holds (short logs; see odoctl/README.md); `none` keeps the
    /// sub-trajectory estimate.
    #[arg(long, value_enum, default_value_t = calib::GeometryRefine::Filter)]
    pub geometry_refine: calib::GeometryRefine,
    /// Measured antenna position from the axle centre, `FORWARD,LEFT` (m, chassis frame):
    /// the reference is the antenna's path (held; the first guess with --fit-antenna).
    #[arg(long, value_name = "F,L", allow_hyphen_values = true)]
    pub antenna: Option<String>,
    /// Estimate the antenna lever arm with the geometry (standard errors in `[fit]`).
    #[arg(long)]
    pub fit_antenna: bool,
}

impl GeometryArgs {
    /// Sets the method, the length and the lever arm of `o`.
    pub fn apply(&self, o: &mut CalibrationOptions) -> Result<()> {
        if !(self.subtrajectory_length > 0.0 && self.subtrajectory_length.is_finite()) {
            anyhow::bail!(
                "--subtrajectory-length {}: must be a positive number of metres",
                self.subtrajectory_length
            );
        }
        let (f, l) = match &self.antenna {
            Some(s) => crate::reference::parse_antenna(s)?,
            None => (0.0, 0.0),
        };
        o.method = self.method;
        o.subtrajectory_length = self.subtrajectory_length;
        o.subtrajectory_cuts = self.subtrajectory_cuts;
        o.geometry_refine = self.geometry_refine;
        o.antenna = if self.fit_antenna {
            LeverArm::Fitted(f, l)
        } else {
            LeverArm::Fixed(f, l)
        };
        Ok(())
    }
}

/// `odoctl calibrate`.
pub fn calibrate(o: &CalibrateOptions, input: &ReferenceArgs) -> Result<ExitCode> {
    let started = Instant::now();
    let timer = calib::PhaseTimer::new();
    // The two files are independent: read on two cores.
    let (samples, reference) = std::thread::scope(|scope| {
        let reference = scope.spawn(|| read_reference(&o.reference, input));
        let samples = csvio::read_samples(&o.samples);
        (samples, reference.join().expect("CSV reader panicked"))
    });
    let (samples, reference) = (samples?, reference?);
    let reference = reference_for_samples(&reference, &samples)?;
    timer.lap("read CSV");
    let mut initial = match &o.initial {
        Some(p) => cfg::read_params(p, ChassisParams::DESIGNED)?,
        None => ChassisParams::DESIGNED,
    };
    cfg::apply_sets(&mut initial, &o.sets)?;
    let initial = cfg::validated(initial, "initial estimate")?;
    let names = (
        o.samples.display().to_string(),
        o.reference.display().to_string(),
    );
    let mut opts = o.calibration.clone();
    o.geometry.apply(&mut opts)?;
    let opts = &opts;
    let c = calib::calibrate(&samples, &reference, (&names.0, &names.1), &initial, opts)?;
    timer.lap("calibration");
    let g = &c.geometry;
    let ev = &c.evaluation;
    let h = summarize(&ev.horizontal[1..]);
    let (he, hs) = ev.heading_pairs();
    let head = summarize(&he.iter().map(|e| e.abs()).collect::<Vec<_>>());
    let cov1 = coverage(&ev.horizontal[1..], &ev.sigma_h[1..], 1.0);
    let cov3 = coverage(&ev.horizontal[1..], &ev.sigma_h[1..], 3.0);

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
    let refined = c.refinement.as_ref().is_some_and(|r| r.skipped.is_none());
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
    if let Some(s) = &c.subtrajectories {
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
    } else {
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
    if let Some(w) = &g.track_warning {
        eprintln!("warning: eq (16) fit: {w}");
    }
    if let Some(hf) = &c.harmonics {
        print_harmonics(hf, &initial);
    }
    for u in &c.uncertainty {
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
    }
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
        "horizontal error: mean {:.4} m, rms {:.4} m, p95 {:.4} m, max {:.4} m; within 1 sigma {:.1} %, 3 sigma {:.1} %",
        h.mean,
        h.rms,
        h.p95,
        h.max,
        100.0 * cov1,
        100.0 * cov3
    );
    if !he.is_empty() {
        crate::outln!(
            "heading error: mean |e| {:.3} deg, rms {:.3} deg, max {:.3} deg; within 1 sigma {:.1} %, 3 sigma {:.1} %",
            head.mean.to_degrees(),
            head.rms.to_degrees(),
            head.max.to_degrees(),
            100.0 * coverage(&he, &hs, 1.0),
            100.0 * coverage(&he, &hs, 3.0)
        );
    }
    if !c.windows.is_empty() {
        print_window_stats(&c.windows);
        if let Some(p) = &o.windows_out {
            write_windows_csv(p, &c.windows)?;
        }
    }
    if let Some(p) = &o.out {
        let mut fit = vec![
            ("samples", FitValue::Text(o.samples.display().to_string())),
            (
                "reference",
                FitValue::Text(o.reference.display().to_string()),
            ),
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
        fit.extend([
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
        ]);
        if !he.is_empty() {
            fit.push(("heading_error_rms", FitValue::Num(head.rms)));
            fit.push(("heading_error_max", FitValue::Num(head.max)));
        }
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
                    FitValue::Text("maximum likelihood of the reference's observations (1 m averages, at most 1000 per run) under an error-state Kalman filter of the odometry, the geometry's relative errors and the wheels' slip (white or Gauss-Markov; kappa = the long-range variance rate)".into()),
                ));
            }
            fit.push(("uncertainty_window", FitValue::Num(opts.delta_window)));
            fit.push(("reference_sigma", FitValue::Num(opts.reference_sigma)));
        }
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
        fit.extend(per_model.iter().map(|(k, v)| (k.as_str(), v.clone())));
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
    }
    if let Some(dir) = &o.plots {
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
    }
    timer.lap("report");
    crate::outln!("done in {:.2} s", started.elapsed().as_secs_f64());
    Ok(ExitCode::SUCCESS)
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

fn print_harmonics(hf: &calib::HarmonicsFit, initial: &odo_core::odometry::ChassisParams) {
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
        let before = odo_core::settings::Key::from_name(k)
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
