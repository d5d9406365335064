//! `odoctl`: the host tool of the odometry unit. See `odoctl --help` and `odoctl/README.md`.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};

use odo_core::odometry::UncertaintyModel;
use odoctl::calib::{CalibrationOptions, DeltaMode, UncertaintyCriterion, WindowStart};
use odoctl::cli_values as v;
use odoctl::reference::cli::{ReceiverArgs, ReferenceArgs};
use odoctl::simulate::{PathKind, SimSettings};

#[derive(Parser)]
#[command(
    name = "odoctl",
    version,
    about = "Host tool of the odometry unit: stream, configure, replay, simulate, calibrate"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Args, Clone)]
struct PortArgs {
    /// Serial port (`/dev/ttyUSB0`) or TCP socket of the QEMU image (`tcp:127.0.0.1:PORT`).
    #[arg(long, short)]
    port: String,
    /// Baud rate of a serial port.
    #[arg(long, default_value_t = 115_200, value_parser = v::baud)]
    baud: u32,
}

#[derive(Args, Clone)]
struct ParamArgs {
    /// Parameter file (TOML, shared key names); the designed values when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Set a parameter, `KEY=VALUE` (repeatable; after `--config`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
}

#[derive(Subcommand)]
enum Cmd {
    /// Show the live pose stream as a table; report CRC errors, sequence gaps, dropped records.
    Monitor {
        #[command(flatten)]
        port: PortArgs,
        /// Stop after this many seconds.
        #[arg(long, allow_negative_numbers = true, value_parser = v::duration)]
        duration: Option<f64>,
        /// Stop after this many pose records.
        #[arg(long, value_parser = v::count)]
        count: Option<u64>,
        /// Print every N-th record only.
        #[arg(long, default_value_t = 1, value_parser = v::count)]
        every: u64,
    },
    /// Record the live pose stream to a SAMPLES CSV (with the unit's pose columns).
    Record {
        #[command(flatten)]
        port: PortArgs,
        /// Output SAMPLES CSV.
        #[arg(long, short)]
        out: PathBuf,
        /// Also keep the raw byte stream (for `decode`).
        #[arg(long)]
        raw: Option<PathBuf>,
        /// Stop after this many seconds.
        #[arg(long, allow_negative_numbers = true, value_parser = v::duration)]
        duration: Option<f64>,
        /// Stop after this many pose records.
        #[arg(long, value_parser = v::count)]
        count: Option<u64>,
        /// Send `reset_pose` first, so the recording starts at zero pose and zero sigmas and
        /// `replay --check` can reproduce it bit for bit.
        #[arg(long)]
        reset_pose: bool,
        /// Also write the unit's poses as ROS 2 topics (/odom, /tf, /diagnostics) to this
        /// MCAP file once recording ends (docs/ROS.md); the twist needs the unit's parameters
        /// (`--config`, `--set`).
        #[arg(long)]
        mcap: Option<PathBuf>,
        #[command(flatten)]
        params: ParamArgs,
    },
    /// Decode a captured raw byte stream to a SAMPLES CSV.
    Decode {
        /// Raw capture.
        file: PathBuf,
        /// Output CSV (stdout when absent).
        #[arg(long, short)]
        out: Option<PathBuf>,
    },
    /// Read and change the unit's settings.
    Config {
        #[command(flatten)]
        port: PortArgs,
        #[command(subcommand)]
        action: ConfigAction,
    },
    /// Run the core integrator over recorded counts; CSV `t,x,y,heading,sigma_x,sigma_y,sigma_heading` to stdout.
    Replay {
        /// SAMPLES CSV.
        samples: PathBuf,
        #[command(flatten)]
        params: ParamArgs,
        /// Initial x (m).
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::position)]
        x: f64,
        /// Initial y (m).
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::position)]
        y: f64,
        /// Initial heading (rad, clockwise from +y).
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::heading)]
        heading: f64,
        /// Compare with the unit's own pose columns of the file, bit for bit; exit non-zero
        /// on any difference.
        #[arg(long)]
        check: bool,
        /// Write the CSV here instead of stdout.
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Also record the replay as ROS 2 topics (/odom, /tf, /diagnostics) in this MCAP
        /// file (docs/ROS.md).
        #[arg(long)]
        mcap: Option<PathBuf>,
    },
    /// Estimate the chassis parameters from a run and its RTK GNSS reference (eq 16).
    Calibrate(CalibrateArgs),
    /// Errors of calibrated parameters on another run, against their predicted uncertainty.
    Validate {
        /// SAMPLES CSV; repeat with `--reference` for an ensemble of runs.
        #[arg(long, required_unless_present = "runs")]
        samples: Vec<PathBuf>,
        /// Reference: REFERENCE CSV, NMEA 0183 log or RTKLIB `.pos` file (one per `--samples`).
        #[arg(long, required_unless_present = "runs")]
        reference: Vec<PathBuf>,
        /// A list of runs, one `SAMPLES REFERENCE` a line: the ensemble coverage by distance.
        #[arg(long, conflicts_with_all = ["samples", "reference"])]
        runs: Option<PathBuf>,
        /// Checkpoints of the ensemble coverage (m of reference path from each start).
        #[arg(long, value_delimiter = ',', default_values_t = odoctl::calib::CHECKPOINTS)]
        checkpoints: Vec<f64>,
        #[command(flatten)]
        reference_input: ReferenceArgs,
        #[command(flatten)]
        params: ParamArgs,
        /// Initial heading (rad); when absent, the heading minimising eq (16) on this run.
        #[arg(long, allow_negative_numbers = true, value_parser = v::heading)]
        heading: Option<f64>,
        /// Per-point errors and sigmas to this CSV.
        #[arg(long)]
        errors: Option<PathBuf>,
        /// Write PNG figures (trajectory, horizontal and heading error with bands) here.
        #[arg(long)]
        plots: Option<PathBuf>,
        /// Which uncertainty models to evaluate (with the coefficients of the file): the file's
        /// `uncertainty_model` (`config`), one, or `all` to compare their coverage.
        #[arg(long, value_enum, default_value_t = Models::Config)]
        models: Models,
        /// Horizontal RMS noise of the reference (m): also reported is the coverage of the
        /// bands widened by it, `sqrt((k sigma_h)^2 + (k sigma_ref)^2)`, as the calibration's
        /// criterion uses.
        #[arg(long, default_value_t = 0.008, allow_negative_numbers = true, value_parser = v::sigma_m)]
        reference_sigma: f64,
        /// Heading noise of the reference (degrees, 1 sigma): also reported is the coverage of
        /// the heading bands widened by it, as `calibrate`'s `delta_diff` criterion uses.
        #[arg(long, default_value_t = 0.5, allow_negative_numbers = true, value_parser = v::sigma_deg)]
        reference_heading_sigma_deg: f64,
        /// Also write the reference track and the odometry path (`nav_msgs/Path`) to this
        /// MCAP file, for Foxglove (docs/ROS.md).
        #[arg(long)]
        mcap: Option<PathBuf>,
    },
    /// Write a synthetic run (SAMPLES and REFERENCE CSVs) with known true parameters.
    Simulate(SimulateArgs),
    /// Publish the live pose on ROS 2 (/odom, /tf, /diagnostics) over DDS (docs/ROS.md).
    Bridge {
        #[command(flatten)]
        port: PortArgs,
        /// The unit's parameters, for the twist from the counts.
        #[command(flatten)]
        params: ParamArgs,
        /// Stop after this many seconds.
        #[arg(long, allow_negative_numbers = true, value_parser = v::duration)]
        duration: Option<f64>,
        /// Stop after this many published records.
        #[arg(long, value_parser = v::count)]
        count: Option<u64>,
        /// Seconds between reconnection attempts, and without records before the status
        /// turns STALE.
        #[arg(long, default_value_t = 1.0, allow_negative_numbers = true, value_parser = v::retry)]
        retry: f64,
        /// Also serve the Foxglove WebSocket protocol (pose, path so far, 1-sigma ellipse).
        #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
        foxglove: Option<String>,
        /// Publish nothing over DDS (Foxglove only).
        #[arg(long, requires = "foxglove")]
        no_dds: bool,
    },
}

/// One uncertainty model.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ModelChoice {
    /// The paper's eqs (19)-(28).
    Paper,
    /// The first-order covariance propagation.
    Covariance,
}

/// A choice of uncertainty models.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Models {
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
    fn list(self) -> Vec<UncertaintyModel> {
        match self {
            Self::Config => vec![],
            Self::Paper => vec![UncertaintyModel::Paper],
            Self::Covariance => vec![UncertaintyModel::Covariance],
            Self::All => vec![UncertaintyModel::Paper, UncertaintyModel::Covariance],
        }
    }
}

#[derive(Subcommand, Clone)]
enum ConfigAction {
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

#[derive(Args)]
struct CalibrateArgs {
    /// SAMPLES CSV of the estimation run.
    #[arg(long)]
    samples: PathBuf,
    /// Reference (RTK GNSS) of the same run: REFERENCE CSV, NMEA 0183 log or RTKLIB `.pos`.
    #[arg(long)]
    reference: PathBuf,
    #[command(flatten)]
    reference_input: ReferenceArgs,
    #[command(flatten)]
    geometry: odoctl::commands::GeometryArgs,
    /// First estimate (TOML, shared keys); the designed values when absent.
    #[arg(long)]
    initial: Option<PathBuf>,
    /// Override a key of the first estimate, `KEY=VALUE` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
    /// Write the result here (TOML: shared keys at top level, the fit's figures in `[fit]`).
    #[arg(long, short)]
    out: Option<PathBuf>,
    /// Sub-trajectory length for the uncertainty fit (m of reference path; 0 = whole run).
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true, value_parser = v::window)]
    delta_window: f64,
    /// Horizontal RMS noise of the reference (m), added to sigma_h in the coverage criterion.
    #[arg(long, default_value_t = 0.008, allow_negative_numbers = true, value_parser = v::sigma_m)]
    reference_sigma: f64,
    /// How the left and right uncertainty coefficients relate.
    #[arg(long, value_enum, default_value_t = DeltaMode::Equal)]
    delta_mode: DeltaMode,
    /// Skip the uncertainty fit (keep the initial coefficients).
    #[arg(long)]
    no_delta: bool,
    /// Keep the initial `delta_diff` instead of fitting it. By default, when the paper's model
    /// is fitted and the reference has a heading column, `delta_diff` is fitted so that the
    /// 1-sigma heading band covers 68.27 % of the heading errors, and delta refitted after it.
    #[arg(long)]
    no_fit_delta_diff: bool,
    /// Reference heading noise (degrees, 1 sigma), added to sigma_heading in the `delta_diff`
    /// criterion; the default is `simulate --heading-sigma-deg`'s (a BD982-like dual antenna).
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true, value_parser = v::sigma_deg)]
    reference_heading_sigma_deg: f64,
    /// Which uncertainty models' coefficients to fit: both (`all`, the default), one, or the
    /// initial estimate's `uncertainty_model` (`config`).
    #[arg(long, value_enum, default_value_t = Models::All)]
    models: Models,
    /// The model the result selects (`uncertainty_model`). Default: `covariance` (the model
    /// that holds its coverage against the truth in the ensemble test), or with `--models
    /// config` the initial estimate's.
    #[arg(long, value_enum)]
    uncertainty_model: Option<ModelChoice>,
    /// How the uncertainty coefficients are fitted: `likelihood` (maximum likelihood of the
    /// errors of restarted sub-trajectories, start headings not fitted to them) or
    /// `coverage` (the paper's statistical fitting: the 1-sigma band covers 68.27 %).
    #[arg(long, value_enum, default_value_t = UncertaintyCriterion::Likelihood)]
    uncertainty_criterion: UncertaintyCriterion,
    /// Add a Nelder-Mead polish of eq (16) after the Newton fit (up to 600 integrator runs;
    /// it finds only the cost's arithmetic noise, about 1e-7 of it).
    #[arg(long)]
    polish: bool,
    /// No Nelder-Mead polish (the default; kept for old scripts).
    #[arg(long, hide = true, conflicts_with = "polish")]
    no_polish: bool,
    /// Stability study: sub-trajectory lengths in metres, e.g. `1,2,4,8`.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true, value_parser = v::window_length)]
    windows: Vec<f64>,
    /// Where the stability study's fits start: the whole-run estimate (`full`), or the
    /// initial estimate as the paper did (`initial`).
    #[arg(long, value_enum, default_value_t = WindowStart::Full)]
    window_start: WindowStart,
    /// Estimate the per-angle wheel function (eqs 3-5): the first N harmonics (1..=3) of each
    /// wheel, `left_cos1..N`, `left_sin1..N`, `right_...`, referenced to the index line, with
    /// the geometry fit's result kept (its corrections refitted alongside as nuisances); needs
    /// SAMPLES with the `left_index`, `right_index` columns.
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=3))]
    wheel_harmonics: u8,
    /// Segment length of the wheel-function fit (m of reference path; each segment restarted
    /// from the reference).
    #[arg(long, default_value_t = odoctl::calib::HARMONICS_SEGMENT)]
    harmonics_window: f64,
    /// Per-sub-trajectory estimates of the stability study to this CSV.
    #[arg(long)]
    windows_out: Option<PathBuf>,
    /// Write PNG figures here (Figs. 4-6 of the paper; 7-8 with `--windows`).
    #[arg(long)]
    plots: Option<PathBuf>,
    /// No progress bars.
    #[arg(long, short)]
    quiet: bool,
    /// Also write the result as ros2_control diff_drive_controller parameters (YAML:
    /// wheel_separation, wheel_radius, the wheel radius multipliers; docs/ROS.md).
    #[arg(long, requires = "out")]
    export_ros: Option<PathBuf>,
    /// Also write the reference track and the calibrated odometry path (`nav_msgs/Path`, the
    /// paper's Fig. 4) to this MCAP file, as `validate --mcap` with the result (docs/ROS.md).
    #[arg(long, requires = "out")]
    mcap: Option<PathBuf>,
}

#[derive(Args)]
struct SimulateArgs {
    /// Output SAMPLES CSV.
    #[arg(long)]
    samples: PathBuf,
    /// Output REFERENCE CSV.
    #[arg(long)]
    reference: PathBuf,
    /// True parameters (TOML); the paper's final estimates (0.2608, 0.2607, 0.5656 m) when absent.
    #[arg(long = "true")]
    truth: Option<PathBuf>,
    /// Override a true parameter, `KEY=VALUE` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
    /// Write the true parameters to this TOML.
    #[arg(long)]
    truth_out: Option<PathBuf>,
    /// Path shape.
    #[arg(long, value_enum, default_value_t = PathKind::Estimation)]
    path: PathKind,
    /// Path length (m; the shape is scaled to it).
    #[arg(long, default_value_t = 70.0, allow_negative_numbers = true, value_parser = v::path_length)]
    length: f64,
    /// Sample rate (Hz).
    #[arg(long, default_value_t = 50.0, allow_negative_numbers = true, value_parser = v::sample_rate)]
    rate: f64,
    /// Speed (m/s).
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true, value_parser = v::speed)]
    speed: f64,
    /// Slip: standard deviation of each wheel's relative turn error.
    #[arg(long, default_value_t = 0.001, allow_negative_numbers = true, value_parser = v::fraction)]
    slip: f64,
    /// Correlation length of the slip (m of wheel travel).
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true, value_parser = v::correlation_length)]
    slip_corr: f64,
    /// Opposite-phase slip when turning (what `delta_diff` models): standard deviation of the
    /// relative error of the differential travel |ds1 - ds2|/2, added to wheel 1 and taken
    /// from wheel 2; 0 = none.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::fraction)]
    slip_turn: f64,
    /// Correlation length of the turning slip (m of differential travel |ds1 - ds2|/2).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true, value_parser = v::correlation_length)]
    slip_turn_corr: f64,
    /// Horizontal RMS noise of the reference position (m); the BD982's RTK figure.
    #[arg(long, default_value_t = 0.008, allow_negative_numbers = true, value_parser = v::sigma_m)]
    rtk_sigma: f64,
    /// Noise of the reference heading (degrees).
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true, value_parser = v::sigma_deg)]
    heading_sigma_deg: f64,
    /// Write no heading column in the reference.
    #[arg(long)]
    no_heading: bool,
    /// Initial x (m).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::position)]
    x0: f64,
    /// Initial y (m).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::position)]
    y0: f64,
    /// Initial heading (rad).
    #[arg(long, default_value_t = 0.3, allow_negative_numbers = true, value_parser = v::heading)]
    heading0: f64,
    /// Seed of the noise generator.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[command(flatten)]
    receiver: ReceiverArgs,
}

fn main() -> ExitCode {
    // Freed large vectors stay in the heap (see odoctl::memory): before any thread starts.
    odoctl::memory::keep_freed_memory();
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            let broken_pipe = e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            });
            if broken_pipe {
                // The reader of our output went away (`odoctl monitor ... | head`): not an error.
                return ExitCode::SUCCESS;
            }
            let _ = std::io::stdout().flush();
            eprintln!("odoctl: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    use odoctl::commands as c;
    match cli.cmd {
        Cmd::Monitor {
            port,
            duration,
            count,
            every,
        } => c::monitor(&port.port, port.baud, duration, count, every),
        Cmd::Record {
            port,
            out,
            raw,
            duration,
            count,
            reset_pose,
            mcap,
            params,
        } => {
            let code = c::record(
                &port.port,
                port.baud,
                &out,
                raw.as_deref(),
                duration,
                count,
                reset_pose,
            )?;
            if let Some(m) = &mcap {
                odoctl::ros::export::record_hook(m, &out, params.config.as_deref(), &params.sets)?;
            }
            Ok(code)
        }
        Cmd::Decode { file, out } => c::decode(&file, out.as_deref()),
        Cmd::Config { port, action } => {
            let action = match action {
                ConfigAction::Get { key } => c::ConfigAction::Get(key),
                ConfigAction::Set { key, value } => c::ConfigAction::Set(key, value),
                ConfigAction::Save => c::ConfigAction::Save,
                ConfigAction::Push { file, no_save } => c::ConfigAction::Push(file, !no_save),
                ConfigAction::Pull { file } => c::ConfigAction::Pull(file),
                ConfigAction::Raw { line } => c::ConfigAction::Raw(line.join(" ")),
            };
            c::config(&port.port, port.baud, action)
        }
        Cmd::Replay {
            samples,
            params,
            x,
            y,
            heading,
            check,
            out,
            mcap,
        } => {
            if let Some(m) = &mcap {
                odoctl::ros::export::replay_hook(
                    m,
                    &samples,
                    params.config.as_deref(),
                    &params.sets,
                    (x, y, heading),
                )?;
            }
            c::replay(
                &samples,
                params.config.as_deref(),
                &params.sets,
                (x, y, heading),
                check,
                out.as_deref(),
            )
        }
        Cmd::Calibrate(a) => {
            let ros = a.export_ros.clone().zip(a.out.clone());
            let tracks = a.mcap.clone().zip(a.out.clone());
            let files = (a.samples.clone(), a.reference.clone());
            let reference_input = a.reference_input.clone();
            let code = c::calibrate(
                &c::CalibrateOptions {
                    samples: a.samples,
                    reference: a.reference,
                    initial: a.initial,
                    sets: a.sets,
                    out: a.out,
                    windows_out: a.windows_out,
                    plots: a.plots,
                    geometry: a.geometry,
                    calibration: CalibrationOptions {
                        delta_window: a.delta_window,
                        reference_sigma: a.reference_sigma,
                        delta_mode: a.delta_mode,
                        fit_delta: !a.no_delta,
                        fit_delta_diff: !a.no_fit_delta_diff,
                        reference_heading_sigma: a.reference_heading_sigma_deg.to_radians(),
                        models: a.models.list(),
                        select: match (a.uncertainty_model, a.models) {
                            (Some(ModelChoice::Paper), _) => Some(UncertaintyModel::Paper),
                            (Some(ModelChoice::Covariance), _) => {
                                Some(UncertaintyModel::Covariance)
                            }
                            (None, Models::Config) => None,
                            (None, Models::Paper) => Some(UncertaintyModel::Paper),
                            (None, _) => Some(UncertaintyModel::Covariance),
                        },
                        criterion: a.uncertainty_criterion,
                        polish: a.polish && !a.no_polish,
                        windows: a.windows,
                        window_start: a.window_start,
                        wheel_harmonics: usize::from(a.wheel_harmonics),
                        harmonics_window: a.harmonics_window,
                        quiet: a.quiet,
                        ..Default::default()
                    },
                },
                &a.reference_input,
            )?;
            if let Some((yaml, result)) = &ros {
                odoctl::ros::diff_drive::export_hook(yaml, result)?;
            }
            if let Some((m, result)) = &tracks {
                odoctl::ros::tracks::validate_hook(
                    m,
                    &files.0,
                    &files.1,
                    &reference_input,
                    Some(result),
                    &[],
                    None,
                )?;
            }
            Ok(code)
        }
        Cmd::Validate {
            samples,
            reference,
            runs,
            checkpoints,
            params,
            plots,
            models,
            reference_sigma,
            reference_heading_sigma_deg,
            reference_input,
            mcap,
            ..
        } if runs.is_some() || samples.len() > 1 || reference.len() > 1 => {
            if mcap.is_some() {
                anyhow::bail!(
                    "--mcap takes one run (--samples and --reference once), not an ensemble"
                );
            }
            let list = match &runs {
                Some(f) => c::read_run_list(f),
                None if samples.len() == reference.len() => {
                    Ok(samples.into_iter().zip(reference).collect())
                }
                None => Err(anyhow::anyhow!(
                    "--samples and --reference: give them in pairs ({} and {})",
                    samples.len(),
                    reference.len()
                )),
            };
            list.and_then(|list| {
                c::validate_ensemble(
                    &c::EnsembleOptions {
                        runs: list,
                        config: params.config.as_deref(),
                        sets: &params.sets,
                        models: &models.list(),
                        reference_sigma,
                        reference_heading_sigma: reference_heading_sigma_deg.to_radians(),
                        checkpoints,
                        plots: plots.as_deref(),
                    },
                    &reference_input,
                )
            })
        }
        Cmd::Validate {
            samples,
            reference,
            params,
            heading,
            errors,
            plots,
            models,
            reference_sigma,
            reference_heading_sigma_deg,
            reference_input,
            mcap,
            ..
        } => {
            if let Some(m) = &mcap {
                odoctl::ros::tracks::validate_hook(
                    m,
                    &samples[0],
                    &reference[0],
                    &reference_input,
                    params.config.as_deref(),
                    &params.sets,
                    heading,
                )?;
            }
            c::validate(
                &samples[0],
                &reference[0],
                params.config.as_deref(),
                &params.sets,
                heading,
                errors.as_deref(),
                plots.as_deref(),
                &models.list(),
                reference_sigma,
                reference_heading_sigma_deg.to_radians(),
                &reference_input,
            )
        }
        Cmd::Bridge {
            port,
            params,
            duration,
            count,
            retry,
            foxglove,
            no_dds,
        } => {
            let secs = |what: &str, v: f64| {
                std::time::Duration::try_from_secs_f64(v)
                    .map_err(|_| anyhow::anyhow!("--{what} {v}: not a duration in seconds"))
            };
            odoctl::ros::bridge::run(&odoctl::ros::bridge::BridgeOptions {
                port: port.port,
                baud: port.baud,
                params: odoctl::config::load(params.config.as_deref(), &params.sets)?,
                duration: duration.map(|d| secs("duration", d)).transpose()?,
                count,
                retry: secs("retry", retry)?,
                foxglove,
                dds: !no_dds,
            })
        }
        Cmd::Simulate(a) => c::simulate(
            &c::SimulateOptions {
                samples: a.samples,
                reference: a.reference,
                truth: a.truth,
                sets: a.sets,
                truth_out: a.truth_out,
                path: a.path,
                length: a.length,
                settings: SimSettings {
                    rate: a.rate,
                    speed: a.speed,
                    slip: a.slip,
                    slip_corr: a.slip_corr,
                    slip_turn: a.slip_turn,
                    slip_turn_corr: a.slip_turn_corr,
                    rtk_sigma: a.rtk_sigma,
                    heading_sigma: (!a.no_heading).then(|| a.heading_sigma_deg.to_radians()),
                    start: (a.x0, a.y0, a.heading0),
                    seed: a.seed,
                },
            },
            &a.receiver,
        ),
    }
}
