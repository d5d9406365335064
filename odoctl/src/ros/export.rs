//! `--mcap`: a SAMPLES file replayed through the core integrator, recorded as ROS 2 topics.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{anyhow, Result};

use super::conventions::{BaseTwist, PoseCovariance, UNOBSERVED_VARIANCE};
use super::recording::{self, OdomSample, RecordingSummary};
use super::stamps::{self, Stamps};
use crate::config as cfg;
use crate::core_api::{ChassisParams, Integrator, Pose};
use crate::csvio::Sample;
use crate::replay::{counts, index_refs};

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
            PoseCovariance::from_sigmas(s.x, s.y, s.heading, s.xy, integ.heading_covariance()),
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
        });
    }
    Ok(out)
}

/// The `odoctl` metadata record of a recording.
pub fn metadata(
    params: &ChassisParams,
    stamps: &Stamps,
    source: &str,
    command: &str,
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
        "REP-103/105: frame odom, child base_link; x east, y north; yaw = pi/2 - heading; see docs/ROS.md".into(),
    );
    put("unobserved_variance", format!("{UNOBSERVED_VARIANCE:e}"));
    put(
        "reset_pose",
        "odom kept continuous (offset composed), WARN on /diagnostics".into(),
    );
    for k in cfg::KEYS {
        if let Ok(v) = cfg::get_key(params, k) {
            put(k, v);
        }
    }
    m
}

/// `odoctl replay ... --mcap OUT`: replays `samples` (read from `source`) from `initial` and
/// records `/odom`, `/tf`, `/diagnostics` and the whole path on `/odom/path`.
pub fn write_replay(
    out: &Path,
    params: &ChassisParams,
    samples: &[Sample],
    initial: Pose,
    source: &str,
) -> Result<RecordingSummary> {
    let stamps = stamps::stamp(samples);
    let odom = odom_samples(params, samples, initial, &stamps)?;
    let mut rec = recording::create(out, &metadata(params, &stamps, source, "replay"))?;
    rec.set_model(params.uncertainty_model);
    for s in &odom {
        rec.push(s)?;
    }
    let path: Vec<(u64, Pose)> = odom.iter().map(|s| (s.stamp_ns, s.pose)).collect();
    rec.path("/odom/path", &path)?;
    rec.finish()
}

/// The one-call hook of `odoctl replay --mcap`: reads the parameters and the samples as
/// `replay` does and writes the recording; prints what it wrote to stderr.
pub fn replay_hook(
    out: &Path,
    samples: &Path,
    config: Option<&Path>,
    sets: &[String],
    start: (f64, f64, f64),
) -> Result<()> {
    let params = cfg::load(config, sets)?;
    let s = crate::csvio::read_samples(samples)?;
    let initial = Pose {
        x: start.0,
        y: start.1,
        heading: start.2,
    };
    let sum = write_replay(out, &params, &s, initial, &samples.display().to_string())?;
    eprintln!(
        "mcap: {} /odom and /tf, {} /diagnostics messages to {}{}",
        sum.odom,
        sum.diagnostics,
        out.display(),
        if sum.overrange > 0 {
            format!(" ({} over-range samples not integrated)", sum.overrange)
        } else {
            String::new()
        }
    );
    Ok(())
}
