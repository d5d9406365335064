//! The geometry refined by the Kalman filter of the kappa likelihood (`--geometry-refine
//! filter`, the default after the sub-trajectory fit; [`refine_subtrajectory_fit`]).
//!
//! [`Innovations`] carries the geometry's relative errors `(c_1, c_2, b)` as states with a wide
//! prior, so its state after the last observation is a generalised least-squares estimate of
//! them that weights every observation by the slip's noise: the turns, where the heading
//! drifts most, count for what they are worth, where the sub-trajectory fit weighs every
//! residual alike. The refinement: the white-slip kappa of the largest likelihood (the slip's
//! long-range rate; on the 70 m path white slip weights the turns better than the fitted
//! correlated model, 0.26 against 0.28 mm RMS on the track over 50 seeds), and the filter's
//! estimate at it applied to the geometry. Where the likelihood finds opposite-phase slip
//! when turning (white `kappa_diff`, a likelihood-ratio test at 95 %) the refinement is not
//! applied: under correlated turning slip (2 % over 1 m of wheel-distance difference,
//! `tests/uncertainty_ensemble.rs`) its diameters were worse than the sub-trajectory fit's and
//! their standard errors half the error.
//!
//! The filter is linearised about its own estimate ([`Innovations::reanchored`]), so one
//! pass is enough (a second moved the RMS errors by 1 um at most on the 70 m to 3 km
//! logs). What remains of the linearisation: the odometry re-anchored to the estimate turns
//! from the truth by the estimate's heading error, whose second order shortens the path by
//! half its variance (relative), of which the filter takes about half for a scale of all
//! three lengths; that error, a quarter of the heading error's mean variance, is added to the
//! covariance as one scale of the three lengths, and when it exceeds the diameters' standard
//! error the refinement is not applied. (Linearised about the odometry integrated open-loop
//! instead, the filter would keep the drift's error of `kappa (R_1 + R_2) / (8 W^2)`, `R_i` the
//! distances the wheels rolled: it would refuse every log longer than a few hundred metres.)
//! The filter holds a lever arm exact: a given one is the user's measurement, as in the
//! sub-trajectory fit; a fitted one's share is added to the covariance
//! ([`add_lever_arm_share`]).

use anyhow::{anyhow, Result};
use odo_unit::odometry::ChassisParams;

use crate::calib::antenna::{LeverArm, ANTENNA_FORWARD, ANTENNA_LEFT};
use crate::calib::filter::innovations::{Innovations, Turning, OBSERVATION_BLOCK};
use crate::calib::filter::search::{
    posterior_mean, slip_rate_range, Search, SearchLog, EVIDENCE_PER_PARAMETER,
};
use crate::calib::run::Run;

use super::subtrajectory::SubtrajectoryFit;

/// Whether `calibrate` refines the sub-trajectory geometry by the filter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum GeometryRefine {
    /// The filter's generalised least-squares estimate ([`refine_geometry`]) where its
    /// linearisation holds (the default).
    #[default]
    Filter,
    /// The sub-trajectory estimate as fitted.
    None,
}

/// Outcome of [`refine_geometry`].
#[derive(Debug, Clone)]
pub struct FilterRefinement {
    /// The refined parameters (the input's when not applied).
    pub params: ChassisParams,
    /// Covariance of `left_diameter`, `right_diameter`, `track_width` (m^2), with the
    /// linearisation bound added as one scale of the three.
    pub covariance: [[f64; 3]; 3],
    /// The white slip of the largest likelihood the filter weighted with (m^2 per m rolled).
    pub kappa: f64,
    /// White opposite-phase slip when turning found by the likelihood beside `kappa`
    /// (`kappa_diff`, m^2 per m of `|s_1 - s_2|`; 0: none, else the refinement is not
    /// applied).
    pub kappa_diff: f64,
    /// Bound of the linearisation's error, relative (see the module documentation).
    pub linearisation: f64,
    /// Filter observations (one per metre of path).
    pub observations: usize,
    /// Why the refinement was not applied (`None`: applied).
    pub skipped: Option<String>,
    /// The filter it ran, linearised about its estimate: the covariance model's kappa fit
    /// takes it rather than building its own (its geometry states absorb the refinement's
    /// step).
    pub innovations: Option<std::sync::Arc<Innovations>>,
    /// Where the likelihood's searches ended, where a later refinement of the same drive on
    /// more data starts its own.
    pub searches: Vec<(Search, f64)>,
}

impl FilterRefinement {
    /// The standard errors of `left_diameter`, `right_diameter`, `track_width` (m).
    pub fn std_errors(&self) -> [f64; 3] {
        std::array::from_fn(|i| self.covariance[i][i].sqrt())
    }
}

/// Refines `params` (a geometry estimate, e.g. the sub-trajectory fit's) by the filter's
/// estimate (module documentation). `heading0` is the run's start heading (used without
/// reference headings), the sigmas are the reference's (m, rad). The likelihood's searches
/// start where `log`'s earlier fit's ended, and are recorded there.
pub fn refine_geometry(
    run: &Run,
    params: &ChassisParams,
    heading0: f64,
    sigmas: (f64, f64),
    log: &SearchLog,
) -> Result<FilterRefinement> {
    let (lo, hi) = slip_rate_range();
    let inn = Innovations::new_after(run, params, (heading0, sigmas, OBSERVATION_BLOCK), log)?;
    // White slip; then whether the likelihood asks for opposite-phase slip when turning.
    let nll = |k: f64, t: Turning| inn.score_with(k, 0.0, t).nll;
    let white = |kappa_diff: f64| Turning {
        kappa_diff,
        corr: 0.0,
    };
    let kappa = log.largest(Search::RefinedWhite, |k| nll(k, Turning::NONE), lo, hi);
    let kd = log.largest(
        Search::RefinedTurningWhite,
        |d| nll(kappa, white(d)),
        lo,
        hi,
    );
    let kappa_diff = if nll(kappa, white(kd)) + EVIDENCE_PER_PARAMETER < nll(kappa, Turning::NONE) {
        kd
    } else {
        0.0
    };
    let s = inn.score_with(kappa, 0.0, Turning::NONE);
    if !s.nll.is_finite() || s.geometry.iter().any(|v| !v.is_finite()) {
        return Err(anyhow!("the filter failed at kappa {kappa:e}"));
    }
    // The covariance at kappa's mean over the likelihood: one drive reads kappa low about as
    // often as high, and the geometry's variances grow with it.
    let kappa_mean = posterior_mean(|l| nll(l.exp(), Turning::NONE), kappa, hi);
    let rel_cov = if kappa_mean > kappa {
        inn.score_with(kappa_mean, 0.0, Turning::NONE).geometry_cov
    } else {
        s.geometry_cov
    };
    let (g, heading_var) = (s.geometry, s.heading_var);
    let mut p = *params;
    p.left_diameter *= 1.0 + g[0];
    p.right_diameter *= 1.0 + g[1];
    p.track_width *= 1.0 + g[2];
    let linearisation = heading_var / 4.0;
    let v = [p.left_diameter, p.right_diameter, p.track_width];
    let mut covariance = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            // The linearisation's error is one scale of all three lengths.
            covariance[i][j] = (rel_cov[i][j] + linearisation * linearisation) * v[i] * v[j];
        }
    }
    let diameters_se = rel_cov[0][0].min(rel_cov[1][1]).sqrt();
    let skipped = if kappa_diff > 0.0 {
        Some(format!(
            "the run has opposite-phase slip when turning (kappa_diff {kappa_diff:.2e} by the likelihood), under which the filter's estimate and its errors do not hold"
        ))
    } else {
        (linearisation > diameters_se).then(|| {
            format!(
            "the filter's linearisation error ({linearisation:.1e} of the lengths: its heading error {:.1e} rad RMS) exceeds its diameters' standard error ({diameters_se:.1e})",
                heading_var.sqrt()
            )
        })
    };
    Ok(FilterRefinement {
        params: if skipped.is_some() { *params } else { p },
        covariance,
        kappa,
        kappa_diff,
        linearisation,
        observations: inn.observations,
        innovations: skipped.is_none().then(|| std::sync::Arc::new(inn)),
        skipped,
        searches: Vec::new(),
    })
}

/// The filter's refinement of a sub-trajectory fit `s` ([`refine_geometry`]) with the
/// reference's sigmas (m, rad), the run's lever arm the fit's; with a fitted lever arm
/// (`antenna`) its share added to the covariance; the likelihood's searches from where
/// `earlier`'s ended (an earlier refinement's of the same drive, [`FilterRefinement::searches`];
/// empty: cold). Not run with the track width held; then `skipped` says why.
pub fn refine_subtrajectory_fit(
    run: &Run,
    s: &SubtrajectoryFit,
    antenna: LeverArm,
    (ref_sigma, ref_heading_sigma): (f64, f64),
    earlier: Vec<(Search, f64)>,
) -> Result<FilterRefinement> {
    if !s.track_estimated {
        return Ok(FilterRefinement {
            params: s.params,
            covariance: [[f64::NAN; 3]; 3],
            kappa: f64::NAN,
            kappa_diff: f64::NAN,
            linearisation: f64::NAN,
            observations: 0,
            skipped: Some("the track width is held".to_string()),
            innovations: None,
            searches: Vec::new(),
        });
    }
    // The start heading (the filter's without reference headings): the first
    // sub-trajectory's fitted one.
    let heading0 = s.blocks.first().map_or(0.0, |b| b.heading);
    let log = SearchLog::after(earlier);
    let sigmas = (ref_sigma, ref_heading_sigma);
    let mut r = refine_geometry(run, &s.params, heading0, sigmas, &log)?;
    r.searches = log.ended();
    if r.skipped.is_none() && antenna.fitted() {
        add_lever_arm_share(run, s, heading0, (ref_sigma, ref_heading_sigma), &mut r)?;
    }
    Ok(r)
}

/// Adds a fitted lever arm's share to `r.covariance`: the filter holds the lever arm at the
/// sub-trajectory fit's estimate, so its estimate is taken again (at `r.kappa`) with each
/// coordinate of the lever arm moved by its standard error, and `J C J^T` is added, `J` the
/// refined lengths' change per metre of lever arm and `C` the sub-trajectory fit's covariance
/// of the lever arm.
fn add_lever_arm_share(
    run: &Run,
    s: &SubtrajectoryFit,
    heading0: f64,
    (ref_sigma, ref_heading_sigma): (f64, f64),
    r: &mut FilterRefinement,
) -> Result<()> {
    let unknowns = [ANTENNA_FORWARD - 1, ANTENNA_LEFT - 1];
    let lengths = |p: &ChassisParams| [p.left_diameter, p.right_diameter, p.track_width];
    let (base, refined) = (lengths(&s.params), lengths(&r.params));
    let mut columns = [[0.0; 3]; 2];
    for (column, (k, &u)) in columns.iter_mut().zip(unknowns.iter().enumerate()) {
        let Some(se) = s.covariance_of(u, u).map(f64::sqrt).filter(|v| *v > 0.0) else {
            return Ok(());
        };
        let mut antenna = s.antenna;
        if k == 0 {
            antenna.0 += se;
        } else {
            antenna.1 += se;
        }
        let moved = Run {
            samples: run.samples,
            reference: run.reference,
            matches: run.matches.clone(),
            dist: run.dist.clone(),
            antenna,
        };
        let inn = Innovations::new(
            &moved,
            &s.params,
            heading0,
            ref_sigma,
            ref_heading_sigma,
            OBSERVATION_BLOCK,
        )?;
        let g = inn.score_with(r.kappa, 0.0, Turning::NONE).geometry;
        for i in 0..3 {
            column[i] = (base[i] * (1.0 + g[i]) - refined[i]) / se;
        }
    }
    for (a, &ua) in unknowns.iter().enumerate() {
        for (b, &ub) in unknowns.iter().enumerate() {
            let c = s.covariance_of(ua, ub).unwrap_or(0.0);
            for i in 0..3 {
                for j in 0..3 {
                    r.covariance[i][j] += columns[a][i] * c * columns[b][j];
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::geometry::subtrajectory::{fit_subtrajectories, SubtrajectoryOptions};
    use crate::calib::testing::{run_of, sim};
    use crate::simulate::PathKind;

    /// A refinement records where its three likelihood searches ended; one started from
    /// those ends refines the geometry as the cold one does, to far within its standard
    /// errors, and ends its searches within their tolerance of the cold ones.
    #[test]
    fn a_warm_refinement_is_the_cold_one() {
        let s = sim(PathKind::Random, 400.0, 8);
        let run = run_of(&s);
        let start = ChassisParams::DESIGNED;
        let fit = fit_subtrajectories(&run, &start, SubtrajectoryOptions::default()).unwrap();
        let refine = |earlier| {
            refine_subtrajectory_fit(&run, &fit, LeverArm::default(), (0.01, 0.01), earlier)
                .unwrap()
        };
        let cold = refine(Vec::new());
        assert!(cold.skipped.is_none(), "{:?}", cold.skipped);
        let names: Vec<Search> = cold.searches.iter().map(|s| s.0).collect();
        assert_eq!(
            names,
            [
                Search::OpenLoop,
                Search::RefinedWhite,
                Search::RefinedTurningWhite
            ]
        );
        let warm = refine(cold.searches.clone());
        let lengths = |p: &ChassisParams| [p.left_diameter, p.right_diameter, p.track_width];
        let (w, c) = (lengths(&warm.params), lengths(&cold.params));
        for (i, se) in cold.std_errors().iter().enumerate() {
            let d = (w[i] - c[i]).abs();
            assert!(d <= 1e-3 * se, "{i}: {d:e} of {se:e}");
        }
        for (w, c) in warm.searches.iter().zip(&cold.searches) {
            assert_eq!(w.0, c.0);
            assert!((w.1 / c.1).ln().abs() <= 2e-3, "{w:?} {c:?}");
        }
    }
}
