//! Covariance of an estimate from its normal equations: the formal one for independent
//! residuals, `H^-1 s^2`, the cluster-robust jackknife ([`cluster_jackknife`]) that
//! `calibrate` reports, and the plain cluster-robust sandwich `H^-1 (G/(G-1) sum_c g_c g_c^T) H^-1`
//! over clusters of residuals (sub-trajectories, or consecutive stretches of one path) whose
//! errors are correlated within a cluster and independent between clusters: `H` the
//! (Gauss-Newton) Hessian of the objective at the estimate, `g_c` the gradient of cluster `c`'s
//! part of it, `G` the number of clusters (the small-sample factor `G/(G-1)`).
//!
//! Odometry errors are a random walk along a path: neighbouring residuals share the slip
//! that went before them, so `H^-1 s^2` is far too small (a thousand times on a 3 km run).
//! The sandwich only asks that whole clusters be independent, which slip with a correlation
//! length of centimetres and a path restarted (or cut) every few metres gives.

use crate::optim;

/// Inverse of the symmetric `n x n` matrix `h` (row-major); `None` when it is singular.
pub fn inverse(h: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut inv = vec![0.0; n * n];
    for j in 0..n {
        let mut e = vec![0.0; n];
        e[j] = 1.0;
        let col = optim::solve(h.to_vec(), e)?;
        if col.iter().any(|v| !v.is_finite()) {
            return None;
        }
        for i in 0..n {
            inv[i * n + j] = col[i];
        }
    }
    Some(inv)
}

/// `H^-1 s^2`: the covariance for independent residuals of variance `s2`.
pub fn independent(h: &[f64], n: usize, s2: f64) -> Option<Vec<f64>> {
    Some(inverse(h, n)?.into_iter().map(|v| v * s2).collect())
}

/// The cluster-robust sandwich `H^-1 (G/(G-1) sum_c g_c g_c^T) H^-1` of the module
/// documentation, from the Hessian `h` (`n x n`) and the clusters' gradients `scores`;
/// `None` when `H` is singular or there are fewer than two clusters.
pub fn cluster_sandwich(h: &[f64], n: usize, scores: &[Vec<f64>]) -> Option<Vec<f64>> {
    let g = scores.len();
    if g < 2 {
        return None;
    }
    let inv = inverse(h, n)?;
    let mut meat = vec![0.0; n * n];
    for s in scores {
        for i in 0..n {
            for j in 0..n {
                meat[i * n + j] += s[i] * s[j];
            }
        }
    }
    let f = g as f64 / (g - 1) as f64;
    let mul = |a: &[f64], b: &[f64]| {
        let mut c = vec![0.0; n * n];
        for i in 0..n {
            for k in 0..n {
                for j in 0..n {
                    c[i * n + j] += a[i * n + k] * b[k * n + j];
                }
            }
        }
        c
    };
    Some(
        mul(&mul(&inv, &meat), &inv)
            .into_iter()
            .map(|v| v * f)
            .collect(),
    )
}

/// The delete-one-cluster jackknife of the estimate, linearised (the cluster-robust `CR3`
/// form): leaving cluster `c` out moves the estimate by `d_c = (H - H_c)^-1 g_c` (`H_c` the
/// cluster's share of the Hessian, `g_c` of the gradient), and the covariance is
/// `(G-1)/G sum_c (d_c - mean d)(d_c - mean d)^T`. Unlike the plain sandwich it is not
/// biased low when a few clusters carry much of the information (the sub-trajectories that
/// turn most, for the track width) or when there are few clusters. `None` when `H` or a
/// leave-one-out `H - H_c` is singular, or with fewer than two clusters.
pub fn cluster_jackknife(
    h: &[f64],
    n: usize,
    clusters: &[(Vec<f64>, Vec<f64>)],
) -> Option<Vec<f64>> {
    let g = clusters.len();
    if g < 2 {
        return None;
    }
    inverse(h, n)?;
    let mut shifts = Vec::with_capacity(g);
    for (hc, gc) in clusters {
        let rest: Vec<f64> = h.iter().zip(hc).map(|(a, b)| a - b).collect();
        shifts.push(optim::solve(rest, gc.clone())?);
    }
    let mean: Vec<f64> = (0..n)
        .map(|i| shifts.iter().map(|d| d[i]).sum::<f64>() / g as f64)
        .collect();
    let f = (g - 1) as f64 / g as f64;
    let mut cov = vec![0.0; n * n];
    for d in &shifts {
        for i in 0..n {
            for j in 0..n {
                cov[i * n + j] += f * (d[i] - mean[i]) * (d[j] - mean[j]);
            }
        }
    }
    Some(cov)
}

/// Square roots of the diagonal of an `n x n` covariance (infinite where negative or not
/// finite).
pub fn diagonal_std_errors(cov: &[f64], n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let v = cov[i * n + i];
            if v >= 0.0 && v.is_finite() {
                v.sqrt()
            } else {
                f64::INFINITY
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Least squares of a mean over clusters with a shared offset each: the sandwich sees the
    /// clusters' spread, the formal error only the residuals'.
    #[test]
    fn sandwich_of_a_clustered_mean() {
        // y = mu + u_c + e, 4 clusters of 3; H = sum 1 = 12 (squares: 2 J^T J / 2).
        let offsets = [0.3, -0.2, 0.1, -0.2];
        let noise = [0.01, -0.01, 0.0];
        let mut ys = Vec::new();
        for u in offsets {
            for e in noise {
                ys.push(u + e);
            }
        }
        let mu = ys.iter().sum::<f64>() / ys.len() as f64;
        let h = [12.0];
        let scores: Vec<Vec<f64>> = ys
            .chunks(3)
            .map(|c| vec![c.iter().map(|y| mu - y).sum()])
            .collect();
        let cov = cluster_sandwich(&h, 1, &scores).unwrap();
        // By hand: sum_c (3 (mean_c - mu))^2 / 144 * 4/3.
        let means: Vec<f64> = ys.chunks(3).map(|c| c.iter().sum::<f64>() / 3.0).collect();
        let meat: f64 = means.iter().map(|m| (3.0 * (m - mu)).powi(2)).sum();
        assert!((cov[0] - meat / 144.0 * 4.0 / 3.0).abs() < 1e-15);
        let s2 = ys.iter().map(|y| (y - mu).powi(2)).sum::<f64>() / 11.0;
        let formal = independent(&h, 1, s2).unwrap()[0];
        assert!(cov[0] > 2.0 * formal, "{} {}", cov[0], formal);
        assert!(cluster_sandwich(&h, 1, &scores[..1]).is_none());
        assert!(inverse(&[0.0], 1).is_none());
        assert_eq!(
            diagonal_std_errors(&[4.0, 0.0, 0.0, -1.0], 2),
            [2.0, f64::INFINITY]
        );
    }
}
