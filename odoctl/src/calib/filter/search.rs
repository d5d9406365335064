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
//! A fit of the same drive on more data (the background batches of `record --calibrate`, the
//! final calibration) starts each search near where the earlier fit's same search ended
//! ([`SearchLog`]): Brent's search within [`WARM_REACH`] of it, and the cold search when the
//! optimum is not inside that bracket.
//!
//! [`Composed::gauss_markov`]: super::blocks::Composed::gauss_markov

use std::cmp::Ordering;
use std::sync::Mutex;

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

/// Tolerance in `ln` of [`polish`].
const POLISH_TOL: f64 = 1e-6;

/// Half-width in `ln` of the bracket about an earlier fit's optimum that a warm-started
/// search tries first.
pub const WARM_REACH: f64 = 0.1;

/// One of the one-dimensional searches of [`Innovations::fit_with_turning`].
///
/// [`Innovations::fit_with_turning`]: super::innovations::Innovations::fit_with_turning
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Search {
    /// White wheel slip's kappa.
    White,
    /// Gauss-Markov wheel slip's kappa at the correlation grid's point `i`.
    Correlated(usize),
    /// White opposite-phase slip's `kappa_diff`.
    TurningWhite,
    /// Gauss-Markov opposite-phase slip's `kappa_diff` at the grid's point `i`.
    Turning(usize),
    /// Kappa in round `i` of kappa and `kappa_diff` fitted in turn.
    JointKappa(usize),
    /// `kappa_diff` in round `i` of the same.
    JointDiff(usize),
    /// White wheel slip's kappa of the filter linearised about the open-loop odometry, at
    /// which the filter is linearised again ([`Innovations::new_after`]).
    ///
    /// [`Innovations::new_after`]: super::innovations::Innovations::new_after
    OpenLoop,
    /// White wheel slip's kappa of the geometry's refinement.
    RefinedWhite,
    /// White opposite-phase slip's `kappa_diff` of the geometry's refinement.
    RefinedTurningWhite,
}

/// Where each search of a likelihood fit ended (its optimum, by [`Search`]): an earlier fit's
/// of the same drive, near which this fit's searches start, and this fit's own (shared between
/// the threads of the correlation grid).
#[derive(Debug, Default)]
pub struct SearchLog {
    earlier: Vec<(Search, f64)>,
    ended: Mutex<Vec<(Search, f64)>>,
}

impl SearchLog {
    /// A log whose searches start near `earlier`'s ends (none: cold).
    pub fn after(earlier: Vec<(Search, f64)>) -> Self {
        Self {
            earlier,
            ended: Mutex::default(),
        }
    }

    /// Where this fit's searches ended.
    pub fn ended(self) -> Vec<(Search, f64)> {
        self.ended.into_inner().unwrap_or_else(|e| e.into_inner())
    }

    fn earlier(&self, s: Search) -> Option<f64> {
        self.earlier.iter().find(|(k, _)| *k == s).map(|&(_, x)| x)
    }

    fn record(&self, s: Search, x: f64) {
        let mut ended = self.ended.lock().unwrap_or_else(|e| e.into_inner());
        ended.push((s, x));
    }

    /// Search `s`: [`largest_likelihood`], from the earlier end when there is one.
    pub(crate) fn largest(&self, s: Search, nll: impl Fn(f64) -> f64, lo: f64, hi: f64) -> f64 {
        let x = match self.earlier(s).and_then(|e| search_warm(&nll, e, lo, hi)) {
            Some((x, _)) => x,
            None => largest_likelihood(nll, lo, hi),
        };
        self.record(s, x);
        x
    }

    /// Search `s`: [`search_near`] `around`, from the earlier end when there is one.
    pub(crate) fn near(
        &self,
        s: Search,
        nll: impl Fn(f64) -> f64,
        around: f64,
        lo: f64,
        hi: f64,
    ) -> (f64, f64) {
        let found = match self.earlier(s).and_then(|e| search_warm(&nll, e, lo, hi)) {
            Some(found) => found,
            None => search_near(nll, around, lo, hi),
        };
        self.record(s, found.0);
        found
    }
}

/// A reported optimum `x` of `nll` (found to [`LN_TOL`]) to [`POLISH_TOL`]: Brent's search
/// within 4 [`LN_TOL`] of it (the bracket its search ended in), inside `[lo, hi]`. A search
/// ends anywhere within its tolerance of the optimum, by where it started (a warm start
/// moved kappa by 0.008 of its standard error); polished, two starts agree.
pub(crate) fn polish(nll: impl Fn(f64) -> f64, x: f64, lo: f64, hi: f64) -> f64 {
    let c = x.ln();
    let (a, b) = (
        (c - 4.0 * LN_TOL).max(lo.ln()),
        (c + 4.0 * LN_TOL).min(hi.ln()),
    );
    if a.partial_cmp(&b) != Some(Ordering::Less) {
        return x;
    }
    let (l, v, _) = brent_min(|l| nll(l.exp()), a, b, POLISH_TOL);
    if v <= nll(x) {
        l.exp()
    } else {
        x
    }
}

/// The search of `ln x` from an earlier fit's end `earlier`, inside `[lo, hi]`: a point `u`
/// is taken when `nll` there is at most its value a tolerance ([`LN_TOL`]) to either side
/// inside the range (for a unimodal `nll` the optimum is then within the tolerance of `u`,
/// where Brent's search would end). `u` is `earlier` itself, then the vertex of the parabola
/// through those three values (within [`WARM_REACH`] of `earlier`, at most at `lo` or `hi`):
/// three to six evaluations instead of about nine to twelve. Otherwise Brent's search within
/// [`WARM_REACH`] of `earlier`. `(x, nll)` when the optimum is inside that bracket (not at an
/// edge short of `lo` or `hi`).
fn search_warm(nll: impl Fn(f64) -> f64, earlier: f64, lo: f64, hi: f64) -> Option<(f64, f64)> {
    let c = earlier.ln();
    let (wa, wb) = (lo.ln(), hi.ln());
    let f = |l: f64| nll(l.exp());
    // The value a tolerance to a side of `u`, infinite beyond the range.
    let side = |l: f64| {
        if l >= wa && l <= wb {
            f(l)
        } else {
            f64::INFINITY
        }
    };
    if c >= wa && c <= wb {
        let (left, v, right) = (side(c - LN_TOL), nll(earlier), side(c + LN_TOL));
        if taken(left, v, right) {
            return Some((earlier, v));
        }
        if let Some(u) = parabola_vertex(c, LN_TOL, (left, v, right)) {
            let u = u.clamp((c - WARM_REACH).max(wa), (c + WARM_REACH).min(wb));
            let x = u.exp().clamp(lo, hi);
            let v = nll(x);
            if taken(side(u - LN_TOL), v, side(u + LN_TOL)) {
                return Some((x, v));
            }
        }
    }
    let (a, b) = ((c - WARM_REACH).max(wa), (c + WARM_REACH).min(wb));
    if a.partial_cmp(&b) != Some(Ordering::Less) {
        return None;
    }
    let (l, v, _) = brent_min(f, a, b, LN_TOL);
    let edge = 3.0 * LN_TOL;
    let inside = (l - a > edge || a == wa) && (b - l > edge || b == wb);
    (inside && v.is_finite()).then(|| (l.exp(), v))
}

/// Whether a finite value `v` is at most `left` and `right`, its neighbours a tolerance to
/// either side (infinite beyond a bound of the range): the optimum of a unimodal function is
/// then within the tolerance of `v`'s point.
fn taken(left: f64, v: f64, right: f64) -> bool {
    v.is_finite() && v <= left && v <= right
}

/// The vertex of the parabola through `(c - h, left)`, `(c, v)`, `(c + h, right)` when it
/// opens upwards, else infinity on the side where the values fall; `None` when a value is
/// not finite or the values give no direction.
fn parabola_vertex(c: f64, h: f64, (left, v, right): (f64, f64, f64)) -> Option<f64> {
    if !(left.is_finite() && v.is_finite() && right.is_finite()) {
        return None;
    }
    let curvature = left - 2.0 * v + right;
    let slope = right - left;
    if curvature > 0.0 {
        Some(c - 0.5 * h * slope / curvature)
    } else if slope != 0.0 {
        Some(if slope > 0.0 {
            f64::NEG_INFINITY
        } else {
            f64::INFINITY
        })
    } else {
        None
    }
}

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

/// The best of `profile(i, corr)` over the correlation grid (`i` the point's index), the grid
/// split between two threads when there are two cores: `(corr, value, nll)`.
pub(super) fn best_over_grid(profile: impl Fn(usize, f64) -> (f64, f64) + Sync) -> (f64, f64, f64) {
    let grid: Vec<(usize, f64)> = corr_grid().enumerate().collect();
    let results: Vec<(f64, f64, f64)> = std::thread::scope(|s| {
        let half = if cores() > 1 {
            grid.len() / 2
        } else {
            grid.len()
        };
        let (first, second) = grid.split_at(half);
        let profile = &profile;
        let run = move |part: &[(usize, f64)]| -> Vec<(f64, f64, f64)> {
            part.iter()
                .map(|&(i, c)| {
                    let (v, nll) = profile(i, c);
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

#[cfg(test)]
mod tests {
    use std::cell::Cell;

    use super::*;

    /// A likelihood whose `ln` optimum is `ln m`, quadratic in `ln x` with a standard error
    /// `se`, counting its evaluations in `n`.
    fn parabola(m: f64, se: f64, n: &Cell<usize>) -> impl Fn(f64) -> f64 + '_ {
        move |x: f64| {
            n.set(n.get() + 1);
            (x.ln() - m.ln()).powi(2) / (2.0 * se * se)
        }
    }

    /// A warm search from an earlier end within the tolerance of the optimum keeps it in three
    /// evaluations; from one near it, finds it at the parabola's vertex in six; from an end too
    /// far off, the optimum still (the cold search); and it is recorded under its name either
    /// way.
    #[test]
    fn warm_searches_start_near_the_earlier_end_and_fall_back() {
        let (lo, hi) = slip_rate_range();
        let n = Cell::new(0);
        let m = 2.0e-7;
        // earlier end (x m), what the search finds within (ln), evaluations at most.
        let table: [(Option<f64>, f64, usize); 7] = [
            (None, 2.0 * LN_TOL, 40),
            (Some(1.0), 0.0, 3),
            (Some(1.0 + 0.5 * LN_TOL), LN_TOL, 3),
            (Some(1.0 + 1.5 * LN_TOL), LN_TOL, 6),
            (Some(1.05), LN_TOL, 6),
            (Some(0.95), LN_TOL, 6),
            (Some(3.0), 2.0 * LN_TOL, 60),
        ];
        let mut warm_evals = 0;
        let mut cold_evals = 0;
        for (earlier, within, most) in table {
            let earlier = earlier
                .map(|f| vec![(Search::White, f * m)])
                .unwrap_or_default();
            let log = SearchLog::after(earlier.clone());
            n.set(0);
            let x = log.largest(Search::White, parabola(m, 0.05, &n), lo, hi);
            assert!((x / m).ln().abs() <= within, "{earlier:?}: {x:e}");
            assert!(n.get() <= most, "{earlier:?}: {} evaluations", n.get());
            match earlier.first() {
                None => cold_evals = n.get(),
                Some(&(_, e)) if (e / m).ln().abs() < WARM_REACH => warm_evals = n.get(),
                _ => {}
            }
            assert_eq!(log.ended(), vec![(Search::White, x)]);
        }
        assert!(warm_evals < cold_evals / 2, "{warm_evals} vs {cold_evals}");
    }

    /// Boundary table of the warm search on likelihoods whose optimum is at a bound of the
    /// range, or not a parabola: the optimum within the tolerance, in the evaluations given.
    #[test]
    fn warm_searches_at_a_bound_or_off_a_parabola_end_within_the_tolerance() {
        let (lo, hi) = slip_rate_range();
        let n = Cell::new(0);
        let rising = |x: f64| {
            n.set(n.get() + 1);
            (x / lo).ln()
        };
        let falling = |x: f64| {
            n.set(n.get() + 1);
            (hi / x).ln()
        };
        let m = 2.0e-7;
        let quartic = |x: f64| {
            n.set(n.get() + 1);
            (x / m).ln().powi(4) * 1e4 + (x / m).ln().abs() * 10.0
        };
        // (likelihood, its optimum, earlier end, evaluations at most)
        type Row<'a> = (&'a dyn Fn(f64) -> f64, f64, f64, usize);
        let table: [Row; 8] = [
            (&rising, lo, lo, 2),
            (&rising, lo, lo * (1.5 * LN_TOL).exp(), 5),
            (&rising, lo, lo * 0.05f64.exp(), 5),
            (&falling, hi, hi, 2),
            (&falling, hi, hi * (-1.5 * LN_TOL).exp(), 5),
            (&quartic, m, m, 3),
            (&quartic, m, m * (2.5 * LN_TOL).exp(), 20),
            (&quartic, m, m * 0.97, 20),
        ];
        for (i, (nll, optimum, earlier, most)) in table.into_iter().enumerate() {
            n.set(0);
            let (x, v) = search_warm(nll, earlier, lo, hi).expect("found near the earlier end");
            assert!((x / optimum).ln().abs() <= LN_TOL, "{i}: {x:e}");
            assert!(x >= lo && x <= hi, "{i}: {x:e} outside the range");
            assert_eq!(v, nll(x), "{i}");
            assert!(n.get() <= most + 1, "{i}: {} evaluations", n.get() - 1);
        }
    }

    /// `near` keeps the earlier end's bracket for its own search and names its ends apart.
    #[test]
    fn near_searches_are_recorded_by_name() {
        let (lo, hi) = slip_rate_range();
        let n = Cell::new(0);
        let log = SearchLog::after(vec![(Search::Correlated(3), 1e-6)]);
        let (a, _) = log.near(
            Search::Correlated(3),
            parabola(1.02e-6, 0.1, &n),
            1e-9,
            lo,
            hi,
        );
        let (b, _) = log.near(Search::Correlated(4), parabola(5e-8, 0.1, &n), 1e-9, lo, hi);
        assert!((a / 1.02e-6).ln().abs() < 2.0 * LN_TOL);
        assert!((b / 5e-8).ln().abs() < 2.0 * LN_TOL);
        assert_eq!(
            log.ended(),
            vec![(Search::Correlated(3), a), (Search::Correlated(4), b)]
        );
    }

    /// Polishing brings two ends of the same optimum, anywhere within the searches'
    /// tolerance, to within its own; an optimum at a bound stays there.
    #[test]
    fn polishing_brings_ends_within_the_searches_tolerance_together() {
        let (lo, hi) = slip_rate_range();
        let n = Cell::new(0);
        let m = 3.0e-7;
        for offset in [-3.0 * LN_TOL, -LN_TOL, 0.0, 0.5 * LN_TOL, 3.0 * LN_TOL] {
            let x = polish(parabola(m, 0.05, &n), m * offset.exp(), lo, hi);
            assert!((x / m).ln().abs() < 10.0 * POLISH_TOL, "{offset}: {x:e}");
        }
        let at_bound = polish(|x: f64| -x.ln(), hi, lo, hi);
        assert!((at_bound / hi).ln().abs() < 4.0 * LN_TOL + 1e-12);
    }
}
