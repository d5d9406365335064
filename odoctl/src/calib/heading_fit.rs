//! The heading at the start of a stretch that minimises eq (16) over it with the geometry
//! held: [`fit_heading`] by integrating at every step, [`fit_restart_heading`] by turning one
//! integrated path about its start (the restarts of the uncertainty fits, the wheel harmonics'
//! segments, the whole-run heading of the sub-trajectory estimate).

use anyhow::{anyhow, Result};
use odo_unit::odometry::ChassisParams;

use crate::optim::{self, LmOptions, NormalAccumulator, Objective};

use super::geometry::paper::HeadingErrors;
use super::run::Run;

/// The heading at match `a` minimising eq (16) over `a..=b` with the geometry fixed.
pub fn fit_heading(
    run: &Run,
    params: &ChassisParams,
    a: usize,
    b: usize,
    guess: f64,
) -> Result<f64> {
    let f = |x: &[f64], acc: &mut NormalAccumulator| {
        run.accumulate_normal(params, a, b, x[0], &[3], acc)
    };
    let res = optim::levenberg_marquardt_streamed(
        f,
        &[guess],
        &[1.0],
        Objective::SumOfNorms,
        LmOptions::default(),
    )
    .ok_or_else(|| anyhow!("parameters: not admissible"))?;
    Ok(res.x[0])
}

/// Stop a restart heading fit when the predicted relative reduction of eq (16) falls below
/// this (the heading is then the minimum within about 1e-10 rad).
const RESTART_PRED_TOL: f64 = 1e-14;

/// A path turned by up to this (rad) is the re-integrated path to within the integrator's
/// own arithmetic noise; a restart heading found further from the heading the path was
/// integrated at is refined from a path integrated at it (the turned path's error grows
/// with the angle: about 1e-7 m at 0.5 rad over 10 m, 1e-7 rad on the heading found).
pub(crate) const RESTART_TURN_EXACT: f64 = 0.01;

/// Integrations of one restart heading fit at most (the second from the first's heading).
const RESTART_PASSES: usize = 2;

/// [`fit_heading`] for the restarts of the uncertainty fits, integrating once (twice when the
/// heading found is more than [`RESTART_TURN_EXACT`] from `guess`). A change of
/// the start heading by `phi` turns the whole path about its start by `phi` (clockwise):
/// the odometry is integrated once at `guess`, and eq (16) is minimised over the rotation of
/// those positions, `x - x0 = dx cos(phi) + dy sin(phi)`, `y - y0 = -dx sin(phi) + dy cos(phi)`
/// (`dx`, `dy` the positions at `guess` relative to the start), with the derivative
/// `d x / d heading0 = y - y0`, `d y / d heading0 = -(x - x0)` (what the forward sensitivity
/// of [`Run::residuals_with_jacobian`] sums). The core integrator turns the same path by
/// the same angle up to its rounding (the sine/cosine kernel, 2e-9 of the distance), so the
/// heading is the one a fit re-integrating at every step would find.
pub fn fit_restart_heading(
    run: &Run,
    params: &ChassisParams,
    a: usize,
    b: usize,
    guess: f64,
) -> Result<f64> {
    let mut t = TurnedPath::starting(run, a, b, guess);
    t.integrate(run, params, (a, b), None)?;
    Ok(t.fit(run, params, (a, b), None)?.heading)
}

/// [`fit_restart_heading`] over `a..=b` from `path`'s heading at `a`, its first integration
/// being `path` itself (`params`' odometry over the run): integrated from the anchor at `a` with
/// that heading, the odometry moves as `path` does from `a` on (the integrator's positions are
/// fixed-point, so the same steps move them by the same amounts wherever they start). Only a
/// heading found more than [`RESTART_TURN_EXACT`] away is refined by an integration.
pub fn fit_restart_heading_along(
    run: &Run,
    params: &ChassisParams,
    path: &RunPath,
    (a, b): (usize, usize),
) -> Result<f64> {
    let mut t = TurnedPath::starting(run, a, b, path.headings[a]);
    let [ax, ay] = path.points[a];
    for k in a + 1..=b {
        let [px, py] = path.points[k];
        let r = run.reference_at(k);
        t.path
            .push([px - ax, py - ay, r.x - t.start.0, r.y - t.start.1]);
    }
    Ok(t.fit(run, params, (a, b), None)?.heading)
}

/// The odometry at every match of a run, integrated from its start (rad, m).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RunPath {
    /// The heading at every match (rad).
    pub headings: Vec<f64>,
    /// The observed point at every match ([`Run::observed`]), relative to the start (m).
    pub points: Vec<[f64; 2]>,
}

/// The path of [`fit_restart_heading`]'s last integration and the heading it found.
struct TurnedPath {
    /// The heading found (rad).
    heading: f64,
    /// The start heading the path was integrated at (rad).
    at: f64,
    /// The start position the path is relative to (m).
    start: (f64, f64),
    /// At each match after the start: the observed point and the reference point, both
    /// relative to the start (m).
    path: Vec<[f64; 4]>,
}

impl TurnedPath {
    /// A path over `a..=b` at the heading `guess` (rad), nothing integrated yet.
    fn starting(run: &Run, a: usize, b: usize, guess: f64) -> Self {
        Self {
            heading: guess,
            at: guess,
            start: run.anchor(a),
            path: Vec::with_capacity(b - a),
        }
    }

    /// [`fit_restart_heading`] over `a..=b` from this path (integrated at `at`), integrating
    /// again when the heading found is more than [`RESTART_TURN_EXACT`] from it; the
    /// odometry's heading at each match after the start in that integration left in
    /// `headings` when given (rad).
    fn fit(
        mut self,
        run: &Run,
        params: &ChassisParams,
        (a, b): (usize, usize),
        mut headings: Option<&mut Vec<f64>>,
    ) -> Result<Self> {
        let t = &mut self;
        for pass in 0..RESTART_PASSES {
            if pass > 0 {
                if let Some(h) = headings.as_deref_mut() {
                    h.clear();
                }
                t.integrate(run, params, (a, b), headings.as_deref_mut())?;
            }
            let at = t.at;
            // The first pass starts from the turn of the least squares (where `sum r . R(phi)
            // d` is largest: one pass over the path), which is near the norms' least; a
            // second from the heading the first found.
            let start = if pass == 0 {
                let (dot, cross) = t.path.iter().fold((0.0, 0.0), |(a, b), &[dx, dy, rx, ry]| {
                    (a + rx * dx + ry * dy, b + rx * dy - ry * dx)
                });
                if dot != 0.0 || cross != 0.0 {
                    at + cross.atan2(dot)
                } else {
                    at
                }
            } else {
                at
            };
            let path = &t.path;
            let f = |x: &[f64], acc: &mut NormalAccumulator| {
                let (sin, cos) = (x[0] - at).sin_cos();
                for &[dx, dy, rx, ry] in path {
                    let (px, py) = (dx * cos + dy * sin, dy * cos - dx * sin);
                    acc.add_pair(px - rx, py - ry, &[py], &[-px]);
                }
                acc.cost().is_finite()
            };
            let res = optim::levenberg_marquardt_streamed(
                f,
                &[start],
                &[1.0],
                Objective::SumOfNorms,
                LmOptions {
                    // The Newton model of the norms converges quadratically: the heading is
                    // the minimum of the turned path's eq (16) to 1e-10 rad, not where the
                    // IRLS majoriser's linear convergence happens to stop (iterations cost no
                    // integration here).
                    newton: true,
                    pred_tol: RESTART_PRED_TOL,
                    ..LmOptions::default()
                },
            )
            .ok_or_else(|| anyhow!("parameters: not admissible"))?;
            t.heading = res.x[0];
            if (t.heading - at).abs() <= RESTART_TURN_EXACT {
                break;
            }
        }
        Ok(self)
    }

    /// Integrates `params` over `a..=b` from the heading found so far, which becomes `at`;
    /// the odometry's heading at each match after the start pushed to `headings` when given
    /// (rad).
    fn integrate(
        &mut self,
        run: &Run,
        params: &ChassisParams,
        (a, b): (usize, usize),
        mut headings: Option<&mut Vec<f64>>,
    ) -> Result<()> {
        let (heading, (x0, y0)) = (self.heading, self.start);
        self.at = heading;
        self.path.clear();
        let path = &mut self.path;
        run.integrate_pose(params, a, b, heading, |k, integ| {
            // The antenna turns with the path about the start, as the centre does.
            let pose = integ.pose();
            let (px, py) = run.observed(&pose, heading);
            let r = run.reference_at(k);
            path.push([px - x0, py - y0, r.x - x0, r.y - y0]);
            if let Some(h) = headings.as_deref_mut() {
                h.push(pose.heading);
            }
        })
        .map_err(|e| anyhow!("parameters: {e}"))
    }
}

impl TurnedPath {
    /// Turns the path's observed points about the start to the heading found, which becomes
    /// `at`: by `phi = heading - at` (rad, clockwise), returned.
    fn turn_to_heading(&mut self) -> f64 {
        let phi = self.heading - self.at;
        let (sin, cos) = phi.sin_cos();
        for p in &mut self.path {
            let [dx, dy, _, _] = *p;
            (p[0], p[1]) = (dx * cos + dy * sin, dy * cos - dx * sin);
        }
        self.at = self.heading;
        phi
    }
}

/// The whole run's start heading at `params` and what its path gives (rad, m).
#[derive(Debug, Clone, PartialEq)]
pub struct WholeRunHeading {
    /// The start heading of the least eq (16) (rad).
    pub heading0: f64,
    /// Eq (16) there (m).
    pub cost: f64,
    /// The odometry at every match from `heading0`: its heading (`heading0` at the first)
    /// and observed point.
    pub path: RunPath,
    /// The start heading's formal and cluster-robust standard errors (rad), the geometry
    /// held ([`HeadingErrors`]).
    pub errors: (Option<f64>, Option<f64>),
}

/// [`fit_restart_heading`] over the whole run from `guess`, and what the path at the heading
/// found gives: eq (16) there, the odometry at each match ([`RunPath`]) and the heading's
/// standard errors (stretches of `length` m for the cluster-robust one), whose rows are the
/// turn's derivative `(y - y0, -(x - x0))`: what the forward sensitivity gives, to the
/// integrator's rounding. That path is the fit's last integration turned about the start to
/// the heading found, which is at most [`RESTART_TURN_EXACT`] away: the integration at that
/// heading to within the integrator's own arithmetic noise (eq (16) to about 1e-9 of itself,
/// the headings to 1e-15 rad); integrated again there when the fit's last step turned it
/// further.
pub fn fit_whole_run_heading(
    run: &Run,
    params: &ChassisParams,
    guess: f64,
    length: f64,
) -> Result<WholeRunHeading> {
    let last = run.len() - 1;
    let mut integrated = Vec::with_capacity(run.len());
    let mut t = TurnedPath::starting(run, 0, last, guess);
    t.integrate(run, params, (0, last), Some(&mut integrated))?;
    let mut t = t.fit(run, params, (0, last), Some(&mut integrated))?;
    let phi = if (t.heading - t.at).abs() > RESTART_TURN_EXACT {
        integrated.clear();
        t.integrate(run, params, (0, last), Some(&mut integrated))?;
        0.0
    } else {
        t.turn_to_heading()
    };
    let mut headings = Vec::with_capacity(run.len());
    headings.push(t.heading);
    headings.extend(integrated.iter().map(|h| h + phi));
    let mut residuals = Vec::with_capacity(2 * t.path.len());
    let mut points = Vec::with_capacity(run.len());
    points.push([0.0; 2]);
    let mut errors = HeadingErrors::new(run.dist[0], length);
    for (i, &[dx, dy, rx, ry]) in t.path.iter().enumerate() {
        let r = (dx - rx, dy - ry);
        residuals.extend([r.0, r.1]);
        points.push([dx, dy]);
        errors.add(run.dist[i + 1], r, dy, -dx);
    }
    if residuals.iter().any(|v| !v.is_finite()) {
        return Err(anyhow!("the estimate is not admissible"));
    }
    Ok(WholeRunHeading {
        heading0: t.heading,
        cost: optim::objective(Objective::SumOfNorms, &residuals),
        path: RunPath { headings, points },
        errors: errors.finish(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::geometry::paper::heading_errors;
    use crate::calib::run::windows;
    use crate::calib::testing::{run_of, sim};
    use crate::optim::norm2;
    use crate::simulate::{default_truth, PathKind};

    /// The whole-run heading fit's figures are those of the integration at the heading it
    /// found, to that integration's arithmetic noise: eq (16) (2e-7 of it), the headings at
    /// every match (1e-12 rad), and the heading's two standard errors from the forward
    /// sensitivities; with a lever arm too, and from a guess far enough for two integrations
    /// in the fit.
    #[test]
    fn whole_run_heading_figures_are_the_integrated_ones() {
        let s = sim(PathKind::Random, 200.0, 5);
        let mut run = run_of(&s);
        let p = default_truth();
        for (antenna, off) in [((0.0, 0.0), 0.001), ((0.3, -0.1), 0.2)] {
            run.antenna = antenna;
            let guess = run.heading_guess(0) + off;
            let w = fit_whole_run_heading(&run, &p, guess, 10.0).unwrap();
            let last = run.len() - 1;
            assert_eq!(
                w.heading0,
                fit_restart_heading(&run, &p, 0, last, guess).unwrap()
            );
            let cost = run.eq16(&p, 0, last, w.heading0).unwrap();
            assert!((w.cost - cost).abs() <= 2e-7 * cost, "{} {cost}", w.cost);
            let (x0, y0) = run.anchor(0);
            let mut headings = vec![w.heading0];
            let mut points = vec![[0.0; 2]];
            run.integrate_pose(&p, 0, last, w.heading0, |_, integ| {
                let (x, y) = run.observed(&integ.pose(), w.heading0);
                headings.push(integ.pose().heading);
                points.push([x - x0, y - y0]);
            })
            .unwrap();
            assert_eq!(headings.len(), w.path.headings.len());
            for (h, wh) in headings.iter().zip(&w.path.headings) {
                assert!((h - wh).abs() < 1e-12, "{h} {wh}");
            }
            assert_eq!(points.len(), w.path.points.len());
            let far = points
                .iter()
                .zip(&w.path.points)
                .map(|(a, b)| norm2(a[0] - b[0], a[1] - b[1]))
                .fold(0.0, f64::max);
            assert!(far < 1e-7, "{far:e} m");
            let (formal, clustered) = heading_errors(&run, &p, w.heading0, 10.0);
            let near =
                |a: Option<f64>, b: Option<f64>| (a.unwrap() / b.unwrap() - 1.0).abs() < 1e-6;
            assert!(near(w.errors.0, formal), "{:?} {formal:?}", w.errors);
            assert!(near(w.errors.1, clustered), "{:?} {clustered:?}", w.errors);
        }
    }

    /// The restarts' heading fit turns one integrated path about its start: the odometry
    /// integrated from another start heading is that path turned (to the integrator's
    /// rounding), and the heading found is the minimum of eq (16) that a fit re-integrating
    /// the odometry at every step finds.
    #[test]
    fn restart_heading_by_rotation_matches_the_integrating_fit() {
        let s = sim(PathKind::Estimation, 70.0, 9);
        let run = run_of(&s);
        let p = default_truth();
        let wins = windows(&run, 10.0, 3);
        assert!(wins.len() >= 6);
        let path = |a: usize, b: usize, h: f64| {
            let mut out = Vec::new();
            run.integrate_pose(&p, a, b, h, |_, integ| {
                let q = integ.pose();
                out.push((q.x, q.y));
            })
            .unwrap();
            out
        };
        for &(a, b) in &wins {
            let (x0, y0) = run.anchor(a);
            let base = path(a, b, 0.3);
            for phi in [0.01, -0.2, 0.5, 3.0] {
                let (sin, cos) = f64::sin_cos(phi);
                for ((x, y), (tx, ty)) in base.iter().zip(path(a, b, 0.3 + phi)) {
                    let (dx, dy) = (x - x0, y - y0);
                    let (rx, ry) = (x0 + dx * cos + dy * sin, y0 + dy * cos - dx * sin);
                    assert!(norm2(rx - tx, ry - ty) < 1e-7, "window {a}..{b}, phi {phi}");
                }
            }
            // Against the fit that re-integrates the odometry at every step, converged as far.
            // That fit's eq (16) carries the fixed-point integrator's arithmetic noise, not
            // smooth in the heading (measured on these windows: +-1e-6 m of a 7.7 m cost
            // between headings 2e-8 rad apart, where the turned path's cost changes by 1e-9 m),
            // and its Newton steps stop on that noise: the two headings agree to about 1e-7
            // rad, and their costs to that noise.
            let integrated = |guess: f64| {
                let res = optim::levenberg_marquardt_streamed(
                    |x: &[f64], acc: &mut NormalAccumulator| {
                        run.accumulate_normal(&p, a, b, x[0], &[3], acc)
                    },
                    &[guess],
                    &[1.0],
                    Objective::SumOfNorms,
                    LmOptions {
                        newton: true,
                        pred_tol: 1e-15,
                        ..LmOptions::default()
                    },
                )
                .unwrap();
                res.x[0]
            };
            for guess in [0.3, 0.3 + 0.2, 0.3 - 0.05] {
                let rotated = fit_restart_heading(&run, &p, a, b, guess).unwrap();
                let integrated = integrated(guess);
                let cost = |h: f64| run.eq16(&p, a, b, h).unwrap();
                let (cr, ci) = (cost(rotated), cost(integrated));
                assert!(
                    (rotated - integrated).abs() < 2e-7 && (cr - ci).abs() <= 5e-7 * ci,
                    "window {a}..{b} from {guess}: {rotated} ({cr}) vs {integrated} ({ci})"
                );
            }
        }
    }
}
