//! The paper's coverage criterion for the uncertainty coefficients (delta or kappa): the
//! smallest coefficient whose 1-sigma band, widened by the reference noise, covers 68.27 % of
//! the horizontal errors of the restarted sub-trajectories ([`Restarts`]); the heading
//! coverage of the same band that the `delta_diff` fit uses.

use std::cell::RefCell;
use std::rc::Rc;

use anyhow::{anyhow, Result};
use indicatif::ProgressBar;
use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::evaluation::Evaluation;
use crate::calib::run::Run;
use crate::cancel::check_this_thread;
use crate::optim::norm2;

use super::coefficients::{set_coefficient, DeltaMode, UncertaintyCriterion, UncertaintyFit};
use super::restarts::Restarts;

/// Nominal coverage of a 1-sigma band of a normal distribution.
pub const ONE_SIGMA_COVERAGE: f64 = 0.682_689_492;

/// A band whose coverage the uncertainty fits count: horizontal or heading-change, widened by
/// the reference's noise.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Band {
    /// `e <= k sqrt(sigma_h^2 + sigma_ref^2)` at every point, `sigma_ref` the epoch's own
    /// horizontal RMS sigma where its log gives one, else this (m, horizontal RMS).
    Horizontal(f64),
    /// `|e| <= k sqrt(sigma_heading^2 + (1 + 1/n) sigma^2)` where the reference has a
    /// heading, `e` the error of the heading change since the stretch's start
    /// ([`Evaluation::heading_change_err`]; the reference noise, this (rad), enters at the
    /// point and, averaged over `n` headings, at the start).
    Heading(f64),
}

impl Band {
    /// Whether point `i` of `ev` lies inside the band of `k` sigmas, at the sigmas `(sigma_h,
    /// sigma_heading)` (m, rad) rather than its own; `None` when it does not count (no
    /// heading).
    fn inside(
        self,
        ev: &Evaluation,
        i: usize,
        k: f64,
        (sigma_h, sigma_heading): (f64, f64),
    ) -> Option<bool> {
        match self {
            Band::Horizontal(ref_sigma) => {
                Some(ev.horizontal[i] <= k * sigma_h.hypot(reference_sigma_at(ev, i, ref_sigma)))
            }
            Band::Heading(ref_heading_sigma) => ev.heading_change_err[i].map(|e| {
                let m = ev.start_headings[i].max(1) as f64;
                e.abs() <= k * norm2(sigma_heading, ref_heading_sigma * (1.0 + 1.0 / m).sqrt())
            }),
        }
    }

    /// Point `i`'s squared error and the squared reference noise its band adds, `(e^2, r^2)`:
    /// inside at `k` sigmas when `e^2 <= k^2 (sigma^2 + r^2)`, `sigma` its sigma in the band
    /// ([`Band::sigma`]); `None` when it does not count.
    fn squares(self, ev: &Evaluation, i: usize) -> Option<(f64, f64)> {
        match self {
            Band::Horizontal(ref_sigma) => {
                let (e, r) = (ev.horizontal[i], reference_sigma_at(ev, i, ref_sigma));
                Some((e * e, r * r))
            }
            Band::Heading(ref_heading_sigma) => ev.heading_change_err[i].map(|e| {
                let m = ev.start_headings[i].max(1) as f64;
                (
                    e * e,
                    ref_heading_sigma * ref_heading_sigma * (1.0 + 1.0 / m),
                )
            }),
        }
    }

    /// Point `i`'s sigma in the band: horizontal (m) or heading (rad).
    fn sigma(self, ev: &Evaluation, i: usize) -> f64 {
        match self {
            Band::Horizontal(_) => ev.sigma_h[i],
            Band::Heading(_) => ev.sigma_heading[i],
        }
    }

    /// The coverage of `inside` points of `counted` over `points`: the share of all points
    /// (horizontal), of the counted ones (heading; NaN without any).
    fn share(self, inside: usize, counted: usize, points: usize) -> f64 {
        match self {
            Band::Horizontal(_) => inside as f64 / points.max(1) as f64,
            Band::Heading(_) if counted == 0 => f64::NAN,
            Band::Heading(_) => inside as f64 / counted as f64,
        }
    }

    /// The coverage of the band of `k` sigmas over the points `from..` of `ev`.
    pub(crate) fn coverage(self, ev: &Evaluation, k: f64, from: usize) -> f64 {
        let (mut counted, mut inside) = (0, 0);
        let points = match self {
            Band::Horizontal(_) => ev.horizontal.len(),
            Band::Heading(_) => ev.heading_change_err.len(),
        };
        let sigma = |v: &[f64], i: usize| v.get(i).copied().unwrap_or(f64::NAN);
        for i in from..points {
            let sigmas = (sigma(&ev.sigma_h, i), sigma(&ev.sigma_heading, i));
            if let Some(yes) = self.inside(ev, i, k, sigmas) {
                counted += 1;
                inside += usize::from(yes);
            }
        }
        self.share(inside, counted, ev.horizontal.len().saturating_sub(from))
    }
}

/// Coverage of the horizontal `k`-sigma band widened by the reference noise, over the points
/// `from..`: the fraction with `e <= k sqrt(sigma_h^2 + sigma_ref^2)`, `sigma_ref` the epoch's
/// own horizontal RMS sigma where its log gives one, else `ref_sigma` (m, horizontal RMS).
pub fn horizontal_coverage(ev: &Evaluation, ref_sigma: f64, k: f64, from: usize) -> f64 {
    Band::Horizontal(ref_sigma).coverage(ev, k, from)
}

/// The reference's horizontal RMS noise (m) at point `i`: the epoch's own sigma, else
/// `ref_sigma`.
pub fn reference_sigma_at(ev: &Evaluation, i: usize, ref_sigma: f64) -> f64 {
    ev.reference_sigma_h
        .get(i)
        .copied()
        .flatten()
        .unwrap_or(ref_sigma)
}

/// Coverage of the heading-change `k`-sigma band widened by the reference heading noise, over
/// the points `from..` where the reference has a heading: the fraction with `|e| <= k
/// sqrt(sigma_heading^2 + (1 + 1/n) ref_heading_sigma^2)`, `e` the error of the heading change
/// since the stretch's start ([`Evaluation::heading_change_err`]; the reference noise enters
/// at the point and, averaged over `n` headings, at the start); NaN without any.
pub fn heading_coverage(ev: &Evaluation, ref_heading_sigma: f64, k: f64, from: usize) -> f64 {
    Band::Heading(ref_heading_sigma).coverage(ev, k, from)
}

/// Relative change of a point's sigmas inside which [`scaled_coverage`] replays the point
/// rather than deciding it from the scaled sigmas: the two differ by the f32 rounding of the
/// uncertainty's steps, about 1e-7 of the sigma.
const SCALED_SIGMA_MARGIN: f64 = 1e-4;

/// The coverage of `band` at `k` sigmas over every point of the restarts' evaluation at `p`
/// ([`Band::coverage`]): [`scaled_coverage`] where it applies, else of the evaluation
/// ([`Restarts::evaluate_memo`]).
pub(crate) fn coverage_at(
    run: &Run,
    restarts: &Restarts,
    p: &ChassisParams,
    band: Band,
    k: f64,
) -> Result<f64> {
    match scaled_coverage(restarts, p, band, k)? {
        Some(c) => Ok(c),
        None => Ok(band.coverage(&*restarts.evaluate_memo(run, p)?, k, 0)),
    }
}

/// The restarts' last integration ([`Restarts::recorded_for`]: its parameters and evaluation)
/// when it integrated `p`'s pose part, both with the paper's model, `delta_diff` zero and both
/// deltas in one ratio `lambda` to `p`'s: the model is then homogeneous in the deltas, and each
/// point's sigmas at `p` are that integration's times `lambda` (but for the rounding).
pub(crate) fn homogeneous_record(
    restarts: &Restarts,
    p: &ChassisParams,
) -> Option<(ChassisParams, Rc<Evaluation>)> {
    let (q, ev) = restarts.recorded_for(p)?;
    let paper = |m: &ChassisParams| {
        m.uncertainty_model == UncertaintyModel::Paper
            && m.delta_diff == 0.0
            && m.delta_left > 0.0
            && m.delta_right > 0.0
    };
    let lambda = f64::from(p.delta_left) / f64::from(q.delta_left);
    let lambda_right = f64::from(p.delta_right) / f64::from(q.delta_right);
    (paper(p) && paper(&q) && (lambda / lambda_right - 1.0).abs() <= 1e-6).then_some((q, ev))
}

/// [`coverage_at`] without replaying the evaluation whole, from the restarts'
/// [`homogeneous_record`] with `p`. A point whose decision a change of its sigmas by
/// [`SCALED_SIGMA_MARGIN`] of them cannot turn is decided from those; only the
/// sub-trajectories holding the others are replayed ([`Restarts::replay_rows`]), and those
/// points are decided from their replayed sigmas: the coverage of the evaluation at `p`.
/// `None` when the restarts hold no such integration.
fn scaled_coverage(
    restarts: &Restarts,
    p: &ChassisParams,
    band: Band,
    k: f64,
) -> Result<Option<f64>> {
    check_this_thread()?;
    p.validate().map_err(|e| anyhow!("parameters: {e}"))?;
    let Some((q, ev)) = homogeneous_record(restarts, p) else {
        return Ok(None);
    };
    let lambda = f64::from(p.delta_left) / f64::from(q.delta_left);
    let (mut counted, mut inside) = (0, 0);
    let k2 = k * k;
    // Compared in squares, each side widened by far more than the few units in the last
    // place by which they differ from the band's own comparison.
    let (low, high) = (
        lambda * (1.0 - SCALED_SIGMA_MARGIN),
        lambda * (1.0 + SCALED_SIGMA_MARGIN),
    );
    let undecided: Vec<bool> = (0..ev.horizontal.len())
        .map(|i| {
            let Some((e2, r2)) = band.squares(&ev, i) else {
                return false;
            };
            let sigma = band.sigma(&ev, i);
            if e2 <= k2 * ((sigma * low).powi(2) + r2) * (1.0 - 1e-9) {
                (counted, inside) = (counted + 1, inside + 1);
                false
            } else if e2 > k2 * ((sigma * high).powi(2) + r2) * (1.0 + 1e-9) {
                counted += 1;
                false
            } else {
                true
            }
        })
        .collect();
    let Some(replayed) = restarts.replay_rows(p, &undecided) else {
        return Ok(None);
    };
    for (i, sigmas) in replayed {
        if let Some(yes) = band.inside(&ev, i, k, sigmas) {
            counted += 1;
            inside += usize::from(yes);
        }
    }
    Ok(Some(band.share(inside, counted, ev.horizontal.len())))
}

/// Number of points `from..` with a heading-change error.
pub fn heading_points(ev: &Evaluation, from: usize) -> usize {
    ev.heading_change_err
        .get(from..)
        .map_or(0, |v| v.iter().filter(|e| e.is_some()).count())
}

/// The smallest `v` in `[0, hi]` with `cover(v) >= ONE_SIGMA_COVERAGE`, for a coverage that is
/// non-decreasing in `v`: 0 when it already holds there, else a bisection in log scale down
/// to a relative width `rel_tol`. Returns the value and a warning when `hi` is not enough or
/// the criterion is not identifiable.
pub(crate) fn smallest_covering(
    hi: f64,
    zero_allowed: bool,
    rel_tol: f64,
    mut cover: impl FnMut(f64) -> Result<f64>,
    progress: &ProgressBar,
) -> Result<(f64, Option<String>)> {
    let lo = hi * 1e-12;
    if zero_allowed && cover(0.0)? >= ONE_SIGMA_COVERAGE {
        return Ok((0.0, None));
    }
    let c_hi = cover(hi)?;
    if c_hi < ONE_SIGMA_COVERAGE {
        return Ok((
            hi,
            Some(format!(
                "even {hi:e} (the largest admissible) covers only {:.1} % of the errors",
                100.0 * c_hi
            )),
        ));
    }
    if cover(lo)? >= ONE_SIGMA_COVERAGE {
        return Ok((
            lo,
            Some("the reference noise alone covers 68.3 % of the errors: the coefficient is not identifiable".into()),
        ));
    }
    let (mut l, mut h) = (lo.ln(), hi.ln());
    while h - l > rel_tol {
        let m = 0.5 * (l + h);
        if cover(m.exp())? >= ONE_SIGMA_COVERAGE {
            h = m;
        } else {
            l = m;
        }
        progress.inc(1);
    }
    Ok((h.exp(), None))
}

/// Fits the uncertainty coefficients by the coverage criterion of the module documentation.
#[allow(clippy::too_many_arguments)]
pub fn fit_uncertainty(
    run: &Run,
    geometry: &ChassisParams,
    heading0: f64,
    initial: &ChassisParams,
    window: f64,
    ref_sigma: f64,
    mode: DeltaMode,
    progress: &ProgressBar,
) -> Result<UncertaintyFit> {
    let restarts = Restarts::new(run, geometry, heading0, window)?;
    fit_uncertainty_on(run, &restarts, geometry, initial, ref_sigma, mode, progress)
}

/// Bisection width (natural log of the coefficient) of the horizontal fit.
pub(crate) const COEFFICIENT_LOG_TOL: f64 = 1e-7;
/// Bisection width of `delta_diff`, and of delta when refitted inside its fit (0.01 %).
pub(crate) const DIFF_LOG_TOL: f64 = 1e-4;

/// [`fit_uncertainty`] on given restarted sub-trajectories; the other coefficients (e.g.
/// `delta_diff`) are those of `geometry`.
pub fn fit_uncertainty_on(
    run: &Run,
    restarts: &Restarts,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    ref_sigma: f64,
    mode: DeltaMode,
    progress: &ProgressBar,
) -> Result<UncertaintyFit> {
    progress.set_length(48);
    fit_coefficient(
        run,
        restarts,
        geometry,
        initial,
        ref_sigma,
        mode,
        COEFFICIENT_LOG_TOL,
        progress,
    )
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn fit_coefficient(
    run: &Run,
    restarts: &Restarts,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    ref_sigma: f64,
    mode: DeltaMode,
    log_tol: f64,
    progress: &ProgressBar,
) -> Result<UncertaintyFit> {
    let (keys, hi) = match geometry.uncertainty_model {
        UncertaintyModel::Paper => (
            ("delta_left", "delta_right"),
            f64::from(ChassisParams::MAX_DELTA),
        ),
        UncertaintyModel::Covariance => (
            ("kappa_left", "kappa_right"),
            f64::from(ChassisParams::MAX_KAPPA),
        ),
    };
    // With the ratio kept, the larger coefficient must stay in range too.
    let q = match (mode, geometry.uncertainty_model) {
        (DeltaMode::KeepRatio, UncertaintyModel::Paper) if initial.delta_left > 0.0 => {
            f64::from(initial.delta_right / initial.delta_left)
        }
        (DeltaMode::KeepRatio, UncertaintyModel::Covariance) if initial.kappa_left > 0.0 => {
            f64::from(initial.kappa_right / initial.kappa_left)
        }
        _ => 1.0,
    };
    let hi = hi / q.max(1.0);
    let at = |v: f64| set_coefficient(geometry, mode, initial, v);
    let coefficient = |p: &ChassisParams| match p.uncertainty_model {
        UncertaintyModel::Paper => f64::from(p.delta_left),
        UncertaintyModel::Covariance => f64::from(p.kappa_left),
    };
    // The evaluations of this family (these parameters but the coefficient) already made,
    // e.g. by the horizontal fit before a refit of delta: (coefficient, coverage).
    let family = |p: &ChassisParams| at(coefficient(p)) == *p;
    let facts = RefCell::new(
        restarts
            .memo_where(family)
            .iter()
            .map(|(p, ev)| (coefficient(p), horizontal_coverage(ev, ref_sigma, 1.0, 0)))
            .collect::<Vec<_>>(),
    );
    let real = |v: f64| -> Result<f64> {
        let p = at(v);
        let c = coverage_at(run, restarts, &p, Band::Horizontal(ref_sigma), 1.0)?;
        facts.borrow_mut().push((v, c));
        Ok(c)
    };
    // The coverage is non-decreasing in the coefficient (what the bisection assumes): a
    // value at or above one known to cover, or at or below one known not to, is decided
    // without an evaluation; the bisection then takes exactly the steps it would take with
    // every coverage evaluated, and only the midpoints between those are evaluated.
    let cover = |v: f64| -> Result<f64> {
        let known = known_coverage(&facts.borrow(), v);
        match known {
            Some(c) => Ok(c),
            None => real(v),
        }
    };
    bracket_threshold(
        restarts,
        hi,
        log_tol,
        family,
        ref_sigma,
        match geometry.uncertainty_model {
            // sigma proportional to delta (with delta_diff = 0), variance to kappa.
            UncertaintyModel::Paper => 1.0,
            UncertaintyModel::Covariance => 0.5,
        },
        coefficient(geometry),
        &facts,
        &real,
    )?;
    let (value, warning) = smallest_covering(hi, false, log_tol, cover, progress)?;
    let warning = warning.map(|w| {
        if w.contains("reference noise") {
            format!("the reference noise alone ({ref_sigma} m) covers 68.3 % of the errors: the coefficient is not identifiable")
        } else {
            w
        }
    });
    let params = at(value);
    let coverage = |k| coverage_at(run, restarts, &params, Band::Horizontal(ref_sigma), k);
    Ok(UncertaintyFit {
        model: geometry.uncertainty_model,
        params,
        keys,
        windows: restarts.windows.len(),
        points: restarts.points(),
        coverage1: coverage(1.0)?,
        coverage3: coverage(3.0)?,
        warning,
        diff: None,
        criterion: UncertaintyCriterion::Coverage,
        heading_coverage: None,
        ln_se: None,
        most_likely: None,
        searches: Vec::new(),
    })
}

/// The coverage at `v` implied by the coverages `facts` (coefficient, coverage) of a
/// non-decreasing coverage: the one at `v` itself, else one `>= ONE_SIGMA_COVERAGE` at or
/// below `v`, else one below it at or above `v` (the caller only compares it with
/// [`ONE_SIGMA_COVERAGE`]); `None` when they do not decide.
pub(crate) fn known_coverage(facts: &[(f64, f64)], v: f64) -> Option<f64> {
    if let Some(&(_, c)) = facts.iter().find(|(u, _)| *u == v) {
        return Some(c);
    }
    facts
        .iter()
        .find(|(u, c)| *u <= v && *c >= ONE_SIGMA_COVERAGE)
        .or_else(|| {
            facts
                .iter()
                .find(|(u, c)| *u >= v && *c < ONE_SIGMA_COVERAGE)
        })
        .map(|&(_, c)| c)
}

/// Predicts, from evaluations of one family at coefficients `a` and `b` (`sigma_h` of each,
/// the horizontal errors being the same), the smallest coefficient whose horizontal 1-sigma
/// band covers [`ONE_SIGMA_COVERAGE`] of the errors: per point, `sigma_h` is taken as a power
/// of the coefficient through the two evaluations (exact for the covariance model, `sigma_h^2`
/// linear in kappa, and for the paper model without `delta_diff`, `sigma_h` linear in delta;
/// to f32 rounding), which gives the coefficient at which the point becomes covered; the
/// prediction is their 68.27 % quantile. With one evaluation (`b` = `None`) the power is
/// `exponent`.
fn predict_threshold(
    e: &[f64],
    ref_sigma: (&[Option<f64>], f64),
    a: (f64, &[f64]),
    b: Option<(f64, &[f64])>,
    exponent: f64,
) -> Option<f64> {
    let n = e.len();
    if a.0 <= 0.0 {
        return None;
    }
    let k = covering_rank(n)?;
    let (la, sa) = (a.0.ln(), a.1);
    let mut t: Vec<f64> = (0..n)
        .map(|i| {
            let r = ref_sigma.0.get(i).copied().flatten().unwrap_or(ref_sigma.1);
            let target2 = e[i] * e[i] - r * r;
            if target2 <= 0.0 {
                return 0.0;
            }
            let ls = 0.5 * target2.ln();
            let s0 = sa[i];
            let p = match b {
                Some((vb, sb)) if sb[i] > 0.0 && s0 > 0.0 && vb != a.0 => {
                    (sb[i].ln() - s0.ln()) / (vb.ln() - la)
                }
                _ => exponent,
            };
            if !(s0 > 0.0 && p > 0.0 && p.is_finite()) {
                return f64::INFINITY;
            }
            (la + (ls - s0.ln()) / p).exp()
        })
        .collect();
    let (_, &mut th, _) = t.select_nth_unstable_by(k - 1, f64::total_cmp);
    (th.is_finite() && th > 0.0).then_some(th)
}

/// The fewest points `k` of `n` whose share `k / n` reaches [`ONE_SIGMA_COVERAGE`]: the rank of
/// the per-point threshold that decides the criterion; `None` for no points.
pub(crate) fn covering_rank(n: usize) -> Option<usize> {
    (1..=n).find(|&k| k as f64 / n as f64 >= ONE_SIGMA_COVERAGE)
}

/// Brackets the threshold of the coverage criterion before the bisection: evaluations
/// (`real`, which records its results in `facts`) on either side of the predicted threshold
/// ([`predict_threshold`], from the latest two evaluations of the family), at a distance of
/// the bisection's width, widened when a prediction misses. The bisection then finds every
/// step outside the bracket decided (see [`known_coverage`]): the result is the bisection's,
/// with a handful of evaluations instead of dozens. Evaluations only; never decides anything.
#[allow(clippy::too_many_arguments)]
fn bracket_threshold(
    restarts: &Restarts,
    hi: f64,
    log_tol: f64,
    family: impl Fn(&ChassisParams) -> bool,
    ref_sigma: f64,
    exponent: f64,
    start: f64,
    facts: &RefCell<Vec<(f64, f64)>>,
    real: &dyn Fn(f64) -> Result<f64>,
) -> Result<()> {
    let lo = hi * 1e-12;
    let coefficient = |p: &ChassisParams| match p.uncertainty_model {
        UncertaintyModel::Paper => f64::from(p.delta_left),
        UncertaintyModel::Covariance => f64::from(p.kappa_left),
    };
    let mut width = log_tol;
    for _ in 0..8 {
        let (below, above) = {
            let f = facts.borrow();
            let below = f
                .iter()
                .filter(|(_, c)| *c < ONE_SIGMA_COVERAGE)
                .map(|p| p.0)
                .fold(f64::NEG_INFINITY, f64::max);
            let above = f
                .iter()
                .filter(|(_, c)| *c >= ONE_SIGMA_COVERAGE)
                .map(|p| p.0)
                .fold(f64::INFINITY, f64::min);
            (below, above)
        };
        if below > 0.0 && above.is_finite() && (above / below).ln() <= 2.5 * log_tol {
            return Ok(());
        }
        if above <= lo || below >= hi {
            return Ok(());
        }
        let evs = restarts.memo_where(&family);
        let Some((pa, ea)) = evs.first() else {
            let v0 = if start > lo && start < hi {
                start
            } else {
                (lo * hi).sqrt()
            };
            real(v0)?;
            continue;
        };
        let b = evs
            .get(1)
            .map(|(pb, eb)| (coefficient(pb), eb.sigma_h.as_slice()));
        let Some(pred) = predict_threshold(
            &ea.horizontal,
            (&ea.reference_sigma_h, ref_sigma),
            (coefficient(pa), &ea.sigma_h),
            b,
            exponent,
        ) else {
            return Ok(());
        };
        // Inside what is known, else bisect what is known.
        let pred = if pred > below && pred < above {
            pred
        } else if below > 0.0 && above.is_finite() {
            (below * above).sqrt()
        } else if pred >= above {
            above * (-width).exp()
        } else {
            below * width.exp()
        };
        let (l, h) = (
            (pred * (-width).exp()).clamp(lo, hi),
            (pred * width.exp()).clamp(lo, hi),
        );
        let c_h = known_coverage(&facts.borrow(), h);
        let c_h = match c_h {
            Some(c) => c,
            None => real(h)?,
        };
        if c_h >= ONE_SIGMA_COVERAGE && known_coverage(&facts.borrow(), l).is_none() {
            real(l)?;
        }
        width *= 4.0;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testing::{run_of, sim};
    use crate::simulate::{default_truth, PathKind};

    /// The coefficient fits (predicted bracket, then the bisection on known coverages) give
    /// the plain bisection's coefficient, every coverage evaluated: paper model without and
    /// with `delta_diff` (sigma then not a power of delta), covariance model, on simulated
    /// runs; also the refit's coarser width on a memo left by the finer fit; and with epochs
    /// that carry their own sigma (every third one 2 cm, as GST gives), which both take.
    #[test]
    fn fast_coefficient_fit_matches_the_plain_bisection() {
        for (seed, own_sigma) in [(1, false), (2, false), (3, true)] {
            let mut s = sim(PathKind::Random, 150.0, seed);
            if own_sigma {
                for r in s.reference.iter_mut().step_by(3) {
                    r.sigma_h = Some(0.02);
                }
            }
            let run = run_of(&s);
            let geometry = default_truth();
            let h0 = run.heading_guess(0);
            for (model, dd) in [
                (UncertaintyModel::Paper, 0.0f32),
                (UncertaintyModel::Paper, 2e-8),
                (UncertaintyModel::Covariance, 0.0),
            ] {
                let g = ChassisParams {
                    uncertainty_model: model,
                    delta_diff: dd,
                    ..geometry
                };
                let restarts = Restarts::new(&run, &g, h0, 10.0).unwrap();
                let hi = f64::from(match model {
                    UncertaintyModel::Paper => ChassisParams::MAX_DELTA,
                    UncertaintyModel::Covariance => ChassisParams::MAX_KAPPA,
                });
                let coef = |p: &ChassisParams| match model {
                    UncertaintyModel::Paper => p.delta_left,
                    UncertaintyModel::Covariance => p.kappa_left,
                };
                for tol in [COEFFICIENT_LOG_TOL, DIFF_LOG_TOL] {
                    let (plain, _) = smallest_covering(
                        hi,
                        false,
                        tol,
                        |v| {
                            let p = set_coefficient(&g, DeltaMode::Equal, &g, v);
                            let ev = restarts.evaluate(&run, &p)?;
                            Ok(horizontal_coverage(&ev, 0.008, 1.0, 0))
                        },
                        &ProgressBar::hidden(),
                    )
                    .unwrap();
                    let fast = fit_coefficient(
                        &run,
                        &restarts,
                        &g,
                        &g,
                        0.008,
                        DeltaMode::Equal,
                        tol,
                        &ProgressBar::hidden(),
                    )
                    .unwrap();
                    let (a, b) = (f64::from(coef(&fast.params)), f64::from(plain as f32));
                    assert!(
                        (a / b).ln().abs() <= tol,
                        "seed {seed} {model:?} delta_diff {dd} width {tol}: fast {a:e}, plain {b:e}"
                    );
                }
            }
        }
    }

    /// The coverages counted from the restarts' integration scaled, with the points it cannot
    /// decide replayed ([`scaled_coverage`]), are those of the whole evaluation: horizontal and
    /// heading, at 1 and 3 sigma, at deltas around where the horizontal 1-sigma coverage
    /// crosses 68.27 % (most points near their thresholds there) and further off; with and
    /// without epochs' own sigmas, both deltas equal and in another ratio. Other coefficients
    /// than the deltas, or a `delta_diff`, are not scaled.
    #[test]
    fn scaled_coverages_are_the_evaluations() {
        for (seed, own_sigma, right) in [(4, false, 1.0f32), (5, true, 1.3)] {
            let mut s = sim(PathKind::Random, 150.0, seed);
            if own_sigma {
                for r in s.reference.iter_mut().step_by(3) {
                    r.sigma_h = Some(0.02);
                }
            }
            let run = run_of(&s);
            let initial = ChassisParams {
                delta_right: default_truth().delta_left * right,
                ..default_truth()
            };
            let restarts = Restarts::new(&run, &initial, run.heading_guess(0), 10.0).unwrap();
            let fit = fit_coefficient(
                &run,
                &restarts,
                &initial,
                &initial,
                0.008,
                DeltaMode::KeepRatio,
                COEFFICIENT_LOG_TOL,
                &ProgressBar::hidden(),
            )
            .unwrap();
            let threshold = f64::from(fit.params.delta_left);
            let bands = [Band::Horizontal(0.008), Band::Heading(0.5f64.to_radians())];
            for f in [1.0, 1.000_01, 0.999_99, 1.001, 0.999, 1.1, 0.9, 3.0, 0.2] {
                let p = set_coefficient(&initial, DeltaMode::KeepRatio, &initial, threshold * f);
                assert!(homogeneous_record(&restarts, &p).is_some());
                let ev = restarts.evaluate(&run, &p).unwrap();
                for band in bands {
                    for k in [1.0, 3.0] {
                        let scaled = scaled_coverage(&restarts, &p, band, k).unwrap().unwrap();
                        let whole = band.coverage(&ev, k, 0);
                        assert!(whole.is_finite());
                        assert_eq!(
                            scaled.to_bits(),
                            whole.to_bits(),
                            "seed {seed} at {f} of the threshold, {band:?} {k}: {scaled} {whole}"
                        );
                    }
                }
            }
            let p = set_coefficient(&initial, DeltaMode::KeepRatio, &initial, threshold);
            for other in [
                ChassisParams {
                    delta_diff: 1e-8,
                    ..p
                },
                ChassisParams {
                    uncertainty_model: UncertaintyModel::Covariance,
                    ..p
                },
            ] {
                assert!(homogeneous_record(&restarts, &other).is_none());
            }
        }
    }
}
