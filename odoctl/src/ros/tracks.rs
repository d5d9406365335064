//! `validate --mcap`: the reference track and the odometry path of a validation (the paper's
//! Figs. 4 and 10) as `nav_msgs/msg/Path` messages, for Foxglove and rviz.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Result;

use super::recording::{self, RecordingSummary};
use crate::calib::{self, Evaluation, Run};
use crate::config as cfg;
use crate::csvio::RefPoint;
use crate::reference::matched::{read_matched_run, MatchedRun, ReferenceSummary};
use crate::reference::ReferenceOptions;
use odo_unit::odometry::Pose;

/// Nanoseconds of a CSV time (s); the files' own time base (metadata `stamp_source` =
/// `samples_t`).
fn nanos(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

/// The reference track: every REFERENCE row, oriented by its heading when the file has one,
/// else along the track (towards the next point; the last keeps the previous direction).
pub fn reference_poses(reference: &[RefPoint]) -> Vec<(u64, Pose)> {
    let mut along = 0.0;
    reference
        .iter()
        .enumerate()
        .map(|(i, r)| {
            if let Some(n) = reference.get(i + 1) {
                let (dx, dy) = (n.x - r.x, n.y - r.y);
                if dx != 0.0 || dy != 0.0 {
                    // Our heading: clockwise from north.
                    along = dx.atan2(dy);
                }
            }
            (
                nanos(r.t),
                Pose {
                    x: r.x,
                    y: r.y,
                    heading: r.heading.unwrap_or(along),
                },
            )
        })
        .collect()
}

/// The odometry at the evaluated common times.
pub fn odometry_poses(ev: &Evaluation) -> Vec<(u64, Pose)> {
    ev.t.iter()
        .zip(&ev.odo)
        .zip(&ev.heading)
        .map(|((&t, &(x, y)), &heading)| (nanos(t), Pose { x, y, heading }))
        .collect()
}

/// Writes `/reference/path` and `/odom/path` (and no `/odom` samples) to `out`.
pub fn write_tracks(
    out: &Path,
    reference: &[RefPoint],
    ev: &Evaluation,
    metadata: &BTreeMap<String, String>,
) -> Result<RecordingSummary> {
    let mut rec = recording::create(out, metadata)?;
    rec.path("/reference/path", &reference_poses(reference))?;
    rec.path("/odom/path", &odometry_poses(ev))?;
    rec.finish()
}

/// The one-call hook of `odoctl validate --mcap`: the same evaluation as `validate` (the
/// reference in any format `--reference` takes, the parameters, the given or eq (16)-fitted
/// initial heading) written as two paths.
pub fn validate_hook(
    out: &Path,
    samples_path: &Path,
    reference_path: &Path,
    reference_input: &ReferenceOptions,
    config: Option<&Path>,
    sets: &[String],
    heading: Option<f64>,
) -> Result<()> {
    let params = cfg::load(config, sets)?;
    // The command calling this hook (validate, calibrate) prints the reference's summary.
    let MatchedRun {
        samples,
        reference,
        matches,
        ..
    } = read_matched_run(
        samples_path,
        reference_path,
        reference_input,
        ReferenceSummary::Quiet,
    )?;
    let antenna = config.map_or(Ok((0.0, 0.0)), calib::read_lever_arm)?;
    let run = Run::new(&samples, &reference, matches).with_antenna(antenna);
    let last = run.len() - 1;
    let h0 = match heading {
        Some(h) => h,
        None => calib::fit_heading(&run, &params, 0, last, run.heading_guess(0))?,
    };
    let ev = calib::evaluate(&run, &params, h0)?;
    let mut meta = BTreeMap::new();
    meta.insert("command".to_string(), "validate".to_string());
    meta.insert("samples".to_string(), samples_path.display().to_string());
    meta.insert(
        "reference".to_string(),
        reference_path.display().to_string(),
    );
    meta.insert("stamp_source".to_string(), "samples_t".to_string());
    meta.insert("initial_heading".to_string(), format!("{h0:?}"));
    for k in cfg::chassis_keys() {
        meta.insert(k.name().to_string(), cfg::chassis_value_text(&params, k));
    }
    let sum = write_tracks(out, &reference, &ev, &meta)?;
    eprintln!(
        "mcap: /reference/path ({} points) and /odom/path ({} points), {} paths to {}",
        reference.len(),
        ev.t.len(),
        sum.paths,
        out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_orientation_along_the_track_or_its_heading() {
        let r = |t: f64, x: f64, y: f64, h: Option<f64>| RefPoint {
            t,
            x,
            y,
            heading: h,
            sigma_h: None,
        };
        // North, then east, then a standstill, then a point with a heading of its own.
        let track = [
            r(0.0, 0.0, 0.0, None),
            r(1.0, 0.0, 1.0, None),
            r(2.0, 1.0, 1.0, None),
            r(3.0, 1.0, 1.0, None),
            r(4.0, 1.0, 1.0, Some(2.0)),
        ];
        let p = reference_poses(&track);
        let h: Vec<f64> = p.iter().map(|(_, p)| p.heading).collect();
        let half_pi = std::f64::consts::FRAC_PI_2;
        assert_eq!(h[0], 0.0);
        assert!((h[1] - half_pi).abs() < 1e-15);
        assert!((h[2] - half_pi).abs() < 1e-15 && (h[3] - half_pi).abs() < 1e-15);
        assert_eq!(h[4], 2.0);
        assert_eq!(p[4].0, 4_000_000_000);
    }
}
