//! The restarted sub-trajectories that the uncertainty fits share.

use std::cell::RefCell;
use std::rc::Rc;

use anyhow::{anyhow, bail, Result};
use odo_unit::odometry::ChassisParams;

use crate::calib::evaluation::{Evaluation, UncertaintyRecord};
use crate::calib::heading_fit::{fit_restart_heading, fit_restart_heading_along, RunPath};
use crate::calib::pipeline::cores;
use crate::calib::run::{windows, Run};
use crate::cancel::check_this_thread;

/// The restarted sub-trajectories of the uncertainty fits: consecutive stretches of `window`
/// metres, each started from the reference position with the heading minimising eq (16) over
/// it. They depend on the geometry only, so every coefficient fit shares them.
#[derive(Debug, Clone)]
pub struct Restarts {
    /// `(start, end)` match indices.
    pub windows: Vec<(usize, usize)>,
    /// Restart headings (rad).
    pub headings: Vec<f64>,
    /// The last evaluations (see [`Restarts::evaluate_memo`]).
    memo: RefCell<Vec<(ChassisParams, Rc<Evaluation>)>>,
    /// The last integrated evaluation with its step geometries, which give the sigmas at
    /// other coefficients of the same geometry ([`Restarts::evaluate_reusing`]).
    recorded: RefCell<Option<Recorded>>,
}

/// An integrated evaluation of the restarts and what replays its sigmas.
#[derive(Debug, Clone)]
struct Recorded {
    /// The parameters it integrated.
    params: ChassisParams,
    /// Their pose part ([`ChassisParams::pose_part`]).
    pose: ChassisParams,
    /// Its evaluation.
    evaluation: Rc<Evaluation>,
    /// Its step geometries, a record for each part evaluated on a core of its own, in order.
    parts: Vec<UncertaintyRecord>,
}

/// Evaluations kept by [`Restarts::evaluate_memo`]: the two latest of a coefficient search
/// (its predictor) and the fit's result.
const MEMO_EVALUATIONS: usize = 4;

impl Restarts {
    /// Cuts the run and fits the restart headings (eq 16 over each sub-trajectory, from the
    /// full-run odometry with `heading0`).
    pub fn new(run: &Run, geometry: &ChassisParams, heading0: f64, window: f64) -> Result<Self> {
        // The full-run odometry headings (the pose does not depend on the uncertainty model).
        let mut full = Vec::with_capacity(run.len());
        full.push(heading0);
        run.integrate_pose(geometry, 0, run.len() - 1, heading0, |_, integ| {
            full.push(integ.pose().heading)
        })
        .map_err(|e| anyhow!("parameters: {e}"))?;
        Self::fitted(run, window, |a, b| {
            fit_restart_heading(run, geometry, a, b, full[a])
        })
    }

    /// [`Restarts::new`] from the full-run odometry already integrated (`path`,
    /// [`fit_whole_run_heading`]): each sub-trajectory's first path is `path`'s stretch
    /// ([`fit_restart_heading_along`]), not an integration of its own.
    ///
    /// [`fit_whole_run_heading`]: crate::calib::heading_fit::fit_whole_run_heading
    pub fn along(run: &Run, geometry: &ChassisParams, path: &RunPath, window: f64) -> Result<Self> {
        let n = run.len();
        if path.headings.len() != n || path.points.len() != n {
            bail!(
                "a path of {} headings and {} points for a run of {n} matches",
                path.headings.len(),
                path.points.len()
            );
        }
        Self::fitted(run, window, |a, b| {
            fit_restart_heading_along(run, geometry, path, (a, b))
        })
    }

    /// The sub-trajectories of `window` m of the run, each restart heading by `fit(a, b)`.
    fn fitted(
        run: &Run,
        window: f64,
        fit: impl Fn(usize, usize) -> Result<f64> + Sync,
    ) -> Result<Self> {
        let wins = windows(run, window, 3);
        if wins.is_empty() {
            bail!("the run is too short for the uncertainty fit (no sub-trajectory of {window} m with 3 points)");
        }
        // The sub-trajectories' fits are independent: spread over the cores (the same fits,
        // in the same order of results, as one after the other).
        let threads = cores().min(wins.len());
        let chunk = wins.len().div_ceil(threads.max(1));
        let fit = &fit;
        let headings = std::thread::scope(|scope| {
            let jobs: Vec<_> = wins
                .chunks(chunk)
                .map(|part| {
                    scope.spawn(move || {
                        part.iter()
                            .map(|&(a, b)| fit(a, b))
                            .collect::<Result<Vec<f64>>>()
                    })
                })
                .collect();
            jobs.into_iter()
                .map(|j| j.join().expect("restart heading fit panicked"))
                .collect::<Result<Vec<_>>>()
        })?
        .concat();
        Ok(Self {
            windows: wins,
            headings,
            memo: RefCell::default(),
            recorded: RefCell::default(),
        })
    }

    /// [`Restarts::evaluate`], remembered: the last [`MEMO_EVALUATIONS`] evaluations are kept
    /// and returned again for the same parameters (the fits of the coefficients evaluate the
    /// same parameters several times: the result, its coverages, the refits of delta).
    pub fn evaluate_memo(&self, run: &Run, p: &ChassisParams) -> Result<Rc<Evaluation>> {
        let mut memo = self.memo.borrow_mut();
        if let Some(i) = memo.iter().position(|(q, _)| q == p) {
            let hit = memo.remove(i);
            let ev = Rc::clone(&hit.1);
            memo.push(hit);
            return Ok(ev);
        }
        // Reuse the buffers of the oldest evaluation when nobody holds it any more.
        let buffers = if memo.len() >= MEMO_EVALUATIONS {
            Rc::try_unwrap(memo.remove(0).1).unwrap_or_default()
        } else {
            Evaluation::default()
        };
        drop(memo);
        let ev = self.evaluate_reusing(run, p, buffers)?;
        self.memo.borrow_mut().push((*p, Rc::clone(&ev)));
        Ok(ev)
    }

    /// The remembered evaluations whose parameters satisfy `family`, newest first.
    pub(crate) fn memo_where(
        &self,
        family: impl Fn(&ChassisParams) -> bool,
    ) -> Vec<(ChassisParams, Rc<Evaluation>)> {
        self.memo
            .borrow()
            .iter()
            .rev()
            .filter(|(q, _)| family(q))
            .map(|(q, ev)| (*q, Rc::clone(ev)))
            .collect()
    }

    /// The points of an evaluation: every match after each restart.
    pub fn points(&self) -> usize {
        self.windows.iter().map(|(a, b)| b - a).sum()
    }

    /// An evaluation whose poses and errors are those at `p` (its sigmas those of other
    /// coefficients, maybe): the last integrated one when it integrated the pose part of `p`,
    /// else [`Restarts::evaluate_memo`].
    pub fn pose_evaluation(&self, run: &Run, p: &ChassisParams) -> Result<Rc<Evaluation>> {
        match self.recorded_for(p) {
            Some((_, ev)) => Ok(ev),
            None => self.evaluate_memo(run, p),
        }
    }

    /// The last integrated evaluation, when it integrated the pose part of `p`: the
    /// parameters it integrated and the evaluation (whose poses and errors are those of `p`).
    pub(crate) fn recorded_for(
        &self,
        p: &ChassisParams,
    ) -> Option<(ChassisParams, Rc<Evaluation>)> {
        let pose = p.pose_part();
        self.recorded
            .borrow()
            .as_ref()
            .filter(|r| r.pose == pose)
            .map(|r| (r.params, Rc::clone(&r.evaluation)))
    }

    /// The horizontal and heading sigmas (m, rad) at `p` of the evaluation's rows that
    /// `wanted` picks, in the order of the rows, replayed from the last integrated evaluation
    /// (which must have integrated the pose part of `p`, [`Restarts::recorded_for`]): only the
    /// sub-trajectories holding a picked row are replayed; `None` without such an evaluation.
    pub(crate) fn replay_rows(
        &self,
        p: &ChassisParams,
        wanted: &[bool],
    ) -> Option<Vec<(usize, (f64, f64))>> {
        let recorded = self.recorded.borrow();
        let r = recorded.as_ref().filter(|r| r.pose == p.pose_part())?;
        let mut out = Vec::new();
        let mut offset = 0;
        for part in &r.parts {
            let rows = &wanted[offset..offset + part.rows()];
            part.replay_rows(p, |i| rows[i], |i, s| out.push((offset + i, s)));
            offset += part.rows();
        }
        Some(out)
    }

    /// Errors and sigmas at every match after each restart (restart points excluded).
    pub fn evaluate(&self, run: &Run, p: &ChassisParams) -> Result<Evaluation> {
        let ev = self.evaluate_reusing(run, p, Evaluation::default())?;
        Ok(Rc::try_unwrap(ev).unwrap_or_else(|shared| (*shared).clone()))
    }

    /// [`Restarts::evaluate`] into `buffers` (cleared first, their allocations reused: the
    /// coverage searches evaluate the same sub-trajectories several times). Parameters that
    /// differ from the last integrated ones in the uncertainty's coefficients alone (the same
    /// [`ChassisParams::pose_part`]) have the same poses and errors: their sigmas are replayed
    /// from that integration's step geometries ([`UncertaintyRecord::replay`]), the same
    /// sigmas bit for bit at a fraction of the cost. Otherwise the sub-trajectories are
    /// integrated on all cores (independent, appended in order: the same evaluation as one
    /// after the other), and the evaluation is kept with their step geometries.
    fn evaluate_reusing(
        &self,
        run: &Run,
        p: &ChassisParams,
        mut buffers: Evaluation,
    ) -> Result<Rc<Evaluation>> {
        check_this_thread()?;
        p.validate().map_err(|e| anyhow!("parameters: {e}"))?;
        let pose = p.pose_part();
        if let Some(r) = self.recorded.borrow().as_ref().filter(|r| r.pose == pose) {
            buffers.clone_from(&r.evaluation);
            replay(&r.parts, p, &mut buffers);
            return Ok(Rc::new(buffers));
        }
        let parts = self.integrate_into(run, p, &mut buffers)?;
        let evaluation = Rc::new(buffers);
        *self.recorded.borrow_mut() = Some(Recorded {
            params: *p,
            pose,
            evaluation: Rc::clone(&evaluation),
            parts,
        });
        Ok(evaluation)
    }

    /// The integration of [`Restarts::evaluate_reusing`]: the evaluation into `ev`, with the
    /// step geometries of each core's part.
    fn integrate_into(
        &self,
        run: &Run,
        p: &ChassisParams,
        ev: &mut Evaluation,
    ) -> Result<Vec<UncertaintyRecord>> {
        ev.clear();
        let threads = cores().min(self.windows.len()).max(1);
        let chunk = self.windows.len().div_ceil(threads);
        let jobs: Vec<_> = self
            .windows
            .chunks(chunk)
            .zip(self.headings.chunks(chunk))
            .collect();
        let (first, rest) = jobs.split_first().expect("at least one sub-trajectory");
        let rows = |wins: &[(usize, usize)]| wins.iter().map(|(a, b)| b - a).sum();
        // Room for every part's rows, which are appended to `ev`'s own.
        ev.reserve(rows(&self.windows));
        let evaluate = |ev: &mut Evaluation, (wins, heads): (&[(usize, usize)], &[f64])| {
            let rows = rows(wins);
            ev.reserve(rows);
            let mut record = UncertaintyRecord::default();
            let samples = wins
                .iter()
                .map(|&(a, b)| run.matches[b].0 - run.matches[a].0);
            record.reserve(samples.sum(), rows);
            for (&(a, b), &h) in wins.iter().zip(heads) {
                ev.extend_recording(run, p, (a, b), h, &mut record)?;
            }
            Ok::<_, anyhow::Error>(record)
        };
        std::thread::scope(|scope| {
            let spawned: Vec<_> = rest
                .iter()
                .map(|&job| {
                    scope.spawn(move || {
                        let mut part = Evaluation::default();
                        evaluate(&mut part, job).map(|r| (part, r))
                    })
                })
                .collect();
            let own = evaluate(ev, *first)?;
            let mut records = vec![own];
            for j in spawned {
                let (mut part, record) = j.join().expect("evaluation panicked")?;
                ev.append(&mut part);
                records.push(record);
            }
            Ok(records)
        })
    }
}

/// The sigmas of `ev` (the evaluation the `parts` were recorded with) at the coefficients of
/// `p`, each part's on a core of its own.
fn replay(parts: &[UncertaintyRecord], p: &ChassisParams, ev: &mut Evaluation) {
    let (mut sigma_h, mut sigma_heading) = (&mut ev.sigma_h[..], &mut ev.sigma_heading[..]);
    std::thread::scope(|scope| {
        let mut own = None;
        for (i, part) in parts.iter().enumerate() {
            let (h, rest_h) = std::mem::take(&mut sigma_h).split_at_mut(part.rows());
            let (a, rest_a) = std::mem::take(&mut sigma_heading).split_at_mut(part.rows());
            (sigma_h, sigma_heading) = (rest_h, rest_a);
            if i == 0 {
                own = Some((part, h, a));
            } else {
                scope.spawn(move || part.replay(p, h, a));
            }
        }
        if let Some((part, h, a)) = own {
            part.replay(p, h, a);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::heading_fit::fit_whole_run_heading;
    use crate::calib::testing::{run_of, sim};
    use crate::simulate::{default_truth, PathKind};
    use odo_unit::odometry::UncertaintyModel;

    impl Restarts {
        /// Restarts of these windows and headings, nothing evaluated yet.
        fn with_headings_fitted(windows: Vec<(usize, usize)>, headings: Vec<f64>) -> Self {
            Self {
                windows,
                headings,
                memo: RefCell::default(),
                recorded: RefCell::default(),
            }
        }
    }

    /// Restarts along the whole-run heading fit's path (at the heading found) are the
    /// restarts that integrate their own from that heading, to the restart fits' convergence
    /// (1e-9 rad), with a lever arm too; a path of another run is refused.
    #[test]
    fn restarts_along_the_whole_run_path_are_the_restarts_that_integrate() {
        let s = sim(PathKind::Random, 120.0, 4);
        let mut run = run_of(&s);
        let g = default_truth();
        for antenna in [(0.0, 0.0), (0.3, -0.1)] {
            run.antenna = antenna;
            let w = fit_whole_run_heading(&run, &g, run.heading_guess(0) + 0.05, 10.0).unwrap();
            let own = Restarts::new(&run, &g, w.heading0, 10.0).unwrap();
            let along = Restarts::along(&run, &g, &w.path, 10.0).unwrap();
            assert_eq!(own.windows, along.windows);
            for (o, a) in own.headings.iter().zip(&along.headings) {
                assert!((o - a).abs() < 1e-9, "{o} {a}");
            }
            let mut short = w.path.clone();
            short.points.pop();
            assert!(Restarts::along(&run, &g, &short, 10.0).is_err());
        }
    }

    /// Every column of two evaluations, for equality.
    fn columns(ev: &Evaluation) -> String {
        format!("{ev:?}")
    }

    /// Evaluations at other coefficients of the same geometry, either model, are replayed
    /// from the last integration's step geometries, and they are the evaluations that
    /// integrate, bit for bit; another geometry is integrated (and recorded) again, and
    /// parameters out of range are refused on either path.
    #[test]
    fn replayed_evaluations_are_the_integrated_ones() {
        let s = sim(PathKind::Random, 150.0, 6);
        let run = run_of(&s);
        let p = default_truth();
        let r = Restarts::new(&run, &p, run.heading_guess(0), 10.0).unwrap();
        let fresh = |q: &ChassisParams| {
            let f = Restarts::with_headings_fitted(r.windows.clone(), r.headings.clone());
            columns(&f.evaluate(&run, q).unwrap())
        };
        // The pose part and the evaluation (its allocation) of the last integration.
        let recorded = |r: &Restarts| {
            let kept = r.recorded.borrow();
            kept.as_ref().map(|x| (x.pose, Rc::as_ptr(&x.evaluation)))
        };
        assert_eq!(columns(&r.evaluate(&run, &p).unwrap()), fresh(&p));
        let integrated = recorded(&r);
        assert_eq!(integrated.map(|(pose, _)| pose), Some(p.pose_part()));
        let others = [
            ChassisParams {
                delta_left: p.delta_left * 3.0,
                delta_diff: 2e-7,
                ..p
            },
            ChassisParams {
                uncertainty_model: UncertaintyModel::Covariance,
                kappa_left: 1e-6,
                kappa_right: 2e-6,
                kappa_diff: 1e-5,
                kappa_diff_corr: 0.5,
                ..p
            },
        ];
        for q in others {
            let replayed = columns(&r.evaluate(&run, &q).unwrap());
            assert_eq!(replayed, fresh(&q));
            assert_ne!(replayed, fresh(&p));
            assert_eq!(recorded(&r), integrated, "integrated again");
        }
        let wider = ChassisParams {
            track_width: p.track_width * 1.001,
            ..p
        };
        assert_eq!(columns(&r.evaluate(&run, &wider).unwrap()), fresh(&wider));
        assert_eq!(recorded(&r).map(|(pose, _)| pose), Some(wider.pose_part()));
        for bad in [
            ChassisParams {
                delta_left: -1.0,
                ..wider
            },
            ChassisParams {
                track_width: -1.0,
                ..p
            },
        ] {
            assert!(r.evaluate(&run, &bad).is_err());
        }
    }
}
