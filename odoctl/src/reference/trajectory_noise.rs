//! A trajectory reference's own noise, from its second differences: what `calibrate` and
//! `validate` take for `--reference-sigma` and `--reference-heading-sigma-deg` against a
//! trajectory (TUM, ROS 2 MCAP) when they are not given.
//!
//! Over three consecutive poses equally spaced in time the motion's second difference is its
//! acceleration times `dt^2` (at 0.5 m/s turning on a 1 m radius and 100 Hz, 0.03 mm), while
//! independent noise of `sigma` per axis gives the second difference a standard deviation of
//! `sqrt 6 sigma`. The robust standard deviation (1.4826 times the median absolute value) over
//! both axes, divided by `sqrt 6`, is the per-axis sigma; `sqrt 2` times it the horizontal RMS
//! the options mean. The same over the headings gives the heading's sigma. Motion capture and
//! most trajectory references have errors independent from pose to pose, which this measures;
//! a slow drift (a SLAM map's) hardly moves a second difference and is not in it (RTK
//! receivers, whose errors are correlated over seconds, keep the stated `--reference-sigma`).

use crate::stats::{median, wrap_angle, MAD_TO_SIGMA};

use super::{LocalEpoch, Reference, TimeScale};

/// Largest time between two poses whose second difference counts (s).
pub const MAX_GAP: f64 = 0.25;

/// Largest relative difference of the two time steps of a counted second difference.
const EVEN_STEPS: f64 = 0.01;

/// Fewest second differences for a figure.
pub const MIN_TRIPLES: usize = 20;

/// A trajectory's noise as its second differences show it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectoryNoise {
    /// Horizontal RMS noise of one pose (m), `hypot(sigma_x, sigma_y)`.
    pub horizontal: f64,
    /// Noise of one pose's heading (rad, 1 sigma), where the trajectory has headings.
    pub heading: Option<f64>,
    /// Second differences behind `horizontal`.
    pub triples: usize,
}

impl TrajectoryNoise {
    /// The noise of `r` when it is a trajectory (TUM, MCAP; [`TrajectoryNoise::of`] its
    /// epochs), `None` for a receiver log or a REFERENCE CSV.
    pub fn of_reference(r: &Reference) -> Option<Self> {
        (r.time == TimeScale::Trajectory)
            .then(|| Self::of(&r.epochs))
            .flatten()
    }

    /// The noise of `epochs` (times increasing); `None` with fewer than [`MIN_TRIPLES`]
    /// evenly spaced triples within [`MAX_GAP`].
    pub fn of(epochs: &[LocalEpoch]) -> Option<Self> {
        let mut axes = Vec::with_capacity(2 * epochs.len());
        let mut headings = Vec::new();
        for w in epochs.windows(3) {
            let (a, b, c) = (&w[0], &w[1], &w[2]);
            let (d1, d2) = (b.t - a.t, c.t - b.t);
            if !(d1 > 0.0 && d2 > 0.0 && d1.max(d2) <= MAX_GAP)
                || (d1 - d2).abs() > EVEN_STEPS * d1.max(d2)
            {
                continue;
            }
            axes.push((c.x - 2.0 * b.x + a.x).abs());
            axes.push((c.y - 2.0 * b.y + a.y).abs());
            if let (Some(ha), Some(hb), Some(hc)) = (a.heading, b.heading, c.heading) {
                headings.push(wrap_angle(wrap_angle(hc - hb) - wrap_angle(hb - ha)).abs());
            }
        }
        let triples = axes.len() / 2;
        if triples < MIN_TRIPLES {
            return None;
        }
        let per_axis = MAD_TO_SIGMA * median(&mut axes)? / 6f64.sqrt();
        let heading = (headings.len() >= MIN_TRIPLES)
            .then(|| median(&mut headings))
            .flatten()
            .map(|m| MAD_TO_SIGMA * m / 6f64.sqrt());
        Some(Self {
            horizontal: 2f64.sqrt() * per_axis,
            heading,
            triples,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::FixQuality;
    use crate::simulate::Rng;

    /// Poses every `dt` s along a circle of radius `radius` m at 0.5 m/s with white noise of
    /// `sigma` per axis (m) and `heading_sigma` (rad).
    fn circle(
        seed: u64,
        n: usize,
        dt: f64,
        radius: f64,
        sigma: f64,
        heading_sigma: f64,
    ) -> Vec<LocalEpoch> {
        let mut rng = Rng::new(seed);
        (0..n)
            .map(|i| {
                let t = i as f64 * dt;
                let a = 0.5 * t / radius;
                LocalEpoch {
                    t,
                    x: radius * a.cos() + sigma * rng.normal(),
                    y: radius * a.sin() + sigma * rng.normal(),
                    up: None,
                    heading: Some(wrap_angle(-a + heading_sigma * rng.normal())),
                    sigma_east_north: None,
                    fix: FixQuality::RtkFixed,
                    line: i + 1,
                }
            })
            .collect()
    }

    #[test]
    fn white_noise_is_recovered_on_a_turning_path() {
        // (rate Hz, radius m, per-axis sigma m, heading sigma rad): motion capture, SLAM.
        for (seed, (rate, radius, sigma, hs)) in [
            (100.0, 1.0, 0.00035, 0.1f64.to_radians()),
            (240.0, 0.8, 0.0002, 0.05f64.to_radians()),
            (10.0, 1.5, 0.007, 0.5f64.to_radians()),
            (20.0, 3.0, 0.007, 0.5f64.to_radians()),
        ]
        .into_iter()
        .enumerate()
        {
            let e = circle(seed as u64 + 1, 20_000, 1.0 / rate, radius, sigma, hs);
            let n = TrajectoryNoise::of(&e).expect("enough triples");
            let h = 2f64.sqrt() * sigma;
            assert!(
                (n.horizontal / h - 1.0).abs() < 0.04,
                "{rate} Hz: {} against {h}",
                n.horizontal
            );
            let a = n.heading.expect("headings");
            assert!((a / hs - 1.0).abs() < 0.04, "{rate} Hz: {a} against {hs}");
            assert_eq!(n.triples, 19_998);
        }
    }

    #[test]
    fn gaps_and_uneven_steps_are_not_counted() {
        let mut e = circle(7, 100, 0.01, 1.0, 0.0003, 0.001);
        // A gap of 0.3 s after pose 50, and pose 20's stamp moved by a fifth of a step.
        for p in &mut e[51..] {
            p.t += 0.3;
        }
        e[20].t += 0.002;
        let n = TrajectoryNoise::of(&e).unwrap();
        assert_eq!(n.triples, 98 - 2 - 3);
        assert!(TrajectoryNoise::of(&e[..21]).is_none());
        let without: Vec<LocalEpoch> = e
            .iter()
            .map(|p| LocalEpoch {
                heading: None,
                ..*p
            })
            .collect();
        assert_eq!(TrajectoryNoise::of(&without).unwrap().heading, None);
    }
}
