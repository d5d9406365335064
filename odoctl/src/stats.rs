//! Descriptive statistics of error series and parameter sets.

/// Summary of a set of values.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Summary {
    /// Number of values.
    pub n: usize,
    /// Mean.
    pub mean: f64,
    /// Sample standard deviation (n - 1); 0 for fewer than two values.
    pub std: f64,
    /// Root mean square.
    pub rms: f64,
    /// Smallest value.
    pub min: f64,
    /// Median.
    pub median: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Largest value.
    pub max: f64,
}

/// Robust standard deviation of a normal sample from its median absolute value.
pub const MAD_TO_SIGMA: f64 = 1.482_602_218_505_602;

/// The median of `v` (reordered; the upper middle of an even count), `None` when empty.
pub fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// The `q` quantile (0..=1) of sorted values, linearly interpolated.
pub fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let i = pos.floor() as usize;
    let frac = pos - i as f64;
    if i + 1 < sorted.len() {
        sorted[i] + frac * (sorted[i + 1] - sorted[i])
    } else {
        sorted[i]
    }
}

/// Summarises `values` (NaN when empty).
pub fn summarize(values: &[f64]) -> Summary {
    let n = values.len();
    if n == 0 {
        let nan = f64::NAN;
        return Summary {
            n,
            mean: nan,
            std: nan,
            rms: nan,
            min: nan,
            median: nan,
            p95: nan,
            max: nan,
        };
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    let var = if n > 1 {
        values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64
    } else {
        0.0
    };
    let rms = (values.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
    let mut order = values.to_vec();
    let extreme = |pick: fn(f64, f64) -> f64| order.iter().copied().reduce(pick);
    let (min, max) = (extreme(min_total), extreme(max_total));
    Summary {
        n,
        mean,
        std: var.sqrt(),
        rms,
        min: min.unwrap_or(f64::NAN),
        median: quantile_selected(&mut order, 0.5),
        p95: quantile_selected(&mut order, 0.95),
        max: max.unwrap_or(f64::NAN),
    }
}

/// The smaller of two values in [`f64::total_cmp`]'s order.
fn min_total(a: f64, b: f64) -> f64 {
    if b.total_cmp(&a).is_lt() {
        b
    } else {
        a
    }
}

/// The larger of two values in [`f64::total_cmp`]'s order.
fn max_total(a: f64, b: f64) -> f64 {
    if b.total_cmp(&a).is_gt() {
        b
    } else {
        a
    }
}

/// [`quantile_sorted`] of `values` sorted by [`f64::total_cmp`], from the two order
/// statistics it reads (selected, not sorted: linear time), reordering `values`.
pub fn quantile_selected(values: &mut [f64], q: f64) -> f64 {
    let n = values.len();
    if n == 0 {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (n - 1) as f64;
    let i = pos.floor() as usize;
    let frac = pos - i as f64;
    let (_, &mut at, above) = values.select_nth_unstable_by(i, f64::total_cmp);
    match above.iter().copied().reduce(min_total) {
        Some(next) => at + frac * (next - at),
        None => at,
    }
}

/// Fraction of `errors[i]` (absolute values) within `k * sigmas[i]`.
pub fn coverage(errors: &[f64], sigmas: &[f64], k: f64) -> f64 {
    if errors.is_empty() {
        return f64::NAN;
    }
    let inside = errors
        .iter()
        .zip(sigmas)
        .filter(|(e, s)| e.abs() <= k * **s)
        .count();
    inside as f64 / errors.len() as f64
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    // Most angles are already in range: returned as they are (exactly), without fmod.
    if a > -std::f64::consts::PI && a <= std::f64::consts::PI {
        return a;
    }
    let tau = std::f64::consts::TAU;
    let mut r = a.rem_euclid(tau);
    if r > std::f64::consts::PI {
        r -= tau;
    }
    r
}

/// The 99 % quantile of chi-square with `k` degrees of freedom (Wilson-Hilferty).
pub fn chi2_quantile_99(k: f64) -> f64 {
    let z = 2.326_347_874;
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_quantile_99_matches_the_tables() {
        // Tabulated 99 % quantiles: 10 -> 23.21, 30 -> 50.89.
        for (k, q) in [(10.0, 23.21), (30.0, 50.89)] {
            assert!((chi2_quantile_99(k) - q).abs() < 0.1, "{k}");
        }
    }

    /// The selected quantiles, minimum and maximum are the sorted values' to the bit: ties,
    /// signed zeros, infinities, one value, every quantile step.
    #[test]
    fn selected_quantiles_are_the_sorted_ones() {
        let mut x = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let special = [0.0, -0.0, 1.0, 1.0, f64::INFINITY, f64::NEG_INFINITY, -2.5];
        for n in [1, 2, 3, 7, 100, 1001] {
            let values: Vec<f64> = (0..n)
                .map(|_| match next() % 4 {
                    0 => special[(next() % special.len() as u64) as usize],
                    _ => (next() % 2000) as f64 / 7.0 - 140.0,
                })
                .collect();
            let mut sorted = values.clone();
            sorted.sort_by(f64::total_cmp);
            for q in [0.0, 0.1, 0.5, 0.95, 0.999, 1.0] {
                let mut v = values.clone();
                let (a, b) = (quantile_selected(&mut v, q), quantile_sorted(&sorted, q));
                assert!(
                    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                    "{n} {q}"
                );
            }
            let s = summarize(&values);
            assert_eq!(s.min.to_bits(), sorted[0].to_bits());
            assert_eq!(s.max.to_bits(), sorted[n - 1].to_bits());
        }
    }

    #[test]
    fn summary_and_coverage() {
        let s = summarize(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(s.mean, 2.5);
        assert_eq!(s.median, 2.5);
        assert!((s.std - 1.2909944487358056).abs() < 1e-12);
        assert_eq!(
            coverage(&[1.0, -2.0, 3.0], &[1.0, 1.0, 1.0], 2.0),
            2.0 / 3.0
        );
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_angle(-0.1) + 0.1).abs() < 1e-15);
    }
}
