//! The `delta_diff` fit of the paper's model by the heading-change coverage.

use std::cell::RefCell;
use std::rc::Rc;

use anyhow::Result;
use indicatif::ProgressBar;
use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::evaluation::Evaluation;
use crate::calib::run::Run;

use super::coefficients::{DeltaMode, DiffFit, UncertaintyFit};
use super::coverage::{
    covering_rank, fit_coefficient, heading_coverage, heading_points, horizontal_coverage,
    known_coverage, smallest_covering, DIFF_LOG_TOL, ONE_SIGMA_COVERAGE,
};
use super::restarts::Restarts;

/// Options of [`fit_delta_diff`].
#[derive(Debug, Clone, Copy)]
pub struct DiffOptions {
    /// Fit `delta_diff` (else keep the initial one and only report the heading coverage).
    pub fit: bool,
    /// Reference heading noise (rad), added to `sigma_heading` in the criterion.
    pub ref_heading_sigma: f64,
    /// Reference horizontal noise (m), for the refits of delta.
    pub ref_sigma: f64,
    /// Left/right relation of delta in its refits.
    pub mode: DeltaMode,
}

/// Fits `delta_diff` of the paper's model jointly with delta, on the restarted
/// sub-trajectories of the horizontal fit `horizontal`.
///
/// Criterion: delta stays the horizontal criterion's (the 1-sigma band widened by the
/// reference noise covers 68.27 % of the horizontal errors), refitted at every trial
/// `delta_diff` (which widens `sigma_x`, `sigma_y` too, so delta comes down as it goes up);
/// `delta_diff` is the smallest value `>= 0` for which the 1-sigma heading band
/// `sqrt(sigma_heading^2 + (1 + 1/n) ref_heading_sigma^2)` covers 68.27 % of the errors of the
/// heading change since each restart ([`heading_coverage`]): 0 when the paper's model already
/// covers them. Both criteria then hold. The heading coverage along that curve is taken as
/// non-decreasing in `delta_diff` (bisection in log scale). When no admissible `delta_diff`
/// meets both (delta would have to fall to zero), delta is held at its horizontal fit and
/// `delta_diff` alone meets the heading criterion (a warning says so; the horizontal band
/// then covers more than 68.27 %). Returns the updated fit (with `diff` set), or `horizontal`
/// unchanged for the covariance model or a reference without heading.
pub fn fit_delta_diff(
    run: &Run,
    restarts: &Restarts,
    horizontal: UncertaintyFit,
    initial: &ChassisParams,
    o: DiffOptions,
    progress: &ProgressBar,
) -> Result<UncertaintyFit> {
    if horizontal.model != UncertaintyModel::Paper {
        return Ok(horizontal);
    }
    let ev = restarts.evaluate_memo(run, &horizontal.params)?;
    let points = heading_points(&ev, 0);
    if points == 0 {
        return Ok(horizontal);
    }
    let cover = |p: &ChassisParams, k: f64| -> Result<f64> {
        let ev = restarts.evaluate_memo(run, p)?;
        Ok(heading_coverage(&ev, o.ref_heading_sigma, k, 0))
    };
    let with = with_delta_diff;
    let initial_dd = f64::from(horizontal.params.delta_diff);
    let delta_before = f64::from(horizontal.params.delta_left);
    let before = (
        heading_coverage(&ev, o.ref_heading_sigma, 1.0, 0),
        heading_coverage(&ev, o.ref_heading_sigma, 3.0, 0),
    );
    let mut fit = horizontal;
    let mut warning = None;
    let mut joint = true;
    if o.fit {
        progress.set_length(40);
        let base = fit.params;
        let hi = f64::from(ChassisParams::MAX_DELTA);
        let search = JointSearch::new(run, restarts, base, initial, o);
        search.bracket(hi)?;
        let (dd, w) = smallest_covering(hi, true, DIFF_LOG_TOL, |v| search.coverage(v), progress)?;
        // Joint only when delta stays identifiable (not pushed to zero by delta_diff).
        let joint_fit = match w {
            None => Some(search.refit(dd)?).filter(|f| f.warning.is_none()),
            Some(_) => None,
        };
        if let Some(f) = joint_fit {
            fit = f;
        } else {
            joint = false;
            let (dd, w2) = smallest_covering(
                hi,
                true,
                DIFF_LOG_TOL,
                |v| cover(&with(&base, v), 1.0),
                progress,
            )?;
            fit.params = with(&base, dd);
            let ev = restarts.evaluate_memo(run, &fit.params)?;
            fit.coverage1 = horizontal_coverage(&ev, o.ref_sigma, 1.0, 0);
            fit.coverage3 = horizontal_coverage(&ev, o.ref_sigma, 3.0, 0);
            warning = Some(match w2 {
                Some(w2) => w2,
                None => format!(
                    "no delta_diff meets the heading and the horizontal criterion together; delta held at its horizontal fit, which now covers {:.1} % of the horizontal errors",
                    100.0 * fit.coverage1
                ),
            });
        }
    }
    fit.diff = Some(DiffFit {
        initial: initial_dd,
        delta_diff: f64::from(fit.params.delta_diff),
        fitted: o.fit,
        joint,
        delta_before,
        points,
        coverage1_before: before.0,
        coverage3_before: before.1,
        coverage1: cover(&fit.params, 1.0)?,
        coverage3: cover(&fit.params, 3.0)?,
        warning,
    });
    Ok(fit)
}

/// `p` with `delta_diff = v`.
fn with_delta_diff(p: &ChassisParams, v: f64) -> ChassisParams {
    ChassisParams {
        delta_diff: v as f32,
        ..*p
    }
}

/// Most trials of [`JointSearch::bracket`].
const BRACKET_STEPS: usize = 12;

/// A trial of the joint search: `delta_diff`, the heading 1-sigma coverage at delta refitted
/// there, and that refit's evaluation.
type Trial = (f64, f64, Rc<Evaluation>);

/// The search for the smallest `delta_diff` of the joint criterion (delta refitted at every
/// trial): every trial remembered, and the bisection fed the coverages they decide.
struct JointSearch<'a> {
    run: &'a Run<'a>,
    restarts: &'a Restarts,
    base: ChassisParams,
    initial: &'a ChassisParams,
    o: DiffOptions,
    refits: RefCell<Vec<(f64, UncertaintyFit)>>,
    trials: RefCell<Vec<Trial>>,
}

impl<'a> JointSearch<'a> {
    fn new(
        run: &'a Run<'a>,
        restarts: &'a Restarts,
        base: ChassisParams,
        initial: &'a ChassisParams,
        o: DiffOptions,
    ) -> Self {
        Self {
            run,
            restarts,
            base,
            initial,
            o,
            refits: RefCell::default(),
            trials: RefCell::default(),
        }
    }

    /// delta refitted by the horizontal criterion at `delta_diff = v` (remembered).
    fn refit(&self, v: f64) -> Result<UncertaintyFit> {
        if let Some((_, f)) = self.refits.borrow().iter().find(|(u, _)| *u == v) {
            return Ok(f.clone());
        }
        // Started from the delta of the nearest refit: the same result, fewer evaluations.
        let start = {
            let refits = self.refits.borrow();
            let nearest = refits
                .iter()
                .filter(|(u, _)| *u > 0.0 && v > 0.0)
                .min_by(|a, b| (a.0 / v).ln().abs().total_cmp(&(b.0 / v).ln().abs()));
            match nearest {
                Some((_, f)) => ChassisParams {
                    delta_left: f.params.delta_left,
                    delta_right: f.params.delta_right,
                    ..self.base
                },
                None => self.base,
            }
        };
        let f = fit_coefficient(
            self.run,
            self.restarts,
            &with_delta_diff(&start, v),
            self.initial,
            self.o.ref_sigma,
            self.o.mode,
            DIFF_LOG_TOL,
            &ProgressBar::hidden(),
        )?;
        self.refits.borrow_mut().push((v, f.clone()));
        Ok(f)
    }

    /// The heading 1-sigma coverage at the refit for `v`, evaluated.
    fn trial(&self, v: f64) -> Result<f64> {
        let f = self.refit(v)?;
        let ev = self.restarts.evaluate_memo(self.run, &f.params)?;
        let c = heading_coverage(&ev, self.o.ref_heading_sigma, 1.0, 0);
        self.trials.borrow_mut().push((v, c, ev));
        Ok(c)
    }

    fn facts(&self) -> Vec<(f64, f64)> {
        self.trials.borrow().iter().map(|t| (t.0, t.1)).collect()
    }

    /// The heading 1-sigma coverage at `v` as the bisection needs it: decided by the trials
    /// when they decide it (the coverage being non-decreasing in `v`), else evaluated.
    fn coverage(&self, v: f64) -> Result<f64> {
        match known_coverage(&self.facts(), v) {
            Some(c) => Ok(c),
            None => self.trial(v),
        }
    }

    /// Brackets the threshold before the bisection, as the coefficient fits do: the trials
    /// nearest below and above it predict it (each point's `sigma_heading^2` taken as
    /// `alpha + beta delta_diff^2` through them: each sample adds `delta_diff`'s term in
    /// quadrature to delta's) while it halves the bracket (else the bracket's middle, as
    /// Brent's method guards a secant); trials a bisection width either side of the
    /// prediction then leave the bisection all but its last steps decided.
    /// Evaluations only; never decides anything.
    fn bracket(&self, hi: f64) -> Result<()> {
        let lo = hi * 1e-12;
        if self.coverage(0.0)? >= ONE_SIGMA_COVERAGE || self.coverage(hi)? < ONE_SIGMA_COVERAGE {
            return Ok(());
        }
        let mut last_width = f64::INFINITY;
        for _ in 0..BRACKET_STEPS {
            let (Some(below), Some(above)) = (self.next_below(f64::INFINITY), self.first_above())
            else {
                return Ok(());
            };
            let floor = below.0.max(lo);
            let width = (above.0 / floor).ln();
            if width <= 2.5 * DIFF_LOG_TOL {
                return Ok(());
            }
            // The prediction while it halves the bracket, else the bracket's middle (log scale).
            let middle = (floor * above.0).sqrt();
            let pred = self
                .predict(&below, &above)
                .filter(|&v| v > floor && v < above.0 && width <= 0.5 * last_width);
            last_width = width;
            let Some(pred) = pred else {
                self.coverage(middle)?;
                continue;
            };
            // A bisection width either side of the prediction: both when it is right.
            let (l, h) = (pred * (-DIFF_LOG_TOL).exp(), pred * DIFF_LOG_TOL.exp());
            if self.coverage(h.min(above.0))? >= ONE_SIGMA_COVERAGE {
                self.coverage(l.max(floor))?;
            }
        }
        Ok(())
    }

    /// The trial with the smallest `delta_diff` that covers.
    fn first_above(&self) -> Option<Trial> {
        self.trials
            .borrow()
            .iter()
            .filter(|t| t.1 >= ONE_SIGMA_COVERAGE)
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .cloned()
    }

    /// The trial with the largest `delta_diff` below `v` (not covering).
    fn next_below(&self, v: f64) -> Option<Trial> {
        self.trials
            .borrow()
            .iter()
            .filter(|t| t.0 < v && t.1 < ONE_SIGMA_COVERAGE)
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .cloned()
    }

    /// The `delta_diff` at which the heading band covers 68.27 % of the points, each point's
    /// `sigma_heading^2` being `alpha + beta delta_diff^2` through the trials `a` and `b`.
    fn predict(&self, a: &Trial, b: &Trial) -> Option<f64> {
        let (ea, eb) = (&a.2, &b.2);
        let r = self.o.ref_heading_sigma;
        let mut need: Vec<f64> = (0..ea.heading_change_err.len())
            .filter_map(|i| {
                let e = ea.heading_change_err[i]?;
                let m = ea.start_headings[i].max(1) as f64;
                let target2 = e * e - r * r * (1.0 + 1.0 / m);
                if target2 <= 0.0 {
                    return Some(0.0);
                }
                let (sa, sb) = (ea.sigma_heading[i], eb.sigma_heading[i]);
                let beta = (sb * sb - sa * sa) / (b.0 * b.0 - a.0 * a.0);
                if beta.is_nan() || beta <= 0.0 {
                    return Some(f64::INFINITY);
                }
                let alpha = sa * sa - beta * a.0 * a.0;
                Some(((target2 - alpha) / beta).max(0.0).sqrt())
            })
            .collect();
        let k = covering_rank(need.len())?;
        let (_, &mut v, _) = need.select_nth_unstable_by(k - 1, f64::total_cmp);
        (v.is_finite() && v > 0.0).then_some(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::csvio::match_times;
    use crate::simulate::{self, default_truth, PathKind, SimSettings};

    /// The bracketed joint search gives the plain bisection's `delta_diff` (every trial
    /// evaluated) with fewer trials, on runs whose wheels slip in opposite phase when turning.
    #[test]
    fn bracketed_joint_search_matches_the_plain_bisection() {
        for seed in [1, 2, 3] {
            let settings = SimSettings {
                seed,
                slip_turn: 0.03,
                ..Default::default()
            };
            let s = simulate::simulate_path(PathKind::Estimation, 70.0, default_truth(), settings);
            let run = Run::new(
                &s.samples,
                &s.reference,
                match_times(&s.samples, &s.reference),
            );
            let base = ChassisParams {
                uncertainty_model: UncertaintyModel::Paper,
                ..default_truth()
            };
            let o = DiffOptions {
                fit: true,
                ref_heading_sigma: 0.5f64.to_radians(),
                ref_sigma: 0.008,
                mode: DeltaMode::Equal,
            };
            let hi = f64::from(ChassisParams::MAX_DELTA);
            let h0 = run.heading_guess(0);
            let hidden = ProgressBar::hidden();
            let search = |bracket: bool| {
                let restarts = Restarts::new(&run, &base, h0, 10.0).unwrap();
                let js = JointSearch::new(&run, &restarts, base, &base, o);
                if bracket {
                    js.bracket(hi).unwrap();
                }
                let (v, w) =
                    smallest_covering(hi, true, DIFF_LOG_TOL, |v| js.coverage(v), &hidden).unwrap();
                let trials = js.trials.borrow().len();
                (v, w, trials)
            };
            let (plain, fast) = (search(false), search(true));
            assert_eq!((plain.0, &plain.1), (fast.0, &fast.1), "seed {seed}");
            assert!(plain.0 > 0.0, "seed {seed}: delta_diff {}", plain.0);
            assert!(
                fast.2 < plain.2,
                "seed {seed}: {} trials, plain {}",
                fast.2,
                plain.2
            );
        }
    }
}
