//! Studies of a calibration beside the pipeline.
//!
//! # Files
//! - `stability.rs`: the stability study, the eq (16) fit repeated on sub-trajectories of
//!   several lengths (the paper's Figs. 7-9; `calibrate --windows`).
//! - `ensemble.rs`: the coverage of the predicted uncertainty over an ensemble of runs by
//!   distance travelled (`validate` on several runs, the ensemble test).

pub mod ensemble;
pub mod stability;
