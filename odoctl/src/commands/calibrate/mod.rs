//! `odoctl calibrate`: reads the files, maps the options ([`options`]), runs
//! [`calib::calibrate`], prints the result ([`report`]) and writes it ([`write`]): the result
//! TOML, the stability study's CSV, the figures, and with `--export-ros`, `--mcap` its ROS
//! forms.

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Result;
use odo_unit::odometry::ChassisParams;

use crate::calib::{self, Calibration, Extras, WarmStart};
use crate::cli::{CalibrateArgs, ReferenceArgs};
use crate::config as cfg;
use crate::csvio::{self, RefPoint, Sample};
use crate::reference::clock::ClockFit;
use crate::reference::matched::print_summary;
use crate::reference::nmea::LogLines;
use crate::reference::trajectory_noise::TrajectoryNoise;
use crate::reference::Reference;
use crate::stats::{coverage, summarize, Summary};

use super::recording::{check_recording_times, resolve_reference, say_own_reference};
use super::reference_options;

pub mod clock_offset;
pub mod options;
pub mod report;
pub mod write;

/// The whole run's errors at the result, as printed and written to `[fit]`.
pub struct ErrorSummary {
    /// Horizontal errors (m), the start left out.
    pub horizontal: Summary,
    /// Absolute heading errors (rad).
    pub heading: Summary,
    /// Heading errors (rad) and their sigmas (rad), where the reference has a heading.
    pub heading_pairs: (Vec<f64>, Vec<f64>),
    /// Share of horizontal errors inside 1 sigma_h.
    pub coverage1: f64,
    /// Share of horizontal errors inside 3 sigma_h.
    pub coverage3: f64,
    /// Shares of horizontal errors inside 1 and 3 sigma_h widened by the reference noise:
    /// what the bands promise to measured errors.
    pub widened: (f64, f64),
    /// Shares of errors of the heading change since the start inside 1 and 3 sigma_heading
    /// widened by the reference heading noise, where the reference has headings.
    pub heading_change: Option<(f64, f64)>,
    /// The reference's stated noise beside its scatter.
    pub noise: calib::NoiseCheck,
}

impl ErrorSummary {
    /// The summary of a calibration's evaluation, the bands widened by `noise`.
    pub fn of(c: &Calibration, noise: &calib::ReferenceNoise) -> Self {
        let ev = &c.evaluation;
        let (he, hs) = ev.heading_pairs();
        Self {
            horizontal: summarize(&ev.horizontal[1..]),
            heading: summarize(&he.iter().map(|e| e.abs()).collect::<Vec<_>>()),
            heading_pairs: (he, hs),
            coverage1: coverage(&ev.horizontal[1..], &ev.sigma_h[1..], 1.0),
            coverage3: coverage(&ev.horizontal[1..], &ev.sigma_h[1..], 3.0),
            widened: (
                noise.horizontal_coverage(ev, 1.0),
                noise.horizontal_coverage(ev, 3.0),
            ),
            heading_change: (calib::heading_points(ev, 1) > 0).then(|| {
                (
                    noise.heading_coverage(ev, 1.0),
                    noise.heading_coverage(ev, 3.0),
                )
            }),
            noise: noise.check(ev),
        }
    }
}

/// True when the filter refined the geometry (its standard errors are the filter's).
pub fn filter_refined(c: &Calibration) -> bool {
    c.refinement.as_ref().is_some_and(|r| r.skipped.is_none())
}

/// `odoctl calibrate`.
pub fn run(a: &CalibrateArgs) -> Result<ExitCode> {
    run_from(a, None)
}

/// The arguments of an `odoctl calibrate` command line (`args[0]` the program's name).
pub fn parse_command_line(args: &[String]) -> Result<CalibrateArgs> {
    use clap::Parser;
    match crate::cli::Cli::try_parse_from(args)?.cmd {
        crate::cli::Cmd::Calibrate(c) => Ok(c),
        _ => anyhow::bail!("not a calibrate command line: {}", args.join(" ")),
    }
}

/// A recording already in memory (`record --calibrate`): the SAMPLES rows of `--samples` as
/// the reader gives them back from the file, and the bytes of the NMEA log beside it with
/// their lines read as they came.
pub struct Recorded<'r> {
    /// The rows of the SAMPLES file.
    pub samples: &'r [Sample],
    /// The content of the NMEA log beside it.
    pub nmea: &'r [u8],
    /// Its lines read as they were appended (named as the log beside `--samples`, with the
    /// reference options' leap seconds; else it is read whole).
    pub lines: LogLines,
}

/// `odoctl calibrate`, with the recording's files taken from `recorded` when given and the
/// reference is the recording's own NMEA log: the same result, printed and written, as
/// from the files. [`read_inputs`], then [`run_read`] ([`ReadInputs::start_from`] between
/// them starts the searches from a warm start: the same result to their tolerances).
pub fn run_from(a: &CalibrateArgs, recorded: Option<Recorded>) -> Result<ExitCode> {
    run_read(a, read_inputs(a, recorded)?)
}

/// A calibration's inputs, read and nothing printed yet ([`read_inputs`]).
pub struct ReadInputs<'r> {
    started: Instant,
    reference_path: PathBuf,
    own: bool,
    source: Reference,
    inputs: Inputs<'r>,
    /// Where the calibration's searches start (a recording's warm start; else none).
    warm: Option<WarmStart>,
}

impl ReadInputs<'_> {
    /// Starts the calibration's searches from `warm` (where a calibration of the recording's
    /// first part left them) when the reference is the recording's own log; else from the
    /// initial estimate.
    pub fn start_from(&mut self, warm: Option<WarmStart>) {
        self.warm = warm.filter(|_| self.own);
    }
}

/// The inputs of [`run_from`]: the recording in memory (`recorded`, when the reference is
/// its own NMEA log: the epochs dated), else the files; prints nothing.
pub fn read_inputs<'r>(
    a: &CalibrateArgs,
    recorded: Option<Recorded<'r>>,
) -> Result<ReadInputs<'r>> {
    let started = Instant::now();
    let timer = calib::PhaseTimer::new();
    let (reference_path, own) = resolve_reference(&a.samples, a.reference.as_deref())?;
    let (samples, source) = match recorded.filter(|_| own) {
        Some(r) => {
            let o = reference_options(&a.reference_input)?;
            let source = crate::reference::load_read(&reference_path, r.nmea, r.lines, &o)?;
            (Cow::Borrowed(r.samples), source)
        }
        None => {
            let (s, source) = read_run(&a.samples, &reference_path, &a.reference_input)?;
            (Cow::Owned(s), source)
        }
    };
    let inputs = Inputs::of(&source, samples)?;
    timer.lap("read CSV");
    Ok(ReadInputs {
        started,
        reference_path,
        own,
        source,
        inputs,
        warm: None,
    })
}

/// [`run_from`] on the inputs `read`: what they are printed, checked, calibrated, the result
/// printed and written.
pub fn run_read(a: &CalibrateArgs, read: ReadInputs) -> Result<ExitCode> {
    let ReadInputs {
        started,
        reference_path,
        own,
        source,
        inputs,
        warm,
    } = read;
    let timer = calib::PhaseTimer::new();
    print_inputs(a, (&reference_path, own), &source, &inputs)?;
    let names = (
        a.samples.display().to_string(),
        reference_path.display().to_string(),
    );
    let extras = Extras {
        warm: warm.as_ref(),
        cancel: None,
    };
    let (c, opts, initial) = calibration_with(a, &inputs, &names, extras)?;
    timer.lap("calibration");
    report_and_write(a, &reference_path, &inputs, (&c, &opts, &initial), started)
}

/// What was read, printed: the recording's own reference (`own`) named, the reference's
/// summary, the trajectory's matching and own noise; a recording's two clocks checked.
fn print_inputs(
    a: &CalibrateArgs,
    (reference_path, own): (&Path, bool),
    source: &Reference,
    inputs: &Inputs,
) -> Result<()> {
    if own {
        say_own_reference(reference_path, &a.samples);
    }
    print_summary(source);
    if let Some(m) = &inputs.matching {
        crate::outln!("  {m}");
    }
    if let Some(line) = inputs
        .noise
        .as_ref()
        .and_then(|n| trajectory_noise_line(n, a))
    {
        crate::outln!("  {line}");
    }
    if own {
        check_recording_times(&inputs.samples, &inputs.reference)?;
    }
    Ok(())
}

/// The calibration of [`ReadInputs`] done, its printing left ([`calibrate_inputs`], then
/// [`run_calibrated`]).
pub struct Calibrated<'r> {
    read: ReadInputs<'r>,
    outcome: Result<(Calibration, calib::CalibrationOptions, ChassisParams)>,
}

/// [`run_read`]'s calibration of `read` alone, nothing printed (for the recording's own
/// NMEA log, which has no clock whose offset's share would be printed); the rest is
/// [`run_calibrated`]'s. `record --calibrate` runs it beside the live fit's last update.
pub fn calibrate_inputs<'r>(a: &CalibrateArgs, read: ReadInputs<'r>) -> Calibrated<'r> {
    let names = (
        a.samples.display().to_string(),
        read.reference_path.display().to_string(),
    );
    let extras = Extras {
        warm: read.warm.as_ref(),
        cancel: None,
    };
    let outcome = calibration_with(a, &read.inputs, &names, extras);
    Calibrated { read, outcome }
}

/// [`run_read`] of a calibration done ([`calibrate_inputs`]): the inputs printed and checked,
/// the result printed and written, as [`run_read`] does.
pub fn run_calibrated(a: &CalibrateArgs, done: Calibrated) -> Result<ExitCode> {
    let ReadInputs {
        started,
        reference_path,
        own,
        source,
        inputs,
        ..
    } = done.read;
    print_inputs(a, (&reference_path, own), &source, &inputs)?;
    let (c, opts, initial) = done.outcome?;
    report_and_write(a, &reference_path, &inputs, (&c, &opts, &initial), started)
}

/// The result `c` (with its options and initial estimate) of `inputs` printed and written
/// (`--out`, the ROS forms); `started` when the command started.
fn report_and_write(
    a: &CalibrateArgs,
    reference_path: &Path,
    inputs: &Inputs,
    (c, opts, initial): (&Calibration, &calib::CalibrationOptions, &ChassisParams),
    started: Instant,
) -> Result<ExitCode> {
    let timer = calib::PhaseTimer::new();
    let noise = calib::ReferenceNoise {
        horizontal: opts.reference_sigma,
        heading: opts.reference_heading_sigma,
    };
    let errors = ErrorSummary::of(c, &noise);
    report::print(c, initial, opts, &errors);
    write::write_result(a, reference_path, c, opts, &errors, inputs.clock.as_ref())?;
    timer.lap("report");
    crate::outln!("done in {:.2} s", started.elapsed().as_secs_f64());
    export_ros(a, reference_path)?;
    Ok(ExitCode::SUCCESS)
}

/// The line saying which of the reference's sigmas a trajectory's own noise `n` sets (those
/// the options do not give), `None` when the options give both.
pub fn trajectory_noise_line(n: &TrajectoryNoise, a: &CalibrateArgs) -> Option<String> {
    let mut set = Vec::new();
    if a.reference_sigma.is_none() {
        set.push(format!("--reference-sigma {:.5} m", n.horizontal));
    }
    if let (None, Some(h)) = (a.reference_heading_sigma_deg, n.heading) {
        set.push(format!(
            "--reference-heading-sigma-deg {:.4}",
            h.to_degrees()
        ));
    }
    (!set.is_empty()).then(|| {
        format!(
            "reference noise: the trajectory's own, from the second differences of {} poses: {}",
            n.triples,
            set.join(", ")
        )
    })
}

/// What a calibration reads: the samples, the reference's rows at them, and what a
/// trajectory reference adds.
pub struct Inputs<'s> {
    /// The SAMPLES rows.
    pub samples: Cow<'s, [Sample]>,
    /// The reference's rows aligned to the samples.
    pub reference: Vec<RefPoint>,
    /// A trajectory reference's clock fit.
    pub clock: Option<ClockFit>,
    /// How a trajectory was matched to the samples' clock, as printed.
    pub matching: Option<String>,
    /// The trajectory resampled on its clock with the offset moved by its standard error
    /// ([`clock_offset`]), when the offset was estimated.
    pub moved: Option<Vec<RefPoint>>,
    /// A trajectory reference's own noise, the default of the reference's sigmas.
    pub noise: Option<TrajectoryNoise>,
}

impl<'s> Inputs<'s> {
    /// The inputs of `samples` against `source`; prints nothing.
    pub fn of(source: &Reference, samples: Cow<'s, [Sample]>) -> Result<Self> {
        let (reference, matching, clock) = source.points_and_clock(&samples)?;
        let moved = clock.filter(|k| k.offset_se > 0.0).map(|k| {
            let moved = ClockFit {
                offset: k.offset + k.offset_se,
                ..k
            };
            source.points_on_clock(&samples, &moved)
        });
        let noise = TrajectoryNoise::of_reference(source);
        Ok(Self {
            samples,
            reference,
            clock,
            matching: matching.map(|m| m.to_string()),
            moved,
            noise,
        })
    }
}

/// The calibration `a` asks for of `inputs`, `names` the two inputs' names for messages; with
/// its options and initial estimate. Prints only what the clock offset adds to the standard
/// errors.
pub fn calibration(
    a: &CalibrateArgs,
    inputs: &Inputs,
    names: &(String, String),
) -> Result<(Calibration, calib::CalibrationOptions, ChassisParams)> {
    calibration_with(a, inputs, names, Extras::default())
}

/// [`calibration`] with a warm start and a cancel flag ([`Extras`]).
pub fn calibration_with(
    a: &CalibrateArgs,
    inputs: &Inputs,
    names: &(String, String),
    extras: Extras,
) -> Result<(Calibration, calib::CalibrationOptions, ChassisParams)> {
    let initial = initial_estimate(a)?;
    let (sigma, heading) = (a.reference_sigma, a.reference_heading_sigma_deg);
    let noise = calib::ReferenceNoise::resolve(sigma, heading, inputs.noise.as_ref());
    let opts = options::calibration_options(a, noise)?;
    let (samples, reference) = (&inputs.samples, &inputs.reference);
    let names = (names.0.as_str(), names.1.as_str());
    let mut c = calib::calibrate_with(samples, reference, names, &initial, &opts, extras)?;
    if let Some(k) = &inputs.clock {
        add_clock_rate_uncertainty(&mut c, k);
    }
    if let Some(moved) = &inputs.moved {
        add_clock_offset_uncertainty(&mut c, samples, moved, &opts);
    }
    Ok((c, opts, initial))
}

/// Adds what an estimated clock rate contributes to the diameters' standard errors: a rate
/// error scales the reference's distances per sample time, and so both diameters, by as
/// much (`D ppm_se 1e-6`, in quadrature); the track width, fitted from the heading change
/// per count difference and the diameters, keeps its own.
fn add_clock_rate_uncertainty(c: &mut Calibration, clock: &ClockFit) {
    let g = &mut c.geometry;
    let d = [g.params.left_diameter, g.params.right_diameter];
    for (k, d) in d.iter().enumerate() {
        let extra = d * clock.ppm_se * 1e-6;
        for v in [&mut g.std_errors[k], &mut g.robust_std_errors[k]]
            .into_iter()
            .flatten()
        {
            *v = v.hypot(extra);
        }
    }
}

/// Adds what an estimated clock offset contributes to the geometry's standard errors
/// ([`clock_offset`]), with a line saying how much; on a failure of the repeated fit, a line
/// saying that it was not added.
fn add_clock_offset_uncertainty(
    c: &mut Calibration,
    samples: &[Sample],
    moved: &[RefPoint],
    opts: &calib::CalibrationOptions,
) {
    match clock_offset::offset_shares(c, samples, moved, opts) {
        Ok(Some(d)) => {
            clock_offset::add_offset_shares(c, d);
            crate::outln!(
                "  the clock offset's share of the standard errors (the sub-trajectory fit with the offset moved by its standard error), added: diameters {:.2e} {:.2e} m, track width {:.2e} m, lever arm {:.2e} {:.2e} m",
                d[0].abs(),
                d[1].abs(),
                d[2].abs(),
                d[3].abs(),
                d[4].abs()
            );
        }
        Ok(None) => {}
        Err(e) => crate::outln!(
            "  the clock offset's share of the standard errors is not added: the repeated fit failed: {e}"
        ),
    }
}

/// Reads the samples and the reference (on two cores: the files are independent).
fn read_run(
    samples: &Path,
    reference: &Path,
    input: &ReferenceArgs,
) -> Result<(Vec<Sample>, Reference)> {
    let (samples, reference) = std::thread::scope(|scope| {
        let reference = scope
            .spawn(|| reference_options(input).and_then(|o| crate::reference::load(reference, &o)));
        let samples = csvio::read_samples(samples);
        (samples, reference.join().expect("CSV reader panicked"))
    });
    Ok((samples?, reference?))
}

/// The first estimate: `--initial` (or the designed values) with the `--set`s over it.
fn initial_estimate(a: &CalibrateArgs) -> Result<ChassisParams> {
    let mut initial = match &a.initial {
        Some(p) => cfg::read_params(p, ChassisParams::DESIGNED)?,
        None => ChassisParams::DESIGNED,
    };
    cfg::apply_sets(&mut initial, &a.sets)?;
    cfg::validated(initial, "initial estimate")
}

/// The result's ROS forms, from the result file `--out`: the diff_drive_controller
/// parameters (`--export-ros`) and the tracks (`--mcap`).
fn export_ros(a: &CalibrateArgs, reference: &Path) -> Result<()> {
    let Some(result) = &a.out else {
        return Ok(());
    };
    if let Some(yaml) = &a.export_ros {
        crate::ros::diff_drive::export_hook(yaml, result)?;
    }
    if let Some(m) = &a.mcap {
        crate::ros::tracks::validate_hook(
            m,
            &a.samples,
            reference,
            &reference_options(&a.reference_input)?,
            Some(result),
            &[],
            None,
        )?;
    }
    Ok(())
}
