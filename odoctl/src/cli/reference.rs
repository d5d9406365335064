//! The options of the reference input: those `calibrate` and `validate` add to `--reference`
//! ([`ReferenceArgs`]), those of `odoctl reference` ([`ReferenceCmdArgs`]), and those
//! `simulate` adds to write receiver logs ([`ReceiverArgs`]).

use std::path::PathBuf;

use clap::Args;

use super::values as v;
use crate::reference::summary::ExportFormat;
use crate::reference::{Format, MinFix};

/// `odoctl reference`.
#[derive(Debug, Clone, Args)]
pub struct ReferenceCmdArgs {
    /// The reference: REFERENCE CSV, NMEA 0183 log, u-blox UBX log or RTKLIB `.pos` file.
    pub file: PathBuf,
    /// How the file is read (the fix-quality filter and origin apply to `--to` and the origin).
    #[command(flatten)]
    pub input: ReferenceArgs,
    /// Write the used epochs in this format (to `--output`, else stdout) instead of the summary.
    #[arg(long, value_enum)]
    pub to: Option<ExportFormat>,
    /// File of `--to`.
    #[arg(long, short, requires = "to")]
    pub output: Option<PathBuf>,
}

/// How `--reference` is read (`calibrate`, `validate`).
#[derive(Debug, Clone, Args)]
pub struct ReferenceArgs {
    /// Format of `--reference`; recognised from the content when absent.
    #[arg(long, value_enum)]
    pub reference_format: Option<Format>,
    /// Least fix quality of the receiver log's epochs that are used.
    #[arg(long, value_enum, default_value_t = MinFix::Fixed)]
    pub min_fix: MinFix,
    /// Origin of the local plane, `LAT,LON,H` (degrees, degrees, metres ellipsoidal); by
    /// default the mean of the log's opening standstill (its first used epoch when it starts
    /// moving).
    #[arg(long, value_name = "LAT,LON,H", allow_hyphen_values = true)]
    pub origin: Option<String>,
    /// GPS - UTC (s) for every UTC time of the log (NMEA, RTKLIB in UTC); by default each
    /// epoch's from its date by the built-in leap-second table (18 since 2017-01-01).
    #[arg(long, allow_negative_numbers = true, value_parser = v::leap_seconds)]
    pub leap_seconds: Option<i32>,
    /// Topic of an MCAP reference (PoseStamped, Odometry or TFMessage); by default its only
    /// PoseStamped or Odometry topic.
    #[arg(long, value_name = "TOPIC")]
    pub reference_topic: Option<String>,
    /// Parent and child frame of the transforms of a TFMessage topic, `PARENT,CHILD`.
    #[arg(long, value_name = "PARENT,CHILD")]
    pub reference_frames: Option<String>,
    /// Clock offset of a trajectory reference (TUM, MCAP): the samples' t minus the
    /// reference's stamp at the same instant, at the middle of the stamps (s); estimated from
    /// the turning when absent.
    #[arg(long, value_name = "SECONDS", allow_negative_numbers = true, value_parser = v::time_offset)]
    pub time_offset: Option<f64>,
    /// Clock rate of a trajectory reference: d(samples' t)/d(stamp) - 1 (ppm); estimated from
    /// the turning when absent.
    #[arg(long, value_name = "PPM", allow_negative_numbers = true, value_parser = v::clock_ppm)]
    pub clock_ppm: Option<f64>,
}

/// Receiver logs of a simulated run (`simulate`).
#[derive(Debug, Clone, Args)]
pub struct ReceiverArgs {
    /// Also write the reference receiver's NMEA 0183 log (GGA, GST, HDT, RMC, ZDA).
    #[arg(long, value_name = "FILE")]
    pub nmea: Option<PathBuf>,
    /// Also write the reference as an RTKLIB `.pos` solution.
    #[arg(long, value_name = "FILE")]
    pub pos: Option<PathBuf>,
    /// Time columns of `--pos`.
    #[arg(long, value_enum, default_value_t = PosTimeArg::Calendar)]
    pub pos_time: PosTimeArg,
    /// Antenna position from the axle centre, `FORWARD,LEFT` (m): the reference (CSV, NMEA,
    /// `.pos`) is the antenna's path.
    #[arg(long, value_name = "F,L", allow_hyphen_values = true)]
    pub antenna: Option<String>,
    /// Epoch rate of the receiver logs (Hz; a divisor of `--rate`).
    #[arg(long, default_value_t = 10.0, value_parser = v::gnss_rate)]
    pub gnss_rate: f64,
    /// Share of 2-s blocks of RTK-float epochs in the receiver logs.
    #[arg(long, default_value_t = 0.1, value_parser = v::fraction)]
    pub float_fraction: f64,
    /// Horizontal RMS noise of RTK-float epochs (m).
    #[arg(long, default_value_t = 0.05, value_parser = v::sigma_m)]
    pub float_sigma: f64,
    /// WGS84 position of the local origin in the logs, `LAT,LON,H`.
    #[arg(
        long = "gnss-origin",
        value_name = "LAT,LON,H",
        allow_hyphen_values = true
    )]
    pub origin: Option<String>,
    /// GPS week and time of week (s) of the run's start in the logs, `WEEK,TOW`; the SAMPLES
    /// and REFERENCE CSVs then carry GPS time of week, as `record` writes it.
    #[arg(long, value_name = "WEEK,TOW")]
    pub gps_start: Option<String>,
    /// GPS - UTC (s) written into the NMEA log's UTC times; by default the leap-second
    /// table's at the run's start, as the reader takes it.
    #[arg(long = "gnss-leap-seconds", value_parser = v::leap_seconds)]
    pub leap_seconds: Option<i32>,
}

/// `--pos-time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PosTimeArg {
    /// `yyyy/mm/dd hh:mm:ss.sss` GPST.
    Calendar,
    /// `week tow`.
    WeekTow,
}
