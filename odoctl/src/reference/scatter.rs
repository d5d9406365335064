//! The position noise a reference shows before any fit: each epoch's deviation from the
//! straight line between its neighbours, over the whole log.
//!
//! For white noise of `sigma` per axis, the deviation of epoch 1 from the line between epochs
//! 0 and 2 has the variance `sigma^2 (1 + a^2 + b^2)` (`a`, `b` the interpolation weights);
//! the chassis's own motion adds about `acceleration dt^2 / 2`, 0.03 mm at 100 Hz and
//! 0.5 m/s^2, so at high rates the deviations are the noise. They are taken robustly (the
//! median of their absolute values, scaled to a standard deviation), so a few jumps do not
//! count.

use super::LocalEpoch;

/// Neighbours further apart than this (s) are a gap: their triples are left out.
pub const MAX_SPAN: f64 = 1.0;

/// Fewest triples for a figure.
pub const MIN_TRIPLES: usize = 20;

/// The position noise per axis (m) shown by the epochs' deviations from their neighbours'
/// line, or `None` with fewer than [`MIN_TRIPLES`] triples within [`MAX_SPAN`].
pub fn position_scatter(epochs: &[LocalEpoch]) -> Option<f64> {
    let mut deviations = Vec::with_capacity(2 * epochs.len());
    for w in epochs.windows(3) {
        let (p0, p1, p2) = (&w[0], &w[1], &w[2]);
        let span = p2.t - p0.t;
        if !(span > 0.0 && span <= MAX_SPAN) {
            continue;
        }
        let (a, b) = ((p2.t - p1.t) / span, (p1.t - p0.t) / span);
        let scale = (1.0 + a * a + b * b).sqrt();
        for (v0, v1, v2) in [(p0.x, p1.x, p2.x), (p0.y, p1.y, p2.y)] {
            let e = (v1 - (a * v0 + b * v2)) / scale;
            if e.is_finite() {
                deviations.push(e.abs());
            }
        }
    }
    if deviations.len() < 2 * MIN_TRIPLES {
        return None;
    }
    let mid = deviations.len() / 2;
    let (_, median, _) = deviations.select_nth_unstable_by(mid, f64::total_cmp);
    // The median of |N(0, 1)| is 0.6745.
    Some(*median / 0.674_489_750_196_081_7)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::FixQuality;

    fn epoch(t: f64, x: f64, y: f64) -> LocalEpoch {
        LocalEpoch {
            t,
            x,
            y,
            up: None,
            heading: None,
            sigma_east_north: None,
            fix: FixQuality::RtkFixed,
            line: 0,
        }
    }

    /// A uniform random number in [0, 1) (xorshift), and a normal one (Box-Muller).
    fn normal(state: &mut u64) -> f64 {
        let mut uniform = || {
            *state ^= *state << 13;
            *state ^= *state >> 7;
            *state ^= *state << 17;
            (*state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (u, v) = (uniform().max(1e-300), uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    /// A circle of radius 4 m at 0.5 m/s, at `rate` Hz with `sigma` of noise per axis and
    /// some irregular spacing.
    fn circle(rate: f64, sigma: f64, seed: u64) -> Vec<LocalEpoch> {
        let mut s = seed.max(1);
        (0..3000)
            .map(|i| {
                let t = (i as f64 + 0.2 * (i % 3) as f64) / rate;
                let phi = 0.5 * t / 4.0;
                epoch(
                    t,
                    4.0 * phi.cos() + sigma * normal(&mut s),
                    4.0 * phi.sin() + sigma * normal(&mut s),
                )
            })
            .collect()
    }

    #[test]
    fn recovers_white_noise_on_a_moving_marker() {
        for (rate, sigma) in [
            (100.0, 0.0005),
            (240.0, 0.0002),
            (10.0, 0.01),
            (50.0, 0.008),
        ] {
            for seed in 1..=5 {
                let got = position_scatter(&circle(rate, sigma, seed)).unwrap();
                assert!((got / sigma - 1.0).abs() < 0.1, "{rate} Hz {sigma}: {got}");
            }
        }
    }

    #[test]
    fn noiseless_motion_shows_almost_nothing() {
        let got = position_scatter(&circle(100.0, 0.0, 1)).unwrap();
        assert!(got < 1e-5, "{got}");
    }

    #[test]
    fn boundaries() {
        // Too few triples, gaps, repeated times: no figure.
        let few: Vec<_> = (0..30).map(|i| epoch(i as f64 * 0.01, 0.0, 0.0)).collect();
        assert_eq!(position_scatter(&few[..MIN_TRIPLES + 1]), None);
        assert!(position_scatter(&few[..MIN_TRIPLES + 2]).is_some());
        let gaps: Vec<_> = (0..100).map(|i| epoch(i as f64 * 0.6, 0.0, 0.0)).collect();
        assert_eq!(position_scatter(&gaps), None);
        let same: Vec<_> = (0..100).map(|_| epoch(1.0, 0.0, 0.0)).collect();
        assert_eq!(position_scatter(&same), None);
        // A few jumps do not move the median.
        let mut c = circle(100.0, 0.0005, 3);
        for e in c.iter_mut().step_by(100) {
            e.x += 1.0;
        }
        let got = position_scatter(&c).unwrap();
        assert!((got / 0.0005 - 1.0).abs() < 0.15, "{got}");
    }
}
