//! The geometry refined by the Kalman filter of the kappa likelihood (`--geometry-refine
//! filter`, the default after the sub-trajectory fit).
//!
//! [`Innovations`] carries the geometry's relative errors `(c_1, c_2, b)` as states with a wide
//! prior, so its state after the last observation is a generalised least-squares estimate of
//! them that weights every observation by the slip's noise: the turns, where the heading
//! drifts most, count for what they are worth, where the sub-trajectory fit weighs every
//! residual alike. The refinement: the white-slip kappa of the largest likelihood (the slip's
//! long-range rate; on the 70 m path white slip weights the turns better than the fitted
//! correlated model, 0.26 against 0.28 mm RMS on the track over 50 seeds), the filter's
//! estimate applied to the geometry, the filter linearised again at the result, until the step
//! is a hundredth of a standard error (two or three passes). Where the likelihood finds
//! opposite-phase slip when turning (white `kappa_diff`, a likelihood-ratio test at 95 %) the
//! refinement is not applied: under correlated turning slip (2 % over 1 m of wheel-distance
//! difference, `tests/uncertainty_ensemble.rs`) its diameters were worse than the
//! sub-trajectory fit's and their standard errors half the error.
//!
//! Its limit: the filter is linearised about the odometry integrated open-loop over the whole
//! run, whose heading drifts from the truth by a random walk of variance
//! `kappa (R_1 + R_2) / W^2` at the end (`R_i` the distances the wheels rolled); the
//! positions' second order in that drift shortens the path by a quarter of it on average
//! (relative), and the filter takes about half of that for a scale of all three lengths (on
//! the 70 m path at the default slip: -1.1e-5 and -1.5e-5 of the diameters on average over 50
//! seeds, against 2.4e-5 for the quarter). That error, `kappa (R_1 + R_2) / (8 W^2)`, is added
//! to the standard errors, and when it exceeds the diameters' own the refinement is not applied
//! (logs of a few hundred metres on: the sub-trajectory estimate is then kept, which is better
//! there). The filter observes the axle centre: a lever arm also keeps the sub-trajectory
//! estimate.

use anyhow::{anyhow, Result};
use odo_core::odometry::ChassisParams;

use super::slip_fit::{largest_likelihood, EVIDENCE_PER_PARAMETER};
use super::{Innovations, Run, Turning, OBSERVATION_BLOCK};

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

/// Largest number of linearisations.
const MAX_PASSES: usize = 4;

/// The refinement stops when its step is below this share of each standard error.
const STEP_TOLERANCE: f64 = 0.01;

/// Outcome of [`refine_geometry`].
#[derive(Debug, Clone)]
pub struct FilterRefinement {
    /// The refined parameters (the input's when not applied).
    pub params: ChassisParams,
    /// Covariance of `left_diameter`, `right_diameter`, `track_width` (m^2), with the
    /// linearisation bound added to the diagonal.
    pub covariance: [[f64; 3]; 3],
    /// The white slip of the largest likelihood the filter weighted with (m^2 per m rolled).
    pub kappa: f64,
    /// White opposite-phase slip when turning found by the likelihood beside `kappa`
    /// (`kappa_diff`, m^2 per m of `|s_1 - s_2|`; 0: none, else the refinement is not
    /// applied).
    pub kappa_diff: f64,
    /// Linearisations run.
    pub passes: usize,
    /// Bound of the linearisation's error, relative (see the module documentation).
    pub linearisation: f64,
    /// Filter observations (one per metre of path).
    pub observations: usize,
    /// Why the refinement was not applied (`None`: applied).
    pub skipped: Option<String>,
}

impl FilterRefinement {
    /// The standard errors of `left_diameter`, `right_diameter`, `track_width` (m).
    pub fn std_errors(&self) -> [f64; 3] {
        std::array::from_fn(|i| self.covariance[i][i].sqrt())
    }
}

/// The distances the two wheels rolled over the run (m).
fn rolled(run: &Run, p: &ChassisParams) -> [f64; 2] {
    let (a, b) = (run.matches[0].0, run.matches[run.len() - 1].0);
    let per = |d: f64| std::f64::consts::PI * d / f64::from(p.ticks_per_rev);
    let (pl, pr) = (per(p.left_diameter), per(p.right_diameter));
    let mut out = [0.0; 2];
    for w in run.samples[a..=b].windows(2) {
        out[0] += ((w[1].left - w[0].left) as f64 * pl).abs();
        out[1] += ((w[1].right - w[0].right) as f64 * pr).abs();
    }
    out
}

/// Reference path of the first look at the slip on a long log (m).
const PREFIX: f64 = 100.0;

/// A long log is not refined when the linearisation bound from its first [`PREFIX`] metres'
/// slip exceeds this many of the sub-trajectory fit's diameter standard errors (which are
/// about the filter's): the filter over the whole log would be run only to be refused.
const PREFIX_MARGIN: f64 = 3.0;

/// Refines `params` (a geometry estimate, e.g. the sub-trajectory fit's) by the filter's
/// estimate (module documentation). `heading0` is the run's start heading (used without
/// reference headings), the sigmas are the reference's (m, rad); `diameters_se` the
/// estimate's own smaller diameter standard error (m), by which a long log is first judged
/// on the slip of its first 100 m.
pub fn refine_geometry(
    run: &Run,
    params: &ChassisParams,
    heading0: f64,
    ref_sigma: f64,
    ref_heading_sigma: f64,
    diameters_se: Option<f64>,
) -> Result<FilterRefinement> {
    let hi = f64::from(ChassisParams::MAX_KAPPA);
    let lo = hi * 1e-12;
    let last = run.len() - 1;
    if let Some(se) = diameters_se.filter(|_| run.dist[last] > 1.5 * PREFIX) {
        let b = run.last_within(0, PREFIX);
        let prefix = Run::new(run.samples, run.reference, run.matches[..=b].to_vec())
            .with_antenna(run.antenna);
        let inn = Innovations::new(
            &prefix,
            params,
            heading0,
            ref_sigma,
            ref_heading_sigma,
            OBSERVATION_BLOCK,
        )?;
        let kappa = inn.fit(lo, hi);
        let r = rolled(run, params);
        let linearisation = kappa * (r[0] + r[1]) / (8.0 * params.track_width.powi(2));
        let relative = se / params.left_diameter.min(params.right_diameter);
        if linearisation > PREFIX_MARGIN * relative {
            return Ok(FilterRefinement {
                params: *params,
                covariance: [[f64::NAN; 3]; 3],
                kappa,
                kappa_diff: f64::NAN,
                passes: 0,
                linearisation,
                observations: inn.observations,
                skipped: Some(format!(
                    "the filter's linearisation error ({linearisation:.1e} of the lengths: white slip kappa {kappa:.2e} m^2/m over the first {PREFIX} m, {:.0} m rolled) exceeds {PREFIX_MARGIN} of the diameters' standard errors ({relative:.1e})",
                    r[0] + r[1]
                )),
            });
        }
    }
    let new = |p: &ChassisParams| {
        Innovations::new(
            run,
            p,
            heading0,
            ref_sigma,
            ref_heading_sigma,
            OBSERVATION_BLOCK,
        )
    };
    let mut inn = new(params)?;
    // White slip; then whether the likelihood asks for opposite-phase slip when turning.
    let nll = |k: f64, t: Turning| inn.score_with(k, 0.0, t).nll;
    let white = |kappa_diff: f64| Turning {
        kappa_diff,
        corr: 0.0,
    };
    let kappa = inn.fit(lo, hi);
    let kd = largest_likelihood(|d| nll(kappa, white(d)), lo, hi);
    let kappa_diff = if nll(kappa, white(kd)) + EVIDENCE_PER_PARAMETER < nll(kappa, Turning::NONE) {
        kd
    } else {
        0.0
    };
    let mut p = *params;
    let mut rel_cov = [[0.0; 3]; 3];
    let mut passes = 0;
    while passes < MAX_PASSES {
        if passes > 0 {
            inn = new(&p)?;
        }
        let s = inn.score_with(kappa, 0.0, Turning::NONE);
        passes += 1;
        if !s.nll.is_finite() || s.geometry.iter().any(|v| !v.is_finite()) {
            return Err(anyhow!("the filter failed at kappa {kappa:e}"));
        }
        let g = s.geometry;
        p.left_diameter *= 1.0 + g[0];
        p.right_diameter *= 1.0 + g[1];
        p.track_width *= 1.0 + g[2];
        rel_cov = s.geometry_cov;
        if (0..3).all(|i| g[i].abs() <= STEP_TOLERANCE * rel_cov[i][i].sqrt()) {
            break;
        }
    }
    let r = rolled(run, &p);
    let w2 = p.track_width * p.track_width;
    let linearisation = kappa * (r[0] + r[1]) / (8.0 * w2);
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
            "the filter's linearisation error ({linearisation:.1e} of the lengths: white slip kappa {kappa:.2e} m^2/m over {:.0} m rolled) exceeds its diameters' standard error ({diameters_se:.1e})",
                r[0] + r[1]
            )
        })
    };
    Ok(FilterRefinement {
        params: if skipped.is_some() { *params } else { p },
        covariance,
        kappa,
        kappa_diff,
        passes,
        linearisation,
        observations: inn.observations,
        skipped,
    })
}
