//! The slip of the largest likelihood under the Kalman filter of [`Innovations`]: the
//! covariance model's kappa (white wheel slip, then Gauss-Markov slip profiled over its
//! correlation length), then opposite-phase slip when turning ([`Turning`]: the unit's
//! `kappa_diff`, and its correlation length `kappa_diff_corr`, which the unit's covariance
//! model carries as the same Gauss-Markov state), kept only when the likelihood says it is
//! there. The more likely of white and correlated wheel slip is kept and its kappa, the
//! long-range rate, is what the unit's white-slip model gets: correlated slip is smoother over
//! a few centimetres than white slip of the same long-range rate, and a white-slip fit alone
//! took it for less slip (a third of it at `L` = 2 m).
//!
//! Each score of a correlated slip needs its Gauss-Markov states composed over the blocks
//! (`filter_blocks`), once per correlation length; for one length the likelihood is a
//! function of kappa alone. So the correlation length is profiled over a fixed grid
//! ([`SLIP_CORR_GRID`] values, a factor 1.82 apart over [`SLIP_CORR_RANGE`]; the likelihood is
//! flat in it within such a factor), each with a one-dimensional search for kappa (Brent's,
//! in `ln kappa`), the grid shared between the machine's cores.

use odo_core::odometry::ChassisParams;

use super::filter_blocks::GaussMarkovBlock;
use super::innovations::SlipModel;
use super::*;
use crate::optim::brent_min;

/// Least decrease of the negative log-likelihood for which a slip parameter more (the wheel
/// slip's correlation length, opposite-phase slip) is kept: the 95 % point of a likelihood-ratio test with one degree of freedom (3.84 / 2).
pub(super) const EVIDENCE_PER_PARAMETER: f64 = 1.92;

/// Shortest and longest slip correlation length the fit considers (m of wheel travel).
pub const SLIP_CORR_RANGE: (f64, f64) = (0.05, 20.0);

/// Number of correlation lengths the profile visits, log-spaced over [`SLIP_CORR_RANGE`].
pub const SLIP_CORR_GRID: usize = 11;

/// Tolerance of the searches in `ln kappa` (0.1 % of kappa; its standard error on a 70 m run
/// is 10-20 %).
const LN_TOL: f64 = 1e-3;

/// How far a correlated fit's kappa is looked for from the white fit's: `ln` below, above.
const LN_REACH: (f64, f64) = (3.0, 8.0);

/// The range the likelihood fits search for a slip rate (m^2 per m): twelve decades up to the
/// unit's largest admissible kappa.
pub(super) fn slip_rate_range() -> (f64, f64) {
    let hi = f64::from(ChassisParams::MAX_KAPPA);
    (hi * 1e-12, hi)
}

/// Most rounds of the alternate fit of kappa and `kappa_diff` once opposite-phase slip is in.
const JOINT_ROUNDS: usize = 4;

/// The correlation lengths of the profile (m).
fn corr_grid() -> impl Iterator<Item = f64> {
    let (lo, hi) = SLIP_CORR_RANGE;
    let step = (hi / lo).ln() / (SLIP_CORR_GRID - 1) as f64;
    (0..SLIP_CORR_GRID).map(move |i| lo * (step * i as f64).exp())
}

/// Opposite-phase slip in the filter: an error `e` on wheel 1's distance and `-e` on wheel
/// 2's, growing by `eps |s_1 - s_2|` per sample. White (`corr` 0): `e` of variance
/// `kappa_diff |s_1 - s_2|` per sample, the core's `kappa_diff`. Correlated: `eps` a
/// Gauss-Markov process over the wheel-distance difference, of correlation length `corr` (m)
/// and variance `kappa_diff / (2 corr)`, which has the same long-range variance
/// `kappa_diff D` over a difference `D >> corr`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Turning {
    /// Long-range variance of `e` per metre of `|s_1 - s_2|` (m^2/m).
    pub kappa_diff: f64,
    /// Correlation length (m of `|s_1 - s_2|`; 0: white).
    pub corr: f64,
}

impl Turning {
    /// No opposite-phase slip.
    pub const NONE: Self = Self {
        kappa_diff: 0.0,
        corr: 0.0,
    };
}

/// The value in `[lo, hi]` where `nll` is least: a grid in log scale (a decade apart), then
/// Brent's search between the best point's neighbours.
pub(super) fn largest_likelihood(nll: impl Fn(f64) -> f64, lo: f64, hi: f64) -> f64 {
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
/// `nll(ln x)`: `ln x` is about normal there, of the variance `v` that the curvature of `nll`
/// gives, and the mean of a log-normal is `exp(v / 2)` times its median (`v` capped at 4, at
/// most `hi`). A variance that few events measure (the opposite-phase slip of one run's few
/// turns: within a factor of 10 on 70 m) is more often under- than overestimated by its most
/// likely value, and the sigma it gives is then too narrow; the mean is what the errors' spread
/// over the likelihood's uncertainty has. Under turning slip it took the ensemble test's
/// coverage from 54-67 % inside 1 sigma (92.5 % inside 3) to 57.5-68.5 % (94 %).
fn posterior_mean(nll: impl Fn(f64) -> f64, x: f64, hi: f64) -> f64 {
    let (l, h) = (x.ln(), 0.3);
    let curvature = (nll(l + h) - 2.0 * nll(l) + nll(l - h)) / (h * h);
    if curvature.is_finite() && curvature > 0.0 {
        (x * (0.5 / curvature).min(2.0).exp()).min(hi)
    } else {
        x
    }
}

/// Brent's search of `ln x` within [`LN_REACH`] of `around`, inside `[lo, hi]`: `(x, nll)`.
fn search_near(nll: impl Fn(f64) -> f64, around: f64, lo: f64, hi: f64) -> (f64, f64) {
    let c = around.ln();
    let (a, b) = ((c - LN_REACH.0).max(lo.ln()), (c + LN_REACH.1).min(hi.ln()));
    let (l, v, _) = brent_min(|l| nll(l.exp()), a, b, LN_TOL);
    (l.exp(), v)
}

/// The best of `profile(corr)` over the correlation grid, the grid split between two threads
/// when there are two cores: `(corr, value, nll)`.
fn best_over_grid(profile: impl Fn(f64) -> (f64, f64) + Sync) -> (f64, f64, f64) {
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

impl Innovations {
    fn nll(
        &self,
        kappa: f64,
        wheels: Option<(f64, &[Vec<GaussMarkovBlock>; 2])>,
        kappa_diff: f64,
        turning: Option<(f64, &[GaussMarkovBlock])>,
    ) -> f64 {
        self.filter(SlipModel {
            kappa,
            wheels,
            kappa_diff,
            turning,
        })
        .nll
    }

    /// The kappa of white slip of the largest likelihood in `[lo, hi]`.
    pub fn fit(&self, lo: f64, hi: f64) -> f64 {
        largest_likelihood(|k| self.nll(k, None, 0.0, None), lo, hi)
    }

    /// The long-range kappa and the slip correlation length (0: white) of the largest
    /// likelihood: the white-slip fit ([`Innovations::fit`]), then the profile over the
    /// correlation grid; the white fit is kept unless correlated slip raises the likelihood by
    /// more than [`EVIDENCE_PER_PARAMETER`] (it has one parameter more). Without that test a
    /// correlation length the data cannot tell won on nearly every run, and its long-range
    /// kappa read q 0.001 slip 15 % high (20 calibrations of the ensemble test).
    pub fn fit_correlated(&self, lo: f64, hi: f64) -> (f64, f64) {
        let white = self.fit(lo, hi);
        let white_nll = self.nll(white, None, 0.0, None);
        let (corr, kappa, nll) = best_over_grid(|corr| {
            let gm = self.wheel_slip(corr);
            search_near(|k| self.nll(k, Some((corr, &gm)), 0.0, None), white, lo, hi)
        });
        if nll + EVIDENCE_PER_PARAMETER < white_nll {
            (kappa, corr)
        } else {
            (white, 0.0)
        }
    }

    /// [`Innovations::fit_correlated`], then opposite-phase slip ([`Turning`]): white (a
    /// search over `kappa_diff`) and correlated (the profile over its correlation length),
    /// kept only when it raises the likelihood by more than [`EVIDENCE_PER_PARAMETER`] per
    /// parameter it adds, then kappa and `kappa_diff` fitted in turn, and `kappa_diff` taken as
    /// its mean over the likelihood ([`posterior_mean`]). Returns `(kappa, corr, turning)`.
    pub fn fit_with_turning(&self, lo: f64, hi: f64) -> (f64, f64, Turning) {
        let (kappa, corr) = self.fit_correlated(lo, hi);
        let gm = (corr > 0.0).then(|| self.wheel_slip(corr));
        let wheels = gm.as_ref().map(|g| (corr, g));
        let without = self.nll(kappa, wheels, 0.0, None);
        let kd = largest_likelihood(|d| self.nll(kappa, wheels, d, None), lo, hi);
        let white = Turning {
            kappa_diff: kd,
            corr: 0.0,
        };
        let mut best = (white, self.nll(kappa, wheels, kd, None), 1.0);
        let (tcorr, tkd, tnll) = best_over_grid(|tc| {
            let gt = self.turning_slip(tc);
            search_near(|d| self.nll(kappa, wheels, d, Some((tc, &gt))), kd, lo, hi)
        });
        if tnll + EVIDENCE_PER_PARAMETER < best.1 {
            let t = Turning {
                kappa_diff: tkd,
                corr: tcorr,
            };
            best = (t, tnll, 2.0);
        }
        if best.1 > without - EVIDENCE_PER_PARAMETER * best.2 {
            return (kappa, corr, Turning::NONE);
        }
        let mut turning = best.0;
        let gt = (turning.corr > 0.0).then(|| self.turning_slip(turning.corr));
        let turn = gt.as_deref().map(|g| (turning.corr, g));
        // Kappa took some of the turning slip for wheel slip before `kappa_diff` was there:
        // the two are fitted in turn until they settle.
        let mut kappa = kappa;
        for _ in 0..JOINT_ROUNDS {
            let (k, _) = search_near(
                |k| self.nll(k, wheels, turning.kappa_diff, turn),
                kappa,
                lo,
                hi,
            );
            let (d, _) = search_near(|d| self.nll(k, wheels, d, turn), turning.kappa_diff, lo, hi);
            let settled =
                (k / kappa).ln().abs() < 0.01 && (d / turning.kappa_diff).ln().abs() < 0.01;
            (kappa, turning.kappa_diff) = (k, d);
            if settled {
                break;
            }
        }
        turning.kappa_diff = posterior_mean(
            |l| self.nll(kappa, wheels, l.exp(), turn),
            turning.kappa_diff,
            hi,
        );
        (kappa, corr, turning)
    }
}

/// The covariance model's kappa by the filter's likelihood (module documentation): the
/// long-range wheel-distance variance per metre, with the slip's correlation length fitted
/// beside it (the unit's model has white slip; over the tens of metres a sigma is used for,
/// the long-range rate is what it must carry).
pub fn fit_kappa_filter(
    innovations: &Innovations,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    mode: DeltaMode,
) -> (UncertaintyFit, f64) {
    let (lo, hi) = slip_rate_range();
    let (kappa, corr, turning) = innovations.fit_with_turning(lo, hi);
    let mut params = set_coefficient(
        &ChassisParams {
            uncertainty_model: odo_core::odometry::UncertaintyModel::Covariance,
            ..*geometry
        },
        mode,
        initial,
        kappa,
    );
    params.kappa_diff = turning.kappa_diff as f32;
    // The unit carries the same Gauss-Markov state (`kappa_diff_corr`, metres of
    // `|s_1 - s_2|` as `Turning::corr`); 0 when the white form won.
    params.kappa_diff_corr = turning.corr as f32;
    let score = innovations.score_with(kappa, corr, turning);
    let warning = if kappa <= lo * 1.01 {
        Some(
            "the errors are explained by the reference noise alone: kappa is not identifiable"
                .to_string(),
        )
    } else if kappa >= hi * 0.99 {
        Some(format!("kappa reached its largest admissible value {hi:e}"))
    } else {
        None
    };
    (
        UncertaintyFit {
            model: params.uncertainty_model,
            params,
            keys: ("kappa_left", "kappa_right"),
            windows: 1,
            points: innovations.observations,
            coverage1: score.horizontal.0,
            coverage3: score.horizontal.1,
            warning,
            diff: None,
            criterion: UncertaintyCriterion::Likelihood,
            heading_coverage: (!score.heading.0.is_nan()).then_some(score.heading),
        },
        corr,
    )
}
