//! The restarted sub-trajectories that the uncertainty fits share.

use std::cell::RefCell;
use std::rc::Rc;

use anyhow::{anyhow, bail, Result};
use odo_unit::odometry::ChassisParams;

use crate::calib::evaluation::Evaluation;
use crate::calib::heading_fit::fit_restart_heading;
use crate::calib::pipeline::cores;
use crate::calib::run::{windows, Run};

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
        Self::with_headings(run, geometry, &full, window)
    }

    /// [`Restarts::new`] with the full-run odometry's headings at each match already
    /// integrated (`full`, [`fit_whole_run_heading`]).
    ///
    /// [`fit_whole_run_heading`]: crate::calib::heading_fit::fit_whole_run_heading
    pub fn with_headings(
        run: &Run,
        geometry: &ChassisParams,
        full: &[f64],
        window: f64,
    ) -> Result<Self> {
        let wins = windows(run, window, 3);
        if wins.is_empty() {
            bail!("the run is too short for the uncertainty fit (no sub-trajectory of {window} m with 3 points)");
        }
        if full.len() != run.len() {
            bail!("{} headings for a run of {} matches", full.len(), run.len());
        }
        // The sub-trajectories' fits are independent: spread over the cores (the same fits,
        // in the same order of results, as one after the other).
        let threads = cores().min(wins.len());
        let chunk = wins.len().div_ceil(threads.max(1));
        let headings = std::thread::scope(|scope| {
            let jobs: Vec<_> = wins
                .chunks(chunk)
                .map(|part| {
                    scope.spawn(move || {
                        part.iter()
                            .map(|&(a, b)| fit_restart_heading(run, geometry, a, b, full[a]))
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
        let mut ev = if memo.len() >= MEMO_EVALUATIONS {
            Rc::try_unwrap(memo.remove(0).1).unwrap_or_default()
        } else {
            Evaluation::default()
        };
        drop(memo);
        self.evaluate_into(run, p, &mut ev)?;
        let ev = Rc::new(ev);
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

    /// Errors and sigmas at every match after each restart (restart points excluded).
    pub fn evaluate(&self, run: &Run, p: &ChassisParams) -> Result<Evaluation> {
        let mut ev = Evaluation::default();
        self.evaluate_into(run, p, &mut ev)?;
        Ok(ev)
    }

    /// [`Restarts::evaluate`] into `ev` (cleared first, its buffers reused: the coverage
    /// searches evaluate the same sub-trajectories several times).
    /// The sub-trajectories are evaluated on all cores (independent, appended in order: the
    /// same evaluation as one after the other).
    pub fn evaluate_into(&self, run: &Run, p: &ChassisParams, ev: &mut Evaluation) -> Result<()> {
        ev.clear();
        let threads = cores().min(self.windows.len()).max(1);
        let chunk = self.windows.len().div_ceil(threads);
        let jobs: Vec<_> = self
            .windows
            .chunks(chunk)
            .zip(self.headings.chunks(chunk))
            .collect();
        let (first, rest) = jobs.split_first().expect("at least one sub-trajectory");
        let reserve = |ev: &mut Evaluation, wins: &[(usize, usize)]| {
            ev.reserve(wins.iter().map(|(a, b)| b - a).sum());
        };
        // Room for every part's rows, which are appended to `ev`'s own.
        reserve(ev, &self.windows);
        let evaluate = |ev: &mut Evaluation, (wins, heads): (&[(usize, usize)], &[f64])| {
            reserve(ev, wins);
            for (&(a, b), &h) in wins.iter().zip(heads) {
                ev.extend(run, p, a, b, h, false)?;
            }
            Ok::<_, anyhow::Error>(())
        };
        let parts = std::thread::scope(|scope| {
            let spawned: Vec<_> = rest
                .iter()
                .map(|&job| {
                    scope.spawn(move || {
                        let mut part = Evaluation::default();
                        evaluate(&mut part, job).map(|()| part)
                    })
                })
                .collect();
            let own = evaluate(ev, *first);
            let parts = spawned
                .into_iter()
                .map(|j| j.join().expect("evaluation panicked"))
                .collect::<Result<Vec<_>>>();
            own.and(parts)
        })?;
        for mut part in parts {
            ev.append(&mut part);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::heading_fit::fit_whole_run_heading;
    use crate::calib::testing::sim;
    use crate::csvio::match_times;
    use crate::simulate::{default_truth, PathKind};

    /// Restarts from the whole-run heading fit's headings (its integration at the heading
    /// found) are the restarts that integrate their own from that heading; headings of
    /// another run are refused.
    #[test]
    fn restarts_from_the_whole_run_headings_are_the_restarts_that_integrate() {
        let s = sim(PathKind::Random, 120.0, 4);
        let run = Run::new(
            &s.samples,
            &s.reference,
            match_times(&s.samples, &s.reference),
        );
        let g = default_truth();
        let w = fit_whole_run_heading(&run, &g, run.heading_guess(0) + 0.05, 10.0).unwrap();
        let own = Restarts::new(&run, &g, w.heading0, 10.0).unwrap();
        let given = Restarts::with_headings(&run, &g, &w.headings, 10.0).unwrap();
        assert_eq!((own.windows, own.headings), (given.windows, given.headings));
        assert!(Restarts::with_headings(&run, &g, &w.headings[1..], 10.0).is_err());
    }
}
