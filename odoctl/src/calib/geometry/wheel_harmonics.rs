//! The per-angle wheel function (eqs 3-5): the Fourier coefficients `left_cos1..N`,
//! `left_sin1..N`, `right_cos1..N`, `right_sin1..N` of each wheel's relative radius,
//! referenced to its index line, estimated against the reference after the geometry fit.
//!
//! # Method
//! A second stage after the geometry fit. The run is cut into consecutive segments of
//! `segment` metres of reference path; each is restarted from the reference (position =
//! [`Run::anchor`], heading = the one minimising eq (16) over it), so the heading drift of
//! slip never accumulates beyond one segment. On each segment the odometry residuals
//! `r = p_odo - p_ref` are modelled as linear in the coefficients `c`, in corrections of the
//! two diameters and the track width (shared by all segments), and in three nuisance
//! unknowns of the segment (a start offset in x and y and a start-heading change, whose
//! derivatives are `(1, 0)`, `(0, 1)` and `(y - y0, -(x - x0))`). The whole run is one
//! linear least-squares problem with the nuisances eliminated per segment (a Schur
//! complement); two Gauss-Newton passes. The columns are the core integrator's own
//! response (forward differences of the positions it integrates, with the index latches of
//! the SAMPLES), so the coefficients are the ones the firmware applies.
//!
//! Why a second stage, and why the geometry corrections in it: an eccentric wheel's
//! distance error is a bounded, zero-mean periodic function of its angle (0.1 mm for a
//! 0.1 mm eccentricity), while the diameters and the track act through distance and
//! heading growing along the run, so the two sets are nearly orthogonal and the geometry
//! fit (whichever estimator `calibrate` uses) is left as it is: the geometry written is its
//! result. But the geometry's own error (millimetres on a long run with eq 16 over the
//! whole run) leaves centimetres of residual per segment, which swamps a 0.1 mm signal;
//! refitted here as shared unknowns, it cannot (on a 3 km run: standard error 0.027 mm of
//! radius with them, 0.07 mm without). Their corrections are not reported.
//!
//! Standard errors: cluster-robust (a sandwich over the `G` segments,
//! `A^-1 (sum_s u_s u_s^T) A^-1 G/(G-n)`, `u_s` a segment's score at the estimate, `n` the
//! global unknowns: the scores' average leverage is `n/G`), since the residuals within a
//! segment are correlated by slip; the independent-residual `s^2 A^-1` is kept alongside.
//! The precision is set by the reference noise: about `sigma_ref / sqrt(points)` per
//! coefficient in radius, 0.027 mm over 3 km at 8 mm RTK noise and 50 Hz.

use anyhow::{anyhow, bail, Result};
use odo_unit::odometry::params::HARMONIC_KEYS;
use odo_unit::odometry::{ChassisParams, WheelHarmonics, WHEEL_HARMONICS};

use crate::calib::heading_fit::fit_restart_heading;
use crate::calib::pipeline::cores;
use crate::calib::run::{windows, Run};
use crate::optim;

/// Default segment length of the harmonics fit (m of reference path): about six turns of a
/// 0.26 m wheel, long enough that a harmonic is not confused with a segment's offset and
/// rotation, short enough that slip adds only millimetres of drift.
pub const HARMONICS_SEGMENT: f64 = 5.0;

/// Step of the forward differences in a coefficient (relative radius).
const STEP: f64 = 1e-3;

/// Step of the forward differences in a diameter or the track width (m).
const GEOMETRY_STEP: f64 = 1e-5;

/// Fraction of the common times at which both wheels' index latches must be known.
const MIN_INDEXED: f64 = 0.5;

/// Result of [`fit_harmonics`].
#[derive(Debug, Clone)]
pub struct HarmonicsFit {
    /// Harmonics fitted per wheel (1..=3).
    pub order: usize,
    /// The parameters with the fitted coefficients (the others as given).
    pub params: ChassisParams,
    /// The fitted keys (`left_cos1`, `left_sin1`, `left_cos2`, ..., `right_...`).
    pub keys: Vec<&'static str>,
    /// Their estimates (relative radius).
    pub values: Vec<f64>,
    /// Their cluster-robust standard errors.
    pub std_errors: Vec<f64>,
    /// Their standard errors for independent residuals (`s^2 A^-1`), for comparison.
    pub std_errors_iid: Vec<f64>,
    /// Segments used.
    pub segments: usize,
    /// Common times used (after each segment's start).
    pub points: usize,
    /// Segment length (m).
    pub segment: f64,
    /// Residual RMS per axis at the estimate (m).
    pub residual_sigma: f64,
}

/// The fitted coefficients in order: for each wheel (left, right), for each harmonic
/// `h = 1..=order`, cos then sin. Returns (wheel, is_sin, h - 1).
fn layout(order: usize) -> Vec<(usize, usize, usize)> {
    (0..2)
        .flat_map(|w| (0..order).flat_map(move |h| [(w, 0, h), (w, 1, h)]))
        .collect()
}

fn coefficient(p: &ChassisParams, (w, s, h): (usize, usize, usize)) -> f32 {
    let wheel = if w == 0 {
        &p.left_wheel
    } else {
        &p.right_wheel
    };
    if s == 0 {
        wheel.cos[h]
    } else {
        wheel.sin[h]
    }
}

fn set_coefficient(p: &mut ChassisParams, (w, s, h): (usize, usize, usize), v: f32) {
    let wheel: &mut WheelHarmonics = if w == 0 {
        &mut p.left_wheel
    } else {
        &mut p.right_wheel
    };
    if s == 0 {
        wheel.cos[h] = v;
    } else {
        wheel.sin[h] = v;
    }
}

/// One segment's normal equations with its nuisances eliminated.
struct SegmentEquations {
    /// `H^T P H` (n x n, n global unknowns).
    a: Vec<f64>,
    /// `H^T P r` (n).
    g: Vec<f64>,
    /// `r^T P r`.
    rr: f64,
    /// Residual components.
    m: usize,
}

/// Estimates the first `order` harmonics of both wheels' functions (see the module) about
/// the geometry of `params` (the higher harmonics held at theirs), from the full-run start
/// heading `heading0`, on segments of `segment` metres.
pub fn fit_harmonics(
    run: &Run,
    params: &ChassisParams,
    heading0: f64,
    order: usize,
    segment: f64,
) -> Result<HarmonicsFit> {
    if !(1..=WHEEL_HARMONICS).contains(&order) {
        bail!("--wheel-harmonics {order}: must be 1..={WHEEL_HARMONICS}");
    }
    if segment.is_nan() || segment <= 0.0 {
        bail!("--harmonics-window {segment}: must be positive metres");
    }
    let indexed = run
        .matches
        .iter()
        .filter(|&&(s, _)| {
            let s = &run.samples[s];
            s.left_index.is_some() && s.right_index.is_some()
        })
        .count();
    if (indexed as f64) < MIN_INDEXED * run.len() as f64 {
        bail!(
            "--wheel-harmonics needs the index latches (left_index, right_index columns of SAMPLES): both wheels' are known at {indexed} of {} common times (at least {:.0} % wanted)",
            run.len(),
            100.0 * MIN_INDEXED
        );
    }
    let segs = windows(run, segment, 10);
    if segs.len() < 2 {
        bail!("the run is too short for the harmonics fit (fewer than 2 segments of {segment} m)");
    }
    let cols = layout(order);
    let q = cols.len();
    // The global unknowns: the q coefficients, then corrections of the three geometry
    // parameters (refitted alongside, so that an error of the geometry estimate cannot leak
    // into the coefficients; not reported).
    let n = q + 3;
    let mut p = *params;
    let mut result = None;
    for _pass in 0..2 {
        let eqs = segment_equations(run, &p, heading0, &segs, &cols)?;
        let (mut a, mut g) = (vec![0.0; n * n], vec![0.0; n]);
        for e in &eqs {
            a.iter_mut().zip(&e.a).for_each(|(x, y)| *x += y);
            g.iter_mut().zip(&e.g).for_each(|(x, y)| *x += y);
        }
        let step = optim::solve(a.clone(), g.iter().map(|v| -v).collect()).ok_or_else(|| {
            anyhow!("the harmonics are not determined by this run (singular normal matrix)")
        })?;
        let inv = inverse(&a, n)?;
        // Scores at the solution and the residual sum of squares.
        let mut meat = vec![0.0; n * n];
        let (mut rss, mut m) = (0.0, 0usize);
        for e in &eqs {
            let u: Vec<f64> = (0..n)
                .map(|i| e.g[i] + (0..n).map(|j| e.a[i * n + j] * step[j]).sum::<f64>())
                .collect();
            for i in 0..n {
                for j in 0..n {
                    meat[i * n + j] += u[i] * u[j];
                }
            }
            let quad: f64 = (0..n)
                .map(|i| {
                    step[i] * (2.0 * e.g[i] + (0..n).map(|j| e.a[i * n + j] * step[j]).sum::<f64>())
                })
                .sum();
            rss += e.rr + quad;
            m += e.m;
        }
        let groups = eqs.len() as f64;
        let dof = m.saturating_sub(n + 3 * eqs.len()).max(1) as f64;
        let s2 = rss.max(0.0) / dof;
        let sandwich = mul(&mul(&inv, &meat, n), &inv, n);
        // The scores' average leverage is n / G: the meat is that much too small.
        let small = groups / (groups - n as f64).max(1.0);
        let mut values = Vec::with_capacity(q);
        for (i, &c) in cols.iter().enumerate() {
            let v = f64::from(coefficient(&p, c)) + step[i];
            if v.is_nan() || v.abs() > f64::from(ChassisParams::MAX_HARMONIC) {
                bail!(
                    "{}: estimate {v:.3e} outside +-{} (the run does not determine the wheel function)",
                    key(c),
                    ChassisParams::MAX_HARMONIC
                );
            }
            values.push(v);
        }
        for (i, &c) in cols.iter().enumerate() {
            set_coefficient(&mut p, c, values[i] as f32);
        }
        // The next pass linearises at the corrected geometry; the result keeps the given one.
        let mut out = p;
        out.left_diameter = params.left_diameter;
        out.right_diameter = params.right_diameter;
        out.track_width = params.track_width;
        p.left_diameter += step[q];
        p.right_diameter += step[q + 1];
        p.track_width += step[q + 2];
        result = Some(HarmonicsFit {
            order,
            params: out,
            keys: cols.iter().map(|&c| key(c)).collect(),
            values,
            std_errors: (0..q)
                .map(|i| (sandwich[i * n + i] * small).max(0.0).sqrt())
                .collect(),
            std_errors_iid: (0..q)
                .map(|i| (inv[i * n + i] * s2).max(0.0).sqrt())
                .collect(),
            segments: eqs.len(),
            points: m / 2,
            segment,
            residual_sigma: (rss.max(0.0) / m.max(1) as f64).sqrt(),
        });
    }
    result.ok_or_else(|| anyhow!("no pass"))
}

fn key((w, s, h): (usize, usize, usize)) -> &'static str {
    HARMONIC_KEYS[w][s][h]
}

/// The per-segment equations at `p` (restart headings refitted at `p`), over the cores.
fn segment_equations(
    run: &Run,
    p: &ChassisParams,
    heading0: f64,
    segs: &[(usize, usize)],
    cols: &[(usize, usize, usize)],
) -> Result<Vec<SegmentEquations>> {
    p.validate().map_err(|e| anyhow!("parameters: {e}"))?;
    let mut full = Vec::with_capacity(run.len());
    full.push(heading0);
    run.integrate_pose(p, 0, run.len() - 1, heading0, |_, integ| {
        full.push(integ.pose().heading)
    })
    .map_err(|e| anyhow!("parameters: {e}"))?;
    // The perturbed parameter sets and their actual steps (the coefficients are f32), then
    // the geometry's.
    let mut perturbed: Vec<(ChassisParams, f64)> = cols
        .iter()
        .map(|&c| {
            let mut q = *p;
            let v0 = coefficient(p, c);
            let v1 = (f64::from(v0) + STEP) as f32;
            set_coefficient(&mut q, c, v1);
            (q, f64::from(v1) - f64::from(v0))
        })
        .collect();
    for i in 0..3 {
        let mut q = *p;
        let (v0, v1) = match i {
            0 => (q.left_diameter, q.left_diameter + GEOMETRY_STEP),
            1 => (q.right_diameter, q.right_diameter + GEOMETRY_STEP),
            _ => (q.track_width, q.track_width + GEOMETRY_STEP),
        };
        *[
            &mut q.left_diameter,
            &mut q.right_diameter,
            &mut q.track_width,
        ][i] = v1;
        perturbed.push((q, v1 - v0));
    }
    let threads = cores().min(segs.len()).max(1);
    let chunk = segs.len().div_ceil(threads);
    std::thread::scope(|scope| {
        let jobs: Vec<_> = segs
            .chunks(chunk)
            .map(|part| {
                let (full, perturbed) = (&full, &perturbed);
                scope.spawn(move || {
                    part.iter()
                        .map(|&(a, b)| segment(run, p, perturbed, a, b, full[a]))
                        .collect::<Result<Vec<_>>>()
                })
            })
            .collect();
        jobs.into_iter()
            .map(|j| j.join().expect("harmonics segment panicked"))
            .collect::<Result<Vec<Vec<_>>>>()
    })
    .map(|v| v.into_iter().flatten().collect())
}

/// The equations of segment `a..=b`.
fn segment(
    run: &Run,
    p: &ChassisParams,
    perturbed: &[(ChassisParams, f64)],
    a: usize,
    b: usize,
    guess: f64,
) -> Result<SegmentEquations> {
    let heading = fit_restart_heading(run, p, a, b, guess)?;
    let positions = |params: &ChassisParams| -> Result<Vec<(f64, f64)>> {
        let mut v = Vec::with_capacity(b - a);
        run.integrate_pose(params, a, b, heading, |_, integ| {
            let q = integ.pose();
            v.push((q.x, q.y));
        })
        .map_err(|e| anyhow!("parameters: {e}"))?;
        Ok(v)
    };
    let base = positions(p)?;
    let cols: Vec<(Vec<(f64, f64)>, f64)> = perturbed
        .iter()
        .map(|(q, d)| positions(q).map(|v| (v, *d)))
        .collect::<Result<_>>()?;
    let q = cols.len();
    let n = q + 3;
    // Normal matrix of [H N] and its right-hand side.
    let mut mm = vec![0.0; n * n];
    let mut mr = vec![0.0; n];
    let mut rr = 0.0;
    let (x0, y0) = run.anchor(a);
    let mut row = vec![0.0; n];
    for (i, (k, &(x, y))) in (a + 1..=b).zip(base.iter()).enumerate() {
        let r = run.reference_at(k);
        for axis in 0..2 {
            let res = if axis == 0 { x - r.x } else { y - r.y };
            for (j, (v, d)) in cols.iter().enumerate() {
                row[j] = (if axis == 0 { v[i].0 - x } else { v[i].1 - y }) / d;
            }
            row[q] = if axis == 0 { 1.0 } else { 0.0 };
            row[q + 1] = if axis == 0 { 0.0 } else { 1.0 };
            row[q + 2] = if axis == 0 { y - y0 } else { -(x - x0) };
            for u in 0..n {
                mr[u] += row[u] * res;
                for w in u..n {
                    mm[u * n + w] += row[u] * row[w];
                }
            }
            rr += res * res;
        }
    }
    for u in 0..n {
        for w in 0..u {
            mm[u * n + w] = mm[w * n + u];
        }
    }
    // Eliminate the nuisances: A = Hh - Hn Nn^-1 Nh, g = Hr - Hn Nn^-1 Nr.
    let nn: Vec<f64> = (0..3)
        .flat_map(|u| (0..3).map(move |w| (u, w)))
        .map(|(u, w)| mm[(q + u) * n + q + w])
        .collect();
    let nn_inv = inverse(&nn, 3)?;
    let hn = |i: usize, u: usize| mm[i * n + q + u];
    let mut a_s = vec![0.0; q * q];
    let mut g_s = vec![0.0; q];
    // Nn^-1 Nr
    let nr: Vec<f64> = (0..3)
        .map(|u| (0..3).map(|w| nn_inv[u * 3 + w] * mr[q + w]).sum())
        .collect();
    for i in 0..q {
        // Hn Nn^-1 (row i)
        let t: Vec<f64> = (0..3)
            .map(|w| (0..3).map(|u| hn(i, u) * nn_inv[u * 3 + w]).sum())
            .collect();
        for j in 0..q {
            a_s[i * q + j] = mm[i * n + j] - (0..3).map(|w| t[w] * hn(j, w)).sum::<f64>();
        }
        g_s[i] = mr[i] - (0..3).map(|w| hn(i, w) * nr[w]).sum::<f64>();
    }
    let rr = rr - (0..3).map(|u| mr[q + u] * nr[u]).sum::<f64>();
    Ok(SegmentEquations {
        a: a_s,
        g: g_s,
        rr,
        m: 2 * base.len(),
    })
}

/// Inverse of a small `n x n` matrix (row-major).
fn inverse(a: &[f64], n: usize) -> Result<Vec<f64>> {
    let mut inv = vec![0.0; n * n];
    for j in 0..n {
        let mut e = vec![0.0; n];
        e[j] = 1.0;
        let col = optim::solve(a.to_vec(), e).ok_or_else(|| anyhow!("singular normal matrix"))?;
        for i in 0..n {
            inv[i * n + j] = col[i];
        }
    }
    Ok(inv)
}

/// Product of two `n x n` matrices (row-major).
fn mul(a: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i * n + k];
            for j in 0..n {
                c[i * n + j] += aik * b[k * n + j];
            }
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::geometry::paper::{fit_geometry, GeomOptions};
    use crate::calib::testing::run_of;
    use crate::csvio::match_times;
    use crate::simulate::{default_truth, simulate_path, PathKind, SimRun, SimSettings};
    use indicatif::ProgressBar;

    /// The run's geometry fit (from the truth: the second stage is what is tested), then
    /// the harmonics fit of `order`.
    fn fit(sim: &SimRun, order: usize) -> Result<HarmonicsFit> {
        let run = Run::new(
            &sim.samples,
            &sim.reference,
            match_times(&sim.samples, &sim.reference),
        );
        let g = fit_geometry(
            &run,
            &default_truth(),
            run.heading_guess(0),
            0,
            run.len() - 1,
            GeomOptions::default(),
            &ProgressBar::hidden(),
        )?;
        fit_harmonics(&run, &g.params, g.heading0, order, HARMONICS_SEGMENT)
    }

    fn sim(length: f64, seed: u64, truth: ChassisParams) -> SimRun {
        simulate_path(
            PathKind::Random,
            length,
            truth,
            SimSettings {
                seed,
                ..SimSettings::default()
            },
        )
    }

    /// A 0.1 mm first harmonic of the radius on each wheel (left in cos, right in sin),
    /// 3 km, RTK noise 8 mm, slip 0.001: recovered within 3 standard errors, each about
    /// 0.025 mm of radius (docs/CALIBRATION.md).
    #[test]
    #[allow(clippy::needless_range_loop)]
    fn eccentric_wheels_are_recovered() {
        let mut truth = default_truth();
        let (rl, rr) = (truth.left_diameter / 2.0, truth.right_diameter / 2.0);
        truth.left_wheel.cos[0] = (1e-4 / rl) as f32;
        truth.right_wheel.sin[0] = (-1e-4 / rr) as f32;
        let f = fit(&sim(3000.0, 1, truth), 1).unwrap();
        assert_eq!(
            f.keys,
            ["left_cos1", "left_sin1", "right_cos1", "right_sin1"]
        );
        let want = [1e-4 / rl, 0.0, 0.0, -1e-4 / rr];
        for i in 0..4 {
            let (v, se) = (f.values[i], f.std_errors[i]);
            eprintln!(
                "{}: {:.4} mm of radius (truth {:.4}), standard error {:.4} mm",
                f.keys[i],
                1e3 * v * rl,
                1e3 * want[i] * rl,
                1e3 * se * rl
            );
            assert!(
                (v - want[i]).abs() < 3.0 * se,
                "{}: {v} vs {}, se {se}",
                f.keys[i],
                want[i]
            );
            assert!(se * rl < 0.035e-3, "{}: se {se}", f.keys[i]);
        }
        // The fitted coefficients are in the parameters (for the TOML and `config push`).
        assert_eq!(f.params.left_wheel.cos[0], f.values[0] as f32);
        assert_eq!(f.params.right_wheel.sin[0], f.values[3] as f32);
        assert_eq!(f.params.left_wheel.cos[1], 0.0);
    }

    /// Round wheels: every coefficient of three harmonics within 3 of its standard errors of
    /// zero on a 1 km run, and over 8 seeds of 300 m the standard errors hold (about 95 %
    /// within 2, none beyond 4).
    #[test]
    fn round_wheels_give_zero_within_standard_errors() {
        let f = fit(&sim(1000.0, 2, default_truth()), 3).unwrap();
        assert_eq!(f.keys.len(), 12);
        for i in 0..12 {
            assert!(
                f.values[i].abs() < 3.0 * f.std_errors[i],
                "{}: {} se {}",
                f.keys[i],
                f.values[i],
                f.std_errors[i]
            );
        }
        let mut z = Vec::new();
        for seed in 1..=8 {
            let f = fit(&sim(300.0, seed, default_truth()), 3).unwrap();
            z.extend(f.values.iter().zip(&f.std_errors).map(|(v, s)| v / s));
        }
        let within2 = z.iter().filter(|z| z.abs() < 2.0).count() as f64 / z.len() as f64;
        let max = z.iter().fold(0f64, |m, z| m.max(z.abs()));
        eprintln!(
            "{} coefficients: {:.1} % within 2 SE, max |z| {max:.2}",
            z.len(),
            100.0 * within2
        );
        assert!(within2 >= 0.88 && max < 4.0, "{within2} {max}");
    }

    #[test]
    fn a_run_without_index_latches_is_refused() {
        let mut s = sim(60.0, 1, default_truth());
        for x in &mut s.samples {
            x.left_index = None;
        }
        let e = fit(&s, 1).unwrap_err().to_string();
        assert!(e.contains("index latches"), "{e}");
        let s = sim(60.0, 1, default_truth());
        let run = run_of(&s);
        let e = fit_harmonics(&run, &default_truth(), 0.3, 4, 5.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("1..=3"), "{e}");
    }
}
