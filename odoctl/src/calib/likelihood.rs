//! The uncertainty coefficients by maximum likelihood of the observed errors (the default
//! criterion; the paper's coverage criterion is in `uncertainty.rs` and `delta_diff.rs`).
//!
//! The run is cut into consecutive sub-trajectories of `window` metres, as for the coverage
//! criterion, but nothing a sub-trajectory is judged on is fitted to it:
//! * its start position is the reference there (averaged over a standstill), whose noise
//!   enters every later error of the sub-trajectory;
//! * its start heading is the reference heading averaged over the standstill before it and
//!   the first second after it ([`Run::start_heading`], variance `sigma_ref_heading^2 / n`)
//!   when the reference has headings, else the heading carried over by the odometry from the
//!   run's start, with the heading variance the model predicts for it (`sigma_heading^2` of
//!   the odometry integrated from the start); the run's start heading is then fitted on the
//!   first sub-trajectory, which is not scored.
//!
//! At every later common time `k` the horizontal error `e_k` (odometry - reference, 2-D) is
//! taken as normal with the covariance
//! `Sigma_k = P_k(c) + var_h0 v_k v_k^T + (r_k^2 + r_a^2 / n_a) I / 2`: `P_k` the x-y block
//! of the model's covariance since the restart (for the paper's model `diag(sigma_x^2,
//! sigma_y^2)`), `v_k = (y_k - y_a, -(x_k - x_a))` the derivative of the position by the start
//! heading, `var_h0` the start heading's variance, `r_k` the reference's horizontal RMS noise
//! at `k` (the epoch's own sigma from GST / `.pos` / a `sigma_h` column, else
//! `--reference-sigma`), `r_a` that of the start over its `n_a` standstill points. With a
//! reference heading, the heading error `wrap(a_k - a_ref,k)` is normal with variance
//! `var_h0 + sigma_heading,k^2 + sigma_ref_heading^2`. The coefficients maximise the sum of
//! these log-likelihoods over all points (a composite likelihood: the points of one
//! sub-trajectory are correlated, which leaves the estimate unbiased and only its spread
//! larger than independent points would give).
//!
//! Covariance model: `kappa_left = kappa_right` (or their initial ratio), every variance
//! linear in kappa, so one evaluation gives the likelihood of all kappas. Paper model: delta
//! (every sigma linear in delta with `delta_diff` fixed), and with a reference heading
//! `delta_diff` jointly (Nelder-Mead over both logarithms, one evaluation per trial).

use anyhow::{anyhow, bail, Result};
use odo_core::odometry::{ChassisParams, UncertaintyModel};

use crate::optim::{nelder_mead, NmOptions};
use crate::stats::wrap_angle;

use super::*;

/// How `calibrate` fits the uncertainty coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum UncertaintyCriterion {
    /// Maximum likelihood of the errors of restarted sub-trajectories under the model's
    /// covariance plus the reference noise, start headings not fitted to the judged data
    /// (the default).
    #[default]
    Likelihood,
    /// The paper's statistical fitting as first implemented: the smallest coefficient whose
    /// 1-sigma band (widened by the reference noise) covers 68.27 % of the pooled horizontal
    /// errors, restart headings fitted by eq (16) on each sub-trajectory; `delta_diff` by the
    /// heading-change coverage.
    Coverage,
}

/// Options of [`fit_likelihood`].
#[derive(Debug, Clone, Copy)]
pub struct LikelihoodOptions {
    /// Sub-trajectory length (m of reference path; 0 = the whole run).
    pub window: f64,
    /// Horizontal RMS noise of reference epochs without their own sigma (m).
    pub ref_sigma: f64,
    /// Reference heading noise (rad).
    pub ref_heading_sigma: f64,
    /// Left/right relation of the coefficients.
    pub mode: DeltaMode,
    /// Fit `delta_diff` with delta (paper's model, reference with headings).
    pub fit_delta_diff: bool,
}

/// A scored sub-trajectory.
#[derive(Debug, Clone, Copy)]
struct Window {
    a: usize,
    b: usize,
    /// Start heading (rad).
    heading: f64,
    /// Variance of the start heading that does not depend on the coefficients (rad^2).
    var0: f64,
}

/// The coefficient-free part of one point's likelihood.
#[derive(Debug, Clone, Copy)]
struct Point {
    window: usize,
    /// Horizontal error odometry - reference (m).
    e: (f64, f64),
    /// Derivative of the position by the start heading (m/rad).
    v: (f64, f64),
    /// Reference noise variance per axis, at the point and at the start (m^2).
    r: f64,
    /// Heading error (rad), where the reference has a heading.
    eh: Option<f64>,
}

/// The model's variances at every point (and the carried start heading's per window).
#[derive(Debug, Clone, Default)]
struct Predicted {
    xx: Vec<f64>,
    yy: Vec<f64>,
    xy: Vec<f64>,
    hh: Vec<f64>,
    /// Heading variance at each window's start from the run's start (carried headings).
    carry: Vec<f64>,
}

/// The errors of the restarted sub-trajectories, ready for the likelihood of any
/// coefficients.
pub struct LikelihoodData {
    windows: Vec<Window>,
    points: Vec<Point>,
    /// Start headings carried from the run's start (else from the reference).
    carried: bool,
    /// The run's start heading (carried headings).
    heading0: f64,
    ref_heading_var: f64,
}

impl LikelihoodData {
    /// Cuts the run and takes the errors (the poses do not depend on the coefficients).
    pub fn new(run: &Run, geometry: &ChassisParams, o: &LikelihoodOptions) -> Result<Self> {
        let wins = windows(run, o.window, 3);
        if wins.is_empty() {
            bail!(
                "the run is too short for the uncertainty fit (no sub-trajectory of {} m with 3 points)",
                o.window
            );
        }
        let with_heading = (0..run.len())
            .filter(|&k| run.reference_at(k).heading.is_some())
            .count()
            * 2
            > run.len();
        let rh2 = o.ref_heading_sigma * o.ref_heading_sigma;
        let r2 = |k: usize| {
            let s = run.reference_at(k).sigma_h.unwrap_or(o.ref_sigma);
            s * s / 2.0
        };
        let start_var = |a: usize| {
            let (lo, hi) = run.standstill(a);
            (lo..=hi).map(r2).sum::<f64>() / ((hi - lo + 1) as f64).powi(2)
        };
        let mut windows_out = Vec::new();
        let (carried, heading0, scored) = if with_heading {
            (false, f64::NAN, wins.clone())
        } else {
            let (a, b) = wins[0];
            let h = fit_restart_heading(run, geometry, a, b, run.heading_guess(a))?;
            (true, h, wins[1..].to_vec())
        };
        if scored.is_empty() {
            bail!("the run is too short for the uncertainty fit without a reference heading (one sub-trajectory fits the start heading, none is left to score)");
        }
        // Carried start headings: the odometry from the run's start.
        let mut full = Vec::new();
        if carried {
            full.reserve(run.len());
            full.push(heading0);
            run.integrate_pose(geometry, 0, run.len() - 1, heading0, |_, integ| {
                full.push(integ.pose().heading)
            })
            .map_err(|e| anyhow!("parameters: {e}"))?;
        }
        let mut points = Vec::new();
        for &(a, b) in &scored {
            let (heading, var0) = if carried {
                (full[a], 0.0)
            } else {
                let mut changes = Vec::new();
                let h_guess = run.reference_at(a).heading.unwrap_or(0.0);
                run.integrate_pose(geometry, a, b, h_guess, |_, integ| {
                    changes.push(integ.pose().heading - h_guess)
                })
                .map_err(|e| anyhow!("parameters: {e}"))?;
                match run.start_heading(a, |k| changes.get(k - a - 1).copied()) {
                    Some((h, n)) => (h, rh2 / n as f64),
                    // No heading at this start: the sub-trajectory is not scored.
                    None => continue,
                }
            };
            let w = windows_out.len();
            windows_out.push(Window {
                a,
                b,
                heading,
                var0,
            });
            let (x0, y0) = run.anchor(a);
            let ra = start_var(a);
            run.integrate_pose(geometry, a, b, heading, |k, integ| {
                let p = integ.pose();
                let r = run.reference_at(k);
                points.push(Point {
                    window: w,
                    e: (p.x - r.x, p.y - r.y),
                    v: (p.y - y0, -(p.x - x0)),
                    r: r2(k) + ra,
                    eh: r.heading.map(|h| wrap_angle(p.heading - h)),
                });
            })
            .map_err(|e| anyhow!("parameters: {e}"))?;
        }
        if points.is_empty() {
            bail!("no point to score in the uncertainty fit");
        }
        Ok(Self {
            windows: windows_out,
            points,
            carried,
            heading0,
            ref_heading_var: rh2,
        })
    }

    /// Number of scored sub-trajectories.
    pub fn windows(&self) -> usize {
        self.windows.len()
    }

    /// Number of scored points.
    pub fn points(&self) -> usize {
        self.points.len()
    }

    /// Whether the start headings are carried by the odometry (no reference heading).
    pub fn carried(&self) -> bool {
        self.carried
    }

    /// The model's variances for `p` (one integration of each sub-trajectory, and of the
    /// whole run for carried headings).
    fn predict(&self, run: &Run, p: &ChassisParams) -> Result<Predicted> {
        let n = self.points.len();
        let mut out = Predicted {
            xx: Vec::with_capacity(n),
            yy: Vec::with_capacity(n),
            xy: Vec::with_capacity(n),
            hh: Vec::with_capacity(n),
            carry: vec![0.0; self.windows.len()],
        };
        let threads = cores().min(self.windows.len()).max(1);
        let chunk = self.windows.len().div_ceil(threads);
        let parts = std::thread::scope(|scope| {
            let jobs: Vec<_> = self
                .windows
                .chunks(chunk)
                .map(|wins| {
                    scope.spawn(move || {
                        let mut v = Vec::new();
                        for w in wins {
                            run.integrate(p, w.a, w.b, w.heading, |_, integ| {
                                let s = integ.sigma();
                                v.push([
                                    f64::from(s.x).powi(2),
                                    f64::from(s.y).powi(2),
                                    f64::from(s.xy),
                                    f64::from(s.heading).powi(2),
                                ]);
                            })
                            .map_err(|e| anyhow!("parameters: {e}"))?;
                        }
                        Ok::<_, anyhow::Error>(v)
                    })
                })
                .collect();
            jobs.into_iter()
                .map(|j| j.join().expect("likelihood evaluation panicked"))
                .collect::<Result<Vec<_>>>()
        })?;
        for [xx, yy, xy, hh] in parts.into_iter().flatten() {
            out.xx.push(xx);
            out.yy.push(yy);
            out.xy.push(xy);
            out.hh.push(hh);
        }
        if self.carried {
            let last = self.windows.last().map_or(0, |w| w.a);
            let mut next = 0;
            run.integrate(p, 0, last.max(1), self.heading0, |k, integ| {
                while next < self.windows.len() && self.windows[next].a == k {
                    out.carry[next] = f64::from(integ.sigma().heading).powi(2);
                    next += 1;
                }
            })
            .map_err(|e| anyhow!("parameters: {e}"))?;
        }
        Ok(out)
    }

    /// Negative log-likelihood (without the constant) of the errors with the variances
    /// `pred` scaled by `s`.
    fn nll(&self, pred: &Predicted, s: f64) -> f64 {
        let mut total = 0.0;
        for (i, pt) in self.points.iter().enumerate() {
            let w = &self.windows[pt.window];
            let vh = w.var0 + s * pred.carry[pt.window];
            let (vx, vy) = pt.v;
            let sxx = s * pred.xx[i] + vh * vx * vx + pt.r;
            let syy = s * pred.yy[i] + vh * vy * vy + pt.r;
            let sxy = s * pred.xy[i] + vh * vx * vy;
            let det = sxx * syy - sxy * sxy;
            let (ex, ey) = pt.e;
            let q = (syy * ex * ex - 2.0 * sxy * ex * ey + sxx * ey * ey) / det;
            total += 0.5 * (det.ln() + q);
            if let Some(eh) = pt.eh {
                let v = vh + s * pred.hh[i] + self.ref_heading_var;
                total += 0.5 * (v.ln() + eh * eh / v);
            }
        }
        if total.is_finite() {
            total
        } else {
            f64::INFINITY
        }
    }

    /// The share of points inside `k` times their predicted band, horizontal
    /// (`|e| <= k sqrt(trace Sigma)`) and heading, with the reference noise in the band.
    fn coverage(&self, pred: &Predicted, k: f64) -> (f64, f64) {
        let (mut inside, mut hn, mut hin) = (0usize, 0usize, 0usize);
        for (i, pt) in self.points.iter().enumerate() {
            let w = &self.windows[pt.window];
            let vh = w.var0 + pred.carry[pt.window];
            let (vx, vy) = pt.v;
            let tr = pred.xx[i] + pred.yy[i] + vh * (vx * vx + vy * vy) + 2.0 * pt.r;
            if pt.e.0.hypot(pt.e.1) <= k * tr.sqrt() {
                inside += 1;
            }
            if let Some(eh) = pt.eh {
                hn += 1;
                if eh.abs() <= k * (vh + pred.hh[i] + self.ref_heading_var).sqrt() {
                    hin += 1;
                }
            }
        }
        (
            inside as f64 / self.points.len().max(1) as f64,
            if hn == 0 {
                f64::NAN
            } else {
                hin as f64 / hn as f64
            },
        )
    }

    /// Whether the points carry heading errors.
    fn has_heading(&self) -> bool {
        self.points.iter().any(|p| p.eh.is_some())
    }
}

/// The coefficient of the model (`delta_left` or `kappa_left`).
fn coefficient(p: &ChassisParams) -> f64 {
    match p.uncertainty_model {
        UncertaintyModel::Paper => f64::from(p.delta_left),
        UncertaintyModel::Covariance => f64::from(p.kappa_left),
    }
}

/// Minimises `f` over `x` in `[lo, hi]` (a log scale): a grid, then golden sections around
/// its best point.
fn minimise_1d(lo: f64, hi: f64, f: impl Fn(f64) -> f64) -> f64 {
    let n = 96;
    let step = (hi - lo) / n as f64;
    let (mut best, mut best_f) = (lo, f64::INFINITY);
    for i in 0..=n {
        let x = lo + step * i as f64;
        let v = f(x);
        if v < best_f {
            best = x;
            best_f = v;
        }
    }
    let (mut a, mut b) = ((best - step).max(lo), (best + step).min(hi));
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    while b - a > 1e-9 {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    let x = 0.5 * (a + b);
    if f(x) <= best_f {
        x
    } else {
        best
    }
}

/// Fits the coefficients of `geometry.uncertainty_model` by maximum likelihood (module
/// documentation); for the paper's model with a reference heading and `fit_delta_diff`,
/// `delta_diff` jointly. Returns the fit with the coverages of its own points.
pub fn fit_likelihood(
    run: &Run,
    data: &LikelihoodData,
    geometry: &ChassisParams,
    initial: &ChassisParams,
    o: &LikelihoodOptions,
) -> Result<UncertaintyFit> {
    let model = geometry.uncertainty_model;
    let (keys, hi, power) = match model {
        UncertaintyModel::Paper => (
            ("delta_left", "delta_right"),
            f64::from(ChassisParams::MAX_DELTA),
            2.0,
        ),
        UncertaintyModel::Covariance => (
            ("kappa_left", "kappa_right"),
            f64::from(ChassisParams::MAX_KAPPA),
            1.0,
        ),
    };
    let at = |v: f64| set_coefficient(geometry, o.mode, initial, v);
    let lo = hi * 1e-12;
    // Variances scale exactly as coefficient^power for the covariance model, and for the
    // paper's model while delta_diff is held: one evaluation at a middle value.
    let scaled_fit = |base: &ChassisParams| -> Result<(f64, f64)> {
        // A typical value (the designed one): sigmas well inside f32's range.
        let c0 = coefficient(&set_coefficient(
            &ChassisParams {
                uncertainty_model: model,
                ..ChassisParams::DESIGNED
            },
            DeltaMode::Equal,
            initial,
            match model {
                UncertaintyModel::Paper => f64::from(ChassisParams::DESIGNED.delta_left),
                UncertaintyModel::Covariance => f64::from(ChassisParams::DESIGNED.kappa_left),
            },
        ));
        let b = match model {
            UncertaintyModel::Paper => ChassisParams {
                delta_diff: 0.0,
                ..*base
            },
            UncertaintyModel::Covariance => *base,
        };
        let p0 = set_coefficient(&b, o.mode, initial, c0);
        let pred = data.predict(run, &p0)?;
        let lx = minimise_1d(lo.ln(), hi.ln(), |lc| {
            data.nll(&pred, ((lc - c0.ln()) * power).exp())
        });
        Ok((lx.exp(), data.nll(&pred, ((lx - c0.ln()) * power).exp())))
    };
    let mut warning = None;
    let mut diff = None;
    let params = match model {
        UncertaintyModel::Covariance => at(scaled_fit(geometry)?.0),
        UncertaintyModel::Paper => {
            let dd0 = f64::from(geometry.delta_diff);
            let (d_only, nll_only) = scaled_fit(geometry)?;
            let before = at(d_only);
            let fit_dd = o.fit_delta_diff && data.has_heading();
            let mut best = ChassisParams {
                delta_diff: 0.0,
                ..before
            };
            if fit_dd {
                let max_dd = f64::from(ChassisParams::MAX_DELTA);
                let eval = |x: &[f64]| -> Option<f64> {
                    let (d, dd) = (x[0].exp(), x[1].exp());
                    if !(lo..=hi).contains(&d) || dd > max_dd {
                        return None;
                    }
                    let mut p = at(d);
                    p.delta_diff = dd as f32;
                    let pred = data.predict(run, &p).ok()?;
                    Some(data.nll(&pred, 1.0))
                };
                let start_dd = if dd0 > 0.0 { dd0 } else { d_only };
                let r = nelder_mead(
                    eval,
                    &[d_only.ln(), start_dd.ln()],
                    &[0.7, 1.5],
                    NmOptions {
                        max_evals: 160,
                        ftol: 1e-9,
                        restarts: 1,
                    },
                );
                if r.cost < nll_only {
                    best = at(r.x[0].exp());
                    best.delta_diff = r.x[1].exp() as f32;
                }
            } else if dd0 > 0.0 {
                // delta_diff held at its initial value: delta by the general search.
                let lx = minimise_1d(lo.ln(), hi.ln(), |lc| {
                    let mut p = at(lc.exp());
                    p.delta_diff = dd0 as f32;
                    data.predict(run, &p)
                        .map_or(f64::INFINITY, |pred| data.nll(&pred, 1.0))
                });
                best = at(lx.exp());
                best.delta_diff = dd0 as f32;
            }
            let pred_before = data.predict(run, &before)?;
            let pred = data.predict(run, &best)?;
            let (_, h1b) = data.coverage(&pred_before, 1.0);
            let (_, h3b) = data.coverage(&pred_before, 3.0);
            let (_, h1) = data.coverage(&pred, 1.0);
            let (_, h3) = data.coverage(&pred, 3.0);
            if data.has_heading() {
                diff = Some(DiffFit {
                    initial: dd0,
                    delta_diff: f64::from(best.delta_diff),
                    fitted: fit_dd,
                    delta_before: d_only,
                    joint: true,
                    points: data.points.iter().filter(|p| p.eh.is_some()).count(),
                    coverage1_before: h1b,
                    coverage3_before: h3b,
                    coverage1: h1,
                    coverage3: h3,
                    warning: None,
                });
            }
            best
        }
    };
    let c = coefficient(&params);
    if c <= lo * 1.01 {
        warning = Some(format!(
            "the errors are explained by the reference noise ({} m) alone: the coefficient is not identifiable",
            o.ref_sigma
        ));
    } else if c >= hi * 0.99 {
        warning = Some(format!(
            "the coefficient reached its largest admissible value {hi:e}"
        ));
    }
    let pred = data.predict(run, &params)?;
    let (c1, h1) = data.coverage(&pred, 1.0);
    let (c3, h3) = data.coverage(&pred, 3.0);
    Ok(UncertaintyFit {
        model,
        params,
        keys,
        windows: data.windows(),
        points: data.points(),
        coverage1: c1,
        coverage3: c3,
        warning,
        diff,
        criterion: UncertaintyCriterion::Likelihood,
        heading_coverage: (!h1.is_nan()).then_some((h1, h3)),
    })
}
