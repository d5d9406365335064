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
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    Summary {
        n,
        mean,
        std: var.sqrt(),
        rms,
        min: sorted[0],
        median: quantile_sorted(&sorted, 0.5),
        p95: quantile_sorted(&sorted, 0.95),
        max: sorted[n - 1],
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
