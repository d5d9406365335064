//! Uncertainty propagation: the paper's model, eqs (19)-(28), and a first-order covariance
//! model (Chong & Kleeman) as an alternative.
//!
//! Both take the partial derivatives of one sample's increments `(dalpha, dx, dy)` with
//! respect to the two wheel distances `s_1`, `s_2` of that sample ([`StepJacobian`]) and
//! with respect to the heading before the sample.
//!
//! Paper model: `sigma_s_i = delta_i * |dGamma_i|` (metres, eq 19 with delta in metres per
//! increment); eq (23) for `sigma_dalpha`; eqs (24)-(25) add `|d(dx)/d(alpha)| *
//! sigma_alpha(t - t0)` linearly (the worst case of full correlation); eqs (26)-(28) sum
//! the sigmas linearly. The optional `delta_diff` term (the paper's proposal in its
//! discussion) adds an opposite-phase error `e` (s_1 + e, s_2 - e) with
//! `sigma_e = delta_diff * |dGamma_1 - dGamma_2|`, as a third independent input of the
//! quadrature sums.
//!
//! Covariance model: the 3x3 covariance `P` of (x, y, alpha) is carried from sample to sample,
//! `P' = F P F^T + J S J^T` with `F` the Jacobian of the update with respect to the previous
//! state and `S = diag(kappa_1 |ds_1|, kappa_2 |ds_2|)` (variances proportional to distance
//! rolled, so the result does not depend on the sampling rate).
//!
//! All sums run in f32 with Kahan compensation ([`CompensatedSum`]), so a sigma that grows by
//! tiny steps over hours keeps full f32 accuracy instead of stalling on rounding.

use super::trig;

/// A Kahan-compensated f32 accumulator.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CompensatedSum {
    sum: f32,
    carry: f32,
}

impl CompensatedSum {
    /// An accumulator holding `value`.
    pub const fn new(value: f32) -> Self {
        Self {
            sum: value,
            carry: 0.0,
        }
    }

    /// Adds `v`.
    #[inline]
    pub fn add(&mut self, v: f32) {
        let y = v - self.carry;
        let t = self.sum + y;
        self.carry = (t - self.sum) - y;
        self.sum = t;
    }

    /// The accumulated value.
    #[inline]
    pub const fn value(&self) -> f32 {
        self.sum
    }
}

/// One sample's geometry as the uncertainty models need it (f32, SI units).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepGeometry {
    /// Absolute increments of the sample, wheel 1 and 2 (`|dGamma_i|`).
    pub abs_counts: [f32; 2],
    /// `|dGamma_1 - dGamma_2|`, increments.
    pub abs_count_difference: f32,
    /// Wheel distances of the sample, metres.
    pub wheel_distance: [f32; 2],
    /// Centre distance `ds` (eq 7), metres.
    pub ds: f32,
    /// Heading change `dalpha` (eq 8), radians.
    pub dalpha: f32,
    /// Chord length `dd` (eqs 9-10), metres.
    pub chord: f32,
    /// `sin` of the chord direction `alpha + dalpha/2`.
    pub sin: f32,
    /// `cos` of the chord direction `alpha + dalpha/2`.
    pub cos: f32,
    /// `1 / track_width`, 1/m.
    pub inv_track: f32,
}

/// Partial derivatives of `(dalpha, dx, dy)` with respect to `(s_1, s_2)`, and of
/// `(dx, dy)` with respect to the heading before the sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepJacobian {
    /// `d(dalpha)/d(s_1)`, `d(dalpha)/d(s_2)`, rad/m.
    pub dalpha: [f32; 2],
    /// `d(dx)/d(s_1)`, `d(dx)/d(s_2)`, dimensionless.
    pub dx: [f32; 2],
    /// `d(dy)/d(s_1)`, `d(dy)/d(s_2)`, dimensionless.
    pub dy: [f32; 2],
    /// `d(dx)/d(alpha)` = `dd cos`, metres per radian.
    pub dx_dalpha: f32,
    /// `d(dy)/d(alpha)` = `-dd sin`, metres per radian.
    pub dy_dalpha: f32,
}

impl StepJacobian {
    /// Differentiates eqs (7)-(12) at `g`: `dd = ds * sinc(dalpha/2)`, `dalpha = (s_1 -
    /// s_2)/w`, `dx = dd sin(alpha + dalpha/2)`, `dy = dd cos(alpha + dalpha/2)`.
    pub fn of(g: &StepGeometry) -> Self {
        let half = 0.5 * g.dalpha;
        let sinc = 1.0 - trig::chord_defect(half);
        let sinc_d = trig::sinc_derivative(half);
        // d(dd)/d(s_i) = sinc/2 + ds * sinc'(dalpha/2) * (1/2) * d(dalpha)/d(s_i).
        let common = 0.5 * sinc;
        let turn = 0.5 * g.ds * sinc_d * g.inv_track;
        let dd = [common + turn, common - turn];
        // d(theta)/d(s_i) = (1/2) d(dalpha)/d(s_i) = +-1/(2w).
        let half_w = 0.5 * g.inv_track;
        let (s, c, chord) = (g.sin, g.cos, g.chord);
        Self {
            dalpha: [g.inv_track, -g.inv_track],
            dx: [
                dd[0] * s + chord * c * half_w,
                dd[1] * s - chord * c * half_w,
            ],
            dy: [
                dd[0] * c - chord * s * half_w,
                dd[1] * c + chord * s * half_w,
            ],
            dx_dalpha: chord * c,
            dy_dalpha: -chord * s,
        }
    }
}

/// Coefficients of the uncertainty models (validated `ChassisParams` values, as f32).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UncertaintyCoefficients {
    /// `delta_left`, `delta_right`: metres per increment.
    pub delta: [f32; 2],
    /// `delta_diff`: metres per increment of `|dGamma_1 - dGamma_2|`.
    pub delta_diff: f32,
    /// `kappa_left`, `kappa_right`: m^2 per metre rolled (covariance model).
    pub kappa: [f32; 2],
    /// `kappa_diff`: m^2 per metre of `|ds_1 - ds_2|` (covariance model).
    pub kappa_diff: f32,
    /// Covariance of the geometry's relative calibration errors (left and right diameter,
    /// track width), upper triangle `[ll, rr, ww, lr, lw, rw]`
    /// (`GeometryUncertainty::relative_covariance`; covariance model).
    pub geometry: [f32; 6],
}

/// The paper's accumulated sigmas, eqs (26)-(28).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PaperUncertainty {
    sigma_x: CompensatedSum,
    sigma_y: CompensatedSum,
    sigma_alpha: CompensatedSum,
}

impl PaperUncertainty {
    /// Propagates one sample, eqs (19) and (23)-(28).
    pub fn step(&mut self, k: &UncertaintyCoefficients, g: &StepGeometry, j: &StepJacobian) {
        let s1 = k.delta[0] * g.abs_counts[0];
        let s2 = k.delta[1] * g.abs_counts[1];
        let se = k.delta_diff * g.abs_count_difference;
        let quad = |d: [f32; 2]| {
            let (a, b, e) = (d[0] * s1, d[1] * s2, (d[0] - d[1]) * se);
            trig::sqrt(a * a + b * b + e * e)
        };
        let sigma_alpha_before = self.sigma_alpha.value();
        let sigma_dalpha = quad(j.dalpha);
        let sigma_dx = quad(j.dx) + (j.dx_dalpha * sigma_alpha_before).abs();
        let sigma_dy = quad(j.dy) + (j.dy_dalpha * sigma_alpha_before).abs();
        self.sigma_alpha.add(sigma_dalpha);
        self.sigma_x.add(sigma_dx);
        self.sigma_y.add(sigma_dy);
    }

    /// `(sigma_x, sigma_y, sigma_alpha)`: metres, metres, radians.
    pub fn sigmas(&self) -> (f32, f32, f32) {
        (
            self.sigma_x.value(),
            self.sigma_y.value(),
            self.sigma_alpha.value(),
        )
    }
}

/// The covariance of (x, y, alpha), carried from sample to sample: the wheels' slip
/// (`kappa`) propagated as a covariance, plus the calibration's geometry errors carried as
/// the pose's sensitivity to them and added as `S G S^T` when read.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CovarianceUncertainty {
    xx: CompensatedSum,
    yy: CompensatedSum,
    aa: CompensatedSum,
    xy: CompensatedSum,
    xa: CompensatedSum,
    ya: CompensatedSum,
    /// `d(x, y, alpha) / d(relative left diameter, relative right diameter, relative
    /// track width)`: rows x, y (m), alpha (rad).
    sensitivity: [[f32; 3]; 3],
    /// The geometry covariance of the last step's coefficients (see
    /// [`UncertaintyCoefficients::geometry`]).
    geometry: [f32; 6],
}

impl CovarianceUncertainty {
    /// Propagates one sample: `P' = F P F^T + J S J^T`.
    pub fn step(&mut self, k: &UncertaintyCoefficients, g: &StepGeometry, j: &StepJacobian) {
        let v1 = k.kappa[0] * g.wheel_distance[0].abs();
        let v2 = k.kappa[1] * g.wheel_distance[1].abs();
        // The opposite-phase error moves s_1 by +e and s_2 by -e.
        let ve = k.kappa_diff * (g.wheel_distance[0] - g.wheel_distance[1]).abs();
        let q = |u: [f32; 2], w: [f32; 2]| {
            u[0] * w[0] * v1 + u[1] * w[1] * v2 + (u[0] - u[1]) * (w[0] - w[1]) * ve
        };
        let (a, b) = (j.dx_dalpha, j.dy_dalpha);
        let (paa, pxa, pya) = (self.aa.value(), self.xa.value(), self.ya.value());
        self.xx.add(2.0 * a * pxa + a * a * paa + q(j.dx, j.dx));
        self.yy.add(2.0 * b * pya + b * b * paa + q(j.dy, j.dy));
        self.xy.add(a * pya + b * pxa + a * b * paa + q(j.dx, j.dy));
        self.xa.add(a * paa + q(j.dx, j.dalpha));
        self.ya.add(b * paa + q(j.dy, j.dalpha));
        self.aa.add(q(j.dalpha, j.dalpha));
        self.step_sensitivity(g, j);
        self.geometry = k.geometry;
    }

    /// Carries the pose's sensitivity to the geometry's relative errors through one sample:
    /// a relative diameter error `e_i` scales wheel `i`'s distance `s_i` by `1 + e_i`; a
    /// relative track error `e_w` scales `dalpha` by `1 - e_w` at the same `ds`.
    fn step_sensitivity(&mut self, g: &StepGeometry, j: &StepJacobian) {
        let [s1, s2] = g.wheel_distance;
        // d(dx)/d(dalpha) and d(dy)/d(dalpha) at a fixed ds: (w/2) (J_1 - J_2).
        let half_w = 0.5 / g.inv_track;
        let turn_x = (j.dx[0] - j.dx[1]) * half_w;
        let turn_y = (j.dy[0] - j.dy[1]) * half_w;
        let inputs = [
            [j.dx[0] * s1, j.dx[1] * s2, -g.dalpha * turn_x],
            [j.dy[0] * s1, j.dy[1] * s2, -g.dalpha * turn_y],
            [j.dalpha[0] * s1, j.dalpha[1] * s2, -g.dalpha],
        ];
        let [sx, sy, sa] = &mut self.sensitivity;
        for c in 0..3 {
            sx[c] += j.dx_dalpha * sa[c] + inputs[0][c];
            sy[c] += j.dy_dalpha * sa[c] + inputs[1][c];
            sa[c] += inputs[2][c];
        }
    }

    /// The geometry part of the covariance, `S G S^T`, as `[xx, yy, aa, xy, xa, ya]`.
    fn geometry_terms(&self) -> [f32; 6] {
        let [ll, rr, ww, lr, lw, rw] = self.geometry;
        let g = [[ll, lr, lw], [lr, rr, rw], [lw, rw, ww]];
        let sg = self
            .sensitivity
            .map(|row| [0, 1, 2].map(|c| row[0] * g[0][c] + row[1] * g[1][c] + row[2] * g[2][c]));
        let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let [x, y, a] = self.sensitivity;
        [
            dot(sg[0], x),
            dot(sg[1], y),
            dot(sg[2], a),
            dot(sg[0], y),
            dot(sg[0], a),
            dot(sg[1], a),
        ]
    }

    /// `(sigma_x, sigma_y, sigma_alpha, cov_xy)`: metres, metres, radians, m^2.
    pub fn sigmas(&self) -> (f32, f32, f32, f32) {
        let [gxx, gyy, gaa, gxy, _, _] = self.geometry_terms();
        (
            trig::sqrt(self.xx.value() + gxx),
            trig::sqrt(self.yy.value() + gyy),
            trig::sqrt(self.aa.value() + gaa),
            self.xy.value() + gxy,
        )
    }

    /// `(cov(x, alpha), cov(y, alpha))`: m rad.
    pub fn heading_terms(&self) -> (f32, f32) {
        let [_, _, _, _, gxa, gya] = self.geometry_terms();
        (self.xa.value() + gxa, self.ya.value() + gya)
    }
}
