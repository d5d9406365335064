//! Simulated runs for the calibration's unit tests.

use crate::calib::run::Run;
use crate::csvio::match_times;
use crate::simulate::{self, default_truth, PathKind, SimRun, SimSettings};

/// A simulated run of `length` metres of path `kind` with the truth's geometry and seed `seed`.
pub(crate) fn sim(kind: PathKind, length: f64, seed: u64) -> SimRun {
    let settings = SimSettings {
        seed,
        ..Default::default()
    };
    simulate::simulate_path(kind, length, default_truth(), settings)
}

/// The calibration's run of `s`, its rows matched by time ([`match_times`]).
pub(crate) fn run_of(s: &SimRun) -> Run<'_> {
    Run::new(
        &s.samples,
        &s.reference,
        match_times(&s.samples, &s.reference),
    )
}
