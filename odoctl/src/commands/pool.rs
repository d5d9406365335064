//! `odoctl pool`: several drives' calibration results into one set of parameters
//! ([`crate::calib::pooling`]).

use std::path::Path;
use std::process::ExitCode;

use anyhow::{anyhow, bail, Context, Result};
use odo_unit::odometry::{ChassisParams, UncertaintyModel, WheelHarmonics};

use crate::calib::calibration::unit_geometry_uncertainty;
use crate::calib::pooling::{pool, DriveEstimate, Pooled};
use crate::calib::uncertainty::likelihood::{length_for, KAPPA_TARGET_LN_SE};
use crate::cli::PoolArgs;
use crate::config::{self as cfg, FitValue};

/// One drive's result file, read.
struct Drive {
    name: String,
    params: ChassisParams,
    estimate: DriveEstimate,
    path_length: f64,
}

/// `odoctl pool`.
pub fn run(a: &PoolArgs) -> Result<ExitCode> {
    let drives = a
        .results
        .iter()
        .map(|p| read_drive(p))
        .collect::<Result<Vec<_>>>()?;
    check_compatible(&drives)?;
    let estimates: Vec<DriveEstimate> = drives.iter().map(|d| d.estimate).collect();
    let pooled = pool(&estimates).map_err(|e| anyhow!("{e} ({})", drive_names(&drives)))?;
    let params = pooled_params(&drives, &pooled);
    let params = cfg::validated(params, "pooled parameters")?;
    report(&drives, &pooled);
    let fit = fit_table(&drives, &pooled);
    let fit: Vec<(&str, FitValue)> = fit.iter().map(|(k, v)| (k.as_str(), v.clone())).collect();
    let text = cfg::render_params(
        &params,
        "odoctl pool: chassis parameters pooled from several drives' calibrations",
        &fit,
    );
    std::fs::write(&a.out, text).with_context(|| format!("{}: cannot write", a.out.display()))?;
    crate::outln!("wrote {}", a.out.display());
    Ok(ExitCode::SUCCESS)
}

/// Reads a calibration result: its parameters and, from `[fit]`, kappa's most likely value,
/// its `ln` standard error and the path length.
fn read_drive(path: &Path) -> Result<Drive> {
    let name = path.display().to_string();
    let params = cfg::read_params(path, ChassisParams::DESIGNED)?;
    if params.uncertainty_model != UncertaintyModel::Covariance {
        bail!("{name}: uncertainty_model is not \"covariance\": pooling takes the covariance model's likelihood fit (kappa and its standard error)");
    }
    let text = std::fs::read_to_string(path).with_context(|| format!("{name}: cannot read"))?;
    let table: toml::Table = text.parse().map_err(|e| anyhow!("{name}: {e}"))?;
    let fit = table.get("fit").and_then(|f| f.as_table()).ok_or_else(|| {
        anyhow!("{name}: no [fit] table: pool takes the files `calibrate --out` writes")
    })?;
    let number = |key: &str| -> Result<f64> {
        let v = fit
            .get(key)
            .ok_or_else(|| anyhow!("{name}: [fit] has no {key} (calibrate with the covariance model's likelihood criterion, the default)"))?;
        v.as_float()
            .or_else(|| v.as_integer().map(|i| i as f64))
            .filter(|x| x.is_finite())
            .ok_or_else(|| anyhow!("{name}: [fit] {key} must be a finite number"))
    };
    let g = params.geometry_uncertainty;
    let se = [g.left_diameter_se, g.right_diameter_se, g.track_width_se].map(f64::from);
    if se.iter().any(|s| *s <= 0.0) {
        bail!("{name}: the geometry's standard errors (left_diameter_se, right_diameter_se, track_width_se) must be positive");
    }
    let corr = [
        [1.0, g.diameters_correlation, g.left_track_correlation],
        [g.diameters_correlation, 1.0, g.right_track_correlation],
        [g.left_track_correlation, g.right_track_correlation, 1.0],
    ];
    let covariance =
        std::array::from_fn(|r| std::array::from_fn(|c| f64::from(corr[r][c]) * se[r] * se[c]));
    Ok(Drive {
        estimate: DriveEstimate {
            geometry: [
                params.left_diameter,
                params.right_diameter,
                params.track_width,
            ],
            covariance,
            kappa_most_likely: number("covariance_most_likely")?,
            kappa_ln_se: number("covariance_ln_se")?,
        },
        path_length: number("path_length")?,
        name,
        params,
    })
}

fn drive_names(drives: &[Drive]) -> String {
    drives
        .iter()
        .enumerate()
        .map(|(i, d)| format!("drive {} = {}", i + 1, d.name))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The drives must describe the same chassis and unit: the same `ticks_per_rev`, round wheels.
fn check_compatible(drives: &[Drive]) -> Result<()> {
    let first = &drives[0];
    for d in drives {
        if d.params.ticks_per_rev != first.params.ticks_per_rev {
            bail!(
                "{}: ticks_per_rev {} differs from {}'s {}",
                d.name,
                d.params.ticks_per_rev,
                first.name,
                first.params.ticks_per_rev
            );
        }
        if d.params.left_wheel != WheelHarmonics::ROUND
            || d.params.right_wheel != WheelHarmonics::ROUND
        {
            bail!("{}: a per-angle wheel function is not pooled; calibrate it on one drive with --wheel-harmonics", d.name);
        }
    }
    Ok(())
}

/// The first drive's parameters with the pooled geometry, its uncertainty and kappa (the
/// right wheel's kappa keeps the first drive's ratio); `kappa_diff` is the drives' mean,
/// `kappa_diff_corr` the mean of those that have one, and the paper model's `delta_*` the
/// drives' means (a coverage criterion has no standard error to weigh by).
fn pooled_params(drives: &[Drive], p: &Pooled) -> ChassisParams {
    let n = drives.len() as f64;
    let mean = |f: fn(&ChassisParams) -> f32| {
        drives.iter().map(|d| f64::from(f(&d.params))).sum::<f64>() / n
    };
    let first = drives[0].params;
    let ratio = if first.kappa_left > 0.0 {
        f64::from(first.kappa_right / first.kappa_left)
    } else {
        1.0
    };
    let corrs: Vec<f64> = drives
        .iter()
        .map(|d| f64::from(d.params.kappa_diff_corr))
        .filter(|c| *c > 0.0)
        .collect();
    let se: [f64; 3] = std::array::from_fn(|k| p.covariance[k][k].sqrt());
    let corr = |i: usize, j: usize| p.covariance[i][j] / (se[i] * se[j]);
    ChassisParams {
        left_diameter: p.geometry[0],
        right_diameter: p.geometry[1],
        track_width: p.geometry[2],
        geometry_uncertainty: unit_geometry_uncertainty(se, [corr(0, 1), corr(0, 2), corr(1, 2)]),
        kappa_left: p.kappa as f32,
        kappa_right: (p.kappa * ratio) as f32,
        kappa_diff: mean(|q| q.kappa_diff) as f32,
        kappa_diff_corr: if corrs.is_empty() {
            0.0
        } else {
            (corrs.iter().sum::<f64>() / corrs.len() as f64) as f32
        },
        delta_left: mean(|q| q.delta_left) as f32,
        delta_right: mean(|q| q.delta_right) as f32,
        delta_diff: mean(|q| q.delta_diff) as f32,
        ..first
    }
}

/// The drives and the pooled values with their standard errors, and the chi-square tests.
fn report(drives: &[Drive], p: &Pooled) {
    crate::outln!(
        "{:<28} {:>10} {:>13} {:>13} {:>13} {:>11} {:>8}",
        "drive",
        "length m",
        "left_diam mm",
        "right_diam mm",
        "track mm",
        "kappa",
        "ln_se"
    );
    let row = |name: &str, len: f64, g: [f64; 3], cov: &[[f64; 3]; 3], k: f64, s: f64| {
        let v = |i: usize| format!("{:.3}+-{:.3}", g[i] * 1e3, cov[i][i].sqrt() * 1e3);
        crate::outln!(
            "{:<28} {:>10.1} {:>13} {:>13} {:>13} {:>11.3e} {:>8.3}",
            name,
            len,
            v(0),
            v(1),
            v(2),
            k,
            s
        );
    };
    for d in drives {
        let e = &d.estimate;
        row(
            &d.name,
            d.path_length,
            e.geometry,
            &e.covariance,
            e.kappa_most_likely,
            e.kappa_ln_se,
        );
    }
    let total: f64 = drives.iter().map(|d| d.path_length).sum();
    row(
        "pooled",
        total,
        p.geometry,
        &p.covariance,
        p.kappa_most_likely,
        p.kappa_ln_se,
    );
    crate::outln!(
        "the unit is told kappa {:.3e}, its mean over the pooled likelihood; about {:.0} m of such driving would measure kappa within 20 %",
        p.kappa,
        length_for(p.kappa_ln_se, total, KAPPA_TARGET_LN_SE)
    );
    let (g, gd, gq) = p.geometry_chi2;
    let (k, kd, kq) = p.kappa_chi2;
    crate::outln!("agreement: geometry chi-square {g:.1} on {gd} degrees of freedom (99 % limit {gq:.1}), ln kappa {k:.1} on {kd} (limit {kq:.1})");
    if g > gq {
        eprintln!("warning: the drives' geometries disagree beyond their standard errors (chi-square {g:.1} > {gq:.1}): a tyre pressure, load or wheel changed between them, or a reference was wrong; pool only drives of one chassis state");
    }
    if k > kq {
        eprintln!("warning: the drives' kappa disagree beyond their standard errors (chi-square {k:.1} > {kq:.1}): the floors slip differently; the pooled kappa's bands will be too narrow on the slipperiest, so pool drives of the surface the robot works on");
    }
}

/// `[fit]`: the drives, the pooled figures and the tests.
fn fit_table(drives: &[Drive], p: &Pooled) -> Vec<(String, FitValue)> {
    let mut fit = vec![
        ("method".to_string(), FitValue::Text("pooled drives: geometry by generalised least squares of the drives' estimates, ln kappa by the precision-weighted mean".into())),
        ("drives".to_string(), FitValue::Int(drives.len() as i64)),
        ("path_length".to_string(), FitValue::Num(drives.iter().map(|d| d.path_length).sum())),
        ("covariance_most_likely".to_string(), FitValue::Num(p.kappa_most_likely)),
        ("covariance_ln_se".to_string(), FitValue::Num(p.kappa_ln_se)),
        ("geometry_chi2".to_string(), FitValue::Num(p.geometry_chi2.0)),
        ("geometry_chi2_dof".to_string(), FitValue::Int(p.geometry_chi2.1 as i64)),
        ("kappa_chi2".to_string(), FitValue::Num(p.kappa_chi2.0)),
        ("kappa_chi2_dof".to_string(), FitValue::Int(p.kappa_chi2.1 as i64)),
    ];
    for (i, d) in drives.iter().enumerate() {
        let k = i + 1;
        fit.push((format!("drive{k}"), FitValue::Text(d.name.clone())));
        fit.push((
            format!("drive{k}_path_length"),
            FitValue::Num(d.path_length),
        ));
        fit.push((
            format!("drive{k}_covariance_most_likely"),
            FitValue::Num(d.estimate.kappa_most_likely),
        ));
        fit.push((
            format!("drive{k}_covariance_ln_se"),
            FitValue::Num(d.estimate.kappa_ln_se),
        ));
    }
    fit
}
