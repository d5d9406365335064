//! `odoctl umbmark`: the chassis geometry from square runs and a measured straight, without a
//! reference device (the square test of Borenstein and Feng, 1996, fitted with the unit's own
//! odometry rather than its small-angle formulas).
//!
//! Each run is a SAMPLES file recorded by `record` and the end pose measured on the floor
//! relative to the start pose: `forward` (m, along the start heading), `left` (m) and
//! optionally `heading_deg` (end heading less start heading, degrees counter-clockwise, near 0
//! after a full square). The fit integrates every run with the core integrator from the start
//! pose and minimises the sum of the squared differences whitened by each run's covariance
//! (the measurement errors plus the end covariance of white wheel slip, its kappa chosen so
//! that chi-square equals its degrees of freedom), over both diameters and the track width
//! (Gauss-Newton, central-difference Jacobian).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{anyhow, bail, Context, Result};
use odo_unit::odometry::{ChassisParams, Integrator, Pose};

use crate::cli::UmbmarkArgs;
use crate::config::{self as cfg, FitValue};
use crate::csvio::{self, Sample};
use crate::optim::invert3;
use crate::replay::{counts, index_refs};
use crate::stats::chi2_quantile_99;

/// Direction of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Clockwise square (four right turns).
    Cw,
    /// Counter-clockwise square.
    Ccw,
    /// A straight (the scale).
    Straight,
}

/// One measured run.
#[derive(Debug, Clone)]
pub struct Run {
    /// The SAMPLES file, as given.
    pub name: String,
    /// The samples.
    pub samples: Vec<Sample>,
    /// Its direction.
    pub direction: Direction,
    /// Measured end position ahead of and left of the start (m).
    pub end: (f64, f64),
    /// Measured end heading less start heading (rad, counter-clockwise), when measured.
    pub heading: Option<f64>,
}

/// The measurement errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sigmas {
    /// Of each measured coordinate (m).
    pub position: f64,
    /// Of a measured heading (rad).
    pub heading: f64,
}

/// Integrates a run with `p` from the origin pose (x = y = heading = 0), calling `each` with the
/// pose after every sample (the first included); returns the integrator at the run's end.
fn integrate(
    p: &ChassisParams,
    samples: &[Sample],
    mut each: impl FnMut(&Pose),
) -> Result<Integrator> {
    let first = samples.first().ok_or_else(|| anyhow!("no samples"))?;
    let start = Pose {
        x: 0.0,
        y: 0.0,
        heading: 0.0,
    };
    let mut integ =
        Integrator::new(p, counts(first), start).map_err(|e| anyhow!("parameters: {e}"))?;
    each(&integ.pose());
    for s in &samples[1..] {
        let _ = integ.step(counts(s), index_refs(s));
        each(&integ.pose());
    }
    Ok(integ)
}

/// The end pose of a run integrated with `p` from the start pose: (forward, left, heading
/// change counter-clockwise) in m, m, rad.
pub fn end_pose(p: &ChassisParams, samples: &[Sample]) -> Result<(f64, f64, f64)> {
    let e = integrate(p, samples, |_| ())?.pose();
    // Forward is +y at heading 0, left is -x; the heading is clockwise.
    Ok((e.y, -e.x, -e.heading))
}

/// The kappa at which [`slip_shape`] integrates (m).
const KAPPA_UNIT: f64 = 1e-6;

/// A run's end covariance from white wheel slip of kappa 1 m (the covariance model's
/// `kappa_left = kappa_right`, variance per metre of wheel travel; its end covariance is linear
/// in kappa): (forward, forward-left, left, heading) in m^2, m^2, m^2, rad^2.
pub fn slip_shape(p: &ChassisParams, samples: &[Sample]) -> Result<[f64; 4]> {
    let q = ChassisParams {
        uncertainty_model: odo_unit::odometry::UncertaintyModel::Covariance,
        kappa_left: KAPPA_UNIT as f32,
        kappa_right: KAPPA_UNIT as f32,
        kappa_diff: 0.0,
        kappa_diff_corr: 0.0,
        geometry_uncertainty: ChassisParams::DESIGNED.geometry_uncertainty,
        ..*p
    };
    let g = integrate(&q, samples, |_| ())?.sigma();
    let v = |a: f32| f64::from(a) * f64::from(a) / KAPPA_UNIT;
    // Forward is y, left is -x.
    Ok([
        v(g.y),
        -f64::from(g.cov_xy) / KAPPA_UNIT,
        v(g.x),
        v(g.heading),
    ])
}

/// The residuals of every run at `p`, each run's whitened by its covariance: the measurement
/// errors plus `kappa` times its slip shape; and each run's first residual's index.
fn residuals(
    p: &ChassisParams,
    runs: &[Run],
    s: Sigmas,
    kappa: f64,
    shapes: &[[f64; 4]],
) -> Result<(Vec<f64>, Vec<usize>)> {
    let mut r = Vec::new();
    let mut first = Vec::new();
    for (run, q) in runs.iter().zip(shapes) {
        first.push(r.len());
        let (f, l, h) = end_pose(p, &run.samples)?;
        let (df, dl) = (f - run.end.0, l - run.end.1);
        // Cholesky of [[a, b], [b, c]].
        let m2 = s.position * s.position;
        let (a, b, c) = (m2 + kappa * q[0], kappa * q[1], m2 + kappa * q[2]);
        let l11 = a.sqrt();
        let l21 = b / l11;
        let l22 = (c - l21 * l21).max(1e-30).sqrt();
        let w1 = df / l11;
        r.push(w1);
        r.push((dl - l21 * w1) / l22);
        if let Some(m) = run.heading {
            let var = s.heading * s.heading + kappa * q[3];
            r.push(crate::stats::wrap_angle(h - m) / var.sqrt());
        }
    }
    Ok((r, first))
}

fn with(p: &ChassisParams, x: [f64; 3]) -> ChassisParams {
    ChassisParams {
        left_diameter: x[0],
        right_diameter: x[1],
        track_width: x[2],
        ..*p
    }
}

/// What [`fit`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct UmbmarkFit {
    /// The fitted parameters (the initial ones with both diameters and the track width).
    pub params: ChassisParams,
    /// Standard errors of (left diameter, right diameter, track width) (m), from the
    /// measurement errors and the slip.
    pub se: [f64; 3],
    /// Their correlations (left-right, left-track, right-track).
    pub correlations: [f64; 3],
    /// Sum of the squared whitened residuals at the estimate (the dof when slip was fitted).
    pub chi2: f64,
    /// The same with the measurement errors alone.
    pub chi2_measurement: f64,
    /// The slip's kappa (m, variance of a wheel's distance per metre of its travel): 0 when
    /// the measurement errors explain the runs.
    pub kappa: f64,
    /// Degrees of freedom.
    pub dof: usize,
    /// The 99 % quantile of chi-square with `dof` degrees of freedom.
    pub chi2_limit: f64,
    /// Each run's largest |weighted residual|.
    pub worst: Vec<f64>,
}

/// Gauss-Newton over the three lengths at a fixed `kappa`, from `x`; returns the lengths and
/// the inverse of the normal matrix.
fn gauss_newton(
    initial: &ChassisParams,
    runs: &[Run],
    s: Sigmas,
    kappa: f64,
    shapes: &[[f64; 4]],
    mut x: [f64; 3],
) -> Result<([f64; 3], [[f64; 3]; 3])> {
    let mut cov = [[0.0; 3]; 3];
    for _ in 0..20 {
        let (r, _) = residuals(&with(initial, x), runs, s, kappa, shapes)?;
        let mut jac = vec![[0.0; 3]; r.len()];
        for k in 0..3 {
            let h = 1e-6 * x[k];
            let (mut up, mut dn) = (x, x);
            up[k] += h;
            dn[k] -= h;
            let (ru, _) = residuals(&with(initial, up), runs, s, kappa, shapes)?;
            let (rd, _) = residuals(&with(initial, dn), runs, s, kappa, shapes)?;
            for (i, row) in jac.iter_mut().enumerate() {
                row[k] = (ru[i] - rd[i]) / (2.0 * h);
            }
        }
        let mut n = [[0.0; 3]; 3];
        let mut g = [0.0; 3];
        for (row, ri) in jac.iter().zip(&r) {
            for a in 0..3 {
                g[a] += row[a] * ri;
                for b in 0..3 {
                    n[a][b] += row[a] * row[b];
                }
            }
        }
        cov = invert3(n).ok_or_else(|| {
            anyhow!("the runs do not determine both diameters and the track width: give a measured straight and squares in both directions")
        })?;
        let step: Vec<f64> = (0..3)
            .map(|a| -(0..3).map(|b| cov[a][b] * g[b]).sum::<f64>())
            .collect();
        for k in 0..3 {
            x[k] += step[k];
        }
        if (0..3).all(|k| step[k].abs() < 1e-12 * x[k].abs()) {
            break;
        }
    }
    Ok((x, cov))
}

fn chi2_at(
    initial: &ChassisParams,
    runs: &[Run],
    s: Sigmas,
    kappa: f64,
    shapes: &[[f64; 4]],
    x: [f64; 3],
) -> Result<f64> {
    let (r, _) = residuals(&with(initial, x), runs, s, kappa, shapes)?;
    Ok(r.iter().map(|v| v * v).sum())
}

/// The slip `kappa` (m) at which chi-square at `x` equals `dof` (bisection in log kappa
/// between 1e-14 and 1e-2 m); 0 when the measurement errors alone explain the runs.
fn slip_kappa(
    initial: &ChassisParams,
    runs: &[Run],
    s: Sigmas,
    shapes: &[[f64; 4]],
    x: [f64; 3],
    dof: f64,
) -> Result<f64> {
    if chi2_at(initial, runs, s, 0.0, shapes, x)? <= dof {
        return Ok(0.0);
    }
    let (mut lo, mut hi) = (-14.0f64, -2.0f64);
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if chi2_at(initial, runs, s, 10f64.powf(mid), shapes, x)? > dof {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(10f64.powf(hi))
}

/// Fits both diameters and the track width to the runs, from `initial`, each run weighted by
/// its measurement errors plus the end covariance of white wheel slip of a `kappa` found so
/// that chi-square equals its degrees of freedom (0 when the measurements alone explain the
/// runs). Fails when the runs cannot determine the lengths (no straight or no square in each
/// direction).
pub fn fit(initial: &ChassisParams, runs: &[Run], s: Sigmas) -> Result<UmbmarkFit> {
    let shapes: Vec<[f64; 4]> = runs
        .iter()
        .map(|r| slip_shape(initial, &r.samples))
        .collect::<Result<_>>()?;
    let x0 = [
        initial.left_diameter,
        initial.right_diameter,
        initial.track_width,
    ];
    let (mut x, _) = gauss_newton(initial, runs, s, 0.0, &shapes, x0)?;
    let n: usize = runs
        .iter()
        .map(|r| 2 + usize::from(r.heading.is_some()))
        .sum();
    let dof = n.saturating_sub(3).max(1);
    let chi2_measurement = chi2_at(initial, runs, s, 0.0, &shapes, x)?;
    let mut kappa = 0.0;
    for _ in 0..3 {
        kappa = slip_kappa(initial, runs, s, &shapes, x, dof as f64)?;
        x = gauss_newton(initial, runs, s, kappa, &shapes, x)?.0;
    }
    let (x, cov) = gauss_newton(initial, runs, s, kappa, &shapes, x)?;
    let params = with(initial, x);
    let (r, first) = residuals(&params, runs, s, kappa, &shapes)?;
    let chi2: f64 = r.iter().map(|v| v * v).sum();
    let se = [0, 1, 2].map(|k| cov[k][k].sqrt());
    let corr = |a: usize, b: usize| cov[a][b] / (cov[a][a] * cov[b][b]).sqrt();
    let worst = first
        .iter()
        .enumerate()
        .map(|(i, &a)| {
            let b = first.get(i + 1).copied().unwrap_or(r.len());
            r[a..b].iter().fold(0.0, |m, v| f64::max(m, v.abs()))
        })
        .collect();
    Ok(UmbmarkFit {
        params,
        se,
        correlations: [corr(0, 1), corr(0, 2), corr(1, 2)],
        chi2,
        chi2_measurement,
        kappa,
        dof,
        chi2_limit: chi2_quantile_99(dof as f64),
        worst,
    })
}

/// The measurements file (TOML).
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct MeasurementsFile {
    /// Side of the square (m), for the check of the recordings.
    side: f64,
    /// Measurement error of each coordinate (m).
    sigma: f64,
    /// Measurement error of a heading (degrees).
    #[serde(default = "default_heading_sigma")]
    heading_sigma_deg: f64,
    run: Vec<RunEntry>,
}

fn default_heading_sigma() -> f64 {
    0.5
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RunEntry {
    samples: toml::Spanned<PathBuf>,
    direction: String,
    forward: f64,
    left: f64,
    heading_deg: Option<f64>,
}

/// Reads the measurements file and its runs' SAMPLES (paths relative to the file), checking
/// each recording against its entry: a square must have turned about a full turn in its
/// direction and travelled about four sides, a straight must have turned less than 45 degrees.
pub fn read_runs(path: &Path, initial: &ChassisParams) -> Result<(Vec<Run>, Sigmas, f64)> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).with_context(|| format!("{file}: cannot read"))?;
    let m: MeasurementsFile = toml::from_str(&text).map_err(|e| anyhow!("{file}: {e}"))?;
    if !(m.sigma > 0.0 && m.sigma < 1.0 && m.heading_sigma_deg > 0.0 && m.side > 0.0) {
        bail!("{file}: side, sigma and heading_sigma_deg must be positive (sigma below 1 m)");
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut runs = Vec::new();
    for (i, e) in m.run.iter().enumerate() {
        let line = text[..e.samples.span().start.min(text.len())]
            .matches('\n')
            .count()
            + 1;
        let samples_path = e.samples.get_ref();
        let at = format!("{file}:{line}: run {} ({})", i + 1, samples_path.display());
        let direction = match e.direction.as_str() {
            "cw" => Direction::Cw,
            "ccw" => Direction::Ccw,
            "straight" => Direction::Straight,
            d => bail!("{at}: direction `{d}`: expected cw, ccw or straight"),
        };
        if ![e.forward, e.left].iter().all(|v| v.is_finite()) {
            bail!("{at}: forward and left must be finite (m)");
        }
        let samples = csvio::read_samples(&dir.join(samples_path))
            .with_context(|| format!("{at}: cannot read the samples"))?;
        check_run(&at, initial, &samples, direction, m.side)?;
        runs.push(Run {
            name: samples_path.display().to_string(),
            samples,
            direction,
            end: (e.forward, e.left),
            heading: e.heading_deg.map(f64::to_radians),
        });
    }
    let sigmas = Sigmas {
        position: m.sigma,
        heading: m.heading_sigma_deg.to_radians(),
    };
    Ok((runs, sigmas, m.side))
}

/// Refuses a recording that does not match its entry (see [`read_runs`]).
fn check_run(
    at: &str,
    p: &ChassisParams,
    samples: &[Sample],
    direction: Direction,
    side: f64,
) -> Result<()> {
    let mut path = 0.0;
    let mut prev: Option<Pose> = None;
    integrate(p, samples, |q| {
        if let Some(r) = prev {
            path += (q.x - r.x).hypot(q.y - r.y);
        }
        prev = Some(*q);
    })
    .map_err(|e| anyhow!("{at}: {e}"))?;
    let prev = prev.unwrap_or_default();
    let turn = -prev.heading.to_degrees();
    let ok = match direction {
        Direction::Cw => (turn + 360.0).abs() < 45.0 && (path / (4.0 * side) - 1.0).abs() < 0.2,
        Direction::Ccw => (turn - 360.0).abs() < 45.0 && (path / (4.0 * side) - 1.0).abs() < 0.2,
        Direction::Straight => turn.abs() < 45.0,
    };
    if !ok {
        bail!(
            "{at}: the recording turned {turn:+.0} deg (counter-clockwise) over {path:.2} m, which does not match a {direction:?} run{}",
            if direction == Direction::Straight {
                String::new()
            } else {
                format!(" of 4 x {side} m")
            }
        );
    }
    Ok(())
}

/// `odoctl umbmark`.
pub fn run(a: &UmbmarkArgs) -> Result<ExitCode> {
    let initial = cfg::load(a.params.config.as_deref(), &a.params.sets)?;
    let (runs, sigmas, side) = read_runs(&a.measurements, &initial)?;
    let f = fit(&initial, &runs, sigmas)?;
    report(&initial, &runs, &f, sigmas, side);
    let p = &f.params;
    let mut params = *p;
    params.geometry_uncertainty.left_diameter_se = f.se[0] as f32;
    params.geometry_uncertainty.right_diameter_se = f.se[1] as f32;
    params.geometry_uncertainty.track_width_se = f.se[2] as f32;
    params.geometry_uncertainty.diameters_correlation = f.correlations[0] as f32;
    params.geometry_uncertainty.left_track_correlation = f.correlations[1] as f32;
    params.geometry_uncertainty.right_track_correlation = f.correlations[2] as f32;
    let fit_values = [
        ("method", FitValue::Text("umbmark".into())),
        ("left_diameter_se", FitValue::Num(f.se[0])),
        ("right_diameter_se", FitValue::Num(f.se[1])),
        ("track_width_se", FitValue::Num(f.se[2])),
        ("ed", FitValue::Num(p.right_diameter / p.left_diameter)),
        ("eb", FitValue::Num(p.track_width / initial.track_width)),
        ("chi2_measurement", FitValue::Num(f.chi2_measurement)),
        ("slip_kappa", FitValue::Num(f.kappa)),
        ("dof", FitValue::Int(f.dof as i64)),
        ("runs", FitValue::Int(runs.len() as i64)),
    ];
    let text = cfg::render_params(
        &params,
        "odoctl umbmark: geometry from square runs and a measured straight",
        &fit_values,
    );
    std::fs::write(&a.out, text).with_context(|| format!("{}: cannot write", a.out.display()))?;
    crate::outln!("wrote {}", a.out.display());
    Ok(ExitCode::SUCCESS)
}

/// The estimates, the classic figures and the runs' agreement, on stdout (warnings on stderr).
fn report(initial: &ChassisParams, runs: &[Run], f: &UmbmarkFit, s: Sigmas, side: f64) {
    let p = &f.params;
    let count = |d: Direction| runs.iter().filter(|r| r.direction == d).count();
    crate::outln!(
        "umbmark: {} clockwise and {} counter-clockwise squares of {side} m, {} straights; measurement sigma {} m, {:.2} deg",
        count(Direction::Cw),
        count(Direction::Ccw),
        count(Direction::Straight),
        s.position,
        s.heading.to_degrees()
    );
    crate::outln!("  parameter               initial       estimate   std. error");
    for (name, a, b, se) in [
        (
            "left_diameter",
            initial.left_diameter,
            p.left_diameter,
            f.se[0],
        ),
        (
            "right_diameter",
            initial.right_diameter,
            p.right_diameter,
            f.se[1],
        ),
        ("track_width", initial.track_width, p.track_width, f.se[2]),
    ] {
        crate::outln!("  {name:<18} {a:>12.6} {b:>14.6} {se:>12.2e}");
    }
    let ed = p.right_diameter / p.left_diameter;
    let ed_se = ed
        * ((f.se[0] / p.left_diameter).powi(2) + (f.se[1] / p.right_diameter).powi(2)
            - 2.0 * f.correlations[0] * f.se[0] * f.se[1] / (p.left_diameter * p.right_diameter))
            .max(0.0)
            .sqrt();
    crate::outln!(
        "  Ed = right/left diameter {ed:.6} (se {ed_se:.1e}); Eb = track width / initial {:.6} (se {:.1e})",
        p.track_width / initial.track_width,
        f.se[2] / initial.track_width
    );
    crate::outln!(
        "  chi2 {:.1} over {} degrees of freedom with the measurement errors alone (99 % limit {:.1})",
        f.chi2_measurement,
        f.dof,
        f.chi2_limit
    );
    if f.chi2_measurement > f.chi2_limit {
        eprintln!(
            "warning: the runs disagree more than their measurement error allows (chi2 {:.1} > {:.1}): \
             the errors include wheel slip of kappa {:.3e} m (white, per metre of wheel travel) that \
             makes chi2 equal its degrees of freedom",
            f.chi2_measurement, f.chi2_limit, f.kappa
        );
    }
    for (r, w) in runs.iter().zip(&f.worst) {
        if *w > 3.0 {
            eprintln!(
                "warning: run {}: a residual of {w:.1} sigmas beyond the measurement error and slip: check its marks and measurements",
                r.name
            );
        }
    }
}
