//! What a calibration takes beside its options in `record --calibrate` ([`Extras`]): a warm
//! start from an earlier calibration of the same drive on less data ([`WarmStart`]: the last
//! background batch's, for the next batch and for the final calibration), and a flag that
//! cancels it between its phases (the background batch's at the drive's end). The same flag
//! set as its thread's ([`cancel_this_thread_on`]) ends it inside its phases too.
//!
//! [`cancel_this_thread_on`]: crate::cancel::cancel_this_thread_on
//!
//! A warm start moves where the searches start, never what they look for:
//! - the sub-trajectory fit starts from the earlier fit's shared unknowns and its
//!   sub-trajectories' fitted start headings (matched by their first match: the drive is cut
//!   from its start, so the earlier sub-trajectories start where they did), takes over the
//!   earlier fit's last evaluation of a sub-trajectory whose data are the same (a 64-bit
//!   fingerprint of its samples and reference points: what evaluating it again at that point
//!   would give) and stops by the same rule, a predicted decrease of the cost below 1e-10 of
//!   it, which leaves it within a few thousandths of a standard error of the minimum from any
//!   start;
//! - the whole run's start heading is searched from the earlier one (one integration instead
//!   of two when the first sub-trajectory's is more than 0.01 rad from the result);
//! - the coverage criterion's bisection takes the earlier coefficient as its first guess, and
//!   its answer does not depend on the guess;
//! - the likelihood's one-dimensional searches (the filter refinement's and the covariance
//!   model's fit's) keep where the earlier fit's same search ended when it is still within
//!   their tolerance of the optimum, else search within [`WARM_REACH`] (in `ln`) of it, and
//!   as a cold fit does when the optimum is not inside; the kappa and `kappa_diff` the
//!   covariance model's fit reports are polished to 1e-6 in `ln` whatever the start.
//!
//! [`WARM_REACH`]: super::filter::search::WARM_REACH

use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{bail, Result};
use odo_unit::odometry::UncertaintyModel;

use crate::cancel::this_thread_cancelled;

use super::filter::search::Search;
use super::geometry::subtrajectory::SubtrajectoryStart;

/// Where an earlier calibration of the same drive left the searches
/// ([`Calibration::warm_start`](super::Calibration::warm_start)).
#[derive(Debug, Clone, PartialEq)]
pub struct WarmStart {
    /// The sub-trajectory fit's.
    pub subtrajectories: SubtrajectoryStart,
    /// The coverage criterion's fitted coefficients: the model and its `delta_left` or
    /// `kappa_left` (m or m^2 per m).
    pub coefficients: Vec<(UncertaintyModel, f64)>,
    /// The whole run's start heading (rad).
    pub heading0: f64,
    /// Where the likelihood's searches ended: the filter refinement's and the covariance
    /// model's likelihood fit's.
    pub likelihood: Vec<(Search, f64)>,
}

impl WarmStart {
    /// The coverage criterion's coefficient of model `m`, when it was fitted.
    pub fn coefficient(&self, m: UncertaintyModel) -> Option<f64> {
        self.coefficients
            .iter()
            .find(|(model, _)| *model == m)
            .map(|&(_, v)| v)
    }

    /// Where the likelihood's searches ended, for the next fit's (empty without a warm
    /// start).
    pub fn likelihood_searches(warm: Option<&Self>) -> Vec<(Search, f64)> {
        warm.map(|w| w.likelihood.clone()).unwrap_or_default()
    }
}

/// What a calibration takes beside its options (the module documentation); the default:
/// none of it.
#[derive(Debug, Clone, Copy, Default)]
pub struct Extras<'a> {
    /// Where the searches start.
    pub warm: Option<&'a WarmStart>,
    /// Once set, the calibration ends with an error at its next phase.
    pub cancel: Option<&'a AtomicBool>,
}

impl Extras<'_> {
    /// An error once the cancel flag (or this thread's, [`this_thread_cancelled`]) is set.
    pub fn check(&self) -> Result<()> {
        if self.cancel.is_some_and(|c| c.load(Ordering::Relaxed)) || this_thread_cancelled() {
            bail!("the calibration was cancelled");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::cancel::cancel_this_thread_on;

    /// The thread's flag cancels its calibrations between their phases too.
    #[test]
    fn the_threads_flag_cancels_between_phases() {
        let flag = Arc::new(AtomicBool::new(false));
        cancel_this_thread_on(Some(Arc::clone(&flag)));
        assert!(Extras::default().check().is_ok());
        flag.store(true, Ordering::Relaxed);
        assert!(Extras::default().check().is_err());
        cancel_this_thread_on(None);
        assert!(Extras::default().check().is_ok());
    }

    #[test]
    fn a_set_flag_cancels() {
        let flag = AtomicBool::new(false);
        let e = Extras {
            warm: None,
            cancel: Some(&flag),
        };
        assert!(e.check().is_ok());
        flag.store(true, Ordering::Relaxed);
        assert!(e.check().is_err());
        assert!(Extras::default().check().is_ok());
    }
}
