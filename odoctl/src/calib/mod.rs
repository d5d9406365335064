//! Calibration against a reference trajectory (RTK GNSS): the wheel diameters and the track
//! width with their uncertainty, the uncertainty coefficients of the unit's covariance model
//! and of the paper's model, the stability study on sub-trajectories (the paper's Figs. 7-9),
//! and the error evaluation that `validate` uses.
//!
//! All odometry goes through the core integrator, so a calibrated run is bit-consistent with
//! what the unit computes.
//!
//! # The pipeline ([`calibrate`])
//! 1. **Geometry** ([`geometry`]). The run is cut into sub-trajectories of 10 m of reference
//!    path; each restarts the odometry, its start position and heading fitted as nuisance
//!    parameters, while the diameters and the track width are shared
//!    ([`fit_subtrajectories`]): slip drift never accumulates beyond one sub-trajectory. The
//!    likelihood's Kalman filter then refines that estimate by generalised least squares,
//!    every observation weighted by the slip's noise, where its linearisation holds
//!    ([`geometry::refinement`]); its covariance is the geometry's uncertainty the unit
//!    carries (else the sub-trajectories' cluster-robust one). The documented alternative is
//!    the paper's eq (16) over the whole run (`--method paper`, [`fit_geometry`]). With
//!    `--wheel-harmonics`, the per-angle wheel function follows as a second stage.
//! 2. **Uncertainty** ([`uncertainty`]). The covariance model's kappa is the slip of the
//!    largest likelihood of the reference's observations under an error-state Kalman filter
//!    along the whole run ([`filter`]), each innovation scored on a prediction from the
//!    observations before it only. The paper's model (and the covariance model with
//!    `--uncertainty-criterion coverage`) takes the paper's coverage criterion: the smallest
//!    coefficient whose 1-sigma band, widened by the reference noise, covers 68.27 % of the
//!    horizontal errors of restarted sub-trajectories; `delta_diff` by the heading-change
//!    coverage. `odoctl calibrate` fits both models and selects the covariance model.
//! 3. **Evaluation** of the whole run with the result ([`evaluate`]), and on request the
//!    stability study ([`studies`]).
//!
//! # Files
//! The matched run, which every layer uses:
//! - `run.rs`: [`Run`], a run matched to its reference: path length, a stretch's anchor and
//!   start heading, the core integrator along it (pose, uncertainty, sensitivities), the
//!   residuals against the reference and their normal equations; the stretches of a run.
//! - `sensitivity.rs`: the pose's forward sensitivities to the geometry unknowns;
//!   `pipeline.rs`: their pass on two cores.
//! - `antenna.rs`: the reference antenna's lever arm: the observed point and its derivatives.
//! - `heading_fit.rs`: the start heading of a stretch minimising eq (16), the geometry held.
//! - `evaluation.rs`: errors and predicted uncertainty along a run.
//! - `pooling.rs`: several drives' calibrations pooled into one (`odoctl pool`).
//!
//! The layers, each using only the matched run and the layers before it:
//! - [`filter`]: the likelihood's Kalman filter, which the geometry's refinement and the
//!   kappa fit share (`innovations.rs`, `blocks.rs`, `kalman.rs`, `search.rs`);
//! - [`geometry`]: `subtrajectory.rs`, `refinement.rs`, `paper.rs`, `covariance.rs`,
//!   `turning.rs`, `wheel_harmonics.rs`;
//! - [`uncertainty`]: `coefficients.rs`, `likelihood.rs`, `coverage.rs`, `restarts.rs`,
//!   `delta_diff.rs`, `reference_noise.rs`;
//! - [`studies`]: `stability.rs`, `ensemble.rs`;
//! - `calibration.rs`: all of it in memory ([`calibrate`]);
//! - `live.rs`: the sub-trajectory fit as the data arrive ([`live::LiveCalibration`], `record
//!   --calibrate`).
//!
//! The items the rest of `odoctl`, the benchmarks and the tests use are re-exported here.

pub mod antenna;
pub mod calibration;
pub mod evaluation;
pub mod filter;
pub mod geometry;
pub mod heading_fit;
pub mod live;
pub mod pipeline;
pub mod pooling;
pub mod run;
pub mod sensitivity;
pub mod studies;
pub mod uncertainty;
pub mod warm;

#[cfg(test)]
mod testing;

pub use antenna::{read_lever_arm, LeverArm};
pub use calibration::{
    calibrate, calibrate_with, Calibration, CalibrationOptions, Method, PhaseTimer,
    DEFAULT_REFERENCE_HEADING_SIGMA_DEG, DEFAULT_REFERENCE_SIGMA,
};
pub use evaluation::{evaluate, Evaluation};
pub use filter::innovations::{Innovations, MAX_OBSERVATIONS};
pub use geometry::paper::{fit_geometry, GeomFit, GeomOptions};
pub use geometry::refinement::{FilterRefinement, GeometryRefine};
pub use geometry::subtrajectory::{
    fit_subtrajectories, Cuts, SubtrajectoryFit, SubtrajectoryOptions, SUBTRAJECTORY_LENGTH,
};
pub use geometry::wheel_harmonics::{fit_harmonics, HarmonicsFit, HARMONICS_SEGMENT};
pub use heading_fit::fit_heading;
pub use run::Run;
pub use sensitivity::GEOMETRY_UNKNOWNS;
pub use studies::ensemble::{CheckpointCoverage, CheckpointSample, Ensemble, CHECKPOINTS};
pub use studies::stability::{
    summarize_windows, windows_study, WindowEstimate, WindowFailure, WindowStart, WindowSummary,
    WINDOW_PARAMS,
};
pub use uncertainty::coefficients::{DeltaMode, DiffFit, UncertaintyCriterion, UncertaintyFit};
pub use uncertainty::coverage::{heading_coverage, heading_points, ONE_SIGMA_COVERAGE};
pub use uncertainty::reference_noise::{NoiseCheck, ReferenceNoise};
pub use warm::{Extras, WarmStart};
