//! Calibration against a reference trajectory (RTK GNSS): eq (16) of the paper for the wheel
//! diameters and the track width, the uncertainty coefficients by a coverage criterion, the
//! stability study on sub-trajectories (the paper's Figs. 7-9), and the error evaluation used
//! by `validate`.
//!
//! All odometry goes through the core integrator, so a calibrated run is bit-consistent with
//! what the unit computes.
//!
//! # Geometry (eq 16)
//! The unknowns are `left_diameter`, `right_diameter`, `track_width` and the initial heading;
//! the initial position is the reference point at the first common time (when the counts
//! show the chassis standing still there, the mean of the reference points over that
//! standstill: the same position with the RTK noise averaged out). The cost is
//! `e = sum_i |p_odo(i) - p_ref(i)|` over all common times. The minimisation:
//! 1. continuation: Levenberg-Marquardt on the squared distances over a growing prefix of the
//!    trajectory (2 m of reference path, then x1.5 per stage up to the whole run), each stage
//!    starting from the previous one's result; a poor first estimate (0.300/0.300/0.700 m)
//!    would otherwise wind the odometry around the reference and trap the fit;
//! 2. damped Newton on eq (16) itself: gradient `sum J_k^T u_k`, Hessian
//!    `sum J_k^T (I - u_k u_k^T) J_k / |r_k|` (`u_k` the unit residual), Levenberg-Marquardt
//!    damping, steps accepted only when eq (16) falls;
//! 3. optionally a Nelder-Mead polish of eq (16) with restarts; the lowest eq (16) is kept.
//!
//! Every Jacobian is analytic: the forward sensitivities of eqs (7)-(15) with respect to the
//! diameters, the track width and the initial heading are propagated in f64 in the same
//! pass as the core integrator ([`Run::integrate_with_sensitivity`]), which stays the one
//! source of the poses. At the estimate, [`standard_errors`] gives the unknowns' standard
//! errors and [`track_width_warning`] says when the run turned too little for the track
//! width.
//!
//! # Uncertainty coefficients
//! The trajectory is cut into consecutive sub-trajectories of `window` metres of reference
//! path. Each is restarted from the reference: position = the reference point, heading = the
//! heading minimising eq (16) over that sub-trajectory (a noisy reference heading would swamp
//! the odometry error), sigmas = 0. At every later common time of the sub-trajectory the
//! horizontal error `e` and the predicted `sigma_h` are taken. The coefficient (`delta_left =
//! delta_right` for the paper's model, `kappa_left = kappa_right` for the covariance model;
//! equal by default, or their initial ratio kept) is the smallest value for which
//! `e <= sqrt(sigma_h^2 + sigma_ref^2)` holds at 68.27 % of those points (the 1-sigma band
//! covers the errors as often as a normal 1-sigma interval would); `sigma_ref` is the
//! reference's own horizontal noise (8 mm RMS for the BD982; 0 to ignore it).
//!
//! For the paper's model with a reference heading, [`fit_delta_diff`] then fits `delta_diff`
//! on the same sub-trajectories by the heading-change coverage, with delta refitted jointly.
//!
//! # Files
//! `run` (a run matched to its reference, the integrator along it), `sensitivity` (forward
//! sensitivities), `pipeline` (their two-core pass), `geometry` (the eq 16 fit), `evaluation`
//! (errors and predicted uncertainty), `restarts` (the restarted sub-trajectories),
//! `uncertainty` (delta, kappa), `delta_diff`, `harmonics` (the per-angle wheel function), `refine` (the filter's refinement of the sub-trajectory geometry), `stability` (the study on sub-trajectories) and
//! `calibration` (all of it in memory: [`calibrate`]).

mod antenna;
mod calibration;
mod covariance;
mod delta_diff;
mod ensemble;
mod evaluation;
mod filter_blocks;
mod geometry;
mod harmonics;
mod innovations;
mod pipeline;
mod refine;
mod restarts;
mod run;
mod sensitivity;
mod slip_fit;
mod stability;
mod subtrajectory;
mod uncertainty;

pub use antenna::*;
pub use calibration::*;
pub use covariance::*;
pub use delta_diff::*;
pub use ensemble::*;
pub use evaluation::*;
pub use geometry::*;
pub use harmonics::*;
pub use innovations::*;
pub use pipeline::*;
pub use refine::*;
pub use restarts::*;
pub use run::*;
pub use sensitivity::*;
pub use slip_fit::*;
pub use stability::*;
pub use subtrajectory::*;
pub use uncertainty::*;

#[cfg(test)]
mod tests;
