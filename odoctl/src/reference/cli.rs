//! The command-line face of the reference input: the options `calibrate` and `validate` add
//! to `--reference` ([`ReferenceArgs`]), those `simulate` adds to write receiver logs
//! ([`ReceiverArgs`]), and the calls the commands make ([`reference_for_samples`],
//! [`read_matched_run`], [`ReceiverArgs::prepare`] / [`ReceiverArgs::write`]).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use super::geodetic::{parse_origin, Geodetic};
use super::simulated::{self, PosTime, ReceiverSim};
use super::{
    antenna_position, gps_time, load, parse_antenna, Format, MinFix, OriginChoice, Reference,
    ReferenceOptions, TimeScale,
};
use crate::csvio::{self, RefPoint, Sample};
use crate::simulate::SimRun;

/// How `--reference` is read (`calibrate`, `validate`).
#[derive(Debug, Clone, clap::Args)]
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
    /// GPS - UTC (s) for the UTC times of NMEA logs (18 since 2017-01-01).
    #[arg(long, default_value_t = gps_time::DEFAULT_LEAP_SECONDS, allow_negative_numbers = true, value_parser = crate::cli_values::leap_seconds)]
    pub leap_seconds: i32,
}

impl ReferenceArgs {
    /// The loader's options.
    pub fn options(&self) -> Result<ReferenceOptions> {
        if !(0..=100).contains(&self.leap_seconds) {
            bail!("--leap-seconds {}: must be in 0..=100", self.leap_seconds);
        }
        Ok(ReferenceOptions {
            format: self.reference_format,
            min_fix: self.min_fix,
            origin: match &self.origin {
                Some(s) => OriginChoice::Given(parse_origin(s)?),
                None => OriginChoice::OpeningStandstill,
            },
            leap_seconds: self.leap_seconds,
        })
    }
}

/// Reads `--reference` of any format.
pub fn read_reference(path: &Path, args: &ReferenceArgs) -> Result<Reference> {
    load(path, &args.options()?)
}

/// The reference rows for these samples: a CSV as it is; a receiver log aligned to the
/// samples' time (refused when they do not overlap), with a summary of what was used on
/// stdout.
pub fn reference_for_samples(r: &Reference, samples: &[Sample]) -> Result<Vec<RefPoint>> {
    let points = r.ref_points(time_span(samples))?;
    print_summary(r);
    Ok(points)
}

/// The first and last sample's time (s), NaN when there is none.
fn time_span(samples: &[Sample]) -> (f64, f64) {
    (
        samples.first().map_or(f64::NAN, |s| s.t),
        samples.last().map_or(f64::NAN, |s| s.t),
    )
}

/// What of a receiver log was used, on stdout (nothing for a REFERENCE CSV).
fn print_summary(r: &Reference) {
    if r.time == TimeScale::Gps {
        crate::outln!("reference {} ({}): {}", r.file, r.format, r.report);
        if let Some(o) = r.origin {
            let how = match r.origin_epochs {
                0 => "given".to_string(),
                1 => "the first used epoch".to_string(),
                n => format!("the mean of the {n} epochs of the opening standstill"),
            };
            crate::outln!("  local origin {o} ({how}); x east, y north (m)");
        }
        if let Some(s) = r.median_horizontal_sigma() {
            crate::outln!(
                "  the log's own sigmas: median horizontal {s:.4} m (compare --reference-sigma)"
            );
        }
    }
}

/// One run read to judge its odometry against the reference (`validate`, `validate --mcap`).
#[derive(Debug, Clone)]
pub struct MatchedRun {
    /// SAMPLES rows.
    pub samples: Vec<Sample>,
    /// REFERENCE rows over the samples' time span (a receiver log aligned to them).
    pub reference: Vec<RefPoint>,
    /// (sample index, reference index) at common times, at least two.
    pub matches: Vec<(usize, usize)>,
}

/// Whether [`read_matched_run`] prints what of a receiver log it used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReferenceSummary {
    /// On stdout, as [`reference_for_samples`] does.
    Print,
    /// Not at all (a second reading of the same files).
    Quiet,
}

/// Reads a SAMPLES file and `--reference` of any format, the reference over the samples'
/// time span, and matches their times; fails naming both files when fewer than two times
/// are common.
pub fn read_matched_run(
    samples_path: &Path,
    reference_path: &Path,
    args: &ReferenceArgs,
    summary: ReferenceSummary,
) -> Result<MatchedRun> {
    let samples = csvio::read_samples(samples_path)?;
    let source = read_reference(reference_path, args)?;
    let reference = match summary {
        ReferenceSummary::Print => reference_for_samples(&source, &samples)?,
        ReferenceSummary::Quiet => source.ref_points(time_span(&samples))?,
    };
    let matches = csvio::match_or_fail(
        &samples,
        &samples_path.display().to_string(),
        &reference,
        &reference_path.display().to_string(),
        2,
    )?;
    Ok(MatchedRun {
        samples,
        reference,
        matches,
    })
}

/// Receiver logs of a simulated run (`simulate`).
#[derive(Debug, Clone, clap::Args)]
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
    #[arg(long, default_value_t = 10.0, value_parser = crate::cli_values::gnss_rate)]
    pub gnss_rate: f64,
    /// Share of 2-s blocks of RTK-float epochs in the receiver logs.
    #[arg(long, default_value_t = 0.1, value_parser = crate::cli_values::fraction)]
    pub float_fraction: f64,
    /// Horizontal RMS noise of RTK-float epochs (m).
    #[arg(long, default_value_t = 0.05, value_parser = crate::cli_values::sigma_m)]
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
    /// GPS - UTC (s) written into the NMEA log's UTC times.
    #[arg(long = "gnss-leap-seconds", default_value_t = gps_time::DEFAULT_LEAP_SECONDS, value_parser = crate::cli_values::leap_seconds)]
    pub leap_seconds: i32,
}

/// `--pos-time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PosTimeArg {
    /// `yyyy/mm/dd hh:mm:ss.sss` GPST.
    Calendar,
    /// `week tow`.
    WeekTow,
}

impl ReceiverArgs {
    fn wanted(&self) -> bool {
        self.nmea.is_some() || self.pos.is_some()
    }

    /// The simulated receiver for a run of `rtk_sigma`, `heading_sigma` and `seed`.
    pub fn receiver(
        &self,
        rtk_sigma: f64,
        heading_sigma: Option<f64>,
        seed: u64,
    ) -> Result<ReceiverSim> {
        let d = ReceiverSim::default();
        let antenna = match &self.antenna {
            Some(s) => parse_antenna(s)?,
            None => (0.0, 0.0),
        };
        let origin: Geodetic = match &self.origin {
            Some(s) => parse_origin(s)?,
            None => d.origin,
        };
        let gps_start = match &self.gps_start {
            Some(s) => {
                let (w, t) = s
                    .split_once(',')
                    .and_then(|(w, t)| {
                        Some((w.trim().parse::<u32>().ok()?, t.trim().parse::<f64>().ok()?))
                    })
                    .filter(|(_, t)| (0.0..gps_time::WEEK).contains(t))
                    .with_context(|| {
                        format!("--gps-start `{s}`: expected WEEK,TOW (TOW in 0..604800 s)")
                    })?;
                f64::from(w) * gps_time::WEEK + t
            }
            None => d.gps_start,
        };
        if !(self.gnss_rate > 0.0 && self.gnss_rate <= 100.0) {
            bail!("--gnss-rate {}: must be in (0, 100] Hz", self.gnss_rate);
        }
        if !(0.0..=1.0).contains(&self.float_fraction)
            || self.float_sigma.is_nan()
            || self.float_sigma < 0.0
        {
            bail!("--float-fraction must be in 0..=1, --float-sigma non-negative");
        }
        Ok(ReceiverSim {
            origin,
            gps_start,
            rate: self.gnss_rate,
            antenna,
            rtk_sigma,
            float_sigma: self.float_sigma,
            float_fraction: self.float_fraction,
            heading_sigma,
            seed,
        })
    }

    /// Before the CSVs are written: with a lever arm, the CSV reference becomes the antenna's
    /// path (its noise kept); with receiver logs, the samples and the CSV reference carry GPS
    /// time of week.
    pub fn prepare(&self, run: &mut SimRun, sim: &ReceiverSim) {
        let (fwd, left) = sim.antenna;
        if fwd != 0.0 || left != 0.0 {
            for (r, &(x, y, h)) in run.reference.iter_mut().zip(&run.truth) {
                let (ax, ay) = antenna_position(x, y, h, fwd, left);
                r.x += ax - x;
                r.y += ay - y;
            }
        }
        if self.wanted() || self.gps_start.is_some() {
            let (_, tow0) = gps_time::week_tow(sim.gps_start);
            for s in &mut run.samples {
                s.t += tow0;
            }
            for r in &mut run.reference {
                r.t += tow0;
            }
        }
    }

    /// Writes the receiver logs of a prepared run.
    pub fn write(&self, run: &SimRun, sim: &ReceiverSim) -> Result<()> {
        if !self.wanted() {
            return Ok(());
        }
        let (_, tow0) = gps_time::week_tow(sim.gps_start);
        let times: Vec<f64> = run.samples.iter().map(|s| s.t - tow0).collect();
        let epochs = simulated::receiver_epochs(&times, &run.truth, sim);
        if epochs.is_empty() {
            bail!("--gnss-rate {}: no sample falls on its epochs", sim.rate);
        }
        let create = |p: &Path| {
            std::fs::File::create(p)
                .map(std::io::BufWriter::new)
                .with_context(|| format!("{}: cannot create", p.display()))
        };
        if let Some(p) = &self.nmea {
            let mut w = create(p)?;
            simulated::write_nmea(&mut w, &epochs, self.leap_seconds)?;
            w.flush()?;
        }
        if let Some(p) = &self.pos {
            let mut w = create(p)?;
            let t = match self.pos_time {
                PosTimeArg::Calendar => PosTime::Calendar,
                PosTimeArg::WeekTow => PosTime::WeekTow,
            };
            simulated::write_pos(&mut w, &epochs, t)?;
            w.flush()?;
        }
        let floats = epochs
            .iter()
            .filter(|e| e.fix == super::FixQuality::RtkFloat)
            .count();
        crate::outln!(
            "receiver log: {} epochs at {} Hz ({floats} RTK float), antenna {:.3} m forward, {:.3} m left, origin {}, start {}",
            epochs.len(),
            sim.rate,
            sim.antenna.0,
            sim.antenna.1,
            sim.origin,
            gps_time::describe(sim.gps_start, self.leap_seconds)
        );
        Ok(())
    }
}
