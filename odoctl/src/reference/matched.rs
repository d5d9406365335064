//! A run's reference as the commands use it: a receiver log aligned to the samples' time,
//! with a summary of what was used ([`reference_for_samples`]), and the samples and the
//! reference of one run read and matched ([`read_matched_run`]).

use std::path::Path;

use anyhow::Result;

use super::clock::ClockFit;
use super::trajectory_noise::TrajectoryNoise;
use super::{load, Reference, ReferenceOptions, TimeScale};
use crate::csvio::{self, RefPoint, Sample};

/// The reference rows for these samples: a CSV as it is; a receiver log aligned to the
/// samples' time (refused when they do not overlap); a trajectory interpolated at the sample
/// instants ([`Reference::points_for`]); with a summary of what was used on stdout.
pub fn reference_for_samples(r: &Reference, samples: &[Sample]) -> Result<Vec<RefPoint>> {
    reference_and_clock_for_samples(r, samples).map(|(p, _)| p)
}

/// [`reference_for_samples`] with a trajectory's clock, when the reference is one.
pub fn reference_and_clock_for_samples(
    r: &Reference,
    samples: &[Sample],
) -> Result<(Vec<RefPoint>, Option<ClockFit>)> {
    let (points, matching, clock) = r.points_and_clock(samples)?;
    print_summary(r);
    if let Some(m) = matching {
        crate::outln!("  {m}");
    }
    Ok((points, clock))
}

/// What of a receiver log was used, on stdout (nothing for a REFERENCE CSV).
pub fn print_summary(r: &Reference) {
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
    if r.time == TimeScale::Trajectory {
        crate::outln!(
            "reference {} ({}): {}; x, y in its own frame (m)",
            r.file,
            r.format,
            r.report
        );
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
    /// A trajectory reference's own noise ([`TrajectoryNoise`]).
    pub noise: Option<TrajectoryNoise>,
}

/// Whether [`read_matched_run`] prints what of a receiver log it used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReferenceSummary {
    /// On stdout, as [`reference_for_samples`] does.
    Print,
    /// Not at all (a second reading of the same files).
    Quiet,
}

/// Reads a SAMPLES file and a reference of any format (`--reference`), the reference over
/// the samples' time span, and matches their times; fails naming both files when fewer than
/// two times are common.
pub fn read_matched_run(
    samples_path: &Path,
    reference_path: &Path,
    options: &ReferenceOptions,
    summary: ReferenceSummary,
) -> Result<MatchedRun> {
    let samples = csvio::read_samples(samples_path)?;
    let source = load(reference_path, options)?;
    let reference = match summary {
        ReferenceSummary::Print => reference_for_samples(&source, &samples)?,
        ReferenceSummary::Quiet => source.points_for(&samples)?.0,
    };
    let matches = csvio::match_or_fail(
        &samples,
        &samples_path.display().to_string(),
        &reference,
        &reference_path.display().to_string(),
        2,
    )?;
    let noise = TrajectoryNoise::of_reference(&source);
    Ok(MatchedRun {
        samples,
        reference,
        matches,
        noise,
    })
}
