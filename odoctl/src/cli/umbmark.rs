//! The options of `odoctl umbmark`.

use std::path::PathBuf;

use clap::Args;

use super::ParamArgs;

/// `odoctl umbmark`.
#[derive(Clone, Args)]
pub struct UmbmarkArgs {
    /// The measurements file (TOML): the square's side, the measurement errors and, per run, its
    /// SAMPLES file, direction and measured end pose (odoctl/README.md).
    #[arg(long)]
    pub measurements: PathBuf,
    /// Output parameter TOML (as `calibrate --out` writes it).
    #[arg(long)]
    pub out: PathBuf,
    /// The initial chassis parameters (the designed ones by default).
    #[command(flatten)]
    pub params: ParamArgs,
}
