//! The whole calibration in memory: the eq (16) fit, the uncertainty and `delta_diff` fits,
//! the final evaluation and the stability study, returning values (no printing).

use std::thread::JoinHandle;
use std::time::Instant;

use anyhow::{bail, Result};
use indicatif::{ProgressBar, ProgressStyle};
use odo_unit::odometry::{ChassisParams, GeometryUncertainty, UncertaintyModel};

use crate::config as cfg;
use crate::csvio;

use super::antenna::LeverArm;
use super::evaluation::{evaluate, Evaluation};
use super::filter::innovations::{Innovations, OBSERVATION_BLOCK};
use super::filter::search::Search;
use super::geometry::paper::{fit_geometry, GeomFit, GeomOptions};
use super::geometry::refinement::{refine_subtrajectory_fit, FilterRefinement, GeometryRefine};
use super::geometry::subtrajectory::{
    fit_subtrajectories_from, Cuts, SubtrajectoryFit, SubtrajectoryOptions, SUBTRAJECTORY_LENGTH,
};
use super::geometry::turning::track_width_warning;
use super::geometry::wheel_harmonics::{fit_harmonics, HarmonicsFit, HARMONICS_SEGMENT};
use super::heading_fit::{fit_whole_run_heading, RunPath, WholeRunHeading};
use super::run::Run;
use super::studies::stability::{windows_study, WindowEstimate, WindowStart};
use super::uncertainty::coefficients::{
    set_coefficient, with_covariance_coefficients, DeltaMode, UncertaintyCriterion, UncertaintyFit,
};
use super::uncertainty::coverage::fit_uncertainty_on;
use super::uncertainty::delta_diff::{fit_delta_diff, DiffOptions};
use super::uncertainty::likelihood::fit_kappa_filter;
use super::uncertainty::restarts::Restarts;
use super::warm::{Extras, WarmStart};
use crate::cancel::{cancel_this_thread_on, this_thread_cancel};

/// How the diameters and the track width are estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Method {
    /// Sub-trajectories restarted every `subtrajectory_length` metres, their start position
    /// and heading fitted, the chassis shared
    /// ([`fit_subtrajectories`](super::geometry::subtrajectory::fit_subtrajectories)): the
    /// default.
    #[default]
    Subtrajectory,
    /// The paper's eq (16) over the whole run ([`fit_geometry`]).
    Paper,
}

/// The reference's horizontal RMS noise of one epoch where neither the log nor the options
/// give one and the reference is not a trajectory (m): an RTK fix's.
pub const DEFAULT_REFERENCE_SIGMA: f64 = 0.008;

/// The reference heading's noise where neither the options nor a trajectory give one
/// (degrees): a BD982-like dual antenna's, `simulate --heading-sigma-deg`'s default.
pub const DEFAULT_REFERENCE_HEADING_SIGMA_DEG: f64 = 0.5;

/// Options of the calibration (`odoctl calibrate`'s fitting options; the defaults are the
/// command line's).
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationOptions {
    /// Sub-trajectory length of the uncertainty fit (m).
    pub delta_window: f64,
    /// Reference noise (m).
    pub reference_sigma: f64,
    /// Left/right relation of the coefficients.
    pub delta_mode: DeltaMode,
    /// Fit the uncertainty coefficients.
    pub fit_delta: bool,
    /// Fit `delta_diff` of the paper's model by the heading criterion (when the reference has
    /// a heading; else the initial value is kept).
    pub fit_delta_diff: bool,
    /// Reference heading noise (rad), added to `sigma_heading` in the heading criterion.
    pub reference_heading_sigma: f64,
    /// The uncertainty models whose coefficients are fitted (empty: the initial estimate's
    /// `uncertainty_model`). The result keeps the initial model when it is among them, else
    /// the last one.
    pub models: Vec<UncertaintyModel>,
    /// How the geometry is estimated.
    pub method: Method,
    /// Sub-trajectory length of [`Method::Subtrajectory`], and of the stretches of the
    /// paper method's cluster-robust standard errors (m of reference path).
    pub subtrajectory_length: f64,
    /// Where [`Method::Subtrajectory`] cuts the run.
    pub subtrajectory_cuts: Cuts,
    /// Whether [`Method::Subtrajectory`]'s estimate is refined by the filter
    /// ([`refine_geometry`](super::geometry::refinement::refine_geometry)).
    pub geometry_refine: GeometryRefine,
    /// The antenna lever arm: measured (held) or fitted with the geometry.
    pub antenna: LeverArm,
    /// The model the result selects (`uncertainty_model`), added to `models` when missing;
    /// `None`: the initial estimate's model when it was fitted, else the last fitted.
    pub select: Option<UncertaintyModel>,
    /// How the covariance model's kappa is fitted (the paper's model always by the coverage
    /// criterion).
    pub criterion: UncertaintyCriterion,
    /// Nelder-Mead polish of eq (16).
    pub polish: bool,
    /// Stability study lengths (m); empty: no study.
    pub windows: Vec<f64>,
    /// Where the study's fits start.
    pub window_start: WindowStart,
    /// Harmonics of the per-angle wheel function to fit per wheel (0 = none, 1..=3).
    pub wheel_harmonics: usize,
    /// Segment length of the harmonics fit (m).
    pub harmonics_window: f64,
    /// No progress bars.
    pub quiet: bool,
}

impl Default for CalibrationOptions {
    /// The sub-trajectory method on 10 m (cut by distance) refined by the filter, no lever arm; 10 m sub-trajectories of the
    /// uncertainty fit, the BD982's 8 mm and 0.5 deg, equal coefficients, `delta` and
    /// `delta_diff` fitted for the initial estimate's model, no polish, no stability study
    /// (its windows started from the whole-run estimate), no wheel harmonics, no progress bars.
    fn default() -> Self {
        Self {
            delta_window: 10.0,
            reference_sigma: DEFAULT_REFERENCE_SIGMA,
            delta_mode: DeltaMode::Equal,
            fit_delta: true,
            fit_delta_diff: true,
            reference_heading_sigma: DEFAULT_REFERENCE_HEADING_SIGMA_DEG.to_radians(),
            models: Vec::new(),
            method: Method::Subtrajectory,
            subtrajectory_length: SUBTRAJECTORY_LENGTH,
            subtrajectory_cuts: Cuts::default(),
            geometry_refine: GeometryRefine::default(),
            antenna: LeverArm::Fixed(0.0, 0.0),
            select: None,
            criterion: UncertaintyCriterion::Likelihood,
            polish: false,
            windows: Vec::new(),
            window_start: WindowStart::Full,
            wheel_harmonics: 0,
            harmonics_window: HARMONICS_SEGMENT,
            quiet: true,
        }
    }
}

fn bar(quiet: bool, what: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(1);
    pb.set_style(
        ProgressStyle::with_template("{prefix:>22} [{bar:40}] {pos}/{len} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb
}

/// The outcome of a calibration (also used by the tests).
pub struct Calibration {
    /// Final parameters.
    pub params: ChassisParams,
    /// The geometry fit, whichever the method (for the sub-trajectory method: its estimate,
    /// robust errors, and the whole run's eq (16) heading and cost at it).
    pub geometry: GeomFit,
    /// The sub-trajectory fit, with [`Method::Subtrajectory`].
    pub subtrajectories: Option<SubtrajectoryFit>,
    /// The filter's refinement of the sub-trajectory estimate, with
    /// [`GeometryRefine::Filter`] (applied unless its `skipped` says why not).
    pub refinement: Option<FilterRefinement>,
    /// The uncertainty fits, one per model fitted.
    pub uncertainty: Vec<UncertaintyFit>,
    /// Evaluation of the whole run with the final parameters.
    pub evaluation: Evaluation,
    /// The stability study.
    pub windows: Vec<WindowEstimate>,
    /// The wheel-function fit (`wheel_harmonics` > 0).
    pub harmonics: Option<HarmonicsFit>,
}

impl Calibration {
    /// The warm start this calibration leaves for one of the same drive on more data;
    /// `None` without a sub-trajectory fit.
    pub fn warm_start(&self) -> Option<WarmStart> {
        let s = self.subtrajectories.as_ref()?;
        let coefficient = |p: &ChassisParams| match p.uncertainty_model {
            UncertaintyModel::Paper => f64::from(p.delta_left),
            UncertaintyModel::Covariance => f64::from(p.kappa_left),
        };
        Some(WarmStart {
            subtrajectories: s.warm_start(),
            coefficients: self
                .uncertainty
                .iter()
                .filter(|u| u.criterion == UncertaintyCriterion::Coverage)
                .map(|u| (u.model, coefficient(&u.params)))
                .collect(),
            heading0: self.geometry.heading0,
            likelihood: self
                .uncertainty
                .iter()
                .filter(|u| u.criterion == UncertaintyCriterion::Likelihood)
                .take(1)
                .flat_map(|u| u.searches.iter().copied())
                .chain(
                    self.refinement
                        .iter()
                        .flat_map(|r| r.searches.iter().copied()),
                )
                .collect(),
        })
    }
}

/// The geometry's calibration uncertainty as the unit's keys (`left_diameter_se`..
/// `right_track_correlation`): the filter refinement's covariance when it was applied, else
/// the sub-trajectory fit's cluster-robust covariance, or for the paper's method its robust
/// standard errors without correlations. A held unknown has none;
/// standard errors beyond [`GeometryUncertainty::MAX_SE`] are capped there, and correlations
/// that f32 rounding would make inconsistent are shrunk until they are not.
pub fn geometry_uncertainty(
    geometry: &GeomFit,
    subtrajectories: Option<&SubtrajectoryFit>,
    refinement: Option<&FilterRefinement>,
) -> GeometryUncertainty {
    let refined = refinement.filter(|r| r.skipped.is_none());
    let covariance_of = |i: usize, j: usize| -> Option<f64> {
        match (refined, subtrajectories) {
            (Some(r), _) => Some(r.covariance[i][j]),
            (None, Some(s)) => s.covariance_of(i, j),
            (None, None) => None,
        }
    };
    let se = |i: usize| -> f64 {
        let v = match (refined, subtrajectories) {
            (None, None) => geometry.robust_std_errors[i],
            _ => covariance_of(i, i).map(f64::sqrt),
        };
        v.filter(|v| v.is_finite()).unwrap_or(0.0)
    };
    let corr = |i: usize, j: usize| -> f64 {
        let c = covariance_of(i, j);
        match (c, se(i) * se(j)) {
            (Some(c), d) if d > 0.0 && c.is_finite() => (c / d).clamp(-1.0, 1.0),
            _ => 0.0,
        }
    };
    unit_geometry_uncertainty([se(0), se(1), se(2)], [corr(0, 1), corr(0, 2), corr(1, 2)])
}

/// The unit's keys of a geometry uncertainty: standard errors of `left_diameter`,
/// `right_diameter`, `track_width` (m) capped at [`GeometryUncertainty::MAX_SE`], and their
/// correlations (left-right, left-track, right-track) shrunk until f32 rounding leaves them
/// consistent.
pub fn unit_geometry_uncertainty(se: [f64; 3], corr: [f64; 3]) -> GeometryUncertainty {
    let cap = |v: f64| v.min(f64::from(GeometryUncertainty::MAX_SE)) as f32;
    let mut g = GeometryUncertainty {
        left_diameter_se: cap(se[0]),
        right_diameter_se: cap(se[1]),
        track_width_se: cap(se[2]),
        diameters_correlation: corr[0] as f32,
        left_track_correlation: corr[1] as f32,
        right_track_correlation: corr[2] as f32,
    };
    while !g.correlations_consistent() {
        g.diameters_correlation *= 0.999;
        g.left_track_correlation *= 0.999;
        g.right_track_correlation *= 0.999;
    }
    g
}

/// Runs the calibration in memory (the work of `odoctl calibrate` without the files and the
/// printing); `names` are the two inputs' names for error messages.
pub fn calibrate(
    samples: &[csvio::Sample],
    reference: &[csvio::RefPoint],
    names: (&str, &str),
    initial: &ChassisParams,
    o: &CalibrationOptions,
) -> Result<Calibration> {
    calibrate_with(samples, reference, names, initial, o, Extras::default())
}

/// [`calibrate`] with a warm start and a cancel flag ([`Extras`]): an error, once cancelled,
/// at the next phase.
pub fn calibrate_with(
    samples: &[csvio::Sample],
    reference: &[csvio::RefPoint],
    names: (&str, &str),
    initial: &ChassisParams,
    o: &CalibrationOptions,
    extras: Extras,
) -> Result<Calibration> {
    if !(o.reference_sigma >= 0.0 && o.reference_heading_sigma >= 0.0) {
        bail!("--reference-sigma and --reference-heading-sigma-deg must be non-negative");
    }
    let matches = csvio::match_or_fail(samples, names.0, reference, names.1, 10)?;
    let mut run = Run::new(samples, reference, matches).with_antenna(o.antenna.value());
    let timer = PhaseTimer::new();
    let models = fitted_models(o, initial);
    let filter_wanted = o.fit_delta
        && models.contains(&UncertaintyModel::Covariance)
        && o.criterion == UncertaintyCriterion::Likelihood;
    let GeometryPhase {
        mut geometry,
        subtrajectories,
        refinement,
        early_filter,
        path,
    } = fit_geometry_phase(&mut run, initial, o, (filter_wanted, extras), &timer)?;
    extras.check()?;
    run.antenna = geometry.antenna;
    let mut params = geometry.params;
    params.geometry_uncertainty =
        geometry_uncertainty(&geometry, subtrajectories.as_ref(), refinement.as_ref());
    let harmonics = if o.wheel_harmonics > 0 {
        let h = fit_harmonics(
            &run,
            &params,
            geometry.heading0,
            o.wheel_harmonics,
            o.harmonics_window,
        )?;
        params = h.params;
        timer.lap("wheel harmonics fit");
        Some(h)
    } else {
        None
    };
    let (uncertainty, early_evaluation) = if o.fit_delta {
        let phase = UncertaintyPhase {
            run: &run,
            heading0: geometry.heading0,
            // Integrated at the geometry: the wheel functions change the path.
            path: path.as_ref().filter(|_| harmonics.is_none()),
            initial,
            o,
            timer: &timer,
            extras,
        };
        phase.fit_models(&mut params, &models, filter_wanted, early_filter)?
    } else {
        (Vec::new(), None)
    };
    extras.check()?;
    let evaluation = match early_evaluation.filter(|(p, _)| *p == params) {
        Some((_, ev)) => ev,
        None => evaluate(&run, &params, geometry.heading0)?,
    };
    timer.lap("final evaluation");
    if harmonics.is_none() {
        // Eq (16) at the reported start as a replay from there gives it: the final
        // evaluation's horizontal errors after the start (the whole-run heading's fit gives it
        // from its path turned to that start, to the integrator's arithmetic noise).
        geometry.cost = evaluation.horizontal.iter().skip(1).sum();
    }
    let windows = stability_study(&run, &geometry, initial, o)?;
    Ok(Calibration {
        params,
        geometry,
        subtrajectories,
        refinement,
        uncertainty,
        evaluation,
        windows,
        harmonics,
    })
}

/// What the geometry phase of [`calibrate`] hands on.
struct GeometryPhase {
    /// The geometry fit, whichever the method.
    geometry: GeomFit,
    /// The sub-trajectory fit, with [`Method::Subtrajectory`].
    subtrajectories: Option<SubtrajectoryFit>,
    /// The filter's refinement, with [`GeometryRefine::Filter`].
    refinement: Option<FilterRefinement>,
    /// The covariance model's kappa, fitted on a thread of its own from the applied
    /// refinement's filter when the likelihood criterion wants it.
    early_filter: Option<JoinHandle<UncertaintyFit>>,
    /// The odometry at each match, integrated at the geometry from its start heading, when
    /// the method integrated it.
    path: Option<RunPath>,
}

/// The geometry of [`calibrate`] by `o.method`; the run's lever arm becomes the fit's.
fn fit_geometry_phase(
    run: &mut Run,
    initial: &ChassisParams,
    o: &CalibrationOptions,
    wanted: (bool, Extras),
    timer: &PhaseTimer,
) -> Result<GeometryPhase> {
    let h0 = run.heading_guess(0);
    match o.method {
        Method::Paper => {
            let pb = bar(o.quiet, "eq (16) fit");
            let g = fit_geometry(
                run,
                initial,
                h0,
                0,
                run.len() - 1,
                GeomOptions {
                    polish: o.polish,
                    antenna: o.antenna,
                    cluster_length: o.subtrajectory_length,
                    ..Default::default()
                },
                &pb,
            )?;
            pb.finish_and_clear();
            timer.lap("eq (16) fit");
            Ok(GeometryPhase {
                geometry: g,
                subtrajectories: None,
                refinement: None,
                early_filter: None,
                path: None,
            })
        }
        Method::Subtrajectory => fit_subtrajectory_phase(run, initial, o, wanted, timer),
    }
}

/// [`fit_geometry_phase`] of [`Method::Subtrajectory`]: the sub-trajectory fit (from
/// `extras`' warm start when given), the filter's refinement, the covariance model's kappa
/// started beside the rest from the refinement's filter when `filter_wanted`, and the
/// whole-run summary.
fn fit_subtrajectory_phase(
    run: &mut Run,
    initial: &ChassisParams,
    o: &CalibrationOptions,
    (filter_wanted, extras): (bool, Extras),
    timer: &PhaseTimer,
) -> Result<GeometryPhase> {
    let s = fit_subtrajectories_from(
        run,
        initial,
        SubtrajectoryOptions {
            length: o.subtrajectory_length,
            antenna: o.antenna,
            cuts: o.subtrajectory_cuts,
            ..Default::default()
        },
        extras.warm.map(|w| &w.subtrajectories),
    )?;
    timer.lap("sub-trajectory fit");
    extras.check()?;
    run.antenna = s.antenna;
    let refinement = match o.geometry_refine {
        GeometryRefine::None => None,
        GeometryRefine::Filter => {
            let r = refine_subtrajectory_fit(
                run,
                &s,
                o.antenna,
                (o.reference_sigma, o.reference_heading_sigma),
                WarmStart::likelihood_searches(extras.warm),
            )?;
            timer.lap("filter refinement");
            extras.check()?;
            Some(r)
        }
    };
    let applied = refinement.as_ref().filter(|r| r.skipped.is_none());
    // The covariance model's kappa needs only the refinement's filter (the geometry
    // it returns is taken from the parameters it is merged into): fitted on a thread
    // of its own from here, beside the rest; the thread owns what it reads (joined
    // where the kappa is taken; on an error before that it ends by itself).
    let early_filter = applied
        .and_then(|r| Some((r.params, r.innovations.clone()?)))
        .filter(|_| filter_wanted)
        .map(|(g, innovations)| {
            let p = ChassisParams {
                uncertainty_model: UncertaintyModel::Covariance,
                ..g
            };
            let (initial, mode) = (*initial, o.delta_mode);
            let earlier = WarmStart::likelihood_searches(extras.warm);
            let cancel = this_thread_cancel();
            std::thread::spawn(move || {
                cancel_this_thread_on(cancel);
                fit_kappa_filter(&innovations, &p, &initial, mode, earlier).0
            })
        });
    let (g, path) = whole_run_summary(run, &s, applied, extras.warm.map(|w| w.heading0))?;
    timer.lap("whole-run heading");
    Ok(GeometryPhase {
        geometry: g,
        subtrajectories: Some(s),
        refinement,
        early_filter,
        path: Some(path),
    })
}

/// An evaluation and the parameters it evaluated.
type Evaluated = (ChassisParams, Evaluation);

/// What the uncertainty phase of [`calibrate`] works on: the run with its fitted lever arm,
/// the whole-run start heading (rad), the initial estimate and the options.
struct UncertaintyPhase<'a> {
    run: &'a Run<'a>,
    heading0: f64,
    /// The odometry at each match from `heading0`, when integrated already.
    path: Option<&'a RunPath>,
    initial: &'a ChassisParams,
    o: &'a CalibrationOptions,
    timer: &'a PhaseTimer,
    /// The warm start of the coverage criterion's bisections, and the cancel flag.
    extras: Extras<'a>,
}

impl UncertaintyPhase<'_> {
    /// Fits the coefficients of every model of `models` into `params`, one fit each, and
    /// selects the result's model. The covariance model's likelihood fit runs on a thread of
    /// its own beside the paper model's fits (`early_filter` when the geometry phase started
    /// it, else from here). When the result selects that model, the final evaluation follows
    /// it on that thread: returned with the parameters it evaluated, the paper model's
    /// coefficients (which the covariance model does not read) those of the result.
    fn fit_models(
        &self,
        params: &mut ChassisParams,
        models: &[UncertaintyModel],
        filter_wanted: bool,
        early_filter: Option<JoinHandle<UncertaintyFit>>,
    ) -> Result<(Vec<UncertaintyFit>, Option<Evaluated>)> {
        let (run, heading0, initial, o) = (self.run, self.heading0, self.initial, self.o);
        let selected = selected_model(o, initial, models);
        let mut uncertainty = Vec::new();
        // The likelihood fit of the covariance model needs only the geometry: without the
        // refinement's filter it is built here, on a thread of its own beside the paper
        // model's fits.
        let earlier = WarmStart::likelihood_searches(self.extras.warm);
        let filter_fit = |p: ChassisParams| fit_kappa_at(run, p, heading0, initial, o, &earlier);
        let base = ChassisParams {
            uncertainty_model: UncertaintyModel::Covariance,
            ..*params
        };
        let mut evaluated = None;
        std::thread::scope(|scope| -> Result<()> {
            let wanted = filter_wanted && models.contains(&UncertaintyModel::Covariance);
            let cancel = this_thread_cancel();
            let mut filter = wanted.then(|| {
                scope.spawn(move || {
                    cancel_this_thread_on(cancel);
                    let u = match early_filter {
                        Some(early) => early
                            .join()
                            .map_err(|_| anyhow::anyhow!("the filter's fit failed"))?,
                        None => filter_fit(base)?,
                    };
                    let p = ChassisParams {
                        uncertainty_model: selected,
                        ..with_covariance_coefficients(&base, &u.params)
                    };
                    let ev = (selected == UncertaintyModel::Covariance)
                        .then(|| evaluate(run, &p, heading0).map(|ev| (p, ev)))
                        .transpose()?;
                    Ok::<_, anyhow::Error>((u, ev))
                })
            });
            // The restarted sub-trajectories of the coverage criterion, made when first needed.
            let mut restarts: Option<Restarts> = None;
            for &m in models {
                self.extras.check()?;
                let mut p = *params;
                p.uncertainty_model = m;
                if m == UncertaintyModel::Covariance
                    && o.criterion == UncertaintyCriterion::Likelihood
                {
                    let (mut u, ev) = match filter.take() {
                        Some(f) => f
                            .join()
                            .map_err(|_| anyhow::anyhow!("the filter's fit failed"))??,
                        None => (filter_fit(p)?, None),
                    };
                    self.timer.lap("uncertainty fit (filter)");
                    *params = with_covariance_coefficients(params, &u.params);
                    u.params = with_covariance_coefficients(&p, &u.params);
                    evaluated = ev;
                    uncertainty.push(u);
                    continue;
                }
                let restarts = match &mut restarts {
                    Some(r) => &*r,
                    None => {
                        let r = match self.path {
                            Some(path) => Restarts::along(run, params, path, o.delta_window)?,
                            None => Restarts::new(run, params, heading0, o.delta_window)?,
                        };
                        self.timer.lap("restart headings");
                        self.extras.check()?;
                        &*restarts.insert(r)
                    }
                };
                let u = self.coverage_fit(restarts, p, m)?;
                *params = u.params;
                uncertainty.push(u);
            }
            Ok(())
        })?;
        params.uncertainty_model = selected;
        // The evaluation with the result's paper coefficients: the same evaluation.
        let evaluated = evaluated.map(|(p, ev)| {
            let p = ChassisParams {
                delta_left: params.delta_left,
                delta_right: params.delta_right,
                delta_diff: params.delta_diff,
                ..p
            };
            (p, ev)
        });
        Ok((uncertainty, evaluated))
    }

    /// The coefficients of model `m` of `p` by the coverage criterion on `restarts`, and for
    /// the paper's model `delta_diff` by the heading coverage.
    fn coverage_fit(
        &self,
        restarts: &Restarts,
        p: ChassisParams,
        m: UncertaintyModel,
    ) -> Result<UncertaintyFit> {
        let (run, o, initial) = (self.run, self.o, self.initial);
        // The earlier fit's coefficient, the bisection's first guess (`fit_uncertainty_on`
        // takes the guess from the parameters and sets the coefficient itself).
        let p = match self.extras.warm.and_then(|w| w.coefficient(m)) {
            Some(v) => set_coefficient(&p, o.delta_mode, initial, v),
            None => p,
        };
        let pb = bar(o.quiet, &format!("{} model fit", cfg::model_name(m)));
        let mut u = fit_uncertainty_on(
            run,
            restarts,
            &p,
            initial,
            o.reference_sigma,
            o.delta_mode,
            &pb,
        )?;
        pb.finish_and_clear();
        self.timer.lap("uncertainty fit");
        self.extras.check()?;
        if m == UncertaintyModel::Paper {
            let pb = bar(o.quiet, "delta_diff fit");
            u = fit_delta_diff(
                run,
                restarts,
                u,
                initial,
                DiffOptions {
                    fit: o.fit_delta_diff,
                    ref_heading_sigma: o.reference_heading_sigma,
                    ref_sigma: o.reference_sigma,
                    mode: o.delta_mode,
                },
                &pb,
            )?;
            pb.finish_and_clear();
            self.timer.lap("delta_diff fit");
        }
        Ok(u)
    }
}

/// The covariance model's kappa at the geometry of `p` by the likelihood of a filter built
/// along `run` from the start heading `heading0` (rad), its searches from `earlier`'s ends.
fn fit_kappa_at(
    run: &Run,
    p: ChassisParams,
    heading0: f64,
    initial: &ChassisParams,
    o: &CalibrationOptions,
    earlier: &[(Search, f64)],
) -> Result<UncertaintyFit> {
    let innovations = Innovations::new(
        run,
        &p,
        heading0,
        o.reference_sigma,
        o.reference_heading_sigma,
        OBSERVATION_BLOCK,
    )?;
    let earlier = earlier.to_vec();
    Ok(fit_kappa_filter(&innovations, &p, initial, o.delta_mode, earlier).0)
}

/// The stability study of [`calibrate`] (`o.windows`; none when empty).
fn stability_study(
    run: &Run,
    geometry: &GeomFit,
    initial: &ChassisParams,
    o: &CalibrationOptions,
) -> Result<Vec<WindowEstimate>> {
    if o.windows.is_empty() {
        return Ok(Vec::new());
    }
    if o.windows.iter().any(|l| l.is_nan() || *l <= 0.0) {
        bail!("--windows: lengths must be positive metres");
    }
    let pb = bar(o.quiet, "sub-trajectories");
    let w = windows_study(run, geometry, initial, &o.windows, o.window_start, &pb)?;
    pb.finish_and_clear();
    Ok(w)
}

/// The model the result selects: `o.select`, else the initial estimate's when it is among
/// `models`, else the last of them.
fn selected_model(
    o: &CalibrationOptions,
    initial: &ChassisParams,
    models: &[UncertaintyModel],
) -> UncertaintyModel {
    if let Some(m) = o.select {
        m
    } else if models.contains(&initial.uncertainty_model) {
        initial.uncertainty_model
    } else {
        *models.last().expect("one model")
    }
}

/// The uncertainty models whose coefficients `calibrate` fits: `o.models` (empty: the
/// initial estimate's), with the one the result selects.
fn fitted_models(o: &CalibrationOptions, initial: &ChassisParams) -> Vec<UncertaintyModel> {
    let mut models = if o.models.is_empty() {
        vec![initial.uncertainty_model]
    } else {
        o.models.clone()
    };
    if let Some(m) = o.select {
        if !models.contains(&m) {
            models.push(m);
        }
    }
    models
}

/// The [`GeomFit`] of a sub-trajectory estimate, for what works on the whole run (the final
/// evaluation, the uncertainty fits' first headings, `validate`'s output): the heading at the
/// run's start minimising eq (16) over the whole run at the estimate (from the first
/// sub-trajectory's), eq (16) there, and the sub-trajectory fit's robust errors (the
/// heading's own, with the geometry held, over stretches of the sub-trajectory length). With
/// an applied `refinement`, its geometry and standard errors. The heading's search starts
/// from `warm` (an earlier calibration's of the same drive) when given. With the odometry at
/// each match from the start heading found.
fn whole_run_summary(
    run: &Run,
    s: &SubtrajectoryFit,
    refinement: Option<&FilterRefinement>,
    warm: Option<f64>,
) -> Result<(GeomFit, RunPath)> {
    let last = run.len() - 1;
    let guess = warm.unwrap_or_else(|| s.blocks.first().map_or(0.0, |b| b.heading));
    let params = refinement.map_or(s.params, |r| r.params);
    // One integration (two when it turns by more than 0.01 rad), the path turned about its
    // start: the heading a re-integrating fit would find, eq (16) there, the headings at the
    // matches and the heading's errors with the geometry held (it is fitted with the geometry
    // held).
    let WholeRunHeading {
        heading0,
        cost,
        path,
        errors: (formal, clustered),
    } = fit_whole_run_heading(run, &params, guess, SUBTRAJECTORY_LENGTH)?;
    let mut se = s.std_errors;
    if let Some(r) = refinement {
        let e = r.std_errors();
        for i in 0..3 {
            se[i] = se[i].map(|_| e[i]);
        }
    }
    let robust = [se[0], se[1], se[2], clustered];
    let min_turning = SubtrajectoryOptions::default().min_turning;
    let g = GeomFit {
        params,
        heading0,
        cost,
        points: last,
        iterations: s.iterations,
        evaluations: s.evaluations,
        stages: 0,
        track_estimated: s.track_estimated,
        turning: s.turning,
        start: run.anchor(0),
        std_errors: [
            s.independent_std_errors[0],
            s.independent_std_errors[1],
            s.independent_std_errors[2],
            formal,
        ],
        robust_std_errors: robust,
        clusters: s.blocks.len(),
        antenna: s.antenna,
        antenna_std_errors: se[3].zip(se[4]).map(|(f, l)| [f, l]),
        residual_sigma: s.residual_sigma,
        track_warning: track_width_warning(
            s.track_estimated,
            s.turning,
            min_turning,
            &params,
            &robust,
        ),
    };
    Ok((g, path))
}

/// Wall time of each calibration phase, and the CPU time the process spent in it on all its
/// threads, printed to stderr when `ODOCTL_DEBUG` is set.
pub struct PhaseTimer {
    last: Option<std::cell::Cell<(Instant, f64)>>,
}

impl Default for PhaseTimer {
    fn default() -> Self {
        Self::new()
    }
}

impl PhaseTimer {
    /// Starts the clock when `ODOCTL_DEBUG` is set.
    pub fn new() -> Self {
        Self {
            last: std::env::var_os("ODOCTL_DEBUG")
                .map(|_| std::cell::Cell::new((Instant::now(), process_cpu_time()))),
        }
    }

    /// Prints the time since the previous lap (or the start) under `phase`.
    pub fn lap(&self, phase: &str) {
        if let Some(last) = &self.last {
            let (then, cpu_then) = last.get();
            let (now, cpu) = (Instant::now(), process_cpu_time());
            eprintln!(
                "time: {phase}: {:.4} s (CPU {:.4} s)",
                (now - then).as_secs_f64(),
                cpu - cpu_then
            );
            last.set((now, cpu));
        }
    }
}

/// The CPU time this process has used on all its threads (s).
fn process_cpu_time() -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    #[allow(unsafe_code)]
    // Note(unsafe): `clock_gettime` writes the timespec it is given, which lives on this
    // stack for the call; the clock id is a constant the kernel knows.
    unsafe {
        libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t)
    };
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testing::sim;
    use crate::simulate::{default_truth, PathKind};

    /// The final evaluation, made beside the paper model's fits when the result selects the
    /// covariance model, is the result's evaluation: the covariance model reads none of the
    /// paper model's coefficients, so other ones evaluate the same.
    #[test]
    fn the_evaluation_beside_the_paper_fits_is_the_results() {
        let s = sim(PathKind::Random, 150.0, 2);
        let o = CalibrationOptions {
            models: vec![UncertaintyModel::Paper, UncertaintyModel::Covariance],
            select: Some(UncertaintyModel::Covariance),
            ..Default::default()
        };
        let initial = default_truth();
        let c = calibrate(&s.samples, &s.reference, ("s", "r"), &initial, &o).unwrap();
        assert_eq!(c.params.uncertainty_model, UncertaintyModel::Covariance);
        assert!(c.params.kappa_left > 0.0 && c.params.delta_left > 0.0);
        let matches = csvio::match_or_fail(&s.samples, "s", &s.reference, "r", 10).unwrap();
        let run = Run::new(&s.samples, &s.reference, matches).with_antenna(c.geometry.antenna);
        let h0 = c.geometry.heading0;
        let again = evaluate(&run, &c.params, h0).unwrap();
        assert_eq!(format!("{:?}", c.evaluation), format!("{again:?}"));
        let other = ChassisParams {
            delta_left: 2.0 * c.params.delta_left,
            delta_right: 3.0 * c.params.delta_right,
            delta_diff: 1e-8,
            ..c.params
        };
        let other = evaluate(&run, &other, h0).unwrap();
        assert_eq!(format!("{other:?}"), format!("{again:?}"));
    }
}
