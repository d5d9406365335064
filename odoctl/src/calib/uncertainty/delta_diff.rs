//! The `delta_diff` fit of the paper's model by the heading-change coverage.

use anyhow::Result;
use indicatif::ProgressBar;
use odo_unit::odometry::{ChassisParams, UncertaintyModel};

use crate::calib::run::Run;
use crate::optim::norm2;

use super::coefficients::{set_coefficient, DeltaMode, DiffFit, UncertaintyFit};
use super::coverage::{
    coverage_at, covering_rank, fit_coefficient, heading_points, homogeneous_record,
    horizontal_coverage, reference_sigma_at, smallest_covering, Band, DIFF_LOG_TOL,
    ONE_SIGMA_COVERAGE,
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
    let points = heading_points(&*restarts.pose_evaluation(run, &horizontal.params)?, 0);
    if points == 0 {
        return Ok(horizontal);
    }
    let cover = |p: &ChassisParams, k: f64| {
        coverage_at(run, restarts, p, Band::Heading(o.ref_heading_sigma), k)
    };
    let with = with_delta_diff;
    let initial_dd = f64::from(horizontal.params.delta_diff);
    let delta_before = f64::from(horizontal.params.delta_left);
    let before = (
        cover(&horizontal.params, 1.0)?,
        cover(&horizontal.params, 3.0)?,
    );
    let mut fit = horizontal;
    let mut warning = None;
    let mut joint = true;
    if o.fit {
        progress.set_length(40);
        let base = fit.params;
        let hi = f64::from(ChassisParams::MAX_DELTA);
        let search = RatioSearch::new(run, restarts, base, initial, o);
        // Joint only when delta stays identifiable (not pushed to zero by delta_diff).
        let joint_fit = match search.smallest(hi, progress)? {
            Some(dd) => Some(search.refit(dd)?).filter(|f| f.warning.is_none()),
            None => None,
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

/// The range of the ratio `delta_diff / delta` the joint search spans.
const RATIO_RANGE: (f64, f64) = (1e-6, 1e8);

/// One trial of [`RatioSearch`]: at the ratio `r = delta_diff / delta`, delta refitted by the
/// horizontal criterion and the heading 1-sigma coverage there.
#[derive(Debug, Clone, Copy)]
struct RatioTrial {
    /// delta of the horizontal criterion at this ratio.
    delta: f64,
    /// `r * delta`.
    delta_diff: f64,
    /// Heading 1-sigma coverage at `(delta, delta_diff)`.
    heading: f64,
}

/// The joint search for the smallest `delta_diff` (delta refitted by the horizontal criterion
/// at every trial) along the ratio `r = delta_diff / delta`. The paper's sigmas are
/// homogeneous of degree one in `(delta_left, delta_right, delta_diff)` (every input enters
/// each sample's quadrature sum linearly, and the sums add), so one evaluation at
/// `(delta_0, r delta_0)` gives every point's sigmas at `(delta, r delta)` as `delta /
/// delta_0` times its own: the delta that meets the horizontal criterion at that ratio is a
/// quantile of the points' thresholds, and the heading coverage there follows, with no
/// further evaluation. A bisection in `ln r` then takes one evaluation per step instead of a
/// refit of delta per step; the result is refitted once by the horizontal criterion
/// ([`fit_coefficient`]) as before.
struct RatioSearch<'a> {
    run: &'a Run<'a>,
    restarts: &'a Restarts,
    base: ChassisParams,
    initial: &'a ChassisParams,
    o: DiffOptions,
}

impl<'a> RatioSearch<'a> {
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
        }
    }

    /// delta of the horizontal fit: where the search evaluates while `delta_diff` stays in
    /// range.
    fn delta0(&self) -> f64 {
        f64::from(self.base.delta_left)
    }

    /// The trial at ratio `r` (one evaluation); `None` when no delta meets the horizontal
    /// criterion there.
    fn at(&self, r: f64) -> Result<Option<RatioTrial>> {
        // Evaluated where delta_diff stays in range (any delta serves: the sigmas scale).
        let d0 = self
            .delta0()
            .min(0.5 * f64::from(ChassisParams::MAX_DELTA) / r.max(1e-300));
        let p = with_delta_diff(
            &set_coefficient(&self.base, self.o.mode, self.initial, d0),
            r * d0,
        );
        // At ratio 0, the restarts' integration of the horizontal fit's geometry serves when
        // its sigmas scale to these.
        let (ev, d0) = match homogeneous_record(self.restarts, &p).filter(|_| r == 0.0) {
            Some((q, ev)) => (ev, f64::from(q.delta_left)),
            None => (self.restarts.evaluate_memo(self.run, &p)?, d0),
        };
        // Each point's smallest delta inside the widened band: |e| <= hypot(s delta / d0, rho).
        let mut need: Vec<f64> = (0..ev.horizontal.len())
            .map(|i| {
                let e = ev.horizontal[i];
                let rho = reference_sigma_at(&ev, i, self.o.ref_sigma);
                let excess = (e * e - rho * rho).max(0.0).sqrt();
                let s = ev.sigma_h[i] / d0;
                if excess == 0.0 {
                    0.0
                } else if s > 0.0 {
                    excess / s
                } else {
                    f64::INFINITY
                }
            })
            .collect();
        let Some(k) = covering_rank(need.len()) else {
            return Ok(None);
        };
        let (_, &mut delta, _) = need.select_nth_unstable_by(k - 1, f64::total_cmp);
        if !delta.is_finite() {
            return Ok(None);
        }
        let scale = delta / d0;
        let rh = self.o.ref_heading_sigma;
        let (mut n, mut inside) = (0usize, 0usize);
        for i in 0..ev.heading_change_err.len() {
            if let Some(e) = ev.heading_change_err[i] {
                let m = ev.start_headings[i].max(1) as f64;
                let band = norm2(scale * ev.sigma_heading[i], rh * (1.0 + 1.0 / m).sqrt());
                n += 1;
                inside += usize::from(e.abs() <= band);
            }
        }
        Ok(Some(RatioTrial {
            delta,
            delta_diff: r * delta,
            heading: inside as f64 / n.max(1) as f64,
        }))
    }

    /// Whether the trial's heading band covers, delta identifiable.
    fn covers(&self, t: Option<RatioTrial>, hi: f64) -> bool {
        t.is_some_and(|t| t.heading >= ONE_SIGMA_COVERAGE && t.delta > hi * 1e-12)
    }

    /// The smallest `delta_diff` of the joint criterion: 0 when the horizontal fit already
    /// covers the heading changes, else a bisection in `ln r` over [`RATIO_RANGE`] to a
    /// relative width [`DIFF_LOG_TOL`] (`delta_diff` grows with the ratio: delta falls more
    /// slowly, held up by the straights); `None` when even the largest ratio does not cover
    /// (then delta would have to fall to zero) or `delta_diff` would exceed `hi`.
    fn smallest(&self, hi: f64, progress: &ProgressBar) -> Result<Option<f64>> {
        if self
            .at(0.0)?
            .is_some_and(|t| t.heading >= ONE_SIGMA_COVERAGE)
        {
            return Ok(Some(0.0));
        }
        let (mut l, mut h) = (RATIO_RANGE.0.ln(), RATIO_RANGE.1.ln());
        let mut best = self.at(h.exp())?;
        if !self.covers(best, hi) {
            return Ok(None);
        }
        if self.covers(self.at(l.exp())?, hi) {
            return Ok(self.at(l.exp())?.map(|t| t.delta_diff));
        }
        while h - l > DIFF_LOG_TOL {
            let m = 0.5 * (l + h);
            let t = self.at(m.exp())?;
            if self.covers(t, hi) {
                h = m;
                best = t;
            } else {
                l = m;
            }
            progress.inc(1);
        }
        Ok(best.map(|t| t.delta_diff).filter(|&dd| dd <= hi))
    }

    /// delta refitted by the horizontal criterion at `delta_diff = v`.
    fn refit(&self, v: f64) -> Result<UncertaintyFit> {
        fit_coefficient(
            self.run,
            self.restarts,
            &with_delta_diff(&self.base, v),
            self.initial,
            self.o.ref_sigma,
            self.o.mode,
            DIFF_LOG_TOL,
            &ProgressBar::hidden(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testing::run_of;
    use crate::calib::uncertainty::coverage::heading_coverage;
    use crate::simulate::{self, default_truth, PathKind, SimSettings};

    /// The ratio search finds the plain joint bisection's `delta_diff` (delta refitted by
    /// the horizontal criterion at every trial), on runs whose wheels slip in opposite phase
    /// when turning.
    #[test]
    fn ratio_search_matches_the_plain_joint_bisection() {
        let mut joint = 0;
        let cases = (1..=6).flat_map(|seed| [(seed, 0.01), (seed, 0.02)]);
        for (seed, slip_turn) in cases {
            let settings = SimSettings {
                seed,
                slip_turn,
                ..Default::default()
            };
            let s = simulate::simulate_path(PathKind::Estimation, 70.0, default_truth(), settings);
            let run = run_of(&s);
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
            let hidden = ProgressBar::hidden();
            let restarts = Restarts::new(&run, &base, run.heading_guess(0), 10.0).unwrap();
            let plain_cover = |v: f64| -> Result<f64> {
                let f = fit_coefficient(
                    &run,
                    &restarts,
                    &with_delta_diff(&base, v),
                    &base,
                    o.ref_sigma,
                    o.mode,
                    DIFF_LOG_TOL,
                    &hidden,
                )?;
                let ev = restarts.evaluate(&run, &f.params)?;
                Ok(heading_coverage(&ev, o.ref_heading_sigma, 1.0, 0))
            };
            let (plain, w) =
                smallest_covering(hi, true, DIFF_LOG_TOL, plain_cover, &hidden).unwrap();
            assert!(w.is_none() && plain > 0.0, "seed {seed}: {plain} {w:?}");
            // The plain search's result is joint only when delta stays identifiable there.
            let refit = fit_coefficient(
                &run,
                &restarts,
                &with_delta_diff(&base, plain),
                &base,
                o.ref_sigma,
                o.mode,
                DIFF_LOG_TOL,
                &hidden,
            )
            .unwrap();
            let fast = RatioSearch::new(&run, &restarts, base, &base, o)
                .smallest(hi, &hidden)
                .unwrap();
            match (refit.warning.is_none(), fast) {
                (true, Some(fast)) => {
                    joint += 1;
                    assert!(
                        (fast / plain).ln().abs() < 0.01,
                        "{slip_turn} seed {seed}: ratio search {fast:e}, plain bisection {plain:e}"
                    );
                }
                (false, None) => {}
                (ok, fast) => panic!(
                    "{slip_turn} seed {seed}: plain {plain:e} (joint {ok}), ratio search {fast:?}"
                ),
            }
        }
        assert!(joint >= 2, "{joint} joint fits");
    }
}
