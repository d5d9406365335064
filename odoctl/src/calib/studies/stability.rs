//! The stability study: the calibration repeated on sub-trajectories (the paper's Figs. 7-9).
//!
//! Each sub-trajectory gets its own eq (16) fit. A fit that does not determine the chassis
//! is reported as failed, with its reason, and kept out of the statistics and the figures
//! (see [`WindowFailure`]): on 1-4 m windows an unchecked fit runs the diameters into their
//! 0.01 m bound or the track width to several metres, and one such value swamps a mean, a
//! standard deviation and a histogram. A window is failed when
//! - the fit itself fails (too few points, parameters leaving the admissible range);
//! - an estimate lies at a bound of the admissible range ([`ChassisParams::MIN_LENGTH`],
//!   [`ChassisParams::MAX_LENGTH`], within [`BOUND_MARGIN`]);
//! - it turned less than the fit's `min_turning` (30 deg), so the track width was held, not
//!   estimated (eq 8: only turning reveals it);
//! - a parameter's standard error exceeds [`MAX_RELATIVE_SE`] of its value (5 %: 13 mm of a
//!   diameter, 28 mm of a track, no better than the designed values are known; the standard
//!   error is the fit's `(J^T J)^-1 s^2`, a lower bound with correlated residuals, so this
//!   flags only windows that are hopeless even by that optimistic measure; on the simulated
//!   70 m run the accepted windows' track widths have at most 2 %, the failed ones 10 % and
//!   more);
//! - the normal matrix, scaled to unit diagonal, has a condition number above
//!   [`MAX_CONDITION`] (1e8: numerically singular, two unknowns indistinguishable).

use anyhow::Result;
use indicatif::ProgressBar;
use odo_unit::odometry::ChassisParams;

use crate::calib::evaluation::evaluate;
use crate::calib::geometry::paper::{fit_geometry, GeomFit, GeomOptions};
use crate::calib::run::{windows, Run};
use crate::optim::{NormalAccumulator, Objective};
use crate::stats::{summarize, Summary};

/// Where the stability study's fits start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WindowStart {
    /// From the initial estimate, as the paper did (Fig. 7): the fits of short windows may
    /// run to another minimum (or a bound) from a poor first estimate.
    Initial,
    /// From the full-trajectory estimate (the default): each window's fit starts at the
    /// whole run's minimum and moves only as far as its own data pull it.
    Full,
}

/// An estimate within this relative distance of a bound of the admissible range counts as
/// at the bound.
pub const BOUND_MARGIN: f64 = 1e-3;

/// Largest accepted standard error of a window's parameter, relative to its value.
pub const MAX_RELATIVE_SE: f64 = 0.05;

/// Largest accepted condition number of a window's normal matrix scaled to unit diagonal.
pub const MAX_CONDITION: f64 = 1e8;

/// Names of the window estimates' parameters (the first three [`GEOMETRY_UNKNOWNS`]).
///
/// [`GEOMETRY_UNKNOWNS`]: crate::calib::sensitivity::GEOMETRY_UNKNOWNS
pub const WINDOW_PARAMS: [&str; 3] = ["left_diameter", "right_diameter", "track_width"];

/// Why a sub-trajectory's estimate is not used.
#[derive(Debug, Clone, PartialEq)]
pub enum WindowFailure {
    /// The fit failed (its message).
    Fit(String),
    /// An estimate lies at a bound of the admissible range.
    Bound {
        /// The parameter.
        key: &'static str,
        /// Its estimate (m).
        value: f64,
    },
    /// The window turned too little to estimate the track width (it was held).
    TooLittleTurning {
        /// Total absolute heading change (deg).
        turning_deg: f64,
        /// The fit's threshold (deg).
        min_deg: f64,
    },
    /// A parameter's standard error exceeds [`MAX_RELATIVE_SE`] of its value.
    Undetermined {
        /// The parameter.
        key: &'static str,
        /// Its standard error relative to its value.
        relative_se: f64,
    },
    /// The scaled normal matrix is numerically singular.
    IllConditioned {
        /// Its condition number.
        condition: f64,
    },
}

impl WindowFailure {
    /// A short class name for the CSV and the summary: `fit`, `bound`, `turning`,
    /// `undetermined`, `ill-conditioned`.
    pub fn code(&self) -> &'static str {
        match self {
            Self::Fit(_) => "fit",
            Self::Bound { .. } => "bound",
            Self::TooLittleTurning { .. } => "turning",
            Self::Undetermined { .. } => "undetermined",
            Self::IllConditioned { .. } => "ill-conditioned",
        }
    }
}

impl std::fmt::Display for WindowFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Fit(e) => write!(f, "fit failed: {e}"),
            Self::Bound { key, value } => write!(f, "{key} at its bound ({value} m)"),
            Self::TooLittleTurning {
                turning_deg,
                min_deg,
            } => write!(
                f,
                "turned {turning_deg:.0} deg (< {min_deg:.0}): track_width not determined"
            ),
            Self::Undetermined { key, relative_se } => write!(
                f,
                "{key} not determined (standard error {:.1} % of it, limit {:.0} %)",
                100.0 * relative_se,
                100.0 * MAX_RELATIVE_SE
            ),
            Self::IllConditioned { condition } => write!(
                f,
                "ill-conditioned normal matrix (condition number {condition:.1e}, limit {MAX_CONDITION:.0e})"
            ),
        }
    }
}

/// One sub-trajectory estimate of the stability study.
#[derive(Debug, Clone)]
pub struct WindowEstimate {
    /// Nominal sub-trajectory length (m).
    pub length: f64,
    /// Path distance of its start from the run's start (m).
    pub start_dist: f64,
    /// Start and end time (s).
    pub t: (f64, f64),
    /// Total absolute heading change along it (rad, from the full-run odometry).
    pub turning: f64,
    /// Common times used.
    pub points: usize,
    /// The estimate (left_diameter, right_diameter, track_width, heading0) of an accepted
    /// window, or why the window failed.
    pub estimate: Result<[f64; 4], WindowFailure>,
    /// What the fit returned, accepted or not (`None` when it failed outright; the track
    /// width NaN where it was held).
    pub fitted: Option<[f64; 4]>,
    /// Standard errors of the fitted values (m, m, m, rad; NaN where held or unknown).
    pub std_errors: [f64; 4],
    /// Condition number of the normal matrix of the free unknowns scaled to unit diagonal
    /// (NaN when the fit failed).
    pub condition: f64,
    /// Eq (16) per point at the estimate (m).
    pub mean_error: f64,
}

impl WindowEstimate {
    /// True when the window's estimate is used.
    pub fn accepted(&self) -> bool {
        self.estimate.is_ok()
    }
}

/// The paper's stability study: estimates on consecutive sub-trajectories of each length.
pub fn windows_study(
    run: &Run,
    full: &GeomFit,
    initial: &ChassisParams,
    lengths: &[f64],
    start: WindowStart,
    progress: &ProgressBar,
) -> Result<Vec<WindowEstimate>> {
    let ev = evaluate(run, &full.params, full.heading0)?;
    let plan: Vec<(f64, usize, usize)> = lengths
        .iter()
        .flat_map(|&l| windows(run, l, 10).into_iter().map(move |(a, b)| (l, a, b)))
        .collect();
    progress.set_length(plan.len() as u64);
    let from = match start {
        WindowStart::Initial => *initial,
        WindowStart::Full => full.params,
    };
    let opts = GeomOptions {
        polish: false,
        ..GeomOptions::default()
    };
    let mut out = Vec::with_capacity(plan.len());
    for (length, a, b) in plan {
        let turning: f64 = ev.heading[a..=b]
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .sum();
        let fit = fit_geometry(
            run,
            &from,
            ev.heading[a],
            a,
            b,
            opts,
            &ProgressBar::hidden(),
        );
        let mut w = WindowEstimate {
            length,
            start_dist: run.dist[a],
            t: (run.reference_at(a).t, run.reference_at(b).t),
            turning,
            points: b - a,
            estimate: Err(WindowFailure::Fit(String::new())),
            fitted: None,
            std_errors: [f64::NAN; 4],
            condition: f64::NAN,
            mean_error: f64::NAN,
        };
        match fit {
            Ok(f) => {
                let v = [
                    f.params.left_diameter,
                    f.params.right_diameter,
                    if f.track_estimated {
                        f.params.track_width
                    } else {
                        f64::NAN
                    },
                    f.heading0,
                ];
                let free = [true, true, f.track_estimated, true];
                w.fitted = Some(v);
                w.std_errors = f.std_errors.map(|s| s.unwrap_or(f64::NAN));
                w.condition = scaled_condition(run, &f.params, a, b, f.heading0, free);
                w.mean_error = f.cost / f.points as f64;
                w.estimate = match judge(&v, &w.std_errors, w.condition, &f, opts.min_turning) {
                    Some(reason) => Err(reason),
                    None => Ok(v),
                };
            }
            Err(e) => w.estimate = Err(WindowFailure::Fit(e.to_string())),
        }
        out.push(w);
        progress.inc(1);
    }
    Ok(out)
}

/// The first reason (in the order of the module's list) why a window's fit `v` with
/// standard errors `se` and scaled condition number `condition` is not used; `None` when
/// it is.
fn judge(
    v: &[f64; 4],
    se: &[f64; 4],
    condition: f64,
    fit: &GeomFit,
    min_turning: f64,
) -> Option<WindowFailure> {
    let (lo, hi) = (ChassisParams::MIN_LENGTH, ChassisParams::MAX_LENGTH);
    for (p, key) in WINDOW_PARAMS.iter().enumerate() {
        let x = v[p];
        if x.is_finite() && (x <= lo * (1.0 + BOUND_MARGIN) || x >= hi * (1.0 - BOUND_MARGIN)) {
            return Some(WindowFailure::Bound { key, value: x });
        }
    }
    if !fit.track_estimated {
        return Some(WindowFailure::TooLittleTurning {
            turning_deg: fit.turning.to_degrees(),
            min_deg: min_turning.to_degrees(),
        });
    }
    if condition.is_nan() || condition > MAX_CONDITION {
        return Some(WindowFailure::IllConditioned { condition });
    }
    for (p, key) in WINDOW_PARAMS.iter().enumerate() {
        let rel = se[p] / v[p].abs();
        if rel.is_nan() || rel > MAX_RELATIVE_SE {
            return Some(WindowFailure::Undetermined {
                key,
                relative_se: rel,
            });
        }
    }
    None
}

/// Condition number of the Gauss-Newton normal matrix `J^T J` of the free unknowns over
/// matches `a..=b`, scaled to unit diagonal (a correlation matrix: independent of the
/// units, large only when unknowns are nearly indistinguishable); NaN when it cannot be
/// formed, infinite when singular.
pub fn scaled_condition(
    run: &Run,
    params: &ChassisParams,
    a: usize,
    b: usize,
    heading0: f64,
    free: [bool; 4],
) -> f64 {
    let idx: Vec<usize> = (0..4).filter(|&i| free[i]).collect();
    let n = idx.len();
    let mut acc = NormalAccumulator::new(Objective::Squares, false, n);
    if !run.accumulate_normal(params, a, b, heading0, &idx, &mut acc) {
        return f64::NAN;
    }
    let (mut m, _) = acc.equations();
    let d: Vec<f64> = (0..n).map(|i| m[i * n + i].sqrt()).collect();
    if d.iter().any(|&x| x.is_nan() || x <= 0.0 || !x.is_finite()) {
        return f64::INFINITY;
    }
    for i in 0..n {
        for j in 0..n {
            m[i * n + j] /= d[i] * d[j];
        }
    }
    let eig = symmetric_eigenvalues(m, n);
    let (min, max) = eig
        .iter()
        .fold((f64::INFINITY, 0f64), |(lo, hi), &e| (lo.min(e), hi.max(e)));
    if min <= 0.0 {
        f64::INFINITY
    } else {
        max / min
    }
}

/// Eigenvalues of a small symmetric matrix (row-major `n x n`) by cyclic Jacobi rotations.
pub fn symmetric_eigenvalues(mut m: Vec<f64>, n: usize) -> Vec<f64> {
    for _ in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| m[i * n + j] * m[i * n + j])
            .sum();
        let diag: f64 = (0..n).map(|i| m[i * n + i] * m[i * n + i]).sum();
        if off <= 1e-30 * diag.max(f64::MIN_POSITIVE) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = m[p * n + q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (m[q * n + q] - m[p * n + p]) / (2.0 * apq);
                let sign = if theta >= 0.0 { 1.0 } else { -1.0 };
                let t = sign / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (mkp, mkq) = (m[k * n + p], m[k * n + q]);
                    m[k * n + p] = c * mkp - s * mkq;
                    m[k * n + q] = s * mkp + c * mkq;
                }
                for k in 0..n {
                    let (mpk, mqk) = (m[p * n + k], m[q * n + k]);
                    m[p * n + k] = c * mpk - s * mqk;
                    m[q * n + k] = s * mpk + c * mqk;
                }
            }
        }
    }
    (0..n).map(|i| m[i * n + i]).collect()
}

/// The statistics of one sub-trajectory length over its accepted windows.
#[derive(Debug, Clone)]
pub struct WindowSummary {
    /// Sub-trajectory length (m).
    pub length: f64,
    /// Windows of this length.
    pub windows: usize,
    /// Windows whose estimates are used.
    pub accepted: usize,
    /// Failed windows per [`WindowFailure::code`], in order of first occurrence.
    pub failures: Vec<(&'static str, usize)>,
    /// Statistics of [`WINDOW_PARAMS`] over the accepted windows.
    pub stats: [Summary; 3],
}

/// The per-length statistics of a study (lengths increasing): failed windows left out.
pub fn summarize_windows(est: &[WindowEstimate]) -> Vec<WindowSummary> {
    let mut lengths: Vec<f64> = est.iter().map(|e| e.length).collect();
    lengths.sort_by(f64::total_cmp);
    lengths.dedup();
    lengths
        .into_iter()
        .map(|l| {
            let all: Vec<&WindowEstimate> = est.iter().filter(|e| e.length == l).collect();
            let ok: Vec<[f64; 4]> = all
                .iter()
                .filter_map(|e| e.estimate.as_ref().ok().copied())
                .collect();
            let mut failures: Vec<(&'static str, usize)> = Vec::new();
            for f in all.iter().filter_map(|e| e.estimate.as_ref().err()) {
                match failures.iter_mut().find(|(c, _)| *c == f.code()) {
                    Some((_, n)) => *n += 1,
                    None => failures.push((f.code(), 1)),
                }
            }
            WindowSummary {
                length: l,
                windows: all.len(),
                accepted: ok.len(),
                failures,
                stats: [0, 1, 2].map(|p| summarize(&ok.iter().map(|v| v[p]).collect::<Vec<_>>())),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::csvio::match_times;
    use crate::simulate::{default_truth, simulate_path, PathKind, SimSettings};

    #[test]
    fn jacobi_eigenvalues_of_a_known_matrix() {
        // [[2, 1, 0], [1, 2, 0], [0, 0, 5]]: eigenvalues 1, 3, 5.
        let mut e = symmetric_eigenvalues(vec![2.0, 1.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 5.0], 3);
        e.sort_by(f64::total_cmp);
        for (got, want) in e.iter().zip([1.0, 3.0, 5.0]) {
            assert!((got - want).abs() < 1e-12, "{e:?}");
        }
    }

    /// The study of the simulated 70 m run from the paper's poor first estimate, both starts:
    /// no window at a bound or undetermined reaches the statistics, every failed window says
    /// why, and the accepted 4 m and 8 m windows' means are close to the truth.
    #[test]
    #[allow(clippy::needless_range_loop)]
    fn failed_windows_are_reported_and_kept_out_of_the_statistics() {
        let truth = default_truth();
        let sim = simulate_path(PathKind::Estimation, 70.0, truth, SimSettings::default());
        let run = Run::new(
            &sim.samples,
            &sim.reference,
            match_times(&sim.samples, &sim.reference),
        );
        let poor = ChassisParams {
            left_diameter: 0.3,
            right_diameter: 0.3,
            track_width: 0.7,
            ..truth
        };
        let full = fit_geometry(
            &run,
            &poor,
            run.heading_guess(0),
            0,
            run.len() - 1,
            GeomOptions::default(),
            &ProgressBar::hidden(),
        )
        .unwrap();
        let t = [truth.left_diameter, truth.right_diameter, truth.track_width];
        for start in [WindowStart::Initial, WindowStart::Full] {
            let est = windows_study(
                &run,
                &full,
                &poor,
                &[1.0, 2.0, 4.0, 8.0],
                start,
                &ProgressBar::hidden(),
            )
            .unwrap();
            let mut bound = 0;
            for e in &est {
                match &e.estimate {
                    Ok(v) => {
                        for p in 0..3 {
                            assert!(
                                v[p] > 0.02
                                    && v[p] < 5.0
                                    && e.std_errors[p] / v[p] <= MAX_RELATIVE_SE,
                                "{start:?}: accepted {e:?}"
                            );
                        }
                        assert!(e.condition <= MAX_CONDITION, "{e:?}");
                    }
                    Err(f) => {
                        assert!(f.to_string().len() > 10, "{f:?}");
                        bound += usize::from(matches!(f, WindowFailure::Bound { .. }));
                        // The fit's values, not used, are still there for the CSV.
                        if !matches!(f, WindowFailure::Fit(_)) {
                            assert!(e.fitted.is_some(), "{e:?}");
                        }
                    }
                }
            }
            // The short windows' fits do run into the bounds: the check is not idle.
            assert!(bound > 0, "{start:?}: no window at a bound");
            let summary = summarize_windows(&est);
            assert_eq!(summary.len(), 4);
            for w in &summary {
                let accepted: Vec<&WindowEstimate> = est
                    .iter()
                    .filter(|e| e.length == w.length && e.accepted())
                    .collect();
                assert_eq!(w.accepted, accepted.len());
                assert_eq!(
                    w.failures.iter().map(|(_, n)| n).sum::<usize>(),
                    w.windows - w.accepted
                );
                for p in 0..3 {
                    assert_eq!(w.stats[p].n, w.accepted);
                    // No bound-hitting value among the statistics.
                    if w.accepted > 0 {
                        assert!(w.stats[p].min > 0.02 && w.stats[p].max < 5.0, "{w:?}");
                    }
                }
                if w.length >= 4.0 {
                    assert!(w.accepted >= 6, "{w:?}");
                    for p in 0..3 {
                        let s = &w.stats[p];
                        let tol = 3.0 * s.std / (s.n as f64).sqrt() + 2e-4;
                        assert!(
                            (s.mean - t[p]).abs() < tol,
                            "{start:?} {} m {}: mean {} truth {} tol {tol}",
                            w.length,
                            WINDOW_PARAMS[p],
                            s.mean,
                            t[p]
                        );
                    }
                }
            }
        }
    }
}
