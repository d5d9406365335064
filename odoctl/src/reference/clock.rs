//! The clock of a trajectory reference against the samples' (`record` time): samples' `t` =
//! `s + offset + rate (s - s_mid)` for a stamp `s`, `s_mid` the middle of the trajectory's
//! stamps (so offset and rate are uncorrelated), estimated from the turning both see.
//!
//! The chassis' heading change is linear in the count differences whatever the geometry:
//! `a (n_1 - n_2) + b (n_1 + n_2)` (`a`, `b` from the diameters, track width and resolution).
//! The marker's yaw differs from it by a constant (its mounting and the frame's turn) and by the
//! slip's drift. So:
//!
//! 1. **coarse** ([`coarse_offset`]): the normalised cross-correlation of the two yaw rates
//!    (changes over [`RATE_SPAN`] of the counts `n_1 - n_2` and of the trajectory's unwrapped
//!    yaw, both on a grid of [`GRID`] s, or of a 40,000th of the longer span when that is
//!    coarser) over
//!    every lag at which they overlap by at least half the shorter; the largest |correlation|,
//!    refined by a parabola through its neighbours;
//! 2. **fit** ([`fit`]): least squares of the yaw at each pose against `c_w + a U(t) + b S(t)`,
//!    `U = n_1 - n_2`, `S = n_1 + n_2` interpolated at the mapped instant `t`, `c_w` one constant
//!    per window of [`WINDOW`] m of the trajectory's path (which the slip's drift cannot run far
//!    from), and, on windows that are straights, of the position along the direction of travel
//!    against `d_w + k S(t)` (the marker moves with the chassis there), each kind weighted by
//!    its residuals' RMS (less the windows' constants); over `(a, b, k, offset, rate)` by
//!    Gauss-Newton with the windows' constants eliminated, the offset's and the rate's columns
//!    from the count rates over [`RATE_HALF_SPAN`] either side of each instant; standard
//!    errors by the delete-one-window jackknife (the windows' errors are independent of each
//!    other's, not the poses'). A time shift of a constant
//!    rate is a constant, which the windows' constants absorb: the offset is seen where the
//!    yaw rate (or the speed on a straight) changes within a window.

use anyhow::{bail, Result};

use crate::csvio::Sample;
use crate::optim::solve;

/// The grid of the coarse cross-correlation (s).
pub const GRID: f64 = 0.05;
/// The interval (s) over which the coarse stage takes each yaw change: the rate over 0.5 s, so
/// that a 10 Hz trajectory's yaw noise (differenced pose to pose) does not drown the turning.
pub const RATE_SPAN: f64 = 0.5;
/// Path length of a window of the fit (m).
pub const WINDOW: f64 = 0.5;
/// Fewest windows of the fit.
pub const MIN_WINDOWS: usize = 5;
/// A rate standard error (ppm) above which the fit says that the rate is poorly determined:
/// two quartz clocks (the unit's HSE crystal, a computer's) differ by well under it, so fixing
/// the rate at 0 (`--clock-ppm 0`) errs less than the estimate.
pub const RATE_SE_NOTE: f64 = 100.0;
/// Least |correlation| of the coarse stage.
pub const MIN_CORRELATION: f64 = 0.5;

/// A trajectory's poses as the clock fit uses them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedYaw {
    /// Stamp (s, the reference's clock).
    pub s: f64,
    /// Position (m).
    pub x: f64,
    /// Position (m).
    pub y: f64,
    /// Yaw, unwrapped (rad).
    pub yaw: f64,
}

/// The estimated clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockFit {
    /// Samples' `t` minus stamp at `s_mid` (s).
    pub offset: f64,
    /// Its standard error (s); 0 when given.
    pub offset_se: f64,
    /// Rate of the samples' clock against the stamps, less 1 (ppm).
    pub ppm: f64,
    /// Its standard error (ppm); 0 when given.
    pub ppm_se: f64,
    /// The middle of the trajectory's stamps (s).
    pub s_mid: f64,
    /// The coarse offset (s), when estimated.
    pub coarse: Option<f64>,
    /// Poses of the fit.
    pub points: usize,
    /// Windows.
    pub windows: usize,
    /// Of those, straights (whose along-track positions are compared with the distance counts).
    pub straights: usize,
}

impl ClockFit {
    /// The samples' `t` of stamp `s`.
    pub fn map(&self, s: f64) -> f64 {
        s + self.offset + self.ppm * 1e-6 * (s - self.s_mid)
    }
}

/// Cumulative counts `U = n_1 - n_2`, `S = n_1 + n_2` at time `t` and their rates (per s),
/// linear between samples; `None` outside the samples.
fn counts_at(samples: &[Sample], t: f64, hint: &mut usize) -> Option<[f64; 4]> {
    let n = samples.len();
    if n < 2 || t < samples[0].t || t > samples[n - 1].t {
        return None;
    }
    let mut k = (*hint).min(n - 2);
    while k > 0 && samples[k].t > t {
        k -= 1;
    }
    while k + 2 < n && samples[k + 1].t < t {
        k += 1;
    }
    *hint = k;
    let (a, b) = (&samples[k], &samples[k + 1]);
    let dt = b.t - a.t;
    let w = (t - a.t) / dt;
    let u = |s: &Sample| (s.left - samples[0].left - (s.right - samples[0].right)) as f64;
    let v = |s: &Sample| (s.left - samples[0].left + (s.right - samples[0].right)) as f64;
    Some([
        u(a) + w * (u(b) - u(a)),
        v(a) + w * (v(b) - v(a)),
        (u(b) - u(a)) / dt,
        (v(b) - v(a)) / dt,
    ])
}

/// Half the span (s) over which [`smoothed_rates`] takes the count rates.
pub const RATE_HALF_SPAN: f64 = 0.05;

/// The counts `c` at `t` ([`counts_at`]) with their rates taken over `t +- RATE_HALF_SPAN`
/// (clamped to the samples) instead of between the two samples around `t`. The rates are
/// the fit's sensitivity to a time shift; taken between two samples they jitter by a count
/// per sample interval, and that jitter is correlated with the quantisation error of the
/// interpolated counts at `t`: it would pull the clock towards instants halfway between
/// samples (where interpolation averages the quantisation away), and so bias the rate.
fn smoothed_rates(samples: &[Sample], t: f64, c: [f64; 4], hints: &mut [usize; 2]) -> [f64; 4] {
    let (t0, t1) = (samples[0].t, samples[samples.len() - 1].t);
    let (lo, hi) = ((t - RATE_HALF_SPAN).max(t0), (t + RATE_HALF_SPAN).min(t1));
    match (
        counts_at(samples, lo, &mut hints[0]),
        counts_at(samples, hi, &mut hints[1]),
    ) {
        (Some(a), Some(b)) if hi > lo => [
            c[0],
            c[1],
            (b[0] - a[0]) / (hi - lo),
            (b[1] - a[1]) / (hi - lo),
        ],
        _ => c,
    }
}

/// The yaw (unwrapped, rad) at stamp `s`, linear between poses; `None` outside.
fn yaw_at(poses: &[StampedYaw], s: f64, hint: &mut usize) -> Option<f64> {
    let n = poses.len();
    if n < 2 || s < poses[0].s || s > poses[n - 1].s {
        return None;
    }
    let mut k = (*hint).min(n - 2);
    while k + 2 < n && poses[k + 1].s < s {
        k += 1;
    }
    *hint = k;
    let (a, b) = (&poses[k], &poses[k + 1]);
    Some(a.yaw + (s - a.s) / (b.s - a.s) * (b.yaw - a.yaw))
}

/// The coarse offset (s; samples' `t` - stamp) by the cross-correlation of the yaw rates, with
/// the correlation reached. Fails when the yaw rates do not correlate by [`MIN_CORRELATION`].
pub fn coarse_offset(samples: &[Sample], poses: &[StampedYaw]) -> Result<(f64, f64)> {
    let (t0, t1) = (samples[0].t, samples[samples.len() - 1].t);
    let (s0, s1) = (poses[0].s, poses[poses.len() - 1].s);
    let grid = GRID.max((t1 - t0).max(s1 - s0) / 40_000.0);
    let rates = |n: f64, f: &mut dyn FnMut(f64) -> Option<f64>, start: f64| -> Vec<f64> {
        let vals: Vec<f64> = (0..=n as usize)
            .map(|i| f(start + i as f64 * grid).unwrap_or(f64::NAN))
            .collect();
        let span = ((RATE_SPAN / grid).round() as usize).max(1);
        vals.windows(span + 1)
            .map(|w| {
                let d = w[span] - w[0];
                if d.is_finite() {
                    d
                } else {
                    0.0
                }
            })
            .collect()
    };
    let mut h = 0;
    let u = rates(
        ((t1 - t0) / grid).floor(),
        &mut |t| counts_at(samples, t, &mut h).map(|c| c[0]),
        t0,
    );
    let mut h = 0;
    let v = rates(
        ((s1 - s0) / grid).floor(),
        &mut |s| yaw_at(poses, s, &mut h),
        s0,
    );
    let (n, m) = (u.len() as i64, v.len() as i64);
    let min_overlap = (n.min(m) / 2).max(10);
    let cu: Vec<f64> = prefix_squares(&u);
    let cv: Vec<f64> = prefix_squares(&v);
    let corr = |k: i64| -> f64 {
        // Pairs u[i], v[i - k].
        let (i0, i1) = (k.max(0), n.min(m + k));
        if i1 - i0 < min_overlap {
            return 0.0;
        }
        let sum: f64 = (i0..i1).map(|i| u[i as usize] * v[(i - k) as usize]).sum();
        let eu = cu[i1 as usize] - cu[i0 as usize];
        let ev = cv[(i1 - k) as usize] - cv[(i0 - k) as usize];
        if eu > 0.0 && ev > 0.0 {
            sum / (eu * ev).sqrt()
        } else {
            0.0
        }
    };
    let (best, r) = (-(m - 1)..n)
        .map(|k| (k, corr(k)))
        .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
        .unwrap_or((0, 0.0));
    if r.abs() < MIN_CORRELATION {
        bail!(
            "the yaw rates of the samples and the trajectory do not correlate at any clock offset \
             (best |r| = {:.2}, {MIN_CORRELATION} needed: too little turning, or not the same run); \
             give --time-offset",
            r.abs()
        );
    }
    let (a, c) = (corr(best - 1).abs(), corr(best + 1).abs());
    let denom = a - 2.0 * r.abs() + c;
    let frac = if denom < 0.0 {
        (0.5 * (a - c) / denom).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Ok((t0 - s0 + (best as f64 + frac) * grid, r))
}

fn prefix_squares(v: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(v.len() + 1);
    let mut acc = 0.0;
    out.push(0.0);
    for x in v {
        acc += x * x;
        out.push(acc);
    }
    out
}

/// What [`fit`] holds fixed: the offset (s), the rate (ppm).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ClockFixed {
    /// `--time-offset`.
    pub offset: Option<f64>,
    /// `--clock-ppm`.
    pub ppm: Option<f64>,
}

/// Number of parameters: `(a, b, k, offset, rate)`.
const NP: usize = 5;
const OFFSET: usize = 3;
const RATE: usize = 4;

/// One window's rows: per pose the weighted, demeaned residual and Jacobian columns
/// `(a, b, k, offset, rate)`, the yaw's first, then on a straight the along-track position's.
#[derive(Default)]
struct Rows {
    r: Vec<f64>,
    j: Vec<[f64; NP]>,
    /// Sum of squares of the yaw and the position residuals (unweighted, less the window's
    /// constant), and their counts.
    ss: [f64; 2],
    n: [usize; 2],
}

/// A window of the fit: its poses, and for a straight the direction of travel (unit vector)
/// along which the position is compared with the distance counts.
struct Window {
    poses: std::ops::Range<usize>,
    along: Option<(f64, f64)>,
}

/// Largest yaw change (rad) within a window that counts as a straight: 0.5 degree.
pub const STRAIGHT_YAW: f64 = 0.5 * std::f64::consts::PI / 180.0;

/// Windows of [`WINDOW`] m of path (shorter when the path is short, so that there are at
/// least [`MIN_WINDOWS`]); a window whose yaw stays within [`STRAIGHT_YAW`] and that covers
/// half its length is a straight.
fn windows(poses: &[StampedYaw]) -> Vec<Window> {
    let mut path = vec![0.0];
    for w in poses.windows(2) {
        path.push(path[path.len() - 1] + (w[1].x - w[0].x).hypot(w[1].y - w[0].y));
    }
    let total = path[path.len() - 1];
    let len = WINDOW.min(total / MIN_WINDOWS as f64).max(1e-9);
    let mut out: Vec<Window> = Vec::new();
    let mut start = 0;
    for i in 1..=poses.len() {
        let end_here = i == poses.len() || (path[i] / len).floor() > (path[start] / len).floor();
        if !end_here {
            continue;
        }
        let ps = &poses[start..i];
        let (lo, hi) = ps
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
                (l.min(p.yaw), h.max(p.yaw))
            });
        let (dx, dy) = (ps[ps.len() - 1].x - ps[0].x, ps[ps.len() - 1].y - ps[0].y);
        let d = dx.hypot(dy);
        let along = (hi - lo < STRAIGHT_YAW && d > 0.5 * len).then(|| (dx / d, dy / d));
        out.push(Window {
            poses: start..i,
            along,
        });
        start = i;
    }
    out
}

/// Demeans the rows `from..` of `w` (one group of one window).
fn demean(w: &mut Rows, from: usize) {
    let n = (w.r.len() - from) as f64;
    if n == 0.0 {
        return;
    }
    let m = w.r[from..].iter().sum::<f64>() / n;
    w.r[from..].iter_mut().for_each(|v| *v -= m);
    for c in 0..NP {
        let m = w.j[from..].iter().map(|j| j[c]).sum::<f64>() / n;
        w.j[from..].iter_mut().for_each(|j| j[c] -= m);
    }
}

/// The windows' rows at parameters `p`, the yaw rows weighted by `weight[0]` (1/rad), the
/// position rows by `weight[1]` (1/m).
fn rows(
    samples: &[Sample],
    poses: &[StampedYaw],
    windows: &[Window],
    p: [f64; NP],
    s_mid: f64,
    weight: [f64; 2],
) -> Vec<Rows> {
    let (mut hint, mut hints) = (0, [0, 0]);
    let mut out = Vec::with_capacity(windows.len());
    for win in windows {
        let mut w = Rows::default();
        let mut at = Vec::new();
        for e in &poses[win.poses.clone()] {
            let t = e.s + p[OFFSET] + p[RATE] * (e.s - s_mid);
            if let Some(c) = counts_at(samples, t, &mut hint) {
                at.push((e, smoothed_rates(samples, t, c, &mut hints)));
            }
        }
        for (e, [u, sc, du, ds]) in &at {
            let rate = p[0] * du + p[1] * ds;
            let r = e.yaw - p[0] * u - p[1] * sc;
            w.n[0] += 1;
            w.r.push(weight[0] * r);
            w.j.push([u, sc, &0.0, &rate, &(rate * (e.s - s_mid))].map(|v| weight[0] * v));
        }
        demean(&mut w, 0);
        w.ss[0] = w.r.iter().map(|r| (r / weight[0]).powi(2)).sum();
        if let (Some((ux, uy)), Some((first, _))) = (win.along, at.first()) {
            let from = w.r.len();
            for (e, [_, sc, _, ds]) in &at {
                let xi = (e.x - first.x) * ux + (e.y - first.y) * uy;
                let rate = p[2] * ds;
                let r = xi - p[2] * sc;
                w.n[1] += 1;
                w.r.push(weight[1] * r);
                w.j.push([&0.0, &0.0, sc, &rate, &(rate * (e.s - s_mid))].map(|v| weight[1] * v));
            }
            demean(&mut w, from);
            w.ss[1] = w.r[from..].iter().map(|r| (r / weight[1]).powi(2)).sum();
        }
        out.push(w);
    }
    out
}

/// Normal equations `(H, g)` of the free columns over the windows `ws`.
fn normal(ws: &[&Rows], free: &[usize]) -> (Vec<f64>, Vec<f64>) {
    let n = free.len();
    let (mut h, mut g) = (vec![0.0; n * n], vec![0.0; n]);
    for w in ws {
        for (r, j) in w.r.iter().zip(&w.j) {
            for (a, &ca) in free.iter().enumerate() {
                g[a] += j[ca] * r;
                for (b, &cb) in free.iter().enumerate() {
                    h[a * n + b] += j[ca] * j[cb];
                }
            }
        }
    }
    (h, g)
}

/// Gauss-Newton from `p` over the free parameters (the linear `a, b, k` alone in the first
/// step), to a step below 1e-8 s in the offset and 1e-11 in the rate.
fn gauss_newton(
    samples: &[Sample],
    poses: &[StampedYaw],
    windows: &[Window],
    p: &mut [f64; NP],
    s_mid: f64,
    weight: [f64; 2],
    free: &[usize],
) -> Result<()> {
    for it in 0..30 {
        let f: Vec<usize> = if it == 0 {
            free.iter().copied().filter(|c| *c < OFFSET).collect()
        } else {
            free.to_vec()
        };
        let ws = rows(samples, poses, windows, *p, s_mid, weight);
        let refs: Vec<&Rows> = ws.iter().collect();
        let (h, gr) = normal(&refs, &f);
        let Some(step) = scaled_solve(&h, &gr, f.len()) else {
            bail!("the clock fit is singular (no turning or straight seen by both); give --time-offset");
        };
        for (k, &c) in f.iter().enumerate() {
            p[c] += step[k];
        }
        let dt = f
            .iter()
            .zip(&step)
            .map(|(c, d)| match *c {
                OFFSET => d.abs(),
                RATE => d.abs() * 1e3,
                _ => 0.0,
            })
            .fold(0.0, f64::max);
        if it >= 1 && dt < 1e-8 {
            break;
        }
    }
    Ok(())
}

/// The clock fit (see the module), from the coarse offset `coarse` (s) unless the offset is
/// fixed. The yaw and the along-track rows are weighted by their own residuals' RMS, found
/// in two passes from 1 mrad and 1 mm.
pub fn fit(
    samples: &[Sample],
    poses: &[StampedYaw],
    fixed: ClockFixed,
    coarse: f64,
) -> Result<ClockFit> {
    let s_mid = 0.5 * (poses[0].s + poses[poses.len() - 1].s);
    let windows = windows(poses);
    if windows.len() < MIN_WINDOWS {
        bail!("the trajectory's path is too short for the clock fit; give --time-offset and --clock-ppm");
    }
    let straights = windows.iter().filter(|w| w.along.is_some()).count();
    let mut free = vec![0, 1];
    if straights > 0 {
        free.push(2);
    }
    if fixed.offset.is_none() {
        free.push(OFFSET);
    }
    if fixed.ppm.is_none() {
        free.push(RATE);
    }
    let mut p = [
        0.0,
        0.0,
        0.0,
        fixed.offset.unwrap_or(coarse),
        fixed.ppm.unwrap_or(0.0) * 1e-6,
    ];
    let mut weight = [1e3, 1e3];
    for _ in 0..3 {
        gauss_newton(samples, poses, &windows, &mut p, s_mid, weight, &free)?;
        let ws = rows(samples, poses, &windows, p, s_mid, weight);
        for (g, wg) in weight.iter_mut().enumerate() {
            let ss: f64 = ws.iter().map(|w| w.ss[g]).sum();
            let n: usize = ws.iter().map(|w| w.n[g]).sum();
            if n > 0 && ss > 0.0 {
                *wg = (n as f64 / ss).sqrt();
            }
        }
    }
    let ws = rows(samples, poses, &windows, p, s_mid, weight);
    let refs: Vec<&Rows> = ws.iter().filter(|w| !w.r.is_empty()).collect();
    let points = refs.iter().map(|w| w.n[0]).sum();
    let (offset_se, ppm_se) = jackknife(&refs, &free);
    Ok(ClockFit {
        offset: p[OFFSET],
        offset_se,
        ppm: p[RATE] * 1e6,
        ppm_se: ppm_se * 1e6,
        s_mid,
        coarse: fixed.offset.is_none().then_some(coarse),
        points,
        windows: refs.len(),
        straights,
    })
}

/// Solves the normal equations with the columns scaled to unit diagonal.
fn scaled_solve(h: &[f64], g: &[f64], n: usize) -> Option<Vec<f64>> {
    let d: Vec<f64> = (0..n).map(|i| h[i * n + i].sqrt().max(1e-300)).collect();
    let hs: Vec<f64> = (0..n * n).map(|k| h[k] / (d[k / n] * d[k % n])).collect();
    let gs: Vec<f64> = (0..n).map(|i| g[i] / d[i]).collect();
    solve(hs, gs).map(|x| x.iter().zip(&d).map(|(x, d)| x / d).collect())
}

/// Standard errors of the offset and the rate (0 when fixed) by the linearised
/// delete-one-window jackknife `(G-1)/G sum_c (d_c - mean d)^2`, `d_c = (H - H_c)^-1 g_c`.
fn jackknife(ws: &[&Rows], free: &[usize]) -> (f64, f64) {
    let n = free.len();
    let (h, _) = normal(ws, free);
    let ds: Vec<Vec<f64>> = ws
        .iter()
        .filter_map(|w| {
            let (hc, gc) = normal(&[*w], free);
            let hm: Vec<f64> = h.iter().zip(&hc).map(|(a, b)| a - b).collect();
            scaled_solve(&hm, &gc, n)
        })
        .collect();
    let gn = ds.len() as f64;
    let se = |c: usize| -> f64 {
        let Some(k) = free.iter().position(|&f| f == c) else {
            return 0.0;
        };
        let mean = ds.iter().map(|d| d[k]).sum::<f64>() / gn;
        ((gn - 1.0) / gn * ds.iter().map(|d| (d[k] - mean).powi(2)).sum::<f64>()).sqrt()
    };
    (se(OFFSET), se(RATE))
}

/// The clock of a trajectory against the samples: the coarse offset unless given, then the
/// fit. `poses` need at least two.
pub fn estimate(samples: &[Sample], poses: &[StampedYaw], fixed: ClockFixed) -> Result<ClockFit> {
    if samples.len() < 2 || poses.len() < 2 {
        bail!("too few samples or poses for the clock fit");
    }
    let coarse = match fixed.offset {
        Some(o) => o,
        None => coarse_offset(samples, poses)?.0,
    };
    fit(samples, poses, fixed, coarse)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::Rng;

    /// A run turning left and right in turns: counts at 50 Hz, poses at 100 Hz on a clock with
    /// `offset`, `ppm`, yaw noise `sigma`.
    fn run(offset: f64, ppm: f64, sigma: f64, seed: u64) -> (Vec<Sample>, Vec<StampedYaw>) {
        let mut rng = Rng::new(seed);
        // Turns of random rate and length between straights, not periodic.
        let mut turns = Vec::new();
        let mut end = 0.0;
        while end < 700.0 {
            end += 2.0 + 6.0 * rng.uniform();
            let w = if turns.len() % 2 == 0 {
                0.0
            } else {
                2.0 * rng.uniform() - 1.0
            };
            turns.push((end, w));
        }
        let rate = |t: f64| turns.iter().find(|(e, _)| t < *e).map_or(0.0, |(_, w)| *w);
        let mut samples = Vec::new();
        let mut poses = Vec::new();
        let (mut l, mut r) = (0.0f64, 0.0f64);
        // Yaw: the integral of the rate, counter-clockwise (the counts turn the other way).
        let (mut yaw, mut x) = (1.0, 0.0);
        let dt = 1e-4;
        let s_mid = (0.5 + 590.0) / 2.0 - offset;
        for i in 0..6_000_000u64 {
            let t = i as f64 * dt;
            if i % 200 == 0 {
                samples.push(Sample {
                    t,
                    left: l.round() as i64,
                    right: r.round() as i64,
                    left_index: None,
                    right_index: None,
                    flags: None,
                    unit: None,
                });
            }
            if i % 100 == 0 && (5_000..=5_900_000).contains(&i) {
                // t = s + offset + r (s - s_mid)
                let s = (t - offset + ppm * 1e-6 * s_mid) / (1.0 + ppm * 1e-6);
                poses.push(StampedYaw {
                    s,
                    x,
                    y: 0.0,
                    yaw: yaw + sigma * rng.normal(),
                });
            }
            // 0.5 m/s, 0.6 m track, 5000 ticks per metre.
            let w = rate(t + 0.5 * dt);
            l += (0.5 + 0.3 * w) * dt * 5000.0;
            r += (0.5 - 0.3 * w) * dt * 5000.0;
            yaw -= w * dt;
            x += 0.5 * dt;
        }
        (samples, poses)
    }

    #[test]
    fn offset_and_rate_recovered_within_their_standard_errors() {
        let (mut zo, mut zr) = (0.0f64, 0.0f64);
        for seed in 1..=4 {
            let (offset, ppm) = (1.7e9 + seed as f64 * 3.21, 40.0 * seed as f64 - 90.0);
            let (samples, poses) = run(-offset, ppm, 0.002, seed);
            let f = estimate(&samples, &poses, ClockFixed::default()).unwrap();
            let truth_offset = -offset;
            eprintln!("{f:?}");
            assert!(f.offset_se > 0.0 && f.offset_se < 1e-3, "{f:?}");
            zo = zo.max(((f.offset - truth_offset) / f.offset_se).abs());
            zr = zr.max(((f.ppm - ppm) / f.ppm_se).abs());
        }
        assert!(zo < 3.5 && zr < 3.5, "{zo} {zr}");
        // Fixed offset: only the rate is fitted.
        let (samples, poses) = run(-5.0, 20.0, 0.002, 9);
        let f = estimate(
            &samples,
            &poses,
            ClockFixed {
                offset: Some(-5.0),
                ppm: None,
            },
        )
        .unwrap();
        assert_eq!((f.offset, f.offset_se, f.coarse), (-5.0, 0.0, None));
        assert!((f.ppm - 20.0).abs() < 4.0 * f.ppm_se, "{f:?}");
    }

    #[test]
    fn no_turning_is_an_error() {
        let (samples, mut poses) = run(0.0, 0.0, 0.0, 1);
        for p in &mut poses {
            p.yaw = 0.0;
        }
        let e = estimate(&samples, &poses, ClockFixed::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("do not correlate"), "{e}");
    }
}
