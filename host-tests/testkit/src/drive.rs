//! Drive generators: per-sample encoder increments of a varied drive (straights, arcs of both
//! senses, pivots, stops and reversing), deterministic for a seed.

use std::vec::Vec;

use crate::Rng;

/// An endless drive at `rate` samples per second and 0.3 to 1.5 m/s: stretches of 50 to
/// 1,549 samples, each a straight, an arc either way, a pivot or a stop, reversing one time
/// in ten. Yields `[d_left, d_right]` increments per sample (the fractions carried over).
#[derive(Debug, Clone)]
pub struct Drive {
    rng: Rng,
    counts_per_metre: f64,
    rate: f64,
    remaining: usize,
    speed: [f64; 2],
    acc: [f64; 2],
}

impl Drive {
    /// A drive for wheels of `counts_per_metre` increments per metre, sampled at `rate` Hz.
    pub fn new(rng: Rng, counts_per_metre: f64, rate: f64) -> Self {
        Self {
            rng,
            counts_per_metre,
            rate,
            remaining: 0,
            speed: [0.0; 2],
            acc: [0.0; 2],
        }
    }
}

impl Iterator for Drive {
    type Item = [i64; 2];

    fn next(&mut self) -> Option<[i64; 2]> {
        let rng = &mut self.rng;
        if self.remaining == 0 {
            self.remaining = 50 + (rng.next_u64() % 1500) as usize;
            let v = 0.3 + 1.2 * rng.uniform();
            let v = if rng.uniform() < 0.1 { -v } else { v };
            self.speed = match rng.next_u64() % 6 {
                0 | 1 => [v, v],
                2 => [v, v * (0.2 + 0.7 * rng.uniform())],
                3 => [v * (0.2 + 0.7 * rng.uniform()), v],
                4 => [0.3 * v, -0.3 * v],
                _ => [0.0, 0.0],
            };
        }
        self.remaining -= 1;
        let mut d = [0i64; 2];
        for (i, d) in d.iter_mut().enumerate() {
            self.acc[i] += self.speed[i] * self.counts_per_metre / self.rate;
            *d = self.acc[i].round() as i64;
            self.acc[i] -= *d as f64;
        }
        Some(d)
    }
}

/// The first `samples` increments of a [`Drive`] (the generator advanced in place, so
/// consecutive calls continue one drive's randomness).
pub fn drive_increments(
    rng: &mut Rng,
    samples: usize,
    counts_per_metre: f64,
    rate: f64,
) -> Vec<[i64; 2]> {
    let mut drive = Drive::new(rng.clone(), counts_per_metre, rate);
    let out = drive.by_ref().take(samples).collect();
    *rng = drive.rng;
    out
}
