//! The error-state Kalman filter of the likelihood of the reference's observations, which
//! both the geometry's refinement and the covariance model's kappa use.
//!
//! The odometry is integrated once along the whole run; the filter carries its pose error,
//! the geometry's relative errors (a wide prior) and the slip's states, observes the
//! reference's positions averaged over each metre of path (and its headings), and scores the
//! innovations: each on a prediction from the observations before it only. The slip of the
//! largest likelihood (white, or Gauss-Markov profiled over its correlation length, and
//! opposite-phase slip when turning, each kept only on a likelihood-ratio test) is the
//! covariance model's kappa; the filter's estimate of the geometry's errors at it refines the
//! geometry.
//!
//! # Files
//! - `innovations.rs`: [`Innovations`](innovations::Innovations), the run prepared for the
//!   likelihood (steps, observations, the linearisation about the filter's own estimate), its
//!   scores and the slip of the largest likelihood.
//! - `blocks.rs`: the filter's transition composed over the steps between two observations.
//! - `kalman.rs`: the filter over the composed blocks: prediction, update, score.
//! - `search.rs`: the one-dimensional searches of the likelihood (slip rate, correlation
//!   length).

pub mod blocks;
pub mod innovations;
pub mod kalman;
pub mod search;
