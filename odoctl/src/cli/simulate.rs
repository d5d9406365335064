//! The options of `odoctl simulate`.

use std::path::PathBuf;

use clap::Args;

use super::values as v;
use super::{ReceiverArgs, TrajectoryArgs};
use crate::simulate::PathKind;

/// `odoctl simulate`.
#[derive(Args)]
pub struct SimulateArgs {
    /// Output SAMPLES CSV.
    #[arg(long)]
    pub samples: PathBuf,
    /// Output REFERENCE CSV.
    #[arg(long)]
    pub reference: PathBuf,
    /// True parameters (TOML); the paper's final estimates (0.2608, 0.2607, 0.5656 m) when absent.
    #[arg(long = "true")]
    pub truth: Option<PathBuf>,
    /// Override a true parameter, `KEY=VALUE` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    /// Write the true parameters to this TOML.
    #[arg(long)]
    pub truth_out: Option<PathBuf>,
    /// Path shape.
    #[arg(long, value_enum, default_value_t = PathKind::Estimation)]
    pub path: PathKind,
    /// Path length (m; the shape is scaled to it).
    #[arg(long, default_value_t = 70.0, allow_negative_numbers = true, value_parser = v::path_length)]
    pub length: f64,
    /// Sample rate (Hz).
    #[arg(long, default_value_t = 50.0, allow_negative_numbers = true, value_parser = v::sample_rate)]
    pub rate: f64,
    /// Speed (m/s).
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true, value_parser = v::speed)]
    pub speed: f64,
    /// Slip: standard deviation of each wheel's relative turn error.
    #[arg(long, default_value_t = 0.001, allow_negative_numbers = true, value_parser = v::fraction)]
    pub slip: f64,
    /// Correlation length of the slip (m of wheel travel).
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true, value_parser = v::correlation_length)]
    pub slip_corr: f64,
    /// Opposite-phase slip when turning (what `delta_diff` models): standard deviation of the
    /// relative error of the differential travel |ds1 - ds2|/2, added to wheel 1 and taken
    /// from wheel 2; 0 = none.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::fraction)]
    pub slip_turn: f64,
    /// Correlation length of the turning slip (m of differential travel |ds1 - ds2|/2).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true, value_parser = v::correlation_length)]
    pub slip_turn_corr: f64,
    /// Horizontal RMS noise of the reference position (m); the BD982's RTK figure.
    #[arg(long, default_value_t = 0.008, allow_negative_numbers = true, value_parser = v::sigma_m)]
    pub rtk_sigma: f64,
    /// Noise of the reference heading (degrees).
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true, value_parser = v::sigma_deg)]
    pub heading_sigma_deg: f64,
    /// Write no heading column in the reference.
    #[arg(long)]
    pub no_heading: bool,
    /// Initial x (m).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::position)]
    pub x0: f64,
    /// Initial y (m).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::position)]
    pub y0: f64,
    /// Initial heading (rad).
    #[arg(long, default_value_t = 0.3, allow_negative_numbers = true, value_parser = v::heading)]
    pub heading0: f64,
    /// Seed of the noise generator.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The receiver logs to write beside the CSVs.
    #[command(flatten)]
    pub receiver: ReceiverArgs,
    /// The trajectory references to write beside the CSVs.
    #[command(flatten)]
    pub trajectory: TrajectoryArgs,
}
