//! `--mcap`: a SAMPLES file replayed through the core integrator, recorded as ROS 2 topics.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{anyhow, Result};

use super::conventions::{BaseTwist, PoseCovariance, UNOBSERVED_VARIANCE, VARIANCE_FLOOR};
use super::names::RosNames;
use super::recording::{self, OdomSample, RecordingSummary};
use super::stamps::{self, Stamps};
use crate::config as cfg;
use crate::csvio::Sample;
use crate::replay::{counts, index_refs};
use odo_unit::odometry::{ChassisParams, Integrator, Pose};

/// The samples of a replay from `initial`: the integrator's pose, sigmas and position-heading
/// covariance after each row (the first row: `initial`, zero covariance, no twist), the
/// twist of each row's interval from its counts, the row's status word and sequence.
pub fn odom_samples(
    params: &ChassisParams,
    samples: &[Sample],
    initial: Pose,
    stamps: &Stamps,
) -> Result<Vec<OdomSample>> {
    let first = samples.first().ok_or_else(|| anyhow!("no samples"))?;
    let mut integ =
        Integrator::new(params, counts(first), initial).map_err(|e| anyhow!("parameters: {e}"))?;
    let state = |integ: &Integrator| {
        let s = integ.sigma();
        (
            integ.pose(),
            PoseCovariance::from_sigmas(s.x, s.y, s.heading, s.cov_xy, integ.heading_covariance()),
        )
    };
    let mut out = Vec::with_capacity(samples.len());
    let (pose, cov) = state(&integ);
    out.push(OdomSample {
        stamp_ns: stamps.nanos[0],
        pose,
        cov,
        twist: None,
        flags: first.flags.and_then(|f| u32::try_from(f).ok()),
        sequence: first.unit.and_then(|u| u.seq),
        overrange: false,
        reset: false,
        counts: Some((first.left, first.right)),
    });
    for (i, w) in samples.windows(2).enumerate() {
        let (prev, s) = (&w[0], &w[1]);
        let status = integ.step(counts(s), index_refs(s));
        let (pose, cov) = state(&integ);
        let dt = stamps.nanos[i + 1].saturating_sub(stamps.nanos[i]) as f64 * 1e-9;
        out.push(OdomSample {
            stamp_ns: stamps.nanos[i + 1],
            pose,
            cov,
            twist: BaseTwist::from_counts(params, s.left - prev.left, s.right - prev.right, dt),
            flags: s.flags.and_then(|f| u32::try_from(f).ok()),
            sequence: s.unit.and_then(|u| u.seq),
            overrange: status.overrange,
            reset: false,
            counts: Some((s.left, s.right)),
        });
    }
    Ok(out)
}

/// The samples of a recording of the unit's own pose records (`record`): the unit's pose and
/// sigmas as sent (the x-y covariance as the unit sends it; the position-heading terms are
/// not on the wire and are 0), the twist of each interval from the counts with `params` (the
/// unit's parameters). A record whose sigmas are all zero after one with a non-zero sigma is
/// a `reset_pose` and is marked so, which keeps `odom` continuous in the recording.
pub fn unit_samples(
    params: &ChassisParams,
    samples: &[Sample],
    stamps: &Stamps,
) -> Result<Vec<OdomSample>> {
    let mut out = Vec::with_capacity(samples.len());
    let mut prev: Option<(&Sample, bool)> = None;
    for (i, s) in samples.iter().enumerate() {
        let u = s.unit.ok_or_else(|| {
            anyhow!(
                "sample {} (t = {}) carries no unit pose (x, y, heading, sigma_x, sigma_y, sigma_heading)",
                i + 1,
                s.t
            )
        })?;
        let zero = u.sigma_x == 0.0 && u.sigma_y == 0.0 && u.sigma_heading == 0.0;
        let twist = prev.and_then(|(p, _)| {
            let dt = stamps.nanos[i].saturating_sub(stamps.nanos[i - 1]) as f64 * 1e-9;
            BaseTwist::from_counts(params, s.left - p.left, s.right - p.right, dt)
        });
        out.push(OdomSample {
            stamp_ns: stamps.nanos[i],
            pose: Pose {
                x: u.x,
                y: u.y,
                heading: u.heading,
            },
            cov: PoseCovariance::from_sigmas(
                u.sigma_x,
                u.sigma_y,
                u.sigma_heading,
                u.cov_xy,
                (0.0, 0.0),
            ),
            twist,
            flags: s.flags.and_then(|f| u32::try_from(f).ok()),
            sequence: u.seq,
            overrange: false,
            reset: zero && prev.is_some_and(|(_, was_zero)| !was_zero),
            counts: Some((s.left, s.right)),
        });
        prev = Some((s, zero));
    }
    Ok(out)
}

/// Whether `params` look like the unit's own: the heading change the counts give with them
/// against the one the unit reported over the recording (within 1 % of the turn plus
/// 0.01 rad, room for per-angle wheel functions). `Some(warning)` when they disagree; `None`
/// when they agree or the recording cannot tell (a reset, no unit pose).
pub fn params_mismatch(params: &ChassisParams, samples: &[Sample]) -> Option<String> {
    let (first, last) = (samples.first()?, samples.last()?);
    let (u0, u1) = (first.unit?, last.unit?);
    let stamps = stamps::stamp(samples);
    if unit_samples(params, samples, &stamps)
        .ok()?
        .iter()
        .any(|s| s.reset)
    {
        return None;
    }
    let ticks = f64::from(params.ticks_per_rev);
    let s1 = (last.left - first.left) as f64 * std::f64::consts::PI * params.left_diameter / ticks;
    let s2 =
        (last.right - first.right) as f64 * std::f64::consts::PI * params.right_diameter / ticks;
    let counts_turn = (s1 - s2) / params.track_width;
    let unit_turn = u1.heading - u0.heading;
    let tolerance = 0.01 * unit_turn.abs().max(counts_turn.abs()) + 0.01;
    ((counts_turn - unit_turn).abs() > tolerance).then(|| {
        format!(
            "the parameters do not look like the unit's: with them the counts turn {counts_turn:.4} rad, the unit reported {unit_turn:.4} rad; the twist on /odom uses them (pass the unit's with --config/--set)"
        )
    })
}

/// Records `odom` (with the whole path on `<odom>/path` at the end) into `out`, named by
/// `names`; the joint states with `params.ticks_per_rev`.
fn write(
    out: &Path,
    meta: &BTreeMap<String, String>,
    odom: &[OdomSample],
    (params, model): (&ChassisParams, Option<odo_unit::odometry::UncertaintyModel>),
    names: RosNames,
) -> Result<RecordingSummary> {
    let mut rec = recording::create_with(out, meta, names)?;
    if let Some(m) = model {
        rec.set_model(m);
    }
    rec.set_ticks_per_rev(params.ticks_per_rev);
    for s in odom {
        rec.push(s)?;
    }
    let path: Vec<(u64, Pose)> = odom.iter().map(|s| (s.stamp_ns, s.pose)).collect();
    let topic = rec.names().path.clone();
    rec.path(&topic, &path)?;
    rec.finish()
}

/// `odoctl record ... --mcap OUT`: the unit's pose records of the SAMPLES file `csv` just
/// written (see [`unit_samples`]); `config`/`sets` are the unit's parameters for the twist
/// and the joint states; `names` the topics and frames.
pub fn record_hook(
    out: &Path,
    csv: &Path,
    (config, sets): (Option<&Path>, &[String]),
    names: RosNames,
) -> Result<()> {
    let params = cfg::load(config, sets)?;
    let samples = crate::csvio::read_samples(csv)?;
    if let Some(w) = params_mismatch(&params, &samples) {
        eprintln!("warning: {w}");
    }
    let stamps = stamps::stamp(&samples);
    let odom = unit_samples(&params, &samples, &stamps)?;
    let meta = metadata(
        &params,
        &stamps,
        &csv.display().to_string(),
        "record",
        &names,
    );
    let tf = names.tf.is_some();
    let sum = write(out, &meta, &odom, (&params, None), names)?;
    report(out, &sum, tf);
    Ok(())
}

fn report(out: &Path, sum: &RecordingSummary, tf: bool) {
    eprintln!(
        "mcap: {} /odom{}, {} /diagnostics messages to {}{}{}",
        sum.stream.odom,
        if tf { " and /tf" } else { " (no /tf)" },
        sum.stream.diagnostics,
        out.display(),
        if sum.stream.overrange > 0 {
            format!(
                "; {} over-range samples not integrated",
                sum.stream.overrange
            )
        } else {
            String::new()
        },
        if sum.stream.resets > 0 {
            format!(
                "; {} reset_pose jumps absorbed, odom kept continuous",
                sum.stream.resets
            )
        } else {
            String::new()
        }
    );
}

/// The `odoctl` metadata record of a recording.
pub fn metadata(
    params: &ChassisParams,
    stamps: &Stamps,
    source: &str,
    command: &str,
    names: &RosNames,
) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    let mut put = |k: &str, v: String| {
        m.insert(k.to_string(), v);
    };
    put("command", command.into());
    put("source", source.into());
    put("stamp_source", stamps.source.name().into());
    if let Some(l) = stamps.leap_seconds {
        put("leap_seconds", l.to_string());
    }
    put("stamps_extrapolated", stamps.extrapolated.to_string());
    put(
        "conventions",
        format!(
            "REP-103/105: frame {}, child {}; x east, y north; yaw = pi/2 - heading; see docs/ROS.md",
            names.odom_frame, names.base_frame
        ),
    );
    put("tf", names.tf.clone().unwrap_or_else(|| "off".into()));
    put("unobserved_variance", format!("{UNOBSERVED_VARIANCE:e}"));
    put("variance_floor", format!("{VARIANCE_FLOOR:e}"));
    put(
        "reset_pose",
        "odom kept continuous (offset composed), WARN on /diagnostics".into(),
    );
    for k in cfg::chassis_keys() {
        put(k.name(), cfg::chassis_value_text(params, k));
    }
    m
}

/// `odoctl replay ... --mcap OUT`: replays `samples` (read from `source`) from `initial` and
/// records `/odom`, `/tf`, `/joint_states`, `/diagnostics` and the whole path on
/// `/odom/path` (names from `names`).
pub fn write_replay(
    out: &Path,
    params: &ChassisParams,
    samples: &[Sample],
    (initial, source): (Pose, &str),
    names: RosNames,
) -> Result<RecordingSummary> {
    let stamps = stamps::stamp(samples);
    let odom = odom_samples(params, samples, initial, &stamps)?;
    let meta = metadata(params, &stamps, source, "replay", &names);
    write(
        out,
        &meta,
        &odom,
        (params, Some(params.uncertainty_model)),
        names,
    )
}

/// The one-call hook of `odoctl replay --mcap`: reads the parameters and the samples as
/// `replay` does and writes the recording; prints what it wrote to stderr.
pub fn replay_hook(
    out: &Path,
    samples: &Path,
    config: Option<&Path>,
    sets: &[String],
    start: (f64, f64, f64),
    names: RosNames,
) -> Result<()> {
    let params = cfg::load(config, sets)?;
    let s = crate::csvio::read_samples(samples)?;
    let initial = Pose {
        x: start.0,
        y: start.1,
        heading: start.2,
    };
    let source = samples.display().to_string();
    let tf = names.tf.is_some();
    let sum = write_replay(out, &params, &s, (initial, &source), names)?;
    report(out, &sum, tf);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::csvio::UnitPose;

    fn unit_row(t: f64, left: i64, x: f64, sigma: f32) -> Sample {
        Sample {
            t,
            left,
            right: left,
            unit: Some(UnitPose {
                x,
                y: 1.0,
                heading: 0.25,
                sigma_x: sigma,
                sigma_y: sigma,
                sigma_heading: sigma,
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    #[test]
    fn a_reset_in_the_unit_records_is_marked_and_odom_stays_continuous() {
        let p = ChassisParams::DESIGNED;
        let rows = [
            unit_row(0.0, 0, 0.0, 0.0),
            unit_row(0.02, 100, 0.5, 1e-3),
            unit_row(0.04, 200, 1.0, 2e-3),
            // reset_pose: the unit jumps to x = 0 with zero sigmas.
            unit_row(0.06, 300, 0.0, 0.0),
            unit_row(0.08, 400, 0.5, 1e-3),
        ];
        let st = stamps::stamp(&rows);
        let odom = unit_samples(&p, &rows, &st).unwrap();
        let resets: Vec<bool> = odom.iter().map(|s| s.reset).collect();
        assert_eq!(resets, [false, false, false, true, false]);
        assert!(odom[0].twist.is_none() && odom[1].twist.is_some());

        let mut rec =
            recording::McapRecording::new(std::io::Cursor::new(Vec::new()), &BTreeMap::new())
                .unwrap();
        for s in &odom {
            rec.push(s).unwrap();
        }
        let sum = rec.finish().unwrap();
        assert_eq!((sum.stream.odom, sum.stream.resets), (5, 1));
        // Diagnostics: the first sample, the WARN of the reset, back to OK after it.
        assert_eq!(sum.stream.diagnostics, 3);

        // A reset: the parameters cannot be checked against the unit's heading.
        assert_eq!(params_mismatch(&p, &rows), None);

        // A file without the unit's pose is refused, naming the sample.
        let bare = [Sample::default()];
        let e = unit_samples(&p, &bare, &stamps::stamp(&bare)).unwrap_err();
        assert!(e.to_string().contains("sample 1"), "{e}");
    }

    #[test]
    fn parameters_unlike_the_units_are_noticed() {
        let p = ChassisParams::DESIGNED;
        // Turning on the spot: 2000 increments forward left, 2000 back right.
        let turn = |l: i64, r: i64| {
            let ticks = f64::from(p.ticks_per_rev);
            let q = std::f64::consts::PI / ticks;
            (l as f64 * q * p.left_diameter - r as f64 * q * p.right_diameter) / p.track_width
        };
        let row = |t: f64, l: i64, r: i64, heading: f64| Sample {
            t,
            left: l,
            right: r,
            unit: Some(UnitPose {
                heading,
                sigma_x: 1e-3,
                ..Default::default()
            }),
            ..Default::default()
        };
        let rows = [
            row(0.0, 0, 0, 0.0),
            row(1.0, 2000, -2000, turn(2000, -2000)),
        ];
        assert_eq!(params_mismatch(&p, &rows), None);
        let mut wide = p;
        wide.track_width *= 1.05;
        let w = params_mismatch(&wide, &rows).unwrap();
        assert!(w.contains("--config"), "{w}");
    }
}
