//! `odoctl validate`: a run evaluated with given parameters, printed and written.

use std::io::Write;
use std::path::Path;
use std::process::ExitCode;

use anyhow::{bail, Result};
use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::{self, ReferenceNoise, Run};
use crate::cli::ValidateArgs;
use crate::config::{self as cfg};
use crate::csvio;
use crate::reference::matched::{read_matched_run, MatchedRun, ReferenceSummary};
use crate::reference::trajectory_noise::TrajectoryNoise;
use crate::stats::{coverage, summarize};

use super::recording::{check_recording_times, reference_for};
use super::{create, reference_options};

/// `odoctl validate`: one run (with its MCAP tracks first when `--mcap` is given), or an
/// ensemble of runs ([`validate_ensemble`](super::validate_ensemble)).
pub fn run(a: &ValidateArgs) -> Result<ExitCode> {
    if a.runs.is_some() || a.samples.len() > 1 || a.reference.len() > 1 {
        return super::validate_ensemble::run(a);
    }
    let (reference, own) = reference_for(&a.samples[0], a.reference.first().map(|p| p.as_path()))?;
    if let Some(m) = &a.mcap {
        crate::ros::tracks::validate_hook(
            m,
            &a.samples[0],
            &reference,
            &reference_options(&a.reference_input)?,
            a.params.config.as_deref(),
            &a.params.sets,
            a.heading,
        )?;
    }
    validate(a, &reference, own)
}

/// One run evaluated with the parameters against `reference_path` (the recording's own
/// log when `own`: its times checked): printed, and written as asked.
fn validate(a: &ValidateArgs, reference_path: &Path, own: bool) -> Result<ExitCode> {
    let config = a.params.config.as_deref();
    let models = a.models.list();
    let mut params = cfg::load(config, &a.params.sets)?;
    if let [one] = models.as_slice() {
        params.uncertainty_model = *one;
    }
    let MatchedRun {
        samples,
        reference,
        matches,
        noise: own_noise,
    } = read_matched_run(
        &a.samples[0],
        reference_path,
        &reference_options(&a.reference_input)?,
        ReferenceSummary::Print,
    )?;
    let noise = reference_noise(a, own_noise.as_ref());
    if !(noise.horizontal >= 0.0 && noise.heading >= 0.0) {
        bail!("--reference-sigma and --reference-heading-sigma-deg must be non-negative");
    }
    if own {
        check_recording_times(&samples, &reference)?;
    }
    let run = Run::new(&samples, &reference, matches).with_antenna(super::lever_arm(config)?);
    let last = run.len() - 1;
    let h0 = match a.heading {
        Some(h) => h,
        None => calib::fit_heading(&run, &params, 0, last, run.heading_guess(0))?,
    };
    let ev = calib::evaluate(&run, &params, h0)?;
    print_summary(&run, &ev, h0, a.heading.is_some(), noise);
    let compared = if models.len() > 1 {
        compare_models(&run, &params, h0, &models, noise)?
    } else {
        Vec::new()
    };
    if let Some(p) = &a.errors {
        write_errors(p, &ev)?;
    }
    if let Some(dir) = &a.plots {
        write_plots(dir, &ev, &compared)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// The reference's noise: the options' where given, else a trajectory's own (`own`), else
/// the defaults; a line says what a trajectory's own noise set.
fn reference_noise(a: &ValidateArgs, own: Option<&TrajectoryNoise>) -> ReferenceNoise {
    let (sigma, heading) = (a.reference_sigma, a.reference_heading_sigma_deg);
    let noise = ReferenceNoise::resolve(sigma, heading, own);
    if let Some(n) = own.filter(|_| sigma.is_none() || heading.is_none()) {
        crate::outln!(
            "  reference noise: the trajectory's own, from the second differences of {} poses, where the options give none: {:.5} m, {:.4} deg",
            n.triples,
            noise.horizontal,
            noise.heading.to_degrees()
        );
    }
    noise
}

/// The run's errors against their bands, on stdout.
fn print_summary(
    run: &Run,
    ev: &calib::Evaluation,
    h0: f64,
    heading_given: bool,
    noise: ReferenceNoise,
) {
    let report = validation_report(ev);
    crate::outln!(
        "validation: {} common times, {:.1} m of reference path, initial heading {:.6} rad ({})",
        run.len(),
        ev.dist.last().unwrap_or(&0.0),
        h0,
        if heading_given {
            "given"
        } else {
            "fitted by eq (16)"
        }
    );
    crate::outln!("{}", report.trim_end());
    let reference_sigma = noise.horizontal;
    crate::outln!(
        "  with the reference noise ({reference_sigma} m) added to the horizontal bands: {:.1} % in 1 sigma, {:.1} % in 3 sigma",
        100.0 * noise.horizontal_coverage(ev, 1.0),
        100.0 * noise.horizontal_coverage(ev, 3.0)
    );
    let heading_deg = noise.heading.to_degrees();
    let heading = (calib::heading_points(ev, 1) > 0).then(|| {
        (
            noise.heading_coverage(ev, 1.0),
            noise.heading_coverage(ev, 3.0),
        )
    });
    if let Some((c1, c3)) = heading {
        crate::outln!(
            "  heading change since the start vs sigma_heading, the reference heading noise ({heading_deg} deg) added: {:.1} % in 1 sigma, {:.1} % in 3 sigma",
            100.0 * c1,
            100.0 * c3
        );
    }
    let check = noise.check(ev);
    crate::outln!("  {}", check.describe());
    for w in check.warnings() {
        eprintln!("warning: {w}");
    }
    if let Some(h) = check.hint() {
        crate::outln!("  {h}");
    }
    let horizontal = (
        noise.horizontal_coverage(ev, 1.0),
        noise.horizontal_coverage(ev, 3.0),
    );
    crate::outln!("{}", band_verdict(horizontal, heading));
}

/// Below this 1-sigma coverage (or [`NARROW_3`] in 3 sigma) a run's bands are too narrow,
/// above [`WIDE_1`] too wide: lenient bounds, since one run's errors are correlated along it
/// and its coverage varies from run to run around the nominal 68.3 %.
const NARROW_1: f64 = 0.45;
/// See [`NARROW_1`].
const NARROW_3: f64 = 0.95;
/// See [`NARROW_1`].
const WIDE_1: f64 = 0.92;

/// The plain verdict on a run's widened coverages (1 and 3 sigma; heading where it has one)
/// and what to do about it.
fn band_verdict(horizontal: (f64, f64), heading: Option<(f64, f64)>) -> String {
    let judge = |what: &str, (c1, c3): (f64, f64)| -> Option<String> {
        if c1 < NARROW_1 || c3 < NARROW_3 {
            Some(format!(
                "the {what} errors fall outside their bands more often than they should ({:.1} % inside 1 sigma where 68.3 % is nominal and {:.0} % is the least one run is expected to show; {:.1} % inside 3 sigma where 99.7 % is nominal): the unit's sigmas are too small for this run",
                100.0 * c1,
                100.0 * NARROW_1,
                100.0 * c3
            ))
        } else if c1 > WIDE_1 {
            Some(format!(
                "the {what} bands are wider than this run's errors need ({:.1} % inside 1 sigma where 68.3 % is nominal)",
                100.0 * c1
            ))
        } else {
            None
        }
    };
    let found: Vec<String> = [
        judge("horizontal", horizontal),
        heading.and_then(|h| judge("heading", h)),
    ]
    .into_iter()
    .flatten()
    .collect();
    if found.is_empty() {
        return "verdict: the errors fall inside their bands as often as they should".to_string();
    }
    format!(
        "verdict: {}. What to do: check the reference noise line above; if it is right, recalibrate on a longer drive that includes this run's kind of path (turns, speed, floor)",
        found.join("; ")
    )
}

/// The coverage of each model on the run, on stdout; their sigma_h for the figure.
fn compare_models(
    run: &Run,
    params: &ChassisParams,
    h0: f64,
    models: &[UncertaintyModel],
    noise: ReferenceNoise,
) -> Result<Vec<(&'static str, Vec<f64>)>> {
    let (reference_sigma, heading_deg) = (noise.horizontal, noise.heading.to_degrees());
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
        let mut p = *params;
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
    let mut compared = Vec::new();
    for (name, p) in rows {
        let e = calib::evaluate(run, &p, h0)?;
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
            pct(noise.horizontal_coverage(&e, 1.0)),
            pct(noise.horizontal_coverage(&e, 3.0)),
            pct(noise.heading_coverage(&e, 1.0)),
            pct(noise.heading_coverage(&e, 3.0)),
            e.sigma_h.last().copied().unwrap_or(f64::NAN)
        );
        compared.push((name, e.sigma_h));
    }
    Ok(compared)
}

/// The per-point errors and sigmas (`--errors`).
fn write_errors(p: &Path, ev: &calib::Evaluation) -> Result<()> {
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
    Ok(())
}

/// The figures (`--plots`), with the models' sigma_h compared when there are several.
fn write_plots(dir: &Path, ev: &calib::Evaluation, compared: &[(&str, Vec<f64>)]) -> Result<()> {
    let mut files = crate::plots::run_figures(dir, "validate", "Validation run", ev)?;
    if !compared.is_empty() {
        files.push(crate::plots::models_figure(
            dir,
            &ev.t,
            &ev.horizontal,
            compared,
        )?);
    }
    for f in files {
        crate::outln!("wrote {}", f.display());
    }
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verdict_boundaries() {
        let ok = "verdict: the errors fall inside their bands as often as they should";
        // (horizontal, heading) -> narrow?, wide?
        type Row = ((f64, f64), Option<(f64, f64)>, bool, bool);
        let table: [Row; 8] = [
            ((0.68, 0.997), None, false, false),
            ((NARROW_1, NARROW_3), None, false, false),
            ((NARROW_1 - 1e-9, 1.0), None, true, false),
            ((0.68, NARROW_3 - 1e-9), None, true, false),
            ((WIDE_1, 1.0), None, false, false),
            ((WIDE_1 + 1e-9, 1.0), None, false, true),
            ((0.68, 0.997), Some((0.30, 0.90)), true, false),
            ((0.68, 0.997), Some((f64::NAN, f64::NAN)), false, false),
        ];
        for (horizontal, heading, narrow, wide) in table {
            let v = band_verdict(horizontal, heading);
            assert_eq!(v.contains("more often than they should"), narrow, "{v}");
            assert_eq!(v.contains("wider than"), wide, "{v}");
            assert_eq!(v == ok, !narrow && !wide, "{v}");
            if narrow {
                assert!(v.contains("What to do"), "{v}");
            }
        }
    }
}
