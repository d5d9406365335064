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
//! Opposite-phase slip when turning (`kappa_diff`: wheel 1's distance `+e`, wheel 2's `-e`)
//! is either white, a third input of `S` of variance `kappa_diff |ds_1 - ds_2|`, or, with a
//! correlation length `L` (`kappa_diff_corr`, metres of `|ds_1 - ds_2|`), a Gauss-Markov slip
//! rate `eps` (`e` grows by `eps |ds_1 - ds_2|`) of stationary variance
//! `sigma^2 = kappa_diff / (2 L)`, decaying by `rho = exp(-|ds_1 - ds_2| / L)` per sample: the
//! state `odoctl`'s calibration filter fits (`Turning`). The unit never observes `eps`, so its
//! variance stays `sigma^2` and only its covariance with the pose, `P_pe` (3 values), is
//! carried. With `u = (J_1 - J_2) |ds_1 - ds_2|` the pose change per unit `eps`:
//! `P' = F P F^T + F P_pe u^T + u P_pe^T F^T + u u^T sigma^2 + J S J^T` and
//! `P_pe' = rho (F P_pe + u sigma^2)` (the step moves the pose with the rate before it
//! decays, as the filter's transition does).
//!
//! All sums run in f32 with Kahan compensation ([`CompensatedSum`]), so a sigma that grows by
//! tiny steps over hours keeps full f32 accuracy instead of stalling on rounding.

use super::params::{ChassisParams, UncertaintyModel};
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
    #[inline(always)]
    pub fn add(&mut self, v: f32) {
        let y = v - self.carry;
        let t = self.sum + y;
        self.carry = (t - self.sum) - y;
        self.sum = t;
    }

    /// The accumulated value.
    #[inline(always)]
    pub const fn value(&self) -> f32 {
        self.sum
    }

    /// Multiplies the accumulated value (and its carry) by `factor`.
    #[inline(always)]
    pub fn scale(&mut self, factor: f32) {
        self.sum *= factor;
        self.carry *= factor;
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
    /// `1 / kappa_diff_corr`, 1/m of `|ds_1 - ds_2|`: 0 for white opposite-phase slip, else
    /// the decay rate of its Gauss-Markov state (covariance model).
    pub turn_decay: f32,
    /// `kappa_diff / (2 kappa_diff_corr)`: the stationary variance of the opposite-phase slip
    /// rate (dimensionless^2; 0 when white).
    pub turn_rate_variance: f32,
    /// Covariance of the geometry's relative calibration errors (left and right diameter,
    /// track width), upper triangle `[ll, rr, ww, lr, lw, rw]`
    /// (`GeometryUncertainty::relative_covariance`; covariance model).
    pub geometry: [f32; 6],
}

/// Shortest correlation length of opposite-phase slip that is carried as a Gauss-Markov
/// state (m of `|ds_1 - ds_2|`): a shorter one is taken as white, its limit as the length
/// goes to zero at the same `kappa_diff` (and far below a sample's difference at any rate).
pub const MIN_TURN_CORRELATION: f32 = 1.0e-3;

impl UncertaintyCoefficients {
    /// The coefficients of `p` (validated), as the integrator uses them.
    pub fn of(p: &ChassisParams) -> Self {
        Self {
            delta: [p.delta_left, p.delta_right],
            delta_diff: p.delta_diff,
            kappa: [p.kappa_left, p.kappa_right],
            kappa_diff: p.kappa_diff,
            turn_decay: 0.0,
            turn_rate_variance: 0.0,
            geometry: p.geometry_uncertainty.relative_covariance(p),
        }
        .with_turning_correlation(p.kappa_diff_corr)
    }

    /// These coefficients with opposite-phase slip of correlation length `corr`
    /// (`kappa_diff_corr`, m of `|ds_1 - ds_2|`): Gauss-Markov from
    /// [`MIN_TURN_CORRELATION`] on, white below (0 included).
    pub fn with_turning_correlation(self, corr: f32) -> Self {
        let (turn_decay, turn_rate_variance) = if corr >= MIN_TURN_CORRELATION {
            (1.0 / corr, self.kappa_diff / (2.0 * corr))
        } else {
            (0.0, 0.0)
        };
        Self {
            turn_decay,
            turn_rate_variance,
            ..self
        }
    }
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
/// (`kappa`) and the opposite-phase slip (`kappa_diff`, white or Gauss-Markov) propagated as a
/// covariance, plus the calibration's geometry errors carried as the pose's sensitivity to
/// them and added as `S G S^T` when read.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CovarianceUncertainty {
    xx: CompensatedSum,
    yy: CompensatedSum,
    aa: CompensatedSum,
    xy: CompensatedSum,
    xa: CompensatedSum,
    ya: CompensatedSum,
    /// Covariance of (x, y, alpha) with the Gauss-Markov opposite-phase slip rate (m, m,
    /// rad); stays zero while the slip is white.
    turn: [CompensatedSum; 3],
    /// `d(x, y, alpha) / d(relative left diameter, relative right diameter, relative
    /// track width)`: rows x, y (m), alpha (rad).
    sensitivity: [[f32; 3]; 3],
    /// The geometry covariance of the last step's coefficients (see
    /// [`UncertaintyCoefficients::geometry`]).
    geometry: [f32; 6],
}

impl CovarianceUncertainty {
    /// Propagates one sample: `P' = F P F^T + J S J^T`, plus the Gauss-Markov opposite-phase
    /// slip's terms when `kappa_diff_corr` is set (module documentation).
    pub fn step(&mut self, k: &UncertaintyCoefficients, g: &StepGeometry, j: &StepJacobian) {
        let v1 = k.kappa[0] * g.wheel_distance[0].abs();
        let v2 = k.kappa[1] * g.wheel_distance[1].abs();
        let diff = (g.wheel_distance[0] - g.wheel_distance[1]).abs();
        // The opposite-phase error moves s_1 by +e and s_2 by -e: white, an input of S;
        // correlated, the slip state's terms.
        let correlated = k.turn_decay > 0.0;
        let ve = if correlated { 0.0 } else { k.kappa_diff * diff };
        let q = |u: [f32; 2], w: [f32; 2]| {
            u[0] * w[0] * v1 + u[1] * w[1] * v2 + (u[0] - u[1]) * (w[0] - w[1]) * ve
        };
        let (a, b) = (j.dx_dalpha, j.dy_dalpha);
        let (paa, pxa, pya) = (self.aa.value(), self.xa.value(), self.ya.value());
        let [txx, tyy, taa, txy, txa, tya] = if correlated {
            self.step_turning_slip(k, diff, j)
        } else {
            [0.0; 6]
        };
        self.xx
            .add(2.0 * a * pxa + a * a * paa + q(j.dx, j.dx) + txx);
        self.yy
            .add(2.0 * b * pya + b * b * paa + q(j.dy, j.dy) + tyy);
        self.xy
            .add(a * pya + b * pxa + a * b * paa + q(j.dx, j.dy) + txy);
        self.xa.add(a * paa + q(j.dx, j.dalpha) + txa);
        self.ya.add(b * paa + q(j.dy, j.dalpha) + tya);
        self.aa.add(q(j.dalpha, j.dalpha) + taa);
        self.step_sensitivity(g, j);
        self.geometry = k.geometry;
    }

    /// The Gauss-Markov opposite-phase slip over one sample of wheel-distance difference
    /// `diff` (m): moves its covariance with the pose to `rho (F P_pe + u sigma^2)` and
    /// returns its terms of the pose covariance, `F P_pe u^T + u P_pe^T F^T + u u^T sigma^2`,
    /// as `[xx, yy, aa, xy, xa, ya]`.
    fn step_turning_slip(
        &mut self,
        k: &UncertaintyCoefficients,
        diff: f32,
        j: &StepJacobian,
    ) -> [f32; 6] {
        let s2 = k.turn_rate_variance;
        // Pose change per unit slip rate.
        let u = [
            (j.dx[0] - j.dx[1]) * diff,
            (j.dy[0] - j.dy[1]) * diff,
            (j.dalpha[0] - j.dalpha[1]) * diff,
        ];
        // F P_pe: the heading's covariance with the rate carried into the position's.
        let pa = self.turn[2].value();
        let w = [
            self.turn[0].value() + j.dx_dalpha * pa,
            self.turn[1].value() + j.dy_dalpha * pa,
            pa,
        ];
        let t = |r: usize, c: usize| w[r] * u[c] + u[r] * w[c] + u[r] * u[c] * s2;
        let rho = trig::exp_neg(diff * k.turn_decay);
        let incoming = [j.dx_dalpha * pa, j.dy_dalpha * pa, 0.0];
        for (i, p) in self.turn.iter_mut().enumerate() {
            p.add(incoming[i] + u[i] * s2);
            p.scale(rho);
        }
        [t(0, 0), t(1, 1), t(2, 2), t(0, 1), t(0, 2), t(1, 2)]
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

/// The uncertainty of a pose: standard uncertainties of x and y (metres) and heading
/// (radians), and the x-y covariance (m^2; zero for the paper's model, which has none).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PoseSigma {
    /// sigma of x, metres.
    pub x: f32,
    /// sigma of y, metres.
    pub y: f32,
    /// sigma of heading, radians.
    pub heading: f32,
    /// Covariance of x and y, m^2 (covariance model only).
    pub cov_xy: f32,
}

impl PoseSigma {
    /// The horizontal uncertainty `sigma_h = sqrt(sigma_x^2 + sigma_y^2)`, metres.
    pub fn horizontal(&self) -> f32 {
        trig::hypot(self.x, self.y)
    }
}

/// The uncertainty of the model that `uncertainty_model` selects, stepped one sample's
/// [`StepGeometry`] at a time: the integrator's own, or replayed by a host tool over the
/// geometries of one integration at other coefficients (the same sigmas, bit for bit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseUncertainty {
    model: UncertaintyModel,
    coefficients: UncertaintyCoefficients,
    paper: PaperUncertainty,
    covariance: CovarianceUncertainty,
}

impl PoseUncertainty {
    /// Zero uncertainty, with the model and coefficients of `p` (validated).
    pub fn new(p: &ChassisParams) -> Self {
        Self {
            model: p.uncertainty_model,
            coefficients: UncertaintyCoefficients::of(p),
            paper: PaperUncertainty::default(),
            covariance: CovarianceUncertainty::default(),
        }
    }

    /// Takes the model and coefficients of `p` (validated), keeping the uncertainty so far.
    pub fn set_params(&mut self, p: &ChassisParams) {
        self.model = p.uncertainty_model;
        self.coefficients = UncertaintyCoefficients::of(p);
    }

    /// Zeroes the uncertainty, keeping the model and coefficients.
    pub fn reset(&mut self) {
        self.paper = PaperUncertainty::default();
        self.covariance = CovarianceUncertainty::default();
    }

    /// Propagates one integrated sample of geometry `g`.
    #[inline]
    pub fn step(&mut self, g: &StepGeometry) {
        let jacobian = StepJacobian::of(g);
        match self.model {
            UncertaintyModel::Paper => self.paper.step(&self.coefficients, g, &jacobian),
            UncertaintyModel::Covariance => self.covariance.step(&self.coefficients, g, &jacobian),
        }
    }

    /// The current uncertainty.
    pub fn sigma(&self) -> PoseSigma {
        match self.model {
            UncertaintyModel::Paper => {
                let (x, y, heading) = self.paper.sigmas();
                PoseSigma {
                    x,
                    y,
                    heading,
                    cov_xy: 0.0,
                }
            }
            UncertaintyModel::Covariance => {
                let (x, y, heading, cov_xy) = self.covariance.sigmas();
                PoseSigma {
                    x,
                    y,
                    heading,
                    cov_xy,
                }
            }
        }
    }

    /// The position-heading covariances `(cov(x, alpha), cov(y, alpha))`, m rad: carried by
    /// the covariance model; zero for the paper's model, which has no correlation terms.
    pub fn heading_covariance(&self) -> (f32, f32) {
        match self.model {
            UncertaintyModel::Paper => (0.0, 0.0),
            UncertaintyModel::Covariance => self.covariance.heading_terms(),
        }
    }
}
