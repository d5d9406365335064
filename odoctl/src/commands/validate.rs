//! `odoctl validate`: a run evaluated with given parameters, printed and written.

use std::io::Write;
use std::path::Path;
use std::process::ExitCode;

use anyhow::{bail, Result};
use odo_core::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::{self, Run};
use crate::config::{self as cfg};
use crate::csvio;
use crate::reference::cli::{read_matched_run, MatchedRun, ReferenceArgs, ReferenceSummary};
use crate::stats::{coverage, summarize};

use super::create;

/// The antenna lever arm `(forward, left)` (m) of a calibration result (`[fit]`), (0, 0)
/// without one; printed when there is one. `validate` and its ensemble apply it to the runs.
pub(super) fn lever_arm(config: Option<&Path>) -> Result<(f64, f64)> {
    let antenna = match config {
        Some(p) => calib::read_lever_arm(p)?,
        None => (0.0, 0.0),
    };
    if antenna != (0.0, 0.0) {
        crate::outln!(
            "antenna lever arm from {}: {:.4} m forward, {:.4} m left of the axle centre",
            config.map_or(String::new(), |p| p.display().to_string()),
            antenna.0,
            antenna.1
        );
    }
    Ok(antenna)
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
    let MatchedRun {
        samples,
        reference,
        matches,
    } = read_matched_run(samples_path, reference_path, input, ReferenceSummary::Print)?;
    let run = Run::new(&samples, &reference, matches).with_antenna(lever_arm(config)?);
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
