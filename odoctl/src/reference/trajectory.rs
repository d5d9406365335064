//! Trajectory references (motion capture, SLAM, localisation): poses of a marker in the
//! reference system's own frame and on its own clock, as a TUM file (`tum.rs`) or a ROS 2
//! MCAP recording (`mcap_pose.rs`) gives them.
//!
//! The frame's origin and orientation are unknown: its x/y are taken as the calibration's
//! plane as they are (a rotation and translation of it is what the calibration's start pose
//! fits), and the marker's offset from the axle centre is the lever arm (`--fit-antenna`). The
//! marker's yaw (counter-clockwise from the frame's +x, ROS) becomes a heading clockwise from
//! the frame's +y, `pi/2 - yaw`; its constant offset from the chassis axis is estimated from
//! the direction of travel on straights ([`marker_yaw_offset`]). The poses meet the samples by
//! interpolation at the sample instants ([`resample`]).

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use anyhow::{bail, Result};

use super::{FixQuality, LocalEpoch};
use crate::csvio::RefPoint;

/// One pose of a trajectory as read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectoryPose {
    /// Stamp (s) on the reference's clock.
    pub t: f64,
    /// Position in the reference frame (m).
    pub position: [f64; 3],
    /// Orientation quaternion `(x, y, z, w)`.
    pub orientation: [f64; 4],
    /// 1-based line (TUM) or message number (MCAP) in the file.
    pub line: usize,
}

/// The angle wrapped to `(-pi, pi]` (rad).
pub fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(TAU);
    if w > PI {
        w - TAU
    } else {
        w
    }
}

/// The yaw (rad, counter-clockwise about +z from +x) of a quaternion `(x, y, z, w)`, of any
/// non-zero norm; `None` when it is not finite or zero, or when the body's x axis points
/// along z (no yaw).
pub fn yaw(q: [f64; 4]) -> Option<f64> {
    let [x, y, z, w] = q;
    let n2 = x * x + y * y + z * z + w * w;
    if !(n2.is_finite() && n2 > 1e-12) {
        return None;
    }
    // The body x axis in the frame, scaled by the squared norm.
    let ax = w * w + x * x - y * y - z * z;
    let ay = 2.0 * (x * y + w * z);
    (ax.hypot(ay) > 1e-6 * n2).then(|| ay.atan2(ax))
}

/// The heading (rad, clockwise from +y, wrapped) of a yaw (rad, counter-clockwise from +x).
pub fn heading_of_yaw(yaw: f64) -> f64 {
    wrap(FRAC_PI_2 - yaw)
}

/// Checks a trajectory's stamps and quaternions: finite, strictly increasing stamps and
/// finite positions, a quaternion with a yaw; the first problem is an error naming `what`
/// (`FILE:LINE`, or the file and topic) and the pose's line or message.
pub fn check(what: &str, unit: &str, poses: &[TrajectoryPose]) -> Result<()> {
    let mut prev: Option<&TrajectoryPose> = None;
    for p in poses {
        if !p.t.is_finite() || p.position.iter().any(|v| !v.is_finite()) {
            bail!("{what}: {unit} {}: stamp or position not finite", p.line);
        }
        if yaw(p.orientation).is_none() {
            bail!(
                "{what}: {unit} {}: quaternion {:?} has no yaw (not finite, zero or pointing up)",
                p.line,
                p.orientation
            );
        }
        if let Some(q) = prev {
            if p.t <= q.t {
                bail!(
                    "{what}: {unit} {}: stamp {:.9} s is not after the previous one ({:.9} s at {unit} {}); \
                     duplicated or non-increasing stamps",
                    p.line,
                    p.t,
                    q.t,
                    q.line
                );
            }
        }
        prev = Some(p);
    }
    if poses.len() < 2 {
        bail!("{what}: {} poses; at least 2 are needed", poses.len());
    }
    Ok(())
}

/// The poses as local epochs: x, y in the reference frame, heading `pi/2 - yaw`, no sigmas.
pub fn epochs(poses: &[TrajectoryPose]) -> Vec<LocalEpoch> {
    poses
        .iter()
        .map(|p| LocalEpoch {
            t: p.t,
            x: p.position[0],
            y: p.position[1],
            up: Some(p.position[2]),
            heading: yaw(p.orientation).map(heading_of_yaw),
            sigma_east_north: None,
            fix: FixQuality::RtkFixed,
            line: p.line,
        })
        .collect()
}

/// Chord (m) of the reference path over which the direction of travel is compared with the
/// marker's heading.
pub const YAW_CHORD: f64 = 0.2;
/// Largest heading change (rad) over a chord that counts as straight.
pub const YAW_STRAIGHT: f64 = 1.0 * PI / 180.0;
/// Fewest straight chords [`marker_yaw_offset`] needs.
pub const YAW_MIN_CHORDS: usize = 10;

/// The marker heading's offset from the chassis axis (rad, to be added to the marker's
/// heading), with the number of straight chords it is estimated from: on chords of
/// [`YAW_CHORD`] m of the path (no longer than 1.05 times that) over which the marker's heading
/// changes less than [`YAW_STRAIGHT`], the chassis moves along its axis, so the direction of
/// travel less the marker heading is the offset, or the offset plus pi when driving backwards.
/// The offset modulo pi is their doubled-angle circular mean; of the two, the one more chords
/// agree with is taken (the chassis is taken to drive forwards more than backwards), then the
/// chords' circular mean about it. `None` with fewer than [`YAW_MIN_CHORDS`] straight chords
/// or without headings.
pub fn marker_yaw_offset(epochs: &[LocalEpoch]) -> Option<(f64, usize)> {
    let mut d = Vec::new();
    let mut i = 0;
    while i < epochs.len() {
        let a = &epochs[i];
        let mut path = 0.0;
        let mut j = i + 1;
        while j < epochs.len() {
            let (p, q) = (&epochs[j - 1], &epochs[j]);
            path += (q.x - p.x).hypot(q.y - p.y);
            if (q.x - a.x).hypot(q.y - a.y) >= YAW_CHORD {
                break;
            }
            j += 1;
        }
        if j >= epochs.len() {
            break;
        }
        let b = &epochs[j];
        if let (Some(ha), Some(hb)) = (a.heading, b.heading) {
            let chord = (b.x - a.x).hypot(b.y - a.y);
            if wrap(hb - ha).abs() < YAW_STRAIGHT && path <= 1.05 * chord {
                let travel = (b.x - a.x).atan2(b.y - a.y);
                d.push(wrap(travel - (ha + 0.5 * wrap(hb - ha))));
            }
        }
        i = j;
    }
    if d.len() < YAW_MIN_CHORDS {
        return None;
    }
    let (s2, c2) = d.iter().fold((0.0, 0.0), |(s, c), v| {
        (s + (2.0 * v).sin(), c + (2.0 * v).cos())
    });
    let half = 0.5 * s2.atan2(c2);
    let forward = d
        .iter()
        .filter(|v| wrap(*v - half).abs() < FRAC_PI_2)
        .count();
    let base = if 2 * forward >= d.len() {
        half
    } else {
        wrap(half + PI)
    };
    let (s, c) = d.iter().fold((0.0, 0.0), |(s, c), v| {
        let mut e = wrap(v - base);
        if e.abs() >= FRAC_PI_2 {
            e = wrap(e + PI);
        }
        (s + e.sin(), c + e.cos())
    });
    Some((wrap(base + s.atan2(c)), d.len()))
}

/// What [`resample`] left out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ResampleReport {
    /// Sample instants inside the reference's span.
    pub inside: usize,
    /// Of those, the ones in a gap of the reference (two poses more than [`GAP_FACTOR`] median
    /// intervals apart): left out.
    pub in_gaps: usize,
    /// Gaps.
    pub gaps: usize,
}

/// A gap: two consecutive poses more than this many median intervals apart.
pub const GAP_FACTOR: f64 = 2.5;

/// The reference at the sample instants `times` (s, samples' clock; increasing), the epochs'
/// stamps mapped to that clock by `to_samples`: positions (and headings, the shorter way
/// round) interpolated linearly between the two poses around each instant, at most one
/// instant per median pose interval (instants closer than 0.999 of it to the previous one
/// kept are passed over, so a 10 Hz reference gives about 10 points per second whatever the
/// sample rate); instants in a gap are left out and counted.
pub fn resample(
    epochs: &[LocalEpoch],
    to_samples: impl Fn(f64) -> f64,
    times: &[f64],
) -> (Vec<RefPoint>, ResampleReport) {
    let mut report = ResampleReport::default();
    let mut out = Vec::new();
    if epochs.len() < 2 {
        return (out, report);
    }
    let ts: Vec<f64> = epochs.iter().map(|e| to_samples(e.t)).collect();
    let mut dts: Vec<f64> = ts.windows(2).map(|w| w[1] - w[0]).collect();
    dts.sort_by(f64::total_cmp);
    let median = dts[dts.len() / 2];
    let mut j = 0;
    let mut last_gap = usize::MAX;
    let mut last_kept = f64::NEG_INFINITY;
    for &t in times {
        if t < ts[0] || t > ts[ts.len() - 1] {
            continue;
        }
        report.inside += 1;
        while j + 2 < ts.len() && ts[j + 1] < t {
            j += 1;
        }
        let (t0, t1) = (ts[j], ts[j + 1]);
        if t1 - t0 > GAP_FACTOR * median {
            report.in_gaps += 1;
            if last_gap != j {
                report.gaps += 1;
                last_gap = j;
            }
            continue;
        }
        if t - last_kept < 0.999 * median {
            continue;
        }
        last_kept = t;
        let w = (t - t0) / (t1 - t0);
        let (a, b) = (&epochs[j], &epochs[j + 1]);
        out.push(RefPoint {
            t,
            x: a.x + w * (b.x - a.x),
            y: a.y + w * (b.y - a.y),
            heading: match (a.heading, b.heading) {
                (Some(ha), Some(hb)) => Some(wrap(ha + w * wrap(hb - ha))),
                _ => None,
            },
            sigma_h: None,
        });
    }
    (out, report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn q_of_yaw(yaw: f64) -> [f64; 4] {
        [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()]
    }

    #[test]
    fn yaw_and_heading_table() {
        // (quaternion, yaw, heading)
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let table = [
            ([0.0, 0.0, 0.0, 1.0], 0.0, FRAC_PI_2),
            ([0.0, 0.0, s, s], FRAC_PI_2, 0.0),
            ([0.0, 0.0, 1.0, 0.0], PI, -FRAC_PI_2),
            ([0.0, 0.0, -s, s], -FRAC_PI_2, PI),
            // Not normalised: the same yaw.
            ([0.0, 0.0, 2.0 * s, 2.0 * s], FRAC_PI_2, 0.0),
            // Rolled by 180 degrees about x: x axis unchanged.
            ([1.0, 0.0, 0.0, 0.0], 0.0, FRAC_PI_2),
        ];
        for (q, y, h) in table {
            let got = yaw(q).unwrap();
            assert!(wrap(got - y).abs() < 1e-12, "{q:?}: {got}");
            assert!(wrap(heading_of_yaw(got) - h).abs() < 1e-12, "{q:?}");
        }
        for bad in [
            [f64::NAN, 0.0, 0.0, 1.0],
            [0.0; 4],
            // x axis along +z: pitched 90 degrees.
            [0.0, -s, 0.0, s],
        ] {
            assert_eq!(yaw(bad), None, "{bad:?}");
        }
        for a in [-7.0, -PI, 0.0, PI, 3.5, 100.0] {
            let w = wrap(a);
            assert!(w > -PI && w <= PI && ((a - w) / TAU).fract().abs() < 1e-9);
        }
    }

    fn pose(t: f64, x: f64, yaw: f64, line: usize) -> TrajectoryPose {
        TrajectoryPose {
            t,
            position: [x, 0.0, 0.0],
            orientation: q_of_yaw(yaw),
            line,
        }
    }

    #[test]
    fn check_names_the_problem() {
        let ok = [pose(0.0, 0.0, 0.0, 1), pose(0.1, 0.1, 0.0, 2)];
        check("f", "line", &ok).unwrap();
        let dup = [pose(0.0, 0.0, 0.0, 1), pose(0.0, 0.1, 0.0, 2)];
        let e = check("f", "line", &dup).unwrap_err().to_string();
        assert!(
            e.contains("f: line 2") && e.contains("non-increasing"),
            "{e}"
        );
        let mut nan = ok;
        nan[1].orientation[3] = f64::NAN;
        let e = check("f", "line", &nan).unwrap_err().to_string();
        assert!(e.contains("f: line 2: quaternion"), "{e}");
        let e = check("f", "line", &ok[..1]).unwrap_err().to_string();
        assert!(e.contains("1 poses"), "{e}");
    }

    /// A square path of side 2 m at 0.1 m steps, driven forwards, marker heading off by
    /// `offset` from the chassis axis.
    fn square(offset: f64) -> Vec<LocalEpoch> {
        let mut out = Vec::new();
        let (mut x, mut y, mut h) = (1.0, -2.0, 0.3f64);
        let mut t = 0.0;
        for _ in 0..4 {
            for _ in 0..20 {
                x += 0.1 * h.sin();
                y += 0.1 * h.cos();
                t += 0.1;
                out.push(LocalEpoch {
                    t,
                    x,
                    y,
                    up: None,
                    heading: Some(wrap(h - offset)),
                    sigma_east_north: None,
                    fix: FixQuality::RtkFixed,
                    line: out.len() + 1,
                });
            }
            h += FRAC_PI_2;
        }
        out
    }

    #[test]
    fn marker_yaw_offset_recovered_forwards_and_backwards() {
        for offset in [0.0, 0.4, -2.0, PI] {
            let (o, n) = marker_yaw_offset(&square(offset)).unwrap();
            assert!(wrap(o - offset).abs() < 1e-9, "{offset}: {o}");
            assert!(n >= YAW_MIN_CHORDS, "{n}");
        }
        // Driven backwards mostly: the heading is the marker's + offset + pi; the majority
        // decides, so the offset found is off by pi.
        let mut back = square(0.4);
        for e in &mut back {
            e.heading = e.heading.map(|h| wrap(h + PI));
        }
        let (o, _) = marker_yaw_offset(&back).unwrap();
        assert!(wrap(o - 0.4 + PI).abs() < 1e-9, "{o}");
        let mut none = square(0.0);
        for e in &mut none {
            e.heading = None;
        }
        assert_eq!(marker_yaw_offset(&none), None);
    }

    #[test]
    fn resampling_interpolates_thins_and_skips_gaps() {
        let mut e = square(0.0);
        // A gap: poses 30..35 missing.
        e.drain(30..35);
        let times: Vec<f64> = (0..1000).map(|k| k as f64 * 0.02 - 5.0).collect();
        let (p, r) = resample(&e, |t| t - 3.0, &times);
        // Span 0.1-3 .. 8-3 s, 0.5 s gap.
        assert_eq!(r.gaps, 1);
        assert!((29..=31).contains(&r.in_gaps), "{r:?}");
        assert!(p.windows(2).all(|w| w[1].t - w[0].t >= 0.0999), "thinned");
        assert!((p.len() as f64 - 73.0).abs() <= 3.0, "{}", p.len());
        // Each point interpolated between the two poses around it.
        for q in &p {
            let k = e.iter().position(|a| a.t - 3.0 >= q.t).unwrap().max(1);
            let (a, b) = (&e[k - 1], &e[k]);
            let w = (q.t + 3.0 - a.t) / (b.t - a.t);
            assert!((q.x - (a.x + w * (b.x - a.x))).abs() < 1e-9, "{q:?}");
            assert!((q.y - (a.y + w * (b.y - a.y))).abs() < 1e-9, "{q:?}");
        }
    }
}
