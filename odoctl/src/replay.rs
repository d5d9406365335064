//! Replay of recorded counts through the core integrator (`odo_unit::odometry::Integrator`).

use std::fmt::Write as _;
use std::io::Write;

use anyhow::{anyhow, Result};

use crate::csvio::{fmt_t, Sample};
use odo_unit::odometry::{ChassisParams, IndexRefs, Integrator, Pose, PoseSigma, WheelCounts};

/// The integrator's input of a SAMPLES row: absolute counts.
pub fn counts(s: &Sample) -> WheelCounts {
    WheelCounts {
        left: s.left,
        right: s.right,
    }
}

/// The integrator's input of a SAMPLES row: latched index counts (`None` when unknown).
pub fn index_refs(s: &Sample) -> IndexRefs {
    IndexRefs {
        left: s.left_index,
        right: s.right_index,
    }
}

/// One replayed row: the integrator's pose and sigmas after the row's counts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayRow {
    /// Sample time (s).
    pub t: f64,
    /// Pose after the row.
    pub pose: Pose,
    /// Sigmas after the row.
    pub sigma: PoseSigma,
}

/// Runs the core integrator over `samples` from `initial` (at the first row's counts); one
/// output row per input row, the first being the initial pose with zero sigmas.
pub fn replay(params: &ChassisParams, samples: &[Sample], initial: Pose) -> Result<Vec<ReplayRow>> {
    let first = samples.first().ok_or_else(|| anyhow!("no samples"))?;
    let mut integ =
        Integrator::new(params, counts(first), initial).map_err(|e| anyhow!("parameters: {e}"))?;
    let mut out = Vec::with_capacity(samples.len());
    out.push(ReplayRow {
        t: first.t,
        pose: integ.pose(),
        sigma: integ.sigma(),
    });
    for s in &samples[1..] {
        let _ = integ.step(counts(s), index_refs(s));
        out.push(ReplayRow {
            t: s.t,
            pose: integ.pose(),
            sigma: integ.sigma(),
        });
    }
    Ok(out)
}

/// Header of the replay CSV.
pub const REPLAY_HEADER: &str = "t,x,y,heading,sigma_x,sigma_y,sigma_heading";

/// Writes the replay CSV (`t,x,y,heading,sigma_x,sigma_y,sigma_heading`); numbers are printed
/// in their shortest form that reads back to the same bits.
pub fn write_replay(w: &mut dyn Write, rows: &[ReplayRow]) -> Result<()> {
    let mut buf = String::with_capacity(1 << 17);
    buf.push_str(REPLAY_HEADER);
    buf.push('\n');
    for r in rows {
        let _ = writeln!(
            buf,
            "{},{:?},{:?},{:?},{:?},{:?},{:?}",
            fmt_t(r.t),
            r.pose.x,
            r.pose.y,
            r.pose.heading,
            r.sigma.x,
            r.sigma.y,
            r.sigma.heading
        );
        if buf.len() > 1 << 16 {
            w.write_all(buf.as_bytes())?;
            buf.clear();
        }
    }
    w.write_all(buf.as_bytes())?;
    Ok(())
}

/// Comparison of a replay against the unit's own pose columns of the same SAMPLES file.
#[derive(Debug, Clone, Default)]
pub struct UnitCheck {
    /// Rows that carry the unit's pose.
    pub compared: usize,
    /// Rows whose pose or sigmas differ.
    pub mismatches: usize,
    /// Description of the first difference.
    pub first: Option<String>,
}

fn same64(ours: f64, theirs: f64) -> bool {
    ours.to_bits() == theirs.to_bits()
        || (ours as f32).to_bits() == (theirs as f32).to_bits() && theirs == (theirs as f32) as f64
}

/// Compares `rows` with the unit's pose columns: bit for bit at the precision the file
/// carries (f64, or f32 when the unit sends single precision).
pub fn check_against_unit(samples: &[Sample], rows: &[ReplayRow]) -> UnitCheck {
    let mut c = UnitCheck::default();
    for (s, r) in samples.iter().zip(rows) {
        let Some(u) = s.unit else { continue };
        c.compared += 1;
        let pairs = [
            ("x", same64(r.pose.x, u.x), r.pose.x, u.x),
            ("y", same64(r.pose.y, u.y), r.pose.y, u.y),
            (
                "heading",
                same64(r.pose.heading, u.heading),
                r.pose.heading,
                u.heading,
            ),
            (
                "sigma_x",
                r.sigma.x.to_bits() == u.sigma_x.to_bits(),
                r.sigma.x.into(),
                u.sigma_x.into(),
            ),
            (
                "sigma_y",
                r.sigma.y.to_bits() == u.sigma_y.to_bits(),
                r.sigma.y.into(),
                u.sigma_y.into(),
            ),
            (
                "sigma_heading",
                r.sigma.heading.to_bits() == u.sigma_heading.to_bits(),
                r.sigma.heading.into(),
                u.sigma_heading.into(),
            ),
        ];
        if let Some((name, _, ours, theirs)) = pairs.iter().find(|p| !p.1) {
            c.mismatches += 1;
            if c.first.is_none() {
                c.first = Some(format!(
                    "t = {}: {name}: replay {ours:?}, unit {theirs:?}",
                    fmt_t(s.t)
                ));
            }
        }
    }
    c
}
