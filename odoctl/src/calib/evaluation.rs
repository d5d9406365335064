//! Errors and predicted uncertainty along a run (`validate`, and the uncertainty fits).

use anyhow::{anyhow, Result};
use odo_unit::odometry::uncertainty::StepGeometry;
use odo_unit::odometry::{ChassisParams, Integrator, PoseSigma, PoseUncertainty};

use crate::optim::norm2;
use crate::stats::wrap_angle;

use super::run::Run;

/// Errors and predicted uncertainty along a run.
#[derive(Debug, Default)]
pub struct Evaluation {
    /// Match indices evaluated.
    pub k: Vec<usize>,
    /// Times (s).
    pub t: Vec<f64>,
    /// Reference path length from the start (m).
    pub dist: Vec<f64>,
    /// Odometry position (m) of the point the reference measures: the axle centre, or the
    /// antenna with a lever arm ([`Run::observed`]).
    pub odo: Vec<(f64, f64)>,
    /// Reference position (m).
    pub reference: Vec<(f64, f64)>,
    /// Horizontal error |odometry - reference| (m).
    pub horizontal: Vec<f64>,
    /// Predicted horizontal sigma (m).
    pub sigma_h: Vec<f64>,
    /// Odometry heading (rad, cumulative).
    pub heading: Vec<f64>,
    /// Heading error odometry - reference, wrapped to (-pi, pi] (rad), where the reference
    /// has a heading.
    pub heading_err: Vec<Option<f64>>,
    /// Predicted heading sigma (rad).
    pub sigma_heading: Vec<f64>,
    /// Error of the heading change since the stretch's start (rad): `(heading - heading at
    /// the start) - (reference heading - reference heading at the start)`, wrapped to (-pi, pi],
    /// where the reference has a heading; the start's reference heading is averaged over a
    /// standstill there ([`Run::start_heading`]). `sigma_heading` (zero at the start)
    /// predicts exactly this error; the absolute heading error also carries the error of
    /// the fitted start heading.
    pub heading_change_err: Vec<Option<f64>>,
    /// Number of reference headings averaged at the stretch's start.
    pub start_headings: Vec<usize>,
    /// The reference epoch's own horizontal RMS sigma `hypot(sigma_east, sigma_north)` (m),
    /// where its log gives one (GST, `.pos` `sdn`/`sde`, a `sigma_h` column).
    pub reference_sigma_h: Vec<Option<f64>>,
}

impl Clone for Evaluation {
    fn clone(&self) -> Self {
        let mut c = Self::default();
        c.clone_from(self);
        c
    }

    /// Copies every column into `self`'s allocations.
    fn clone_from(&mut self, source: &Self) {
        self.k.clone_from(&source.k);
        self.t.clone_from(&source.t);
        self.dist.clone_from(&source.dist);
        self.odo.clone_from(&source.odo);
        self.reference.clone_from(&source.reference);
        self.horizontal.clone_from(&source.horizontal);
        self.sigma_h.clone_from(&source.sigma_h);
        self.heading.clone_from(&source.heading);
        self.heading_err.clone_from(&source.heading_err);
        self.sigma_heading.clone_from(&source.sigma_heading);
        self.heading_change_err
            .clone_from(&source.heading_change_err);
        self.start_headings.clone_from(&source.start_headings);
        self.reference_sigma_h.clone_from(&source.reference_sigma_h);
    }
}

impl Evaluation {
    /// Empties every column, keeping the allocations.
    pub fn clear(&mut self) {
        let Self {
            k,
            t,
            dist,
            odo,
            reference,
            horizontal,
            sigma_h,
            heading,
            heading_err,
            sigma_heading,
            heading_change_err,
            start_headings,
            reference_sigma_h,
        } = self;
        k.clear();
        t.clear();
        dist.clear();
        odo.clear();
        reference.clear();
        horizontal.clear();
        sigma_h.clear();
        heading.clear();
        heading_err.clear();
        sigma_heading.clear();
        heading_change_err.clear();
        start_headings.clear();
        reference_sigma_h.clear();
    }

    /// Reserves room for `n` more rows in every column.
    pub(crate) fn reserve(&mut self, n: usize) {
        self.k.reserve(n);
        self.t.reserve(n);
        self.dist.reserve(n);
        self.odo.reserve(n);
        self.reference.reserve(n);
        self.horizontal.reserve(n);
        self.sigma_h.reserve(n);
        self.heading.reserve(n);
        self.heading_err.reserve(n);
        self.sigma_heading.reserve(n);
        self.heading_change_err.reserve(n);
        self.start_headings.reserve(n);
        self.reference_sigma_h.reserve(n);
    }

    /// Moves the rows of `other` to the end of `self`.
    pub(crate) fn append(&mut self, other: &mut Self) {
        let Self {
            k,
            t,
            dist,
            odo,
            reference,
            horizontal,
            sigma_h,
            heading,
            heading_err,
            sigma_heading,
            heading_change_err,
            start_headings,
            reference_sigma_h,
        } = other;
        self.k.append(k);
        self.t.append(t);
        self.dist.append(dist);
        self.odo.append(odo);
        self.reference.append(reference);
        self.horizontal.append(horizontal);
        self.sigma_h.append(sigma_h);
        self.heading.append(heading);
        self.heading_err.append(heading_err);
        self.sigma_heading.append(sigma_heading);
        self.heading_change_err.append(heading_change_err);
        self.start_headings.append(start_headings);
        self.reference_sigma_h.append(reference_sigma_h);
    }

    /// Appends the evaluation of matches `a+1..=b` from a restart at `a` (see
    /// [`Run::integrate`]); with `include_start`, the start point itself too (zero error
    /// by construction, zero sigma).
    pub fn extend(
        &mut self,
        run: &Run,
        params: &ChassisParams,
        a: usize,
        b: usize,
        heading0: f64,
        include_start: bool,
    ) -> Result<()> {
        let mut rows = Vec::with_capacity(b - a);
        run.integrate(params, a, b, heading0, |k, integ| {
            rows.push(Row::at(run, k, integ, heading0, integ.sigma()));
        })
        .map_err(|e| anyhow!("parameters: {e}"))?;
        self.extend_rows(run, a, heading0, include_start, rows);
        Ok(())
    }

    /// [`Evaluation::extend`] without the start point, with each integrated sample's step
    /// geometry appended to `record.geometries` and, for each row appended, how many there
    /// are by its match to `record.steps`: what [`UncertaintyRecord::replay`] needs to give
    /// the sigmas at other coefficients.
    pub fn extend_recording(
        &mut self,
        run: &Run,
        params: &ChassisParams,
        (a, b): (usize, usize),
        heading0: f64,
        record: &mut UncertaintyRecord,
    ) -> Result<()> {
        let mut rows = Vec::with_capacity(b - a);
        let UncertaintyRecord {
            geometries,
            steps,
            windows,
        } = record;
        let first = geometries.len();
        run.integrate_geometry(params, (a, b), heading0, geometries, |k, integ, u, n| {
            steps.push(n - first);
            rows.push(Row::at(run, k, integ, heading0, u.sigma()));
        })
        .map_err(|e| anyhow!("parameters: {e}"))?;
        windows.push((rows.len(), geometries.len() - first));
        self.extend_rows(run, a, heading0, false, rows);
        Ok(())
    }

    /// The rows of a restart at `a` with `heading0` appended (the start point first with
    /// `include_start`).
    fn extend_rows(
        &mut self,
        run: &Run,
        a: usize,
        heading0: f64,
        include_start: bool,
        rows: Vec<Row>,
    ) {
        let start = run
            .start_heading(a, |k| rows.get(k - a - 1).map(|r| r.heading - heading0))
            .map(|(h, n)| (heading0, h, n));
        self.reserve(rows.len() + usize::from(include_start));
        if include_start {
            self.push(run, a, run.anchor(a), heading0, 0.0, 0.0, start);
        }
        for r in rows {
            self.push(
                run,
                r.k,
                r.odo,
                r.heading,
                r.sigma_h,
                r.sigma_heading,
                start,
            );
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        run: &Run,
        k: usize,
        odo: (f64, f64),
        heading: f64,
        sigma_h: f64,
        sigma_heading: f64,
        start: Option<(f64, f64, usize)>,
    ) {
        let r = run.reference_at(k);
        let change = match (start, r.heading) {
            (Some((h0, r0, n)), Some(rh)) => {
                self.start_headings.push(n);
                Some(wrap_angle((heading - h0) - wrap_angle(rh - r0)))
            }
            _ => {
                self.start_headings.push(0);
                None
            }
        };
        self.heading_change_err.push(change);
        self.k.push(k);
        self.t.push(r.t);
        self.dist.push(run.dist[k]);
        self.odo.push(odo);
        self.reference.push((r.x, r.y));
        self.horizontal.push(norm2(odo.0 - r.x, odo.1 - r.y));
        self.sigma_h.push(sigma_h);
        self.heading.push(heading);
        self.heading_err
            .push(r.heading.map(|h| wrap_angle(heading - h)));
        self.sigma_heading.push(sigma_heading);
        self.reference_sigma_h.push(r.sigma_h);
    }

    /// The heading errors and sigmas where the reference has a heading.
    pub fn heading_pairs(&self) -> (Vec<f64>, Vec<f64>) {
        self.heading_err
            .iter()
            .zip(&self.sigma_heading)
            .filter_map(|(e, s)| e.map(|e| (e, *s)))
            .unzip()
    }
}

/// One match's row as the integration leaves it.
struct Row {
    k: usize,
    odo: (f64, f64),
    heading: f64,
    sigma_h: f64,
    sigma_heading: f64,
}

impl Row {
    /// The row of match `k` of `run`, restarted with `heading0`, at `integ`'s pose and the
    /// uncertainty `sigma`.
    fn at(run: &Run, k: usize, integ: &Integrator, heading0: f64, sigma: PoseSigma) -> Self {
        let p = integ.pose();
        Self {
            k,
            odo: run.observed(&p, heading0),
            heading: p.heading,
            sigma_h: f64::from(sigma.horizontal()),
            sigma_heading: f64::from(sigma.heading),
        }
    }
}

/// The step geometries of restarted stretches evaluated one after the other
/// ([`Evaluation::extend_recording`]): the sigmas of their evaluation at any other
/// coefficients, bit for bit, without integrating the pose again ([`UncertaintyRecord::replay`]).
#[derive(Debug, Clone, Default)]
pub struct UncertaintyRecord {
    /// Every integrated sample's geometry, stretch after stretch.
    geometries: Vec<StepGeometry>,
    /// For each row, the geometries of its stretch up to its match.
    steps: Vec<usize>,
    /// For each stretch, its rows and its geometries.
    windows: Vec<(usize, usize)>,
}

impl UncertaintyRecord {
    /// Reserves room for `samples` more geometries and `rows` more rows.
    pub fn reserve(&mut self, samples: usize, rows: usize) {
        self.geometries.reserve_exact(samples);
        self.steps.reserve_exact(rows);
    }

    /// The rows recorded.
    pub fn rows(&self) -> usize {
        self.steps.len()
    }

    /// The horizontal and heading sigmas (m, rad) of every recorded row at the coefficients of
    /// `params` (validated; its geometry that of the recording), into `sigma_h` and
    /// `sigma_heading` ([`UncertaintyRecord::rows`] long).
    pub fn replay(&self, params: &ChassisParams, sigma_h: &mut [f64], sigma_heading: &mut [f64]) {
        self.replay_rows(
            params,
            |_| true,
            |i, (h, a)| {
                (sigma_h[i], sigma_heading[i]) = (h, a);
            },
        );
    }

    /// The horizontal and heading sigmas (m, rad) of [`UncertaintyRecord::replay`] at the rows
    /// `wanted` picks (this record's row indices), `visit(row, (sigma_h, sigma_heading))` in
    /// the order of the rows: only the stretches holding a picked row are replayed, each up
    /// to its last one.
    pub fn replay_rows(
        &self,
        params: &ChassisParams,
        wanted: impl Fn(usize) -> bool,
        mut visit: impl FnMut(usize, (f64, f64)),
    ) {
        let (mut g, mut r) = (0, 0);
        for &(rows, geometries) in &self.windows {
            if let Some(last) = (r..r + rows).rev().find(|&i| wanted(i)) {
                let stretch = &self.geometries[g..g + geometries];
                let mut uncertainty = PoseUncertainty::new(params);
                let mut done = 0;
                for i in r..=last {
                    for step in &stretch[done..self.steps[i]] {
                        uncertainty.step(step);
                    }
                    done = self.steps[i];
                    if wanted(i) {
                        let s = uncertainty.sigma();
                        visit(i, (f64::from(s.horizontal()), f64::from(s.heading)));
                    }
                }
            }
            (g, r) = (g + geometries, r + rows);
        }
    }
}

/// Evaluation of the whole run from match 0.
pub fn evaluate(run: &Run, params: &ChassisParams, heading0: f64) -> Result<Evaluation> {
    let mut ev = Evaluation::default();
    ev.extend(run, params, 0, run.len() - 1, heading0, true)?;
    Ok(ev)
}
