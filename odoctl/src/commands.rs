//! The subcommands behind the command line (`main.rs` only parses arguments).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};

pub use crate::link::{config, decode, monitor, record, ConfigAction};

use crate::calib::{self, DeltaMode, Run, WindowStart};
use crate::config::{self as cfg, FitValue};
use crate::core_api::{ChassisParams, Pose, UncertaintyModel};
use crate::csvio;
use crate::reference::cli::{read_reference, reference_for_samples, ReceiverArgs, ReferenceArgs};
use crate::replay as rp;
use crate::simulate::{self, PathKind};
use crate::stats::{coverage, summarize};

fn create(path: &Path) -> Result<BufWriter<File>> {
    Ok(BufWriter::new(File::create(path).with_context(|| {
        format!("{}: cannot create", path.display())
    })?))
}

/// `odoctl replay`.
pub fn replay(
    samples: &Path,
    config: Option<&Path>,
    sets: &[String],
    start: (f64, f64, f64),
    check: bool,
    out: Option<&Path>,
) -> Result<ExitCode> {
    let params = cfg::load(config, sets)?;
    let s = csvio::read_samples(samples)?;
    let rows = rp::replay(
        &params,
        &s,
        Pose {
            x: start.0,
            y: start.1,
            heading: start.2,
        },
    )?;
    match out {
        Some(p) => {
            let mut w = create(p)?;
            rp::write_replay(&mut w, &rows)?;
            w.flush()?;
        }
        None => {
            let stdout = std::io::stdout();
            let mut w = BufWriter::new(stdout.lock());
            rp::write_replay(&mut w, &rows)?;
            w.flush()?;
        }
    }
    if check {
        let c = rp::check_against_unit(&s, &rows);
        if c.compared == 0 {
            bail!("{}: --check: the file carries no unit pose columns (x, y, heading, sigma_x, sigma_y, sigma_heading)", samples.display());
        }
        if c.mismatches > 0 {
            eprintln!(
                "replay --check: {} of {} rows differ from the unit's records; first: {}",
                c.mismatches,
                c.compared,
                c.first.unwrap_or_default()
            );
            return Ok(ExitCode::FAILURE);
        }
        eprintln!(
            "replay --check: all {} rows match the unit's records bit for bit",
            c.compared
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Options of `odoctl simulate`.
pub struct SimulateOptions {
    /// Output SAMPLES CSV.
    pub samples: PathBuf,
    /// Output REFERENCE CSV.
    pub reference: PathBuf,
    /// True parameters file.
    pub truth: Option<PathBuf>,
    /// `KEY=VALUE` overrides of the truth.
    pub sets: Vec<String>,
    /// Where to write the truth.
    pub truth_out: Option<PathBuf>,
    /// Path shape.
    pub path: PathKind,
    /// Path length (m).
    pub length: f64,
    /// Rate, speed, noise, start and seed.
    pub settings: simulate::SimSettings,
}

/// The default true chassis of `simulate`: the paper's final estimates (Table 2) with its
/// designed encoder and uncertainty (Table 3).
pub fn default_truth() -> ChassisParams {
    ChassisParams {
        left_diameter: 0.2608,
        right_diameter: 0.2607,
        track_width: 0.5656,
        ..ChassisParams::DESIGNED
    }
}

/// `odoctl simulate`.
pub fn simulate(o: &SimulateOptions, logs: &ReceiverArgs) -> Result<ExitCode> {
    let mut truth = match &o.truth {
        Some(p) => cfg::read_params(p, default_truth())?,
        None => default_truth(),
    };
    cfg::apply_sets(&mut truth, &o.sets)?;
    let truth = cfg::validated(truth, "true parameters")?;
    let run = &o.settings;
    if !(run.rate > 0.0 && run.rate <= 10_000.0) {
        bail!("--rate {}: must be in (0, 10000] Hz", run.rate);
    }
    if !(run.speed > 0.0 && run.speed <= 10.0) {
        bail!("--speed {}: must be in (0, 10] m/s", run.speed);
    }
    if o.length.is_nan()
        || o.length <= 0.0
        || !(run.slip >= 0.0 && run.slip_turn >= 0.0 && run.rtk_sigma >= 0.0)
    {
        bail!("--length must be positive, --slip, --slip-turn and --rtk-sigma non-negative");
    }
    let mut rng = simulate::Rng::new(run.seed ^ 0x5EED);
    let segments = simulate::path(o.path, o.length, &mut rng);
    let receiver = logs.receiver(run.rtk_sigma, run.heading_sigma, run.seed)?;
    let mut sim = simulate::simulate(&simulate::SimOptions {
        truth,
        segments,
        settings: o.settings,
    });
    logs.prepare(&mut sim, &receiver);
    logs.write(&sim, &receiver)?;
    let mut w = create(&o.samples)?;
    csvio::write_samples(&mut w, &sim.samples, false)?;
    w.flush()?;
    let mut w = create(&o.reference)?;
    csvio::write_reference(&mut w, &sim.reference)?;
    w.flush()?;
    if let Some(p) = &o.truth_out {
        let text = cfg::render_params(
            &truth,
            "odoctl simulate: the true parameters of the synthetic run",
            &[],
        );
        std::fs::write(p, text).with_context(|| format!("{}: cannot write", p.display()))?;
    }
    let travelled: f64 = sim
        .truth
        .windows(2)
        .map(|w| (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1))
        .sum();
    let turned: f64 = sim.truth.windows(2).map(|w| (w[1].2 - w[0].2).abs()).sum();
    crate::outln!(
        "simulated {} samples over {:.1} s: {:.1} m travelled, {:.0} deg turned; true left_diameter {}, right_diameter {}, track_width {}",
        sim.samples.len(),
        sim.samples.last().map_or(0.0, |s| s.t - sim.samples[0].t),
        travelled,
        turned.to_degrees(),
        truth.left_diameter,
        truth.right_diameter,
        truth.track_width
    );
    Ok(ExitCode::SUCCESS)
}

/// Options of `odoctl calibrate`.
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
    /// Sub-trajectory length of the uncertainty fit (m).
    pub delta_window: f64,
    /// Reference noise (m).
    pub reference_sigma: f64,
    /// Left/right relation of the coefficients.
    pub delta_mode: DeltaMode,
    /// Fit the uncertainty coefficients.
    pub fit_delta: bool,
    /// Fit `delta_diff` of the paper's model by the heading criterion (when the reference has
    /// a heading; else the initial value is kept).
    pub fit_delta_diff: bool,
    /// Reference heading noise (rad), added to `sigma_heading` in the heading criterion.
    pub reference_heading_sigma: f64,
    /// The uncertainty models whose coefficients are fitted (empty: the initial estimate's
    /// `uncertainty_model`). The result keeps the initial model when it is among them, else
    /// the last one.
    pub models: Vec<UncertaintyModel>,
    /// Nelder-Mead polish of eq (16).
    pub polish: bool,
    /// Stability study lengths (m).
    pub windows: Vec<f64>,
    /// Where the study's fits start.
    pub window_start: WindowStart,
    /// Study CSV.
    pub windows_out: Option<PathBuf>,
    /// Figure directory.
    pub plots: Option<PathBuf>,
    /// No progress bars.
    pub quiet: bool,
}

fn bar(quiet: bool, what: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(1);
    pb.set_style(
        ProgressStyle::with_template("{prefix:>22} [{bar:40}] {pos}/{len} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb
}

/// The outcome of a calibration (also used by the tests).
pub struct Calibration {
    /// Final parameters.
    pub params: ChassisParams,
    /// The eq (16) fit.
    pub geometry: calib::GeomFit,
    /// The uncertainty fits, one per model fitted.
    pub uncertainty: Vec<calib::UncertaintyFit>,
    /// Evaluation of the whole run with the final parameters.
    pub evaluation: calib::Evaluation,
    /// The stability study.
    pub windows: Vec<calib::WindowEstimate>,
}

/// Runs the calibration in memory (the work of `odoctl calibrate` without the printing).
#[allow(clippy::too_many_arguments)]
pub fn calibrate_run(
    samples: &[csvio::Sample],
    reference: &[csvio::RefPoint],
    names: (&str, &str),
    initial: &ChassisParams,
    o: &CalibrateOptions,
) -> Result<Calibration> {
    if !(o.reference_sigma >= 0.0 && o.reference_heading_sigma >= 0.0) {
        bail!("--reference-sigma and --reference-heading-sigma-deg must be non-negative");
    }
    let matches = csvio::match_or_fail(samples, names.0, reference, names.1, 10)?;
    let run = Run::new(samples, reference, matches);
    let timer = PhaseTimer::new();
    let h0 = run.heading_guess(0);
    let pb = bar(o.quiet, "eq (16) fit");
    let geometry = calib::fit_geometry(
        &run,
        initial,
        h0,
        0,
        run.len() - 1,
        calib::GeomOptions {
            polish: o.polish,
            ..Default::default()
        },
        &pb,
    )?;
    pb.finish_and_clear();
    timer.lap("eq (16) fit");
    let mut params = geometry.params;
    let mut uncertainty = Vec::new();
    if o.fit_delta {
        let models = if o.models.is_empty() {
            vec![initial.uncertainty_model]
        } else {
            o.models.clone()
        };
        let restarts = calib::Restarts::new(&run, &params, geometry.heading0, o.delta_window)?;
        timer.lap("restart headings");
        for &m in &models {
            let pb = bar(o.quiet, &format!("{} model fit", cfg::model_name(m)));
            let mut p = params;
            p.uncertainty_model = m;
            let mut u = calib::fit_uncertainty_on(
                &run,
                &restarts,
                &p,
                initial,
                o.reference_sigma,
                o.delta_mode,
                &pb,
            )?;
            pb.finish_and_clear();
            timer.lap("uncertainty fit");
            if m == UncertaintyModel::Paper {
                let pb = bar(o.quiet, "delta_diff fit");
                u = calib::fit_delta_diff(
                    &run,
                    &restarts,
                    u,
                    initial,
                    calib::DiffOptions {
                        fit: o.fit_delta_diff,
                        ref_heading_sigma: o.reference_heading_sigma,
                        ref_sigma: o.reference_sigma,
                        mode: o.delta_mode,
                    },
                    &pb,
                )?;
                pb.finish_and_clear();
                timer.lap("delta_diff fit");
            }
            params = u.params;
            uncertainty.push(u);
        }
        params.uncertainty_model = if models.contains(&initial.uncertainty_model) {
            initial.uncertainty_model
        } else {
            *models.last().expect("one model")
        };
    }
    let evaluation = calib::evaluate(&run, &params, geometry.heading0)?;
    timer.lap("final evaluation");
    let windows = if o.windows.is_empty() {
        Vec::new()
    } else {
        if o.windows.iter().any(|l| l.is_nan() || *l <= 0.0) {
            bail!("--windows: lengths must be positive metres");
        }
        let pb = bar(o.quiet, "sub-trajectories");
        let w = calib::windows_study(&run, &geometry, initial, &o.windows, o.window_start, &pb)?;
        pb.finish_and_clear();
        w
    };
    Ok(Calibration {
        params,
        geometry,
        uncertainty,
        evaluation,
        windows,
    })
}

/// Wall time of each calibration phase, printed to stderr when `ODOCTL_DEBUG` is set.
struct PhaseTimer {
    last: Option<std::cell::Cell<Instant>>,
}

impl PhaseTimer {
    fn new() -> Self {
        Self {
            last: std::env::var_os("ODOCTL_DEBUG").map(|_| std::cell::Cell::new(Instant::now())),
        }
    }

    /// Prints the time since the previous lap (or the start) under `phase`.
    fn lap(&self, phase: &str) {
        if let Some(last) = &self.last {
            let now = Instant::now();
            eprintln!("time: {phase}: {:.4} s", (now - last.get()).as_secs_f64());
            last.set(now);
        }
    }
}

/// `odoctl calibrate`.
pub fn calibrate(o: &CalibrateOptions, input: &ReferenceArgs) -> Result<ExitCode> {
    let started = Instant::now();
    let timer = PhaseTimer::new();
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
    let c = calibrate_run(&samples, &reference, (&names.0, &names.1), &initial, o)?;
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
    let se = |i: usize| g.std_errors[i].map_or_else(|| "held".to_string(), |v| format!("{v:.2e}"));
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
    crate::outln!(
        "  start position {:.4} m E, {:.4} m N (the reference, averaged over the standstill there); standard errors (J^T J)^-1 s^2, s = {:.4} m, residuals taken as independent",
        g.start.0,
        g.start.1,
        g.residual_sigma
    );
    if let Some(w) = &g.track_warning {
        eprintln!("warning: eq (16) fit: {w}");
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
        crate::outln!(
            "{} model fit: {} sub-trajectories of {} m, {} points; 1-sigma band covers {:.1} % (target 68.3 %), 3-sigma {:.1} %",
            cfg::model_name(u.model),
            u.windows,
            o.delta_window,
            u.points,
            100.0 * u.coverage1,
            100.0 * u.coverage3
        );
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
            let deg = o.reference_heading_sigma.to_degrees();
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
    crate::outln!(
        "eq (16): {:.6} m over {} points (mean {:.4} m); {} stages, {} iterations, {} integrator runs",
        g.cost,
        g.points,
        g.cost / g.points as f64,
        g.stages,
        g.iterations,
        g.evaluations
    );
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
        for (name, se) in calib::GEOMETRY_UNKNOWNS.iter().zip(g.std_errors) {
            if let Some(v) = se {
                fit.push((se_keys(name), FitValue::Num(v)));
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
                    match o.delta_mode {
                        DeltaMode::Equal => "equal",
                        DeltaMode::KeepRatio => "keep-ratio",
                    }
                )),
            ));
            fit.push(("uncertainty_window", FitValue::Num(o.delta_window)));
            fit.push(("reference_sigma", FitValue::Num(o.reference_sigma)));
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
                FitValue::Num(o.reference_heading_sigma),
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
        fit.extend(per_model.iter().map(|(k, v)| (k.as_str(), v.clone())));
        let always: &[&str] = if diff.is_some_and(|d| d.fitted) {
            &["delta_diff"]
        } else {
            &[]
        };
        let text = cfg::render_params_with(
            &c.params,
            "odoctl calibrate: chassis parameters estimated by eq (16) of Jilek, Burian, Kriz",
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

fn print_window_stats(est: &[calib::WindowEstimate]) {
    let mut lengths: Vec<f64> = est.iter().map(|e| e.length).collect();
    lengths.sort_by(f64::total_cmp);
    lengths.dedup();
    crate::outln!("stability study (estimates on consecutive sub-trajectories):");
    crate::outln!(
        "  {:>6} {:>5} {:>5}  {:<15} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "length",
        "fits",
        "fail",
        "parameter",
        "mean",
        "std",
        "median",
        "min",
        "max"
    );
    for l in lengths {
        let all: Vec<&calib::WindowEstimate> = est.iter().filter(|e| e.length == l).collect();
        let ok: Vec<[f64; 4]> = all
            .iter()
            .filter_map(|e| e.estimate.as_ref().ok().copied())
            .collect();
        for (p, name) in ["left_diameter", "right_diameter", "track_width"]
            .iter()
            .enumerate()
        {
            let vals: Vec<f64> = ok.iter().map(|v| v[p]).filter(|v| v.is_finite()).collect();
            let s = summarize(&vals);
            let note = if vals.len() < ok.len() {
                format!(
                    "  ({} of {} turned too little)",
                    ok.len() - vals.len(),
                    ok.len()
                )
            } else {
                String::new()
            };
            let head = if p == 0 {
                format!("{:>5} m {:>5} {:>5}", l, ok.len(), all.len() - ok.len())
            } else {
                format!("{:>7} {:>5} {:>5}", "", "", "")
            };
            crate::outln!(
                "  {head}  {name:<15} {:>10.5} {:>10.5} {:>10.5} {:>10.5} {:>10.5}{note}",
                s.mean,
                s.std,
                s.median,
                s.min,
                s.max
            );
        }
    }
}

fn write_windows_csv(path: &Path, est: &[calib::WindowEstimate]) -> Result<()> {
    let mut w = create(path)?;
    writeln!(
        w,
        "length,start_dist,t_start,t_end,points,turning,left_diameter,right_diameter,track_width,initial_heading,mean_error,error"
    )?;
    for e in est {
        let (v, err) = match &e.estimate {
            Ok(v) => (
                v.map(|x| {
                    if x.is_finite() {
                        format!("{x:?}")
                    } else {
                        String::new()
                    }
                })
                .join(","),
                String::new(),
            ),
            Err(s) => (",,,".to_string(), s.replace(',', ";")),
        };
        writeln!(
            w,
            "{},{:.3},{},{},{},{:.6},{},{:?},{}",
            e.length,
            e.start_dist,
            csvio::fmt_t(e.t.0),
            csvio::fmt_t(e.t.1),
            e.points,
            e.turning,
            v,
            e.mean_error,
            err
        )?;
    }
    w.flush()?;
    Ok(())
}

/// `odoctl validate`.
#[allow(clippy::too_many_arguments)]
pub fn validate(
    samples_path: &Path,
    reference_path: &Path,
    config: Option<&Path>,
    sets: &[String],
    heading: Option<f64>,
    errors: Option<&Path>,
    plots: Option<&Path>,
    models: &[UncertaintyModel],
    reference_sigma: f64,
    reference_heading_sigma: f64,
    input: &ReferenceArgs,
) -> Result<ExitCode> {
    if !(reference_sigma >= 0.0 && reference_heading_sigma >= 0.0) {
        bail!("--reference-sigma and --reference-heading-sigma-deg must be non-negative");
    }
    let mut params = cfg::load(config, sets)?;
    if let [one] = models {
        params.uncertainty_model = *one;
    }
    let samples = csvio::read_samples(samples_path)?;
    let reference = reference_for_samples(&read_reference(reference_path, input)?, &samples)?;
    let matches = csvio::match_or_fail(
        &samples,
        &samples_path.display().to_string(),
        &reference,
        &reference_path.display().to_string(),
        2,
    )?;
    let run = Run::new(&samples, &reference, matches);
    let last = run.len() - 1;
    let h0 = match heading {
        Some(h) => h,
        None => calib::fit_heading(&run, &params, 0, last, run.heading_guess(0))?,
    };
    let ev = calib::evaluate(&run, &params, h0)?;
    let report = validation_report(&ev);
    crate::outln!(
        "validation: {} common times, {:.1} m of reference path, initial heading {:.6} rad ({})",
        run.len(),
        ev.dist.last().unwrap_or(&0.0),
        h0,
        if heading.is_some() {
            "given"
        } else {
            "fitted by eq (16)"
        }
    );
    crate::outln!("{}", report.trim_end());
    let widened = |e: &calib::Evaluation, k: f64| -> f64 {
        let s: Vec<f64> = e.sigma_h[1..]
            .iter()
            .map(|s| (s * s + reference_sigma * reference_sigma).sqrt())
            .collect();
        coverage(&e.horizontal[1..], &s, k)
    };
    crate::outln!(
        "  with the reference noise ({reference_sigma} m) added to the horizontal bands: {:.1} % in 1 sigma, {:.1} % in 3 sigma",
        100.0 * widened(&ev, 1.0),
        100.0 * widened(&ev, 3.0)
    );
    // Heading: the error of the heading change since the start (what sigma_heading, zero at
    // the start, predicts), bands widened by the reference heading noise; the start excluded.
    let widened_heading =
        |e: &calib::Evaluation, k: f64| calib::heading_coverage(e, reference_heading_sigma, k, 1);
    let heading_deg = reference_heading_sigma.to_degrees();
    if calib::heading_points(&ev, 1) > 0 {
        crate::outln!(
            "  heading change since the start vs sigma_heading, the reference heading noise ({heading_deg} deg) added: {:.1} % in 1 sigma, {:.1} % in 3 sigma",
            100.0 * widened_heading(&ev, 1.0),
            100.0 * widened_heading(&ev, 3.0)
        );
    }
    let mut compared = Vec::new();
    if models.len() > 1 {
        crate::outln!(
            "uncertainty models on this run (observed coverage; nominal 68.3 % in 1 sigma, 99.7 % in 3 sigma; bands widened by the reference noise, {reference_sigma} m horizontal, {heading_deg} deg heading; heading = change since the start):"
        );
        crate::outln!(
            "  {:<12} {:>11} {:>11} {:>11} {:>11} {:>14}",
            "model",
            "horiz 1sig",
            "horiz 3sig",
            "head 1sig",
            "head 3sig",
            "final sigma_h"
        );
        // The paper's model with and without its proposed delta_diff term, when the file has one.
        let mut rows: Vec<(&'static str, ChassisParams)> = Vec::new();
        for &m in models {
            let mut p = params;
            p.uncertainty_model = m;
            if m == UncertaintyModel::Paper && p.delta_diff > 0.0 {
                rows.push((
                    "paper",
                    ChassisParams {
                        delta_diff: 0.0,
                        ..p
                    },
                ));
                rows.push(("paper+diff", p));
            } else {
                rows.push((cfg::model_name(m), p));
            }
        }
        for (name, p) in rows {
            let e = calib::evaluate(&run, &p, h0)?;
            let pct = |v: f64| {
                if v.is_nan() {
                    "-".to_string()
                } else {
                    format!("{:.1} %", 100.0 * v)
                }
            };
            crate::outln!(
                "  {:<12} {:>11} {:>11} {:>11} {:>11} {:>12.4} m",
                name,
                pct(widened(&e, 1.0)),
                pct(widened(&e, 3.0)),
                pct(widened_heading(&e, 1.0)),
                pct(widened_heading(&e, 3.0)),
                e.sigma_h.last().copied().unwrap_or(f64::NAN)
            );
            compared.push((name, e.sigma_h));
        }
    }
    if let Some(p) = errors {
        let mut w = create(p)?;
        writeln!(
            w,
            "t,dist,x,y,x_ref,y_ref,horizontal_error,sigma_h,heading,heading_error,sigma_heading"
        )?;
        for i in 0..ev.t.len() {
            writeln!(
                w,
                "{},{:.4},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{},{:?}",
                csvio::fmt_t(ev.t[i]),
                ev.dist[i],
                ev.odo[i].0,
                ev.odo[i].1,
                ev.reference[i].0,
                ev.reference[i].1,
                ev.horizontal[i],
                ev.sigma_h[i],
                ev.heading[i],
                ev.heading_err[i]
                    .map(|e| format!("{e:?}"))
                    .unwrap_or_default(),
                ev.sigma_heading[i]
            )?;
        }
        w.flush()?;
    }
    if let Some(dir) = plots {
        let mut files = crate::plots::run_figures(dir, "validate", "Validation run", &ev)?;
        if !compared.is_empty() {
            files.push(crate::plots::models_figure(
                dir,
                &ev.t,
                &ev.horizontal,
                &compared,
            )?);
        }
        for f in files {
            crate::outln!("wrote {}", f.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The text table of `validate`: error statistics and band coverage.
pub fn validation_report(ev: &calib::Evaluation) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let e = &ev.horizontal[1..];
    let sh = &ev.sigma_h[1..];
    let h = summarize(e);
    let _ = writeln!(
        s,
        "  {:<22} {:>10} {:>10} {:>10} {:>10} {:>10} {:>9} {:>9}",
        "", "mean", "rms", "median", "p95", "max", "in 1sig", "in 3sig"
    );
    let _ = writeln!(
        s,
        "  {:<22} {:>10.4} {:>10.4} {:>10.4} {:>10.4} {:>10.4} {:>8.1}% {:>8.1}%",
        "horizontal error [m]",
        h.mean,
        h.rms,
        h.median,
        h.p95,
        h.max,
        100.0 * coverage(e, sh, 1.0),
        100.0 * coverage(e, sh, 3.0)
    );
    let (he, hs) = ev.heading_pairs();
    if he.len() > 1 {
        let abs: Vec<f64> = he[1..].iter().map(|v| v.abs().to_degrees()).collect();
        let a = summarize(&abs);
        let _ = writeln!(
            s,
            "  {:<22} {:>10.4} {:>10.4} {:>10.4} {:>10.4} {:>10.4} {:>8.1}% {:>8.1}%",
            "|heading error| [deg]",
            a.mean,
            a.rms,
            a.median,
            a.p95,
            a.max,
            100.0 * coverage(&he[1..], &hs[1..], 1.0),
            100.0 * coverage(&he[1..], &hs[1..], 3.0)
        );
    }
    let fin = e.last().copied().unwrap_or(f64::NAN);
    let _ = writeln!(
        s,
        "  final horizontal error {:.4} m with sigma_h {:.4} m; nominal coverage of a normal error: 68.3 % (1 sigma), 99.7 % (3 sigma)",
        fin,
        sh.last().copied().unwrap_or(f64::NAN)
    );
    s
}

/// Helper for errors about files.
pub fn file_err(path: &Path, e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("{}: {e}", path.display())
}
