//! The stability study: the calibration repeated on sub-trajectories (the paper's Figs. 7-9).

use anyhow::Result;
use indicatif::ProgressBar;
use odo_core::odometry::ChassisParams;

use super::*;

/// Where the stability study's fits start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WindowStart {
    /// From the initial estimate, as the paper did (Fig. 7).
    Initial,
    /// From the full-trajectory estimate.
    Full,
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
    /// The estimate (left_diameter, right_diameter, track_width, heading0), or why it failed;
    /// the track width is NaN where the sub-trajectory turned too little to determine it.
    pub estimate: Result<[f64; 4], String>,
    /// Eq (16) per point at the estimate (m).
    pub mean_error: f64,
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
        let (estimate, mean_error) = match fit {
            Ok(f) => (
                Ok([
                    f.params.left_diameter,
                    f.params.right_diameter,
                    if f.track_estimated {
                        f.params.track_width
                    } else {
                        f64::NAN
                    },
                    f.heading0,
                ]),
                f.cost / f.points as f64,
            ),
            Err(e) => (Err(e.to_string()), f64::NAN),
        };
        out.push(WindowEstimate {
            length,
            start_dist: run.dist[a],
            t: (run.reference_at(a).t, run.reference_at(b).t),
            turning,
            points: b - a,
            estimate,
            mean_error,
        });
        progress.inc(1);
    }
    Ok(out)
}
