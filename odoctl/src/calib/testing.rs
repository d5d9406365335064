//! Simulated runs for the calibration's unit tests.

use crate::simulate::{self, default_truth, PathKind, SimRun, SimSettings};

/// A simulated run of `length` metres of path `kind` with the truth's geometry and seed `seed`.
pub(crate) fn sim(kind: PathKind, length: f64, seed: u64) -> SimRun {
    let settings = SimSettings {
        seed,
        ..Default::default()
    };
    simulate::simulate_path(kind, length, default_truth(), settings)
}
