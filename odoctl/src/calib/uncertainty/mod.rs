//! The uncertainty coefficients: kappa of the unit's covariance model (by default), delta and
//! `delta_diff` of the paper's model.
//!
//! By default the covariance model's kappa is the slip of the largest likelihood under the
//! Kalman filter ([`likelihood`], `--uncertainty-criterion likelihood`; the filter is
//! [`crate::calib::filter`]). The paper's model, and the covariance model with
//! `--uncertainty-criterion coverage`, take the paper's coverage criterion ([`coverage`]): the
//! run is cut into consecutive sub-trajectories, each restarted from the reference with the
//! heading minimising eq (16) over it ([`restarts`]), and the coefficient is the smallest for
//! which the 1-sigma band, widened by the reference noise, covers 68.27 % of the horizontal
//! errors; `delta_diff` then by the heading-change coverage, delta refitted with it
//! ([`delta_diff`]).
//!
//! # Files
//! - `coefficients.rs`: which coefficients, how the wheels' relate, by which criterion, and
//!   the result.
//! - `likelihood.rs`: kappa by the filter's likelihood.
//! - `coverage.rs`: the coverage criterion.
//! - `restarts.rs`: the restarted sub-trajectories the coverage fits share.
//! - `delta_diff.rs`: `delta_diff` by the heading-change coverage.
//! - `reference_noise.rs`: the reference's noise as stated and as the data show it, and the
//!   bands widened by it that `calibrate` and `validate` report.

pub mod coefficients;
pub mod coverage;
pub mod delta_diff;
pub mod likelihood;
pub mod reference_noise;
pub mod restarts;
