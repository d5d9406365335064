//! The one-dimensional searches of the filter's likelihood: a slip rate in `ln` scale (a grid
//! a decade apart, then Brent's search), near a known one, its mean over the likelihood, and
//! the profile over the slip's correlation length.
//!
//! Each score of a correlated slip needs its Gauss-Markov states composed over the blocks
//! ([`Composed::gauss_markov`]), once per correlation length; for one length the likelihood is
//! a function of kappa alone. So the correlation length is profiled over a fixed grid
//! ([`SLIP_CORR_GRID`] values, a factor 1.82 apart over [`SLIP_CORR_RANGE`]; the likelihood is
//! flat in it within such a factor), each with a one-dimensional search for kappa (Brent's,
//! in `ln kappa`), the grid shared between the machine's cores.
//!
//! [`Composed::gauss_markov`]: super::blocks::Composed::gauss_markov

use odo_unit::odometry::ChassisParams;

use crate::calib::pipeline::cores;
use crate::optim::brent_min;

/// Least decrease of the negative log-likelihood for which a slip parameter more (the wheel
/// slip's correlation length, opposite-phase slip) is kept: the 95 % point of a
/// likelihood-ratio test with one degree of freedom (3.84 / 2).
pub(crate) const EVIDENCE_PER_PARAMETER: f64 = 1.92;

/// The range the likelihood fits search for a slip rate (m^2 per m): twelve decades up to the
/// unit's largest admissible kappa.
pub(crate) fn slip_rate_range() -> (f64, f64) {
    let hi = f64::from(ChassisParams::MAX_KAPPA);
    (hi * 1e-12, hi)
}

/// Shortest and longest slip correlation length the fit considers (m of wheel travel).
pub const SLIP_CORR_RANGE: (f64, f64) = (0.05, 20.0);

/// Number of correlation lengths the profile visits, log-spaced over [`SLIP_CORR_RANGE`].
pub const SLIP_CORR_GRID: usize = 11;

/// The correlation lengths of the profile (m).
fn corr_grid() -> impl Iterator<Item = f64> {
    let (lo, hi) = SLIP_CORR_RANGE;
    let step = (hi / lo).ln() / (SLIP_CORR_GRID - 1) as f64;
    (0..SLIP_CORR_GRID).map(move |i| lo * (step * i as f64).exp())
}

/// Tolerance of the searches in `ln kappa` (0.1 % of kappa; its standard error on a 70 m run
/// is 10-20 %).
const LN_TOL: f64 = 1e-3;

/// How far a correlated fit's kappa is looked for from the white fit's: `ln` below, above.
const LN_REACH: (f64, f64) = (3.0, 8.0);

/// The value in `[lo, hi]` where `nll` is least: a grid in log scale (a decade apart), then
/// Brent's search between the best point's neighbours.
pub(crate) fn largest_likelihood(nll: impl Fn(f64) -> f64, lo: f64, hi: f64) -> f64 {
    let f = |l: f64| nll(l.exp());
    let (a, b) = (lo.ln(), hi.ln());
    let n = ((b - a) / 10f64.ln()).ceil().max(1.0) as usize;
    let step = (b - a) / n as f64;
    let (mut best, mut best_f) = (a, f64::INFINITY);
    for i in 0..=n {
        let l = a + step * i as f64;
        let v = f(l);
        if v < best_f {
            best = l;
            best_f = v;
        }
    }
    let (l, fl, _) = brent_min(&f, (best - step).max(a), (best + step).min(b), LN_TOL);
    if fl <= best_f {
        l.exp()
    } else {
        best.exp()
    }
}

/// The mean of a rate `x` over its likelihood rather than its most likely value, `x` given by
/// `nll(ln x)`: [`mean_from_ln_se`] with the standard error of `ln x` that the curvature of
/// `nll` gives (none where it is not positive).
pub(crate) fn posterior_mean(nll: impl Fn(f64) -> f64, x: f64, hi: f64) -> f64 {
    let (l, h) = (x.ln(), 0.3);
    let curvature = (nll(l + h) - 2.0 * nll(l) + nll(l - h)) / (h * h);
    let ln_se = (curvature.is_finite() && curvature > 0.0).then(|| curvature.sqrt().recip());
    mean_from_ln_se(x, ln_se, hi)
}

/// The mean of a rate over its likelihood from its most likely value `x` and the standard
/// error `ln_se` of `ln x`: `ln x` is about normal there, and the mean of a log-normal is
/// `exp(ln_se^2 / 2)` times its median (the exponent capped at 2, the mean at most `hi`);
/// `x` itself without a standard error. A variance that few events measure (the
/// opposite-phase slip of one run's few turns: within a factor of 10 on 70 m) is more often
/// under- than overestimated by its most likely value, and the sigma it gives is then too
/// narrow; the mean is what the errors' spread over the likelihood's uncertainty has.
pub(crate) fn mean_from_ln_se(x: f64, ln_se: Option<f64>, hi: f64) -> f64 {
    match ln_se {
        Some(s) => (x * (0.5 * s * s).min(2.0).exp()).min(hi),
        None => x,
    }
}

/// Brent's search of `ln x` within [`LN_REACH`] of `around`, inside `[lo, hi]`: `(x, nll)`.
pub(super) fn search_near(nll: impl Fn(f64) -> f64, around: f64, lo: f64, hi: f64) -> (f64, f64) {
    let c = around.ln();
    let (a, b) = ((c - LN_REACH.0).max(lo.ln()), (c + LN_REACH.1).min(hi.ln()));
    let (l, v, _) = brent_min(|l| nll(l.exp()), a, b, LN_TOL);
    (l.exp(), v)
}

/// The best of `profile(corr)` over the correlation grid, the grid split between two threads
/// when there are two cores: `(corr, value, nll)`.
pub(super) fn best_over_grid(profile: impl Fn(f64) -> (f64, f64) + Sync) -> (f64, f64, f64) {
    let grid: Vec<f64> = corr_grid().collect();
    let results: Vec<(f64, f64, f64)> = std::thread::scope(|s| {
        let half = if cores() > 1 {
            grid.len() / 2
        } else {
            grid.len()
        };
        let (first, second) = grid.split_at(half);
        let profile = &profile;
        let run = move |part: &[f64]| -> Vec<(f64, f64, f64)> {
            part.iter()
                .map(|&c| {
                    let (v, nll) = profile(c);
                    (c, v, nll)
                })
                .collect()
        };
        let other = s.spawn(move || run(second));
        let mut out = run(first);
        out.extend(other.join().unwrap_or_default());
        out
    });
    results
        .into_iter()
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .unwrap_or((0.0, 0.0, f64::INFINITY))
}
