//! Coverage of the predicted uncertainty over an ensemble of runs, by distance travelled: the
//! test of an uncertainty model that one run cannot give (its errors along the run are one
//! correlated sample). Used by `validate` on several runs and by the ensemble test against
//! the simulator's truth.

/// The default checkpoints: 10, 20, ..., 60 m of travel from the start.
pub const CHECKPOINTS: [f64; 6] = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0];

/// Nominal levels of the reliability diagram.
pub const RELIABILITY_LEVELS: [f64; 9] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];

/// One run's error and predicted sigma at a checkpoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckpointSample {
    /// Horizontal error (m) and `sigma_h` (m).
    pub horizontal: (f64, f64),
    /// Heading error (rad) and `sigma_heading` (rad), when known.
    pub heading: Option<(f64, f64)>,
}

/// The errors of many runs at the checkpoints.
#[derive(Debug, Clone, Default)]
pub struct Ensemble {
    /// Distances travelled from the start (m).
    pub distances: Vec<f64>,
    /// Per checkpoint, one sample per run that reached it.
    pub samples: Vec<Vec<CheckpointSample>>,
    /// Runs added.
    pub runs: usize,
}

/// The coverage at one checkpoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckpointCoverage {
    /// Distance (m).
    pub distance: f64,
    /// Runs that reached it.
    pub runs: usize,
    /// Share of horizontal errors within 1 and 3 `sigma_h`.
    pub horizontal: (f64, f64),
    /// Share of heading errors within 1 and 3 `sigma_heading` (NaN without headings).
    pub heading: (f64, f64),
}

impl Ensemble {
    /// An empty ensemble over `distances` (m).
    pub fn new(distances: &[f64]) -> Self {
        Self {
            distances: distances.to_vec(),
            samples: vec![Vec::new(); distances.len()],
            runs: 0,
        }
    }

    /// Adds one run: at each checkpoint the first point whose distance from the start
    /// (`dist`, non-decreasing) reaches it; `at(i)` gives that point's sample.
    pub fn add_run(&mut self, dist: &[f64], at: impl Fn(usize) -> CheckpointSample) {
        self.runs += 1;
        let mut i = 0;
        for (c, &d) in self.distances.iter().enumerate() {
            while i < dist.len() && dist[i] < d {
                i += 1;
            }
            if i < dist.len() {
                self.samples[c].push(at(i));
            }
        }
    }

    /// The coverage at every checkpoint.
    pub fn coverage(&self) -> Vec<CheckpointCoverage> {
        self.distances
            .iter()
            .zip(&self.samples)
            .map(|(&distance, s)| {
                let share = |f: &dyn Fn(&CheckpointSample) -> Option<bool>| {
                    let v: Vec<bool> = s.iter().filter_map(f).collect();
                    if v.is_empty() {
                        f64::NAN
                    } else {
                        v.iter().filter(|b| **b).count() as f64 / v.len() as f64
                    }
                };
                let h = |k: f64| share(&|p| Some(p.horizontal.0.abs() <= k * p.horizontal.1));
                let a = |k: f64| share(&|p| p.heading.map(|(e, s)| e.abs() <= k * s));
                CheckpointCoverage {
                    distance,
                    runs: s.len(),
                    horizontal: (h(1.0), h(3.0)),
                    heading: (a(1.0), a(3.0)),
                }
            })
            .collect()
    }

    /// The reliability diagram over all checkpoints: per nominal level `p`
    /// ([`RELIABILITY_LEVELS`]) the share of errors inside the band that a calibrated model
    /// covers with probability `p`. Heading: normal, `|e| <= z sigma`, `z` the two-sided
    /// normal quantile. Horizontal: a round 2-D normal (`sigma_x = sigma_y`), `|e| <= c
    /// sigma_h` with `c = sqrt(-ln(1 - p))` (an elongated error ellipse covers a little more
    /// at the low levels and less at the high ones). Returns `(p, horizontal, heading)`.
    pub fn reliability(&self) -> Vec<(f64, f64, f64)> {
        let all: Vec<&CheckpointSample> = self.samples.iter().flatten().collect();
        RELIABILITY_LEVELS
            .iter()
            .map(|&p| {
                let c = (-(1.0 - p).ln()).sqrt();
                let z = normal_quantile(0.5 + 0.5 * p);
                let h = all
                    .iter()
                    .filter(|s| s.horizontal.0 <= c * s.horizontal.1)
                    .count() as f64
                    / all.len().max(1) as f64;
                let heads: Vec<(f64, f64)> = all.iter().filter_map(|s| s.heading).collect();
                let a = if heads.is_empty() {
                    f64::NAN
                } else {
                    heads.iter().filter(|(e, s)| e.abs() <= z * s).count() as f64
                        / heads.len() as f64
                };
                (p, h, a)
            })
            .collect()
    }
}

/// The standard normal quantile (Acklam's rational approximation, relative error 1.2e-9).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p <= 0.0 {
        return f64::NEG_INFINITY;
    }
    if p >= 1.0 {
        return f64::INFINITY;
    }
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_quantiles() {
        for (p, z) in [
            (0.5, 0.0),
            (0.841_344_746, 1.0),
            (0.977_249_868, 2.0),
            (0.998_650_102, 3.0),
            (0.01, -2.326_347_874),
        ] {
            assert!((normal_quantile(p) - z).abs() < 1e-6, "{p}");
        }
    }

    #[test]
    fn checkpoints_take_the_first_point_past_them() {
        let mut e = Ensemble::new(&[1.0, 2.0, 5.0]);
        let dist = [0.0, 0.6, 1.2, 1.9, 2.0, 3.0];
        e.add_run(&dist, |i| CheckpointSample {
            horizontal: (i as f64, 2.5),
            heading: None,
        });
        assert_eq!(e.samples[0][0].horizontal.0, 2.0);
        assert_eq!(e.samples[1][0].horizontal.0, 4.0);
        assert!(
            e.samples[2].is_empty(),
            "a checkpoint not reached has no sample"
        );
        let c = e.coverage();
        assert_eq!(c[0].horizontal, (1.0, 1.0));
        assert_eq!(c[1].horizontal, (0.0, 1.0));
        assert!(c[0].heading.0.is_nan());
    }

    #[test]
    fn reliability_of_a_calibrated_normal_is_the_diagonal() {
        let mut rng = odo_testkit::Rng::new(7);
        let mut e = Ensemble::new(&[1.0]);
        for _ in 0..20_000 {
            let (x, y, a) = (rng.normal(), rng.normal(), rng.normal());
            e.add_run(&[1.0], |_| CheckpointSample {
                horizontal: (x.hypot(y) * 0.3, 0.3 * 2f64.sqrt()),
                heading: Some((a * 0.01, 0.01)),
            });
        }
        for (p, h, a) in e.reliability() {
            assert!((h - p).abs() < 0.015, "{p}: {h}");
            assert!((a - p).abs() < 0.015, "{p}: {a}");
        }
    }
}
