//! `odoctl validate` on several runs at once: the coverage of the predicted uncertainty over
//! the ensemble, by distance travelled, and its figures.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::{
    self, CheckpointSample, Ensemble, Run, DEFAULT_REFERENCE_HEADING_SIGMA_DEG,
    DEFAULT_REFERENCE_SIGMA,
};
use crate::cli::{ReferenceArgs, ValidateArgs};
use crate::config as cfg;
use crate::reference::matched::{read_matched_run, MatchedRun, ReferenceSummary};

use super::reference_options;

/// What `validate` takes for an ensemble.
#[derive(Debug, Clone)]
pub struct EnsembleOptions<'a> {
    /// `(SAMPLES, REFERENCE)` of every run.
    pub runs: Vec<(PathBuf, PathBuf)>,
    /// Parameter file.
    pub config: Option<&'a Path>,
    /// `--set KEY=VALUE`s over it.
    pub sets: &'a [String],
    /// Models evaluated (empty: the file's).
    pub models: &'a [UncertaintyModel],
    /// Reference noise for epochs without their own sigma (m).
    pub reference_sigma: f64,
    /// Reference heading noise (rad).
    pub reference_heading_sigma: f64,
    /// Checkpoints (m of reference path from each run's start).
    pub checkpoints: Vec<f64>,
    /// Figure directory.
    pub plots: Option<&'a Path>,
}

/// `odoctl validate` with several runs (`--runs`, or `--samples` and `--reference` repeated).
pub fn run(a: &ValidateArgs) -> Result<ExitCode> {
    if a.mcap.is_some() {
        bail!("--mcap takes one run (--samples and --reference once), not an ensemble");
    }
    let list = match &a.runs {
        Some(f) => read_run_list(f)?,
        None if a.samples.len() == a.reference.len() => a
            .samples
            .iter()
            .cloned()
            .zip(a.reference.iter().cloned())
            .collect(),
        None => bail!(
            "--samples and --reference: give them in pairs ({} and {})",
            a.samples.len(),
            a.reference.len()
        ),
    };
    validate_ensemble(
        &EnsembleOptions {
            runs: list,
            config: a.params.config.as_deref(),
            sets: &a.params.sets,
            models: &a.models.list(),
            reference_sigma: a.reference_sigma.unwrap_or(DEFAULT_REFERENCE_SIGMA),
            reference_heading_sigma: a
                .reference_heading_sigma_deg
                .unwrap_or(DEFAULT_REFERENCE_HEADING_SIGMA_DEG)
                .to_radians(),
            checkpoints: a.checkpoints.clone(),
            plots: a.plots.as_deref(),
        },
        &a.reference_input,
    )
}

/// Reads a run list: one run a line, `SAMPLES REFERENCE` (separated by spaces, a tab or a
/// comma; paths relative to the list's directory), blank lines and `#` comments skipped.
pub fn read_run_list(path: &Path) -> Result<Vec<(PathBuf, PathBuf)>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let mut runs = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let parts: Vec<&str> = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .collect();
        let [s, r] = parts[..] else {
            bail!(
                "{}:{}: expected `SAMPLES REFERENCE`, found `{line}`",
                path.display(),
                i + 1
            );
        };
        runs.push((base.join(s), base.join(r)));
    }
    if runs.is_empty() {
        bail!("{}: no run listed", path.display());
    }
    Ok(runs)
}

/// `odoctl validate` with several runs: each is read as `validate` reads its run (the same
/// matching, the calibration result's antenna lever arm applied) and replayed from its start
/// (the reference position, averaged over the opening standstill; the reference heading
/// averaged there when the reference has headings, else the heading minimising eq (16) on that
/// run, which makes the horizontal figures optimistic), and compared with the reference at every checkpoint. The
/// bands are widened by what the reference adds to the observed error: its noise at the point
/// and at the start, and for the horizontal error the start heading's noise turned over the
/// distance from the start. Heading: the change since the start (what `sigma_heading`
/// predicts).
pub fn validate_ensemble(o: &EnsembleOptions, input: &ReferenceArgs) -> Result<ExitCode> {
    if !(o.reference_sigma >= 0.0 && o.reference_heading_sigma >= 0.0) {
        bail!("--reference-sigma and --reference-heading-sigma-deg must be non-negative");
    }
    if o.checkpoints.is_empty() || o.checkpoints.iter().any(|d| !d.is_finite() || *d <= 0.0) {
        bail!("--checkpoints: distances must be positive metres");
    }
    let params = cfg::load(o.config, o.sets)?;
    let models: Vec<UncertaintyModel> = if o.models.is_empty() {
        vec![params.uncertainty_model]
    } else {
        o.models.to_vec()
    };
    let mut ensembles: Vec<Ensemble> = models
        .iter()
        .map(|_| Ensemble::new(&o.checkpoints))
        .collect();
    let mut fitted_heading = 0usize;
    // The calibration result's lever arm, applied to every run as `validate` applies it.
    let antenna = super::lever_arm(o.config)?;
    let options = reference_options(input)?;
    for (sp, rp) in &o.runs {
        let MatchedRun {
            samples,
            reference,
            matches,
            ..
        } = read_matched_run(sp, rp, &options, ReferenceSummary::Print)?;
        let run = Run::new(&samples, &reference, matches).with_antenna(antenna);
        if add_run(&run, &params, &models, &mut ensembles, o)? {
            fitted_heading += 1;
        }
    }
    print_coverage(o, &models, &ensembles, fitted_heading);
    if let Some(dir) = o.plots {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
        let named: Vec<(&str, &Ensemble)> = models
            .iter()
            .map(|m| cfg::model_name(*m))
            .zip(ensembles.iter())
            .collect();
        for f in crate::plots::ensemble_figures(dir, "validate_ensemble", &named)? {
            crate::outln!("wrote {}", f.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Adds one run to the ensembles, one per model: replayed from its start, compared with the
/// reference at every checkpoint. True when its start heading is the eq (16) heading (no
/// reference heading).
fn add_run(
    run: &Run,
    params: &ChassisParams,
    models: &[UncertaintyModel],
    ensembles: &mut [Ensemble],
    o: &EnsembleOptions,
) -> Result<bool> {
    let rh2 = o.reference_heading_sigma * o.reference_heading_sigma;
    let mut fitted_heading = false;
    let last = run.len() - 1;
    // Start heading not fitted to the judged errors when the reference has headings.
    let mut changes = Vec::new();
    let guess = run.heading_guess(0);
    run.integrate_pose(params, 0, last, guess, |_, integ| {
        changes.push(integ.pose().heading - guess)
    })
    .map_err(|e| anyhow::anyhow!("parameters: {e}"))?;
    let (h0, var_h0) = match run.start_heading(0, |k| changes.get(k - 1).copied()) {
        Some((h, n)) => (h, rh2 / n as f64),
        None => {
            fitted_heading = true;
            (calib::fit_heading(run, params, 0, last, guess)?, 0.0)
        }
    };
    let (lo, hi) = run.standstill(0);
    let var = |k: usize| {
        let s = run.reference_at(k).sigma_h.unwrap_or(o.reference_sigma);
        s * s
    };
    let n0 = (hi - lo + 1) as f64;
    let var_start = (lo..=hi).map(var).sum::<f64>() / (n0 * n0);
    let start = run.anchor(0);
    for (m, ens) in models.iter().zip(ensembles.iter_mut()) {
        let p = ChassisParams {
            uncertainty_model: *m,
            ..*params
        };
        let ev = calib::evaluate(run, &p, h0)?;
        ens.add_run(&ev.dist, |i| {
            let (x, y) = ev.odo[i];
            let turned = (x - start.0).powi(2) + (y - start.1).powi(2);
            let band = (ev.sigma_h[i].powi(2) + var(ev.k[i]) + var_start + var_h0 * turned).sqrt();
            let n = ev.start_headings[i].max(1) as f64;
            CheckpointSample {
                horizontal: (ev.horizontal[i], band),
                heading: ev.heading_change_err[i].map(|e| {
                    (
                        e,
                        (ev.sigma_heading[i].powi(2) + rh2 * (1.0 + 1.0 / n)).sqrt(),
                    )
                }),
            }
        });
    }
    Ok(fitted_heading)
}

/// The ensemble's coverage by checkpoint and its reliability, per model, on stdout.
fn print_coverage(
    o: &EnsembleOptions,
    models: &[UncertaintyModel],
    ensembles: &[Ensemble],
    fitted_heading: usize,
) {
    crate::outln!(
        "ensemble validation: {} runs; bands widened by the reference noise ({} m where an epoch has no sigma, {} deg heading){}",
        o.runs.len(),
        o.reference_sigma,
        o.reference_heading_sigma.to_degrees(),
        if fitted_heading > 0 {
            format!("; {fitted_heading} runs without a reference heading start at the eq (16) heading (fitted to the judged run: horizontal figures optimistic)")
        } else {
            String::new()
        }
    );
    crate::outln!(
        "share inside 1 and 3 sigma (nominal 68.3 % / 99.7 %; horizontal sigma_h of a round error covers 63.2 %; target 60-76 % / >= 97 %):"
    );
    crate::outln!(
        "  {:<11} {:>8} {:>5} {:>12} {:>12} {:>12} {:>12}",
        "model",
        "distance",
        "runs",
        "horiz 1sig",
        "horiz 3sig",
        "head 1sig",
        "head 3sig"
    );
    let pct = |v: f64| {
        if v.is_nan() {
            "-".to_string()
        } else {
            format!("{:.1} %", 100.0 * v)
        }
    };
    for (m, e) in models.iter().zip(ensembles) {
        for c in e.coverage() {
            crate::outln!(
                "  {:<11} {:>6.1} m {:>5} {:>12} {:>12} {:>12} {:>12}",
                cfg::model_name(*m),
                c.distance,
                c.runs,
                pct(c.horizontal.0),
                pct(c.horizontal.1),
                pct(c.heading.0),
                pct(c.heading.1)
            );
        }
    }
    crate::outln!(
        "reliability (observed share inside the band of each nominal level, all checkpoints):"
    );
    for (m, e) in models.iter().zip(ensembles) {
        let rows: Vec<String> = e
            .reliability()
            .iter()
            .map(|(p, h, a)| format!("{:.0}: {} / {}", 100.0 * p, pct(*h), pct(*a)))
            .collect();
        crate::outln!(
            "  {:<11} horizontal / heading  {}",
            cfg::model_name(*m),
            rows.join(", ")
        );
    }
}
