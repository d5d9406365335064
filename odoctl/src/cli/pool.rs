//! The options of `odoctl pool`.

use std::path::PathBuf;

use clap::Args;

/// `odoctl pool`.
#[derive(Clone, Args)]
pub struct PoolArgs {
    /// The drives' calibration results (TOML, as `calibrate --out` writes them, covariance
    /// model); at least two.
    #[arg(required = true, num_args = 2..)]
    pub results: Vec<PathBuf>,
    /// Output parameter TOML: the pooled parameters, `[fit]` with each drive's figures.
    #[arg(long, short)]
    pub out: PathBuf,
}
