//! The options of `odoctl calibrate`.

use std::path::PathBuf;

use clap::Args;

use super::values as v;
use super::{ModelChoice, Models, ReferenceArgs};
use crate::calib::{self, DeltaMode, Method, UncertaintyCriterion, WindowStart};

/// `odoctl calibrate`.
#[derive(Args)]
pub struct CalibrateArgs {
    /// SAMPLES CSV of the estimation run.
    #[arg(long)]
    pub samples: PathBuf,
    /// Reference (RTK GNSS) of the same run: REFERENCE CSV, NMEA 0183 log, u-blox UBX log or
    /// RTKLIB `.pos`. Default: the recording's NMEA log beside `--samples` (`run.csv` ->
    /// `run.nmea`, as `record` writes it), its times checked against the samples'.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// How `--reference` is read.
    #[command(flatten)]
    pub reference_input: ReferenceArgs,
    /// The geometry method and the antenna lever arm.
    #[command(flatten)]
    pub geometry: GeometryArgs,
    /// First estimate (TOML, shared keys); the designed values when absent.
    #[arg(long)]
    pub initial: Option<PathBuf>,
    /// Override a key of the first estimate, `KEY=VALUE` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    /// Write the result here (TOML: shared keys at top level, the fit's figures in `[fit]`).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Sub-trajectory length for the uncertainty fit (m of reference path; 0 = whole run).
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true, value_parser = v::window)]
    pub delta_window: f64,
    /// Horizontal RMS noise of one reference epoch (m): `hypot(sigma_east, sigma_north)`, each
    /// axis carrying 1/sqrt(2) of it. Epochs whose log gives its own sigmas (GST, `.pos`
    /// `sdn`/`sde`, a `sigma_h` column) use those instead. The filter's likelihood and the
    /// coverage criteria take it as the reference's noise. Default: against a trajectory (TUM,
    /// ROS 2 MCAP) its own noise from its poses' second differences, else 0.008.
    #[arg(long, allow_negative_numbers = true, value_parser = v::sigma_m)]
    pub reference_sigma: Option<f64>,
    /// How the left and right uncertainty coefficients relate.
    #[arg(long, value_enum, default_value_t = DeltaMode::Equal)]
    pub delta_mode: DeltaMode,
    /// Skip the uncertainty fit (keep the initial coefficients).
    #[arg(long)]
    pub no_delta: bool,
    /// Keep the initial `delta_diff` instead of fitting it. By default, when the paper's model
    /// is fitted and the reference has a heading column, `delta_diff` is fitted so that the
    /// 1-sigma heading band covers 68.27 % of the heading errors, and delta refitted after it.
    #[arg(long)]
    pub no_fit_delta_diff: bool,
    /// Noise of one reference heading (degrees, 1 sigma), in the filter's likelihood and added
    /// to sigma_heading in the `delta_diff` criterion. Default: against a trajectory with
    /// headings its own heading noise from its poses' second differences, else 0.5 (`simulate
    /// --heading-sigma-deg`'s, a BD982-like dual antenna).
    #[arg(long, allow_negative_numbers = true, value_parser = v::sigma_deg)]
    pub reference_heading_sigma_deg: Option<f64>,
    /// Which uncertainty models' coefficients to fit: both (`all`, the default), one, or the
    /// initial estimate's `uncertainty_model` (`config`).
    #[arg(long, value_enum, default_value_t = Models::All)]
    pub models: Models,
    /// The model the result selects (`uncertainty_model`). Default: `covariance` (the model
    /// that holds its coverage against the truth in the ensemble test), or with `--models
    /// config` the initial estimate's.
    #[arg(long, value_enum)]
    pub uncertainty_model: Option<ModelChoice>,
    /// How the uncertainty coefficients are fitted: `likelihood` (maximum likelihood of the
    /// errors of restarted sub-trajectories, start headings not fitted to them) or
    /// `coverage` (the paper's statistical fitting: the 1-sigma band covers 68.27 %).
    #[arg(long, value_enum, default_value_t = UncertaintyCriterion::Likelihood)]
    pub uncertainty_criterion: UncertaintyCriterion,
    /// Add a Nelder-Mead polish of eq (16) after the Newton fit (up to 600 integrator runs;
    /// it finds only the cost's arithmetic noise, about 1e-7 of it).
    #[arg(long)]
    pub polish: bool,
    /// No Nelder-Mead polish (the default; kept for old scripts).
    #[arg(long, hide = true, conflicts_with = "polish")]
    pub no_polish: bool,
    /// Stability study: sub-trajectory lengths in metres, e.g. `1,2,4,8`.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true, value_parser = v::window_length)]
    pub windows: Vec<f64>,
    /// Where the stability study's fits start: the whole-run estimate (`full`), or the
    /// initial estimate as the paper did (`initial`).
    #[arg(long, value_enum, default_value_t = WindowStart::Full)]
    pub window_start: WindowStart,
    /// Estimate the per-angle wheel function (eqs 3-5): the first N harmonics (1..=3) of each
    /// wheel, `left_cos1..N`, `left_sin1..N`, `right_...`, referenced to the index line, with
    /// the geometry fit's result kept (its corrections refitted alongside as nuisances); needs
    /// SAMPLES with the `left_index`, `right_index` columns.
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=3))]
    pub wheel_harmonics: u8,
    /// Segment length of the wheel-function fit (m of reference path; each segment restarted
    /// from the reference).
    #[arg(long, default_value_t = calib::HARMONICS_SEGMENT)]
    pub harmonics_window: f64,
    /// Per-sub-trajectory estimates of the stability study to this CSV.
    #[arg(long)]
    pub windows_out: Option<PathBuf>,
    /// Write PNG figures here (Figs. 4-6 of the paper; 7-8 with `--windows`).
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
    /// Also write the result as ros2_control diff_drive_controller parameters (YAML:
    /// wheel_separation, wheel_radius, the wheel radius multipliers; docs/ROS.md).
    #[arg(long, requires = "out")]
    pub export_ros: Option<PathBuf>,
    /// Also write the reference track and the calibrated odometry path (`nav_msgs/Path`, the
    /// paper's Fig. 4) to this MCAP file, as `validate --mcap` with the result (docs/ROS.md).
    #[arg(long, requires = "out")]
    pub mcap: Option<PathBuf>,
}

/// How `calibrate` estimates the geometry: the method, its sub-trajectory length, the antenna
/// lever arm.
#[derive(Debug, Clone, Default, Args)]
pub struct GeometryArgs {
    /// Geometry estimator: `subtrajectory` (restarted every --subtrajectory-length metres, the
    /// default) or `paper` (eq 16 over the whole run).
    #[arg(long, value_enum, default_value_t = Method::Subtrajectory)]
    pub method: Method,
    /// Sub-trajectory length of the default method, and the stretches of the paper method's
    /// cluster-robust standard errors (m of reference path).
    #[arg(long, default_value_t = calib::SUBTRAJECTORY_LENGTH)]
    pub subtrajectory_length: f64,
    /// Where the default method cuts the run: `distance` (exactly every
    /// --subtrajectory-length metres, the default) or `straights` (near every
    /// --subtrajectory-length metres, at the point farthest from any turning, so that no arc
    /// or spin is split: better on short runs' track width, see docs/RESULTS.md).
    #[arg(long, value_enum, default_value_t = calib::Cuts::Distance)]
    pub subtrajectory_cuts: calib::Cuts,
    /// After the default method: `filter` (the default) refines the geometry by the Kalman
    /// filter of the kappa likelihood, which weights the turns by the slip's heading noise,
    /// where its linearisation holds (docs/CALIBRATION.md); `none` keeps the
    /// sub-trajectory estimate.
    #[arg(long, value_enum, default_value_t = calib::GeometryRefine::Filter)]
    pub geometry_refine: calib::GeometryRefine,
    /// Measured antenna position from the axle centre, `FORWARD,LEFT` (m, chassis frame):
    /// the reference is the antenna's path (held; the first guess with --fit-antenna).
    #[arg(long, value_name = "F,L", allow_hyphen_values = true)]
    pub antenna: Option<String>,
    /// Estimate the antenna lever arm with the geometry (standard errors in `[fit]`).
    #[arg(long)]
    pub fit_antenna: bool,
}
