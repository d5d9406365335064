//! Several drives' calibrations pooled into one: the geometry by generalised least squares of
//! the independent estimates, kappa by the precision-weighted mean of `ln kappa`, each with a
//! chi-square test of whether the drives agree within their standard errors.
//!
//! Each drive was driven from its own start and calibrated on its own (its start pose and its
//! reference's noise are its own), so the drives' estimates are independent: to first order the
//! pooled estimate is the one a joint fit of all drives gives, and its covariance is the inverse
//! of the summed information.

use crate::optim::invert3;
use crate::stats::chi2_quantile_99;

/// One drive's calibration, as `calibrate` wrote it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveEstimate {
    /// `left_diameter`, `right_diameter`, `track_width` (m).
    pub geometry: [f64; 3],
    /// Their covariance (m^2).
    pub covariance: [[f64; 3]; 3],
    /// kappa of the largest likelihood (m^2/m).
    pub kappa_most_likely: f64,
    /// Standard error of `ln kappa`.
    pub kappa_ln_se: f64,
}

/// The pooled estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pooled {
    /// `left_diameter`, `right_diameter`, `track_width` (m).
    pub geometry: [f64; 3],
    /// Their covariance (m^2).
    pub covariance: [[f64; 3]; 3],
    /// Chi-square of the drives' geometries about the pooled one, its degrees of freedom
    /// (`3 (n - 1)`) and its 99 % quantile.
    pub geometry_chi2: (f64, usize, f64),
    /// kappa of the largest pooled likelihood (m^2/m).
    pub kappa_most_likely: f64,
    /// Standard error of the pooled `ln kappa`.
    pub kappa_ln_se: f64,
    /// kappa's mean over the pooled likelihood, what the unit is told (m^2/m):
    /// `exp(min(ln_se^2 / 2, 2))` times the most likely value, as for one drive.
    pub kappa: f64,
    /// Chi-square of the drives' `ln kappa` about the pooled one, its degrees of freedom
    /// (`n - 1`) and its 99 % quantile.
    pub kappa_chi2: (f64, usize, f64),
}

/// Why drives cannot be pooled.
#[derive(Debug, Clone, PartialEq)]
pub enum PoolError {
    /// Fewer than two drives.
    TooFew,
    /// Drive `i` (0-based) has a singular or non-finite geometry covariance.
    Covariance(usize),
    /// Drive `i` has a kappa or `ln_se` that is not positive and finite.
    Kappa(usize),
}

impl std::fmt::Display for PoolError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TooFew => write!(f, "pooling needs at least two drives"),
            Self::Covariance(i) => write!(
                f,
                "drive {}: its geometry covariance is singular or not finite",
                i + 1
            ),
            Self::Kappa(i) => write!(
                f,
                "drive {}: kappa and its ln standard error must be positive and finite",
                i + 1
            ),
        }
    }
}

impl std::error::Error for PoolError {}

/// Pools the drives' estimates (module documentation).
pub fn pool(drives: &[DriveEstimate]) -> Result<Pooled, PoolError> {
    if drives.len() < 2 {
        return Err(PoolError::TooFew);
    }
    let infos = drives
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let finite = d.covariance.iter().flatten().all(|v| v.is_finite())
                && d.geometry.iter().all(|v| v.is_finite());
            finite
                .then(|| invert3(d.covariance))
                .flatten()
                .ok_or(PoolError::Covariance(i))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut info = [[0.0; 3]; 3];
    let mut rhs = [0.0; 3];
    for (d, w) in drives.iter().zip(&infos) {
        for r in 0..3 {
            for c in 0..3 {
                info[r][c] += w[r][c];
                rhs[r] += w[r][c] * d.geometry[c];
            }
        }
    }
    let covariance = invert3(info).ok_or(PoolError::Covariance(0))?;
    let geometry: [f64; 3] =
        std::array::from_fn(|r| (0..3).map(|c| covariance[r][c] * rhs[c]).sum());
    let geometry_chi2: f64 = drives
        .iter()
        .zip(&infos)
        .map(|(d, w)| {
            let e: [f64; 3] = std::array::from_fn(|k| d.geometry[k] - geometry[k]);
            (0..3)
                .flat_map(|r| (0..3).map(move |c| (r, c)))
                .map(|(r, c)| e[r] * w[r][c] * e[c])
                .sum::<f64>()
        })
        .sum();
    let (mut wsum, mut lsum) = (0.0, 0.0);
    for (i, d) in drives.iter().enumerate() {
        let ok = d.kappa_most_likely > 0.0
            && d.kappa_most_likely.is_finite()
            && d.kappa_ln_se > 0.0
            && d.kappa_ln_se.is_finite();
        if !ok {
            return Err(PoolError::Kappa(i));
        }
        let w = d.kappa_ln_se.powi(-2);
        wsum += w;
        lsum += w * d.kappa_most_likely.ln();
    }
    let l = lsum / wsum;
    let kappa_ln_se = wsum.sqrt().recip();
    let kappa_chi2: f64 = drives
        .iter()
        .map(|d| ((d.kappa_most_likely.ln() - l) / d.kappa_ln_se).powi(2))
        .sum();
    let n = drives.len();
    let dof = |k: usize| (k, chi2_quantile_99(k as f64));
    let (gd, gq) = dof(3 * (n - 1));
    let (kd, kq) = dof(n - 1);
    Ok(Pooled {
        geometry,
        covariance,
        geometry_chi2: (geometry_chi2, gd, gq),
        kappa_most_likely: l.exp(),
        kappa_ln_se,
        kappa: (l + (kappa_ln_se * kappa_ln_se / 2.0).min(2.0)).exp(),
        kappa_chi2: (kappa_chi2, kd, kq),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn drive(g: [f64; 3], se: [f64; 3], kappa: f64, ln_se: f64) -> DriveEstimate {
        let mut covariance = [[0.0; 3]; 3];
        for k in 0..3 {
            covariance[k][k] = se[k] * se[k];
        }
        covariance[0][2] = 0.3 * se[0] * se[2];
        covariance[2][0] = covariance[0][2];
        DriveEstimate {
            geometry: g,
            covariance,
            kappa_most_likely: kappa,
            kappa_ln_se: ln_se,
        }
    }

    proptest! {
        /// n identical drives pool to the same values with variances n times smaller and no
        /// disagreement.
        #[test]
        fn identical_drives_shrink_by_their_number(
            n in 2usize..8,
            d in 0.2f64..0.3,
            b in 0.4f64..0.7,
            se in 1e-6f64..1e-4,
            kappa in 1e-8f64..1e-5,
            ln_se in 0.05f64..1.0,
        ) {
            let one = drive([d, d * 1.001, b], [se, se * 1.1, se * 10.0], kappa, ln_se);
            let p = pool(&vec![one; n]).unwrap();
            for k in 0..3 {
                prop_assert!((p.geometry[k] - one.geometry[k]).abs() < 1e-12);
                for c in 0..3 {
                    let want = one.covariance[k][c] / n as f64;
                    prop_assert!((p.covariance[k][c] - want).abs() <= 1e-9 * one.covariance[k][k].max(one.covariance[c][c]));
                }
            }
            prop_assert!(p.geometry_chi2.0.abs() < 1e-6);
            prop_assert!((p.kappa_most_likely / kappa - 1.0).abs() < 1e-12);
            prop_assert!((p.kappa_ln_se - ln_se / (n as f64).sqrt()).abs() < 1e-12);
            prop_assert!(p.kappa >= p.kappa_most_likely);
        }
    }

    /// Two drives: the more precise one weighs more; disagreement beyond the standard errors
    /// shows in the chi-squares.
    #[test]
    fn weights_and_disagreement() {
        let a = drive([0.26, 0.26, 0.56], [1e-5, 1e-5, 1e-4], 1e-7, 0.2);
        let b = drive([0.2601, 0.2601, 0.561], [3e-5, 3e-5, 3e-4], 4e-7, 0.4);
        let p = pool(&[a, b]).unwrap();
        // The first drive is 9 times as precise on the left diameter.
        assert!((p.geometry[0] - 0.26).abs() < (p.geometry[0] - 0.2601).abs());
        assert!(
            p.geometry_chi2.0 > p.geometry_chi2.2,
            "{:?}",
            p.geometry_chi2
        );
        assert_eq!(p.geometry_chi2.1, 3);
        // ln kappa: weights 25 and 6.25 -> 0.8 ln 1e-7 + 0.2 ln 4e-7.
        let want = (0.8 * 1e-7f64.ln() + 0.2 * 4e-7f64.ln()).exp();
        assert!((p.kappa_most_likely / want - 1.0).abs() < 1e-12);
        assert_eq!(p.kappa_chi2.1, 1);
        // (ln 4) ^ 2 / (0.2^2 + 0.4^2) = 9.6 > 6.63.
        assert!(p.kappa_chi2.0 > p.kappa_chi2.2, "{:?}", p.kappa_chi2);
    }

    /// What cannot be pooled, named by drive.
    #[test]
    fn bad_drives_are_refused() {
        let a = drive([0.26, 0.26, 0.56], [1e-5, 1e-5, 1e-4], 1e-7, 0.2);
        assert_eq!(pool(&[a]), Err(PoolError::TooFew));
        let mut singular = a;
        singular.covariance[1] = singular.covariance[0];
        assert_eq!(pool(&[a, singular]), Err(PoolError::Covariance(1)));
        let mut nan = a;
        nan.geometry[2] = f64::NAN;
        assert_eq!(pool(&[nan, a]), Err(PoolError::Covariance(0)));
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let mut k = a;
            k.kappa_ln_se = bad;
            assert_eq!(pool(&[a, k]), Err(PoolError::Kappa(1)));
            let mut k = a;
            k.kappa_most_likely = bad;
            assert_eq!(pool(&[a, k]), Err(PoolError::Kappa(1)));
        }
    }
}
