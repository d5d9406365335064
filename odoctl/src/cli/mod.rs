//! The command line: clap's types of every subcommand and its options. The values are checked
//! as they are parsed ([`values`]); what a command does with them is in `commands/`, one
//! module per subcommand.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use odo_unit::odometry::UncertaintyModel;

mod calibrate;
mod pool;
mod reference;
mod ros;
mod simulate;
mod trajectory;
mod umbmark;
pub mod values;

pub use calibrate::{CalibrateArgs, GeometryArgs};
pub use pool::PoolArgs;
pub use reference::{PosTimeArg, ReceiverArgs, ReferenceArgs, ReferenceCmdArgs};
pub use ros::RosNameArgs;
pub use simulate::SimulateArgs;
pub use trajectory::TrajectoryArgs;
pub use umbmark::UmbmarkArgs;

use values as v;

/// Host tool of the odometry unit: stream, configure, replay, simulate, calibrate
#[derive(Parser)]
#[command(name = "odoctl", version)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub cmd: Cmd,
}

/// The link to the unit.
#[derive(Args, Clone)]
pub struct PortArgs {
    /// Serial port (`/dev/ttyUSB0`) or TCP socket of the QEMU image (`tcp:127.0.0.1:PORT`).
    #[arg(long, short)]
    pub port: String,
    /// Baud rate of a serial port.
    #[arg(long, default_value_t = 115_200, value_parser = v::baud)]
    pub baud: u32,
}

/// The chassis parameters: a file and overrides.
#[derive(Args, Clone)]
pub struct ParamArgs {
    /// Parameter file (TOML, shared key names); the designed values when absent.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Set a parameter, `KEY=VALUE` (repeatable; after `--config`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
}

/// The subcommands.
#[derive(Subcommand)]
pub enum Cmd {
    /// Show the live pose stream as a table; report CRC errors, sequence gaps, dropped records.
    Monitor(MonitorArgs),
    /// Record the live pose stream to a SAMPLES CSV (with the unit's pose columns).
    Record(RecordArgs),
    /// Decode a captured raw byte stream to a SAMPLES CSV.
    Decode(DecodeArgs),
    /// Read and change the unit's settings.
    Config(ConfigArgs),
    /// Run the core integrator over recorded counts; CSV `t,x,y,heading,sigma_x,sigma_y,sigma_heading` to stdout.
    Replay(ReplayArgs),
    /// Estimate the chassis parameters from a run and its RTK GNSS reference (eq 16).
    Calibrate(CalibrateArgs),
    /// Errors of calibrated parameters on another run, against their predicted uncertainty.
    Validate(ValidateArgs),
    /// Write a synthetic run (SAMPLES and REFERENCE CSVs) with known true parameters.
    Simulate(SimulateArgs),
    /// Publish the live pose on ROS 2 (/odom, /tf, /joint_states, /diagnostics, a reset_pose
    /// service) over DDS (docs/ROS.md).
    Bridge(BridgeArgs),
    /// Fit the diameters and track width to square runs and a straight measured on the floor.
    Umbmark(UmbmarkArgs),
    /// Inspect a reference (receiver log, RTKLIB solution, CSV); `--to` converts its track.
    Reference(ReferenceCmdArgs),
    /// Pool several drives' calibration results into one set of parameters.
    Pool(PoolArgs),
}

/// `odoctl monitor`.
#[derive(Args)]
pub struct MonitorArgs {
    /// The link.
    #[command(flatten)]
    pub port: PortArgs,
    /// Stop after this many seconds.
    #[arg(long, allow_negative_numbers = true, value_parser = v::duration)]
    pub duration: Option<f64>,
    /// Stop after this many pose records.
    #[arg(long, value_parser = v::count)]
    pub count: Option<u64>,
    /// Print every N-th record only.
    #[arg(long, default_value_t = 1, value_parser = v::count)]
    pub every: u64,
}

/// `odoctl record`.
#[derive(Args)]
pub struct RecordArgs {
    /// The link.
    #[command(flatten)]
    pub port: PortArgs,
    /// Output SAMPLES CSV.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Also keep the raw byte stream (for `decode`).
    #[arg(long)]
    pub raw: Option<PathBuf>,
    /// Stop after this many seconds.
    #[arg(long, allow_negative_numbers = true, value_parser = v::duration)]
    pub duration: Option<f64>,
    /// Stop after this many pose records.
    #[arg(long, value_parser = v::count)]
    pub count: Option<u64>,
    /// Send `reset_pose` first, so the recording starts at zero pose and zero sigmas and
    /// `replay --check` can reproduce it bit for bit.
    #[arg(long)]
    pub reset_pose: bool,
    /// Also write the unit's poses as ROS 2 topics (/odom, /tf, /diagnostics) to this
    /// MCAP file once recording ends (docs/ROS.md); the twist needs the unit's parameters
    /// (`--config`, `--set`).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// The unit's parameters, for the twist of `--mcap` and as `--calibrate`'s initial
    /// estimate.
    #[command(flatten)]
    pub params: ParamArgs,
    /// Frames, topics and joints of `--mcap`.
    #[command(flatten)]
    pub ros: RosNameArgs,
    /// Calibrate while recording (docs/CALIBRATION.md): the sub-trajectory fit follows the
    /// records and the forwarded sentences, shown once a second with what is still missing
    /// against `--target-se`; when the drive ends (Ctrl-C, `--duration`, `--count`, the end
    /// of the link) `calibrate` runs on the recording, from `--config`/`--set` as its initial
    /// estimate, and writes `--result`.
    #[arg(long)]
    pub calibrate: bool,
    /// Standard errors `--calibrate` aims at, `DIAMETER,TRACK`: each wheel diameter's and the
    /// track width's, as lengths with `mm` (also without a unit), `um` or `m`; default
    /// `0.05mm,0.5mm`.
    #[arg(long, value_parser = v::target_se, requires = "calibrate")]
    pub target_se: Option<v::Targets>,
    /// Where `--calibrate` writes the result (TOML, as `calibrate --out`).
    #[arg(long, requires = "calibrate")]
    pub result: Option<PathBuf>,
}

/// `odoctl decode`.
#[derive(Args)]
pub struct DecodeArgs {
    /// Raw capture.
    pub file: PathBuf,
    /// Output CSV (stdout when absent).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

/// `odoctl config`.
#[derive(Args)]
pub struct ConfigArgs {
    /// The link.
    #[command(flatten)]
    pub port: PortArgs,
    /// What to do.
    #[command(subcommand)]
    pub action: ConfigAction,
}

/// What `config` does.
#[derive(Subcommand, Clone)]
pub enum ConfigAction {
    /// Print one setting, or all.
    Get {
        /// Key (all settings when absent).
        key: Option<String>,
    },
    /// Change a setting (in RAM; `save` makes it permanent).
    Set {
        /// Key.
        key: String,
        /// Value.
        #[arg(allow_negative_numbers = true)]
        value: String,
    },
    /// Store the settings in flash.
    Save,
    /// Send a parameter file (a calibration result, or unit options) in atomic `set` lines,
    /// then `save` unless `--no-save`.
    Push {
        /// TOML file with the shared key names.
        file: PathBuf,
        /// Do not save to flash.
        #[arg(long)]
        no_save: bool,
    },
    /// Write the unit's settings (its `get` reply) to a TOML file that `push` sends back
    /// bit for bit.
    Pull {
        /// TOML file to write.
        file: PathBuf,
    },
    /// Send any command line and print the reply.
    Raw {
        /// The command line, e.g. `status`.
        line: Vec<String>,
    },
}

/// `odoctl replay`.
#[derive(Args)]
pub struct ReplayArgs {
    /// SAMPLES CSV.
    pub samples: PathBuf,
    /// The chassis parameters.
    #[command(flatten)]
    pub params: ParamArgs,
    /// Initial x (m).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::position)]
    pub x: f64,
    /// Initial y (m).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::position)]
    pub y: f64,
    /// Initial heading (rad, clockwise from +y).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::heading)]
    pub heading: f64,
    /// Compare with the unit's own pose columns of the file, bit for bit; exit non-zero
    /// on any difference.
    #[arg(long)]
    pub check: bool,
    /// Write the CSV here instead of stdout.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Also record the replay as ROS 2 topics (/odom, /tf, /diagnostics) in this MCAP
    /// file (docs/ROS.md).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Frames, topics and joints of `--mcap`.
    #[command(flatten)]
    pub ros: RosNameArgs,
}

/// `odoctl validate`.
#[derive(Args)]
pub struct ValidateArgs {
    /// SAMPLES CSV; repeat with `--reference` for an ensemble of runs.
    #[arg(long, required_unless_present = "runs")]
    pub samples: Vec<PathBuf>,
    /// Reference: REFERENCE CSV, NMEA 0183 log, u-blox UBX log or RTKLIB `.pos` file (one per
    /// `--samples`). Default for one run: the recording's NMEA log beside `--samples`
    /// (`run.csv` -> `run.nmea`, as `record` writes it), its times checked against the
    /// samples'.
    #[arg(long)]
    pub reference: Vec<PathBuf>,
    /// A list of runs, one `SAMPLES REFERENCE` a line: the ensemble coverage by distance.
    #[arg(long, conflicts_with_all = ["samples", "reference"])]
    pub runs: Option<PathBuf>,
    /// Checkpoints of the ensemble coverage (m of reference path from each start).
    #[arg(long, value_delimiter = ',', default_values_t = crate::calib::CHECKPOINTS)]
    pub checkpoints: Vec<f64>,
    /// How `--reference` is read.
    #[command(flatten)]
    pub reference_input: ReferenceArgs,
    /// The calibrated parameters.
    #[command(flatten)]
    pub params: ParamArgs,
    /// Initial heading (rad); when absent, the heading minimising eq (16) on this run.
    #[arg(long, allow_negative_numbers = true, value_parser = v::heading)]
    pub heading: Option<f64>,
    /// Per-point errors and sigmas to this CSV.
    #[arg(long)]
    pub errors: Option<PathBuf>,
    /// Write PNG figures (trajectory, horizontal and heading error with bands) here.
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Which uncertainty models to evaluate (with the coefficients of the file): the file's
    /// `uncertainty_model` (`config`), one, or `all` to compare their coverage.
    #[arg(long, value_enum, default_value_t = Models::Config)]
    pub models: Models,
    /// Horizontal RMS noise of one reference epoch (m): `hypot(sigma_east, sigma_north)`, each
    /// axis carrying 1/sqrt(2) of it; epochs whose log gives its own sigmas use those. Also
    /// reported is the coverage of the bands widened by it, `k sqrt(sigma_h^2 +
    /// sigma_ref^2)`, as the calibration's criterion uses. Default as `calibrate`'s: against
    /// one trajectory (TUM, ROS 2 MCAP) its own noise from its poses' second differences, else
    /// (and with `--ensemble`) 0.008.
    #[arg(long, allow_negative_numbers = true, value_parser = v::sigma_m)]
    pub reference_sigma: Option<f64>,
    /// Noise of one reference heading (degrees, 1 sigma): also reported is the coverage of
    /// the heading bands widened by it, as `calibrate`'s `delta_diff` criterion uses. Default
    /// as `calibrate`'s: a trajectory's own, else 0.5.
    #[arg(long, allow_negative_numbers = true, value_parser = v::sigma_deg)]
    pub reference_heading_sigma_deg: Option<f64>,
    /// Also write the reference track and the odometry path (`nav_msgs/Path`) to this
    /// MCAP file, for Foxglove (docs/ROS.md).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
}

/// `odoctl bridge`.
#[derive(Args)]
pub struct BridgeArgs {
    /// The link.
    #[command(flatten)]
    pub port: PortArgs,
    /// The unit's parameters, for the twist from the counts.
    #[command(flatten)]
    pub params: ParamArgs,
    /// Stop after this many seconds.
    #[arg(long, allow_negative_numbers = true, value_parser = v::duration)]
    pub duration: Option<f64>,
    /// Stop after this many published records.
    #[arg(long, value_parser = v::count)]
    pub count: Option<u64>,
    /// Seconds between reconnection attempts, and without records before the status
    /// turns STALE.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true, value_parser = v::retry)]
    pub retry: f64,
    /// Also serve the Foxglove WebSocket protocol (pose, path so far, 1-sigma ellipse).
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<String>,
    /// Publish nothing over DDS (Foxglove only).
    #[arg(long, requires = "foxglove")]
    pub no_dds: bool,
    /// Send MAVLink 2 ODOMETRY and HEARTBEAT instead (udpout:HOST:PORT or serial:PATH:BAUD),
    /// for a flight controller (docs/MAVLINK.md).
    #[arg(long, value_name = "TARGET", conflicts_with_all = ["foxglove", "no_dds"])]
    pub mavlink: Option<String>,
    /// Frames, topics, joints and TF.
    #[command(flatten)]
    pub ros: RosNameArgs,
    /// ROS 2 node name.
    #[arg(long, default_value = "odoctl_bridge")]
    pub node_name: String,
}

/// One uncertainty model.
#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum ModelChoice {
    /// The paper's eqs (19)-(28).
    Paper,
    /// The first-order covariance propagation.
    Covariance,
}

/// A choice of uncertainty models.
#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum Models {
    /// The model named by the parameters (`uncertainty_model`).
    Config,
    /// The paper's eqs (19)-(28).
    Paper,
    /// The first-order covariance propagation.
    Covariance,
    /// Both.
    All,
}

impl Models {
    /// The models named; empty for `config` (the parameters' own).
    pub fn list(self) -> Vec<UncertaintyModel> {
        match self {
            Self::Config => vec![],
            Self::Paper => vec![UncertaintyModel::Paper],
            Self::Covariance => vec![UncertaintyModel::Covariance],
            Self::All => vec![UncertaintyModel::Paper, UncertaintyModel::Covariance],
        }
    }
}
