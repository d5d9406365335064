//! The geometry: the wheel diameters and the track width (and the antenna lever arm with
//! `--fit-antenna`), with their standard errors.
//!
//! The default estimator is the sub-trajectory fit ([`subtrajectory`]): the run is cut into
//! sub-trajectories of 10 m of reference path, each restarted with its own start position and
//! heading, the chassis shared; least squares on the observed point's x and y differences from
//! the reference, cluster-robust standard errors over the sub-trajectories. The Kalman filter
//! of the likelihood then refines that estimate by its generalised least squares
//! ([`refinement`], `--geometry-refine filter`), where its linearisation holds; its covariance
//! is the geometry's uncertainty the unit carries.
//!
//! The alternative is the paper's estimator ([`paper`], `--method paper`): eq (16), the sum of
//! the distances between odometry and reference over the whole run, minimised by continuation
//! and damped Newton from the initial estimate; cluster-robust standard errors over stretches
//! of the run.
//!
//! With `--wheel-harmonics`, a second stage estimates the per-angle wheel function
//! ([`wheel_harmonics`]): it is part of the chassis geometry the unit applies (the relative
//! radius of each wheel by its angle), fitted after the diameters and the track width.
//!
//! # Files
//! - `subtrajectory.rs`: the sub-trajectory estimator and where it cuts the run.
//! - `refinement.rs`: the filter's refinement of the sub-trajectory estimate.
//! - `paper.rs`: the eq (16) estimator and its standard errors.
//! - `covariance.rs`: covariance of an estimate from its normal equations (formal,
//!   cluster-robust sandwich and jackknife).
//! - `turning.rs`: how much a stretch turned, and the track width's warning.
//! - `wheel_harmonics.rs`: the per-angle wheel function.

pub mod covariance;
pub mod paper;
pub mod refinement;
pub mod subtrajectory;
pub mod turning;
pub mod wheel_harmonics;
