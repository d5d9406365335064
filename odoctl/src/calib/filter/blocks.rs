//! The Kalman filter's transition composed over the steps between two observations: the
//! likelihood needs the state only where the reference observes it, so the many small steps
//! of the odometry (5 cm) are multiplied out once into one transition and one noise per block,
//! and each score of the likelihood runs over the blocks.
//!
//! State (`innovations`): the pose error `(dx, dy, dalpha)`, the geometry's relative errors
//! `(c_1, c_2, b)`, the two wheels' Gauss-Markov slip rates and the opposite-phase one. A step
//! moves the pose error by `T_k = I + m_k e_3^T` (the chord turned by a heading error) plus
//! `B_k` times the other states; the geometry is constant, a Gauss-Markov rate decays by
//! `rho_k = exp(-l_k / L)` over its step length `l_k`. All `T_k` commute (`e_3^T m = 0`), so the
//! pose's transition from step `k` to the block's end is `M_k = I + R_k e_3^T` with `R_k` the
//! sum of the later `m_i`: the geometry's columns and the white slip's noise compose without
//! any slip parameter ([`Composed::new`]); a Gauss-Markov state's column and noise depend on
//! its correlation length and are composed for one length at a time ([`Composed::gauss_markov`],
//! per unit of kappa).

// 3x3 and 4x4 matrix arithmetic reads best by index.
#![allow(clippy::needless_range_loop)]

use crate::calib::pipeline::cores;

/// Symmetric 3x3 (pose) matrix.
pub type Mat3 = [[f64; 3]; 3];

/// One step's linearised motion.
#[derive(Debug, Clone, Copy, Default)]
pub struct StepTerms {
    /// Position change (x, y; m) per heading error (rad) at the step's start.
    pub m: [f64; 2],
    /// Pose change (x, y: m; heading: rad) per unit relative distance error of wheel 1 and 2.
    pub wheel: [[f64; 3]; 2],
    /// Pose change per unit opposite-phase slip rate (wheel 1 `+e`, wheel 2 `-e`, per metre of
    /// `|s_1 - s_2|`).
    pub turn: [f64; 3],
    /// Pose change per unit relative track-width error: `(0, 0, -dalpha)`.
    pub track: [f64; 3],
    /// Pose covariance of white wheel slip per unit kappa (m^2 per m rolled).
    pub qw: Mat3,
    /// Pose covariance of white opposite-phase slip per unit `kappa_diff`.
    pub qt: Mat3,
    /// Distances over which the Gauss-Markov rates decay (m): wheel 1 and 2 rolled,
    /// `|s_1 - s_2|`.
    pub decay: [f64; 3],
}

/// The steps of one block composed, without the Gauss-Markov states.
#[derive(Debug, Clone, Copy)]
pub struct BlockBase {
    /// Position change (x, y; m) per heading error at the block's start.
    pub r: [f64; 2],
    /// Pose change per unit geometry error: `g[row][col]`, rows (x, y, heading), columns
    /// `(c_1, c_2, b)`.
    pub g: Mat3,
    /// Pose covariance of white wheel slip over the block, per unit kappa.
    pub qw: Mat3,
    /// Pose covariance of white opposite-phase slip over the block, per unit `kappa_diff`.
    pub qt: Mat3,
    /// The block's steps (indices into [`Composed`]'s per-step arrays).
    first: usize,
    end: usize,
}

/// One Gauss-Markov state composed over a block, per unit kappa.
#[derive(Debug, Clone, Copy, Default)]
pub struct GaussMarkovBlock {
    /// The transition's column of the state: pose change (x, y, heading) per unit rate at the
    /// block's start, and the rate's decay over the block.
    pub z: [f64; 4],
    /// The block's noise in (x, y, heading, rate), per unit kappa.
    pub q: [[f64; 4]; 4],
}

/// One step of one Gauss-Markov state, as its composition reads it.
#[derive(Debug, Clone, Copy, Default)]
struct RateStep {
    /// `M_k` times the step's column of the rate.
    column: [f64; 3],
    /// The distance over which the rate decays in the step (m).
    decay: f64,
}

/// The run's blocks composed.
#[derive(Debug, Clone, Default)]
pub struct Composed {
    /// One per observation.
    pub blocks: Vec<BlockBase>,
    /// Per Gauss-Markov state (wheel 1's, wheel 2's and the opposite-phase rate), per step.
    rates: [Vec<RateStep>; 3],
}

/// `M v` for `M = I + (r_x, r_y, 0) e_3^T`.
fn carry(r: [f64; 2], v: [f64; 3]) -> [f64; 3] {
    [v[0] + r[0] * v[2], v[1] + r[1] * v[2], v[2]]
}

/// `M q M^T` for `M = I + (r_x, r_y, 0) e_3^T`.
fn carry_cov(r: [f64; 2], q: &Mat3) -> Mat3 {
    let u = [r[0], r[1], 0.0];
    let mut mq = *q;
    for i in 0..3 {
        for j in 0..3 {
            mq[i][j] += u[i] * q[2][j];
        }
    }
    let mut out = mq;
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] += mq[i][2] * u[j];
        }
    }
    out
}

fn add3(a: &mut Mat3, b: &Mat3) {
    for (ra, rb) in a.iter_mut().zip(b) {
        for (x, y) in ra.iter_mut().zip(rb) {
            *x += y;
        }
    }
}

/// Fewest steps [`Composed::new`] spreads over two cores (below, the thread costs about what
/// it saves).
pub const PARALLEL_STEPS: usize = 20_000;

/// The blocks ending at `ends` (the first starting at step `first`) composed from `steps`,
/// each step's rate steps written to `rates[kind][k - first]`.
fn compose(
    steps: &[StepTerms],
    ends: &[usize],
    mut first: usize,
    rates: [&mut [RateStep]; 3],
) -> Vec<BlockBase> {
    let offset = first;
    let mut blocks = Vec::with_capacity(ends.len());
    for &end in ends {
        let mut b = BlockBase {
            r: [0.0; 2],
            g: [[0.0; 3]; 3],
            qw: [[0.0; 3]; 3],
            qt: [[0.0; 3]; 3],
            first,
            end,
        };
        // Backwards: `r` is the sum of the later steps' `m`.
        let mut r = [0.0f64; 2];
        for k in (first..end).rev() {
            let s = &steps[k];
            let cols = [
                carry(r, s.wheel[0]),
                carry(r, s.wheel[1]),
                carry(r, s.track),
            ];
            for (c, col) in cols.iter().enumerate() {
                for (row, v) in col.iter().enumerate() {
                    b.g[row][c] += v;
                }
            }
            add3(&mut b.qw, &carry_cov(r, &s.qw));
            add3(&mut b.qt, &carry_cov(r, &s.qt));
            let columns = [cols[0], cols[1], carry(r, s.turn)];
            for (kind, column) in columns.into_iter().enumerate() {
                rates[kind][k - offset] = RateStep {
                    column,
                    decay: s.decay[kind],
                };
            }
            r[0] += s.m[0];
            r[1] += s.m[1];
        }
        b.r = r;
        blocks.push(b);
        first = end;
    }
    blocks
}

impl Composed {
    /// Composes `steps`; block `i` ends with step `ends[i] - 1` (ends increasing, the last at
    /// most `steps.len()`), where its observation is. The blocks are independent: with two
    /// cores and at least [`PARALLEL_STEPS`] steps, the first half of them is composed on
    /// this thread and the second on another (the same results).
    pub fn new(steps: &[StepTerms], ends: &[usize]) -> Self {
        let mut rates: [Vec<RateStep>; 3] =
            std::array::from_fn(|_| vec![RateStep::default(); steps.len()]);
        let half = ends.len() / 2;
        let blocks = if cores() > 1 && steps.len() >= PARALLEL_STEPS && half > 0 {
            let at = ends[half - 1];
            let [r0, r1, r2] = &mut rates;
            let ((e0, l0), (e1, l1), (e2, l2)) = (
                r0.split_at_mut(at),
                r1.split_at_mut(at),
                r2.split_at_mut(at),
            );
            std::thread::scope(|scope| {
                let second = scope.spawn(|| compose(steps, &ends[half..], at, [l0, l1, l2]));
                let mut blocks = compose(steps, &ends[..half], 0, [e0, e1, e2]);
                blocks.extend(second.join().expect("composing the blocks panicked"));
                blocks
            })
        } else {
            let [r0, r1, r2] = &mut rates;
            compose(steps, ends, 0, [r0, r1, r2])
        };
        Self { blocks, rates }
    }

    /// Gauss-Markov state `kind` (0, 1: wheel 1, 2 slip; 2: opposite-phase) of correlation
    /// length `corr` (m, > 0) and stationary variance `1 / (2 corr)` (per unit kappa)
    /// composed over each block.
    pub fn gauss_markov(&self, kind: usize, corr: f64) -> Vec<GaussMarkovBlock> {
        let rates = &self.rates[kind];
        let (per_length, variance) = (-1.0 / corr, 0.5 / corr);
        self.blocks
            .iter()
            .map(|b| {
                let mut z = [0.0, 0.0, 0.0, 1.0];
                let mut q = [[0.0; 4]; 4];
                for step in rates[b.first..b.end].iter().rev() {
                    let rho = (step.decay * per_length).exp();
                    // The noise entering after the step moves the block's end by `z`.
                    let w = (1.0 - rho * rho) * variance;
                    // The upper triangle; the lower is its mirror.
                    for i in 0..4 {
                        for j in i..4 {
                            q[i][j] += w * z[i] * z[j];
                        }
                    }
                    let c = step.column;
                    z = [
                        c[0] + rho * z[0],
                        c[1] + rho * z[1],
                        c[2] + rho * z[2],
                        rho * z[3],
                    ];
                }
                for i in 1..4 {
                    for j in 0..i {
                        q[i][j] = q[j][i];
                    }
                }
                GaussMarkovBlock { z, q }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Composed on two threads (at least [`PARALLEL_STEPS`] steps) as on one, to the bit.
    #[test]
    fn composed_on_two_threads_is_composed_on_one() {
        let steps: Vec<StepTerms> = (0..PARALLEL_STEPS + 7)
            .map(|i| {
                let x = i as f64 * 1e-3;
                StepTerms {
                    m: [x.sin(), x.cos()],
                    wheel: [[x, 1.0, x.sin()], [x.cos(), 2.0, x]],
                    turn: [x, x * x, 1.0],
                    track: [0.0, 0.0, -x],
                    qw: [[x; 3]; 3],
                    qt: [[1.0, x, 0.5]; 3],
                    decay: [x, 2.0 * x, 1.0],
                }
            })
            .collect();
        let ends: Vec<usize> = (1..=steps.len() / 10).map(|k| 10 * k + k % 3).collect();
        let two = Composed::new(&steps, &ends);
        let mut rates: [Vec<RateStep>; 3] =
            std::array::from_fn(|_| vec![RateStep::default(); steps.len()]);
        let [r0, r1, r2] = &mut rates;
        let one = Composed {
            blocks: compose(&steps, &ends, 0, [r0, r1, r2]),
            rates,
        };
        assert_eq!(format!("{two:?}"), format!("{one:?}"));
    }

    /// The full 9-state transition and noise of one step, as the filter ran it per step
    /// before the composition: `x <- A x`, then the noise.
    fn step_matrices(
        s: &StepTerms,
        corr: [f64; 3],
        unit: [f64; 2],
    ) -> ([[f64; 9]; 9], [[f64; 9]; 9]) {
        let mut a = [[0.0; 9]; 9];
        for (i, row) in a.iter_mut().enumerate() {
            row[i] = 1.0;
        }
        a[0][2] = s.m[0];
        a[1][2] = s.m[1];
        for r in 0..3 {
            a[r][3] = s.wheel[0][r];
            a[r][4] = s.wheel[1][r];
            a[r][5] = s.track[r];
            a[r][6] = s.wheel[0][r];
            a[r][7] = s.wheel[1][r];
            a[r][8] = s.turn[r];
        }
        let mut q = [[0.0; 9]; 9];
        for k in 0..3 {
            let rho = (-s.decay[k] / corr[k]).exp();
            a[6 + k][6 + k] = rho;
            q[6 + k][6 + k] =
                (1.0 - rho * rho) / (2.0 * corr[k]) * if k < 2 { unit[0] } else { unit[1] };
        }
        for r in 0..3 {
            for c in 0..3 {
                q[r][c] = s.qw[r][c] * unit[0] + s.qt[r][c] * unit[1];
            }
        }
        (a, q)
    }

    fn mul(a: &[[f64; 9]; 9], b: &[[f64; 9]; 9]) -> [[f64; 9]; 9] {
        let mut o = [[0.0; 9]; 9];
        for r in 0..9 {
            for c in 0..9 {
                o[r][c] = (0..9).map(|k| a[r][k] * b[k][c]).sum();
            }
        }
        o
    }

    fn transpose(a: &[[f64; 9]; 9]) -> [[f64; 9]; 9] {
        let mut o = [[0.0; 9]; 9];
        for r in 0..9 {
            for c in 0..9 {
                o[r][c] = a[c][r];
            }
        }
        o
    }

    fn random_steps(n: usize, seed: u64) -> Vec<StepTerms> {
        let mut rng = odo_testkit::Rng::new(seed);
        let mut u = |s: f64| s * (2.0 * rng.uniform() - 1.0);
        (0..n)
            .map(|_| {
                let sym = |u: &mut dyn FnMut(f64) -> f64| {
                    let v = [u(1.0), u(1.0), u(1.0)];
                    let mut m = [[0.0; 3]; 3];
                    for i in 0..3 {
                        for j in 0..3 {
                            m[i][j] = v[i] * v[j];
                        }
                    }
                    m
                };
                StepTerms {
                    m: [u(0.05), u(0.05)],
                    wheel: [[u(0.05), u(0.05), u(0.1)], [u(0.05), u(0.05), u(0.1)]],
                    turn: [u(0.01), u(0.01), u(0.1)],
                    track: [0.0, 0.0, u(0.1)],
                    qw: sym(&mut u),
                    qt: sym(&mut u),
                    decay: [u(0.05).abs(), u(0.05).abs(), u(0.02).abs()],
                }
            })
            .collect()
    }

    #[test]
    fn a_composed_block_is_the_product_of_its_steps() {
        // Blocks of 1, 2 and 7 steps; slip correlation lengths from much shorter to much
        // longer than a step; the composed transition's columns and noise against the
        // product of the per-step 9x9 matrices (`P <- A P A^T + Q` from zero).
        let steps = random_steps(10, 7);
        let ends = [1, 3, 10];
        let composed = Composed::new(&steps, &ends);
        let unit = [1.0, 1.0];
        for corr in [[0.01, 0.3, 0.002], [5.0, 0.05, 20.0]] {
            let gm: Vec<Vec<GaussMarkovBlock>> =
                (0..3).map(|k| composed.gauss_markov(k, corr[k])).collect();
            let mut first = 0;
            for (b, &end) in ends.iter().enumerate() {
                let mut phi = [[0.0; 9]; 9];
                for (i, row) in phi.iter_mut().enumerate() {
                    row[i] = 1.0;
                }
                let mut p = [[0.0; 9]; 9];
                for s in &steps[first..end] {
                    let (a, q) = step_matrices(s, corr, unit);
                    phi = mul(&a, &phi);
                    p = mul(&mul(&a, &p), &transpose(&a));
                    for r in 0..9 {
                        for c in 0..9 {
                            p[r][c] += q[r][c];
                        }
                    }
                }
                first = end;
                let base = &composed.blocks[b];
                let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * (1.0 + y.abs());
                assert!(close(base.r[0], phi[0][2]) && close(base.r[1], phi[1][2]));
                for r in 0..3 {
                    for c in 0..3 {
                        assert!(close(base.g[r][c], phi[r][3 + c]), "g {r} {c}");
                        // The pose noise: white parts plus the three Gauss-Markov states'.
                        let gm_pose: f64 = (0..3).map(|k| gm[k][b].q[r][c]).sum();
                        assert!(
                            close(base.qw[r][c] + base.qt[r][c] + gm_pose, p[r][c]),
                            "q {r} {c}"
                        );
                    }
                }
                for k in 0..3 {
                    let g = &gm[k][b];
                    for r in 0..3 {
                        assert!(close(g.z[r], phi[r][6 + k]), "z {k} {r}");
                        assert!(close(g.q[r][3], p[r][6 + k]), "q pose-rate {k} {r}");
                    }
                    assert!(close(g.z[3], phi[6 + k][6 + k]));
                    assert!(close(g.q[3][3], p[6 + k][6 + k]));
                }
            }
        }
    }
}
