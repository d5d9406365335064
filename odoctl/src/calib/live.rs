//! The default geometry estimator run as the data arrive (`odoctl record --calibrate`): the
//! sub-trajectory fit of [`fit_subtrajectories`](super::fit_subtrajectories), each update
//! costing what the new data cost.
//!
//! - Samples and reference points are appended in time order; a sample is matched to the
//!   reference (as [`match_times`](crate::csvio::match_times) does) once a reference point
//!   later than it has arrived, and the reference path length, the cuts every
//!   `length` metres (as [`Cuts::Distance`](super::Cuts::Distance) cuts) and the turning
//!   (as the batch measures it) follow match by match.
//! - A sub-trajectory is evaluated once, when it is complete, at the estimate of that moment:
//!   its reduced normal equations `S_j`, `g_j` (its start position and heading eliminated by
//!   the Schur complement, as in the batch fit), kept as the linear model
//!   `g_j(x) = g_j + S_j (x - x_j)` about its linearisation point `x_j`. The estimate solves
//!   `sum_j g_j(x) = 0`, from running sums: a 3 x 3 system whatever the length of the drive.
//! - Relinearisation: after each update, the sub-trajectories whose linearisation point is
//!   farther than [`RELINEARISE`] standard errors from the estimate are evaluated again at
//!   it, at most [`RELINEARISE_PER_UPDATE`] per update (the farthest first);
//!   [`LiveCalibration::finish`] relinearises until none is farther, so that the last
//!   estimate is the batch fit's minimum to within the linearisation's second order.
//! - Standard errors: the batch's cluster jackknife over the sub-trajectories, from their
//!   `S_j` and `g_j(x)` (a few microseconds per sub-trajectory), computed when a
//!   sub-trajectory is added.
//!
//! The track width is held (as in the batch fit) until the drive has turned
//! [`MIN_TURNING_DEG`] in all. The filter's refinement and the uncertainty coefficients are
//! the batch calibration's, computed once at the drive's end.

use odo_unit::odometry::{ChassisParams, Integrator, Pose};

use crate::csvio::{RefPoint, Sample, MATCH_TOLERANCE};
use crate::memory::{for_drive, DRIVE_EPOCHS_PER_S, DRIVE_SAMPLES_PER_S};
use crate::optim;
use crate::replay::{counts, index_refs};

use super::geometry::covariance::cluster_jackknife;
use super::geometry::subtrajectory::{eval_block, MIN_POINTS};
use super::run::{Run, PATH_STEP};

/// Distance (standard errors of the estimate) of a sub-trajectory's linearisation point from
/// the estimate beyond which it is evaluated again, during the drive and at its end. What it
/// leaves in the estimate is of second order; a threshold within the estimate's own wander as
/// sub-trajectories are added (a tenth of a standard error) would evaluate every
/// sub-trajectory again every few new ones.
pub const RELINEARISE: f64 = 1.0;

/// Sub-trajectories evaluated again per update at most (the farthest first).
pub const RELINEARISE_PER_UPDATE: usize = 2;

/// Total turning (degrees) before the track width is estimated, as in the batch fit.
pub const MIN_TURNING_DEG: f64 = 30.0;

/// Path step (m of reference path) over which the turning is summed, as in the batch fit.
const TURNING_STEP: f64 = 0.25;

/// One complete sub-trajectory and its linear model.
#[derive(Debug, Clone)]
struct Block {
    /// First and last match (global indices).
    a: usize,
    b: usize,
    /// Linearisation point: left diameter, right diameter, track width (m).
    x: [f64; 3],
    /// Reduced Hessian (row-major 3 x 3) and gradient at `x`.
    s: [f64; 9],
    g: [f64; 3],
    /// Fitted start heading (rad), the next evaluation's first guess.
    heading: f64,
}

/// What the live estimate shows.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveEstimate {
    /// Left diameter, right diameter, track width (m).
    pub values: [f64; 3],
    /// Their cluster-robust standard errors (m); `None` before two sub-trajectories, and for
    /// the track width while it is held.
    pub std_errors: [Option<f64>; 3],
    /// Complete sub-trajectories.
    pub subtrajectories: usize,
    /// Reference path driven (m).
    pub distance: f64,
    /// Turning so far to the left and to the right (rad, each positive).
    pub turned_left: f64,
    /// See `turned_left`.
    pub turned_right: f64,
    /// True once the drive turned [`MIN_TURNING_DEG`] in all.
    pub track_estimated: bool,
    /// Samples and reference points received, and common times.
    pub samples: usize,
    /// See `samples`.
    pub reference_points: usize,
    /// See `samples`.
    pub matches: usize,
    /// Reference points left out for a time not after the previous one's.
    pub reference_out_of_order: usize,
}

/// The incremental sub-trajectory fit (module documentation).
pub struct LiveCalibration {
    initial: ChassisParams,
    length: f64,
    samples: Vec<Sample>,
    reference: Vec<RefPoint>,
    out_of_order: usize,
    /// Next sample to match, and the reference cursor of the matching.
    next_sample: usize,
    ref_cursor: usize,
    matches: Vec<(usize, usize)>,
    dist: Vec<f64>,
    path_anchor: Option<(f64, f64)>,
    /// Turning: the integrator (initial geometry) over the matched samples, the last
    /// (heading, distance) summed, and the sums to the left and right.
    turn_integ: Option<Integrator>,
    turn_last: (f64, f64),
    turn_h: f64,
    turned: (f64, f64),
    /// First match of the open sub-trajectory.
    open: usize,
    blocks: Vec<Block>,
    sum_s: [f64; 9],
    sum_rhs: [f64; 3],
    x: [f64; 3],
    se: [Option<f64>; 3],
    /// Sub-trajectories evaluated again, in all.
    relinearised: usize,
    finished: bool,
}

impl LiveCalibration {
    /// An empty estimate from `initial`'s geometry, cutting every `length` metres of
    /// reference path.
    pub fn new(initial: &ChassisParams, length: f64) -> Self {
        Self {
            initial: *initial,
            length,
            samples: for_drive(DRIVE_SAMPLES_PER_S),
            reference: for_drive(DRIVE_EPOCHS_PER_S),
            out_of_order: 0,
            next_sample: 0,
            ref_cursor: 0,
            matches: for_drive(DRIVE_SAMPLES_PER_S),
            dist: for_drive(DRIVE_SAMPLES_PER_S),
            path_anchor: None,
            turn_integ: None,
            turn_last: (0.0, 0.0),
            turn_h: 0.0,
            turned: (0.0, 0.0),
            open: 0,
            blocks: Vec::new(),
            sum_s: [0.0; 9],
            sum_rhs: [0.0; 3],
            x: [
                initial.left_diameter,
                initial.right_diameter,
                initial.track_width,
            ],
            se: [None; 3],
            relinearised: 0,
            finished: false,
        }
    }

    /// The first and the last sample's time (s), once there is a sample.
    pub fn time_span(&self) -> Option<(f64, f64)> {
        Some((self.samples.first()?.t, self.samples.last()?.t))
    }

    /// Appends a sample (times increasing; a sample not after the previous one is left out).
    pub fn push_sample(&mut self, s: Sample) {
        if self.samples.last().is_none_or(|l| s.t > l.t) {
            self.samples.push(s);
        }
    }

    /// Appends a reference point; one not after the previous one is left out and counted.
    pub fn push_reference(&mut self, r: RefPoint) {
        if self.reference.last().is_none_or(|l| r.t > l.t) {
            self.reference.push(r);
        } else {
            self.out_of_order += 1;
        }
    }

    /// Takes in what arrived since the last update: new matches, complete sub-trajectories,
    /// up to [`RELINEARISE_PER_UPDATE`] relinearisations, the estimate and its errors.
    pub fn update(&mut self) {
        self.match_new(false);
        let closed = self.close_blocks(false);
        let redone = self.relinearise(RELINEARISE, RELINEARISE_PER_UPDATE);
        // The estimate changes only with the sums; its errors (a pass over the
        // sub-trajectories) are computed again when one is added.
        if closed + redone > 0 {
            self.solve(closed > 0);
        }
    }

    /// The drive ended: the last samples matched, the last sub-trajectory closed (as the
    /// batch cuts it), every sub-trajectory relinearised until none is farther than
    /// [`RELINEARISE`] from the estimate.
    pub fn finish(&mut self) {
        self.finished = true;
        self.match_new(true);
        // The last match ends the last turning step, as in the batch.
        self.add_turn(self.turn_h, self.dist.last().copied().unwrap_or(0.0));
        self.close_blocks(true);
        self.solve(true);
        for _ in 0..8 {
            if self.relinearise(RELINEARISE, usize::MAX) == 0 {
                break;
            }
            self.solve(true);
        }
        // The running sums again from the blocks (no rounding carried from replacements).
        self.sum_s = [0.0; 9];
        self.sum_rhs = [0.0; 3];
        for i in 0..self.blocks.len() {
            self.add(i, 1.0);
        }
        self.solve(true);
    }

    /// The estimate now.
    pub fn estimate(&self) -> LiveEstimate {
        LiveEstimate {
            values: self.x,
            std_errors: self.se,
            subtrajectories: self.blocks.len(),
            distance: self.dist.last().copied().unwrap_or(0.0),
            turned_left: self.turned.0,
            turned_right: self.turned.1,
            track_estimated: self.track_estimated(),
            samples: self.samples.len(),
            reference_points: self.reference.len(),
            matches: self.matches.len(),
            reference_out_of_order: self.out_of_order,
        }
    }

    /// The parameters at the estimate (the initial ones with its diameters and track).
    pub fn params(&self) -> ChassisParams {
        ChassisParams {
            left_diameter: self.x[0],
            right_diameter: self.x[1],
            track_width: self.x[2],
            ..self.initial
        }
    }

    fn track_estimated(&self) -> bool {
        self.turned.0 + self.turned.1 >= MIN_TURNING_DEG.to_radians()
    }

    /// Matches the samples whose nearest reference points are known (all at the end).
    fn match_new(&mut self, all: bool) {
        let last_ref = self.reference.last().map_or(f64::NEG_INFINITY, |r| r.t);
        while self.next_sample < self.samples.len() {
            let i = self.next_sample;
            let t = self.samples[i].t;
            if !all && last_ref <= t + MATCH_TOLERANCE {
                break;
            }
            self.next_sample += 1;
            let r = &self.reference;
            let mut j = self.ref_cursor;
            while j + 1 < r.len() && r[j + 1].t <= t {
                j += 1;
            }
            self.ref_cursor = j;
            let mut best: Option<usize> = None;
            for k in [j, j + 1] {
                if k < r.len() && (r[k].t - t).abs() <= MATCH_TOLERANCE {
                    best = match best {
                        Some(b) if (r[b].t - t).abs() <= (r[k].t - t).abs() => Some(b),
                        _ => Some(k),
                    };
                }
            }
            if let Some(k) = best {
                self.add_match(i, k);
            }
        }
    }

    /// One common time: the path length (as `Run::new` measures it) and the turning.
    fn add_match(&mut self, i: usize, k: usize) {
        let p = self.reference[k];
        let total = self.dist.last().copied().unwrap_or(0.0);
        let total = match self.path_anchor {
            None => {
                self.path_anchor = Some((p.x, p.y));
                total
            }
            Some((ax, ay)) => {
                let d = (p.x - ax).hypot(p.y - ay);
                if d >= PATH_STEP {
                    self.path_anchor = Some((p.x, p.y));
                    total + d
                } else {
                    total
                }
            }
        };
        self.matches.push((i, k));
        self.dist.push(total);
        self.follow_turning(i, total);
    }

    /// The odometry's heading change at the initial geometry, summed over steps of
    /// [`TURNING_STEP`] of path, to the left and right apart.
    fn follow_turning(&mut self, i: usize, dist: f64) {
        let Some(integ) = &mut self.turn_integ else {
            self.turn_integ =
                Integrator::new(&self.initial, counts(&self.samples[i]), Pose::default()).ok();
            self.turn_last = (0.0, dist);
            return;
        };
        let from = self.matches[self.matches.len() - 2].0;
        for j in from + 1..=i {
            let s = &self.samples[j];
            let _ = integ.step_pose(counts(s), index_refs(s));
        }
        let h = integ.pose().heading;
        self.turn_h = h;
        if dist - self.turn_last.1 >= TURNING_STEP {
            self.add_turn(h, dist);
        }
    }

    /// The heading change since the last step summed, to the left (negative) or right.
    fn add_turn(&mut self, h: f64, dist: f64) {
        let d = h - self.turn_last.0;
        if d < 0.0 {
            self.turned.0 -= d;
        } else {
            self.turned.1 += d;
        }
        self.turn_last = (h, dist);
    }

    /// Closes the sub-trajectories that a match beyond `length` metres from their start
    /// completes (at the end: the rest), as `run::windows` cuts; each is evaluated at the
    /// estimate. Returns how many.
    fn close_blocks(&mut self, end: bool) -> usize {
        let n = self.matches.len();
        let before = self.blocks.len();
        if n == 0 {
            return 0;
        }
        let last = n - 1;
        loop {
            let a = self.open;
            if a >= last {
                break;
            }
            let limit = self.dist[a] + self.length;
            let b = match (a + 1..n).find(|&k| self.dist[k] > limit) {
                Some(k) => (k - 1).max(a + 1),
                None if end => last,
                None => break,
            };
            if b - a >= MIN_POINTS && self.dist[b] - self.dist[a] >= 0.5 * self.length {
                if let Some(block) = self.evaluate(a, b, None) {
                    self.blocks.push(block);
                    self.add(self.blocks.len() - 1, 1.0);
                }
            }
            self.open = b;
        }
        self.blocks.len() - before
    }

    /// Sub-trajectory `a..=b` evaluated at the estimate, from start heading `guess` (the
    /// reference's first guess when `None`), on a window of the data around it: the
    /// standstill before `a` (its anchor) through `b`.
    fn evaluate(&self, a: usize, b: usize, guess: Option<f64>) -> Option<Block> {
        let c = counts(&self.samples[self.matches[a].0]);
        let still = |k: usize| counts(&self.samples[self.matches[k].0]) == c;
        let mut lo = a;
        while lo > 0 && still(lo - 1) {
            lo -= 1;
        }
        let mut hi = b;
        while hi + 1 < self.matches.len() && still(hi + 1) {
            hi += 1;
        }
        let (s0, r0) = self.matches[lo];
        let (s1, r1) = self.matches[hi];
        let local: Vec<(usize, usize)> = self.matches[lo..=hi]
            .iter()
            .map(|&(i, k)| (i - s0, k - r0))
            .collect();
        let run = Run::new(&self.samples[s0..=s1], &self.reference[r0..=r1], local);
        let (la, lb) = (a - lo, b - lo);
        let guess = guess.unwrap_or_else(|| run.heading_guess(la));
        let params = self.params();
        let mut rows = Vec::new();
        let e = eval_block(
            &run,
            &params,
            (0.0, 0.0),
            &[0, 1, 2],
            (la, lb),
            guess,
            &mut rows,
        )?;
        Some(Block {
            a,
            b,
            x: self.x,
            s: e.s.try_into().ok()?,
            g: e.g.try_into().ok()?,
            heading: e.heading,
        })
    }

    /// Adds (`sign` 1) or removes (-1) block `i`'s linear model from the running sums.
    fn add(&mut self, i: usize, sign: f64) {
        let b = &self.blocks[i];
        for r in 0..3 {
            let sx: f64 = (0..3).map(|c| b.s[r * 3 + c] * b.x[c]).sum();
            self.sum_rhs[r] += sign * (sx - b.g[r]);
        }
        for (t, v) in self.sum_s.iter_mut().zip(&b.s) {
            *t += sign * v;
        }
    }

    /// The columns solved for: both diameters, and the track width once turned enough.
    fn cols(&self) -> Vec<usize> {
        if self.track_estimated() {
            vec![0, 1, 2]
        } else {
            vec![0, 1]
        }
    }

    /// The estimate from the running sums (the held track width's column moved to the right
    /// side), and with `errors` its jackknife standard errors.
    fn solve(&mut self, errors: bool) {
        if self.blocks.len() < 2 {
            return;
        }
        let cols = self.cols();
        let held = [0, 1, 2].into_iter().filter(|c| !cols.contains(c));
        let mut fixed = self.x;
        for h in held {
            fixed[h] = self.initial.track_width;
        }
        let sub = |m: &[f64; 9]| -> Vec<f64> {
            cols.iter()
                .flat_map(|&r| cols.iter().map(move |&c| m[r * 3 + c]))
                .collect()
        };
        let rhs: Vec<f64> = cols
            .iter()
            .map(|&r| {
                self.sum_rhs[r]
                    - (0..3)
                        .filter(|c| !cols.contains(c))
                        .map(|c| self.sum_s[r * 3 + c] * fixed[c])
                        .sum::<f64>()
            })
            .collect();
        let Some(sol) = optim::solve(sub(&self.sum_s), rhs) else {
            return;
        };
        if sol.iter().any(|v| !v.is_finite() || *v <= 0.0) {
            return;
        }
        let mut x = fixed;
        for (&c, v) in cols.iter().zip(sol) {
            x[c] = v;
        }
        self.x = x;
        if !errors {
            return;
        }
        // Each block's gradient at the estimate, for the jackknife.
        let clusters: Vec<(Vec<f64>, Vec<f64>)> = self
            .blocks
            .iter()
            .map(|b| {
                let g: Vec<f64> = cols
                    .iter()
                    .map(|&r| {
                        b.g[r]
                            + (0..3)
                                .map(|c| b.s[r * 3 + c] * (x[c] - b.x[c]))
                                .sum::<f64>()
                    })
                    .collect();
                (sub(&b.s), g)
            })
            .collect();
        let p = cols.len();
        self.se = [None; 3];
        if let Some(cov) = cluster_jackknife(&sub(&self.sum_s), p, &clusters) {
            for (k, &c) in cols.iter().enumerate() {
                let v = cov[k * p + k];
                self.se[c] = (v >= 0.0 && v.is_finite()).then(|| v.sqrt());
            }
        }
    }

    /// Evaluates again, at the estimate, up to `most` sub-trajectories whose linearisation
    /// point is farther than `limit` standard errors from it (the farthest first); returns
    /// how many.
    fn relinearise(&mut self, limit: f64, most: usize) -> usize {
        let scale: [f64; 3] = std::array::from_fn(|i| match self.se[i] {
            Some(se) if se > 0.0 => se,
            _ => 1e-6 * self.x[i],
        });
        let far = |b: &Block| -> f64 {
            (0..3)
                .map(|i| (b.x[i] - self.x[i]).abs() / scale[i])
                .fold(0.0, f64::max)
        };
        let mut stale: Vec<(f64, usize)> = self
            .blocks
            .iter()
            .enumerate()
            .map(|(i, b)| (far(b), i))
            .filter(|(d, _)| *d > limit)
            .collect();
        stale.sort_by(|p, q| q.0.total_cmp(&p.0));
        let mut done = 0;
        for &(_, i) in stale.iter().take(most) {
            let (a, b, h) = (self.blocks[i].a, self.blocks[i].b, self.blocks[i].heading);
            if let Some(new) = self.evaluate(a, b, Some(h)) {
                self.add(i, -1.0);
                self.blocks[i] = new;
                self.add(i, 1.0);
                done += 1;
            }
        }
        self.relinearised += done;
        done
    }

    /// True after [`LiveCalibration::finish`].
    pub fn finished(&self) -> bool {
        self.finished
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::geometry::subtrajectory::{fit_subtrajectories, SubtrajectoryOptions};
    use crate::calib::testing::{run_of, sim};
    use crate::simulate::PathKind;

    /// Feeds a simulated drive in chunks of `chunk` samples (the reference points up to the
    /// chunk's last time with it, as a receiver's arrive), updating after each.
    fn live_of(
        kind: PathKind,
        length: f64,
        seed: u64,
        chunk: usize,
    ) -> (LiveCalibration, crate::simulate::SimRun) {
        let s = sim(kind, length, seed);
        let mut live = LiveCalibration::new(&ChassisParams::DESIGNED, 10.0);
        let mut r = 0;
        for c in s.samples.chunks(chunk) {
            for x in c {
                live.push_sample(*x);
            }
            let t = c.last().unwrap().t;
            while r < s.reference.len() && s.reference[r].t <= t {
                live.push_reference(s.reference[r]);
                r += 1;
            }
            live.update();
        }
        for p in &s.reference[r..] {
            live.push_reference(*p);
        }
        live.finish();
        (live, s)
    }

    /// After the last update, the live estimate is the batch sub-trajectory fit of the same
    /// data to within a tenth of its standard errors, with standard errors within 10 %.
    fn check_equals_batch(kind: PathKind, length: f64, seed: u64, chunk: usize) {
        let (live, s) = live_of(kind, length, seed, chunk);
        let run = run_of(&s);
        assert_eq!(live.matches, run.matches);
        assert_eq!(live.dist, run.dist);
        let batch = fit_subtrajectories(
            &run,
            &ChassisParams::DESIGNED,
            SubtrajectoryOptions::default(),
        )
        .unwrap();
        let e = live.estimate();
        assert_eq!(e.subtrajectories, batch.blocks.len());
        assert_eq!(e.track_estimated, batch.track_estimated);
        let b = [
            batch.params.left_diameter,
            batch.params.right_diameter,
            batch.params.track_width,
        ];
        for (i, &b) in b.iter().enumerate() {
            let Some(se) = batch.std_errors[i] else {
                assert!(e.std_errors[i].is_none());
                continue;
            };
            let d = (e.values[i] - b).abs() / se;
            assert!(
                d < 0.1,
                "unknown {i}: live {} batch {b} se {se}: {d:.3} SE",
                e.values[i]
            );
            let ls = e.std_errors[i].unwrap();
            assert!(
                (ls / se - 1.0).abs() < 0.1,
                "unknown {i}: se live {ls} batch {se}"
            );
        }
    }

    #[test]
    fn live_equals_batch_on_the_estimation_path() {
        check_equals_batch(PathKind::Estimation, 70.0, 1, 50);
    }

    /// The property over drives and chunkings: random paths (seeds), updates after 1 to a
    /// few hundred samples.
    #[test]
    fn live_equals_batch_whatever_the_chunks() {
        for (seed, chunk) in [(2, 1), (3, 7), (4, 97), (5, 333), (6, 50)] {
            check_equals_batch(PathKind::Random, 60.0, seed, chunk);
        }
    }

    /// After the drive, every sub-trajectory's linearisation point is within [`RELINEARISE`]
    /// standard errors of the estimate; during it, relinearisations stay a few per
    /// sub-trajectory (a threshold inside the estimate's wander redoes them all, again and
    /// again).
    #[test]
    fn relinearisation_reaches_the_end_without_chasing_the_estimate() {
        let (live, _) = live_of(PathKind::Random, 300.0, 7, 50);
        let redone = live.relinearised;
        let blocks = live.blocks.len();
        assert!(blocks >= 25, "{blocks} sub-trajectories");
        assert!(
            redone <= 3 * blocks,
            "{redone} relinearisations of {blocks}"
        );
        let se = live.se.map(|v| v.unwrap());
        for b in &live.blocks {
            for ((x, at), se) in live.x.iter().zip(b.x).zip(se) {
                let d = (at - x).abs() / se;
                assert!(d <= RELINEARISE, "block {}..{}: {d} SE", b.a, b.b);
            }
        }
    }

    #[test]
    fn nothing_before_two_subtrajectories() {
        let (live, _) = live_of(PathKind::Estimation, 12.0, 2, 50);
        let e = live.estimate();
        assert!(e.subtrajectories < 2);
        assert_eq!(e.std_errors, [None; 3]);
        assert_eq!(e.values[0], ChassisParams::DESIGNED.left_diameter);
    }
}
