//! Our pose, uncertainty and counts in ROS terms (REP-103, REP-105): the one place that
//! converts. The table in docs/ROS.md states every rule implemented here.
//!
//! Ours: x east, y north (m); heading `alpha` 0 along +y, growing clockwise, cumulative.
//! ROS: frame `odom` (x, y passed through), `base_link` forward along +x; yaw 0 along +x,
//! counter-clockwise: `yaw = pi/2 - alpha`.

use std::f64::consts::{FRAC_PI_2, PI};

use super::msgs::{Covariance6, Quaternion};
use odo_unit::odometry::{ChassisParams, Pose, UncertaintyModel};

/// Variance given to the dimensions a planar odometry does not observe (z, roll, pitch; vz,
/// roll and pitch rates): large, finite, never zero (m^2, rad^2, (m/s)^2, (rad/s)^2).
pub const UNOBSERVED_VARIANCE: f64 = 1.0e6;

/// The least variance published for an observed dimension (x, y, yaw; vx, vy, yaw rate):
/// m^2, rad^2, (m/s)^2, (rad/s)^2. A variance below it (the exactly-zero pose covariance at
/// the first record and after a reset) is published as this floor, because filters such as
/// robot_localization warn on and mishandle zero variances. 1e-10 is a 10 um (10 urad)
/// sigma, below the quantisation of one count of the designed chassis.
pub const VARIANCE_FLOOR: f64 = 1.0e-10;

/// Parent frame of the pose (REP-105), the default of the frame options.
pub const ODOM_FRAME: &str = "odom";
/// Frame of the chassis and of the twist (REP-105), the default of the frame options.
pub const BASE_FRAME: &str = "base_link";

/// Raises the observed variances `[0]`, `[7]`, `[35]` to at least [`VARIANCE_FLOOR`].
fn floored(mut c: [f64; 36]) -> Covariance6 {
    for i in [0, 7, 35] {
        c[i] = c[i].max(VARIANCE_FLOOR);
    }
    Covariance6(c)
}

/// ROS yaw (rad, counter-clockwise from +x) of our heading, wrapped to (-pi, pi].
pub fn yaw_of_heading(heading: f64) -> f64 {
    let yaw = FRAC_PI_2 - heading;
    let w = yaw - (2.0 * PI) * ((yaw + PI) / (2.0 * PI)).floor();
    // `w` is in [-pi, pi); -pi is the same angle as pi.
    if w <= -PI {
        PI
    } else {
        w
    }
}

/// The orientation quaternion of our heading: a rotation by `yaw_of_heading` about +z, with
/// `w >= 0` (the wrapped yaw makes the sign unique).
pub fn quaternion_of_heading(heading: f64) -> Quaternion {
    let half = 0.5 * yaw_of_heading(heading);
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: half.sin(),
        w: half.cos(),
    }
}

/// The 3x3 covariance of our pose `(x, y, alpha)` (m^2, m rad, rad^2).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PoseCovariance {
    /// var(x), m^2.
    pub xx: f64,
    /// var(y), m^2.
    pub yy: f64,
    /// var(alpha), rad^2.
    pub aa: f64,
    /// cov(x, y), m^2.
    pub xy: f64,
    /// cov(x, alpha), m rad.
    pub xa: f64,
    /// cov(y, alpha), m rad.
    pub ya: f64,
}

impl PoseCovariance {
    /// From the sigmas the unit reports (`sigma_x`, `sigma_y`, `sigma_heading`) and its x-y
    /// covariance (`cov_xy`), and the position-heading covariances (zero for the paper's model).
    pub fn from_sigmas(sx: f32, sy: f32, sh: f32, cov_xy: f32, heading_terms: (f32, f32)) -> Self {
        let sq = |s: f32| f64::from(s) * f64::from(s);
        Self {
            xx: sq(sx),
            yy: sq(sy),
            aa: sq(sh),
            xy: f64::from(cov_xy),
            xa: f64::from(heading_terms.0),
            ya: f64::from(heading_terms.1),
        }
    }

    /// As a symmetric matrix over `(x, y, alpha)`.
    fn matrix(&self) -> [[f64; 3]; 3] {
        [
            [self.xx, self.xy, self.xa],
            [self.xy, self.yy, self.ya],
            [self.xa, self.ya, self.aa],
        ]
    }

    fn from_matrix(m: &[[f64; 3]; 3]) -> Self {
        Self {
            xx: m[0][0],
            yy: m[1][1],
            aa: m[2][2],
            xy: 0.5 * (m[0][1] + m[1][0]),
            xa: 0.5 * (m[0][2] + m[2][0]),
            ya: 0.5 * (m[1][2] + m[2][1]),
        }
    }

    /// The `nav_msgs/Odometry` pose covariance: row-major 6x6 over (x, y, z, roll, pitch,
    /// yaw). `yaw = pi/2 - alpha` flips the sign of the position-yaw terms; z, roll and pitch
    /// get [`UNOBSERVED_VARIANCE`]; the x, y and yaw variances at least [`VARIANCE_FLOOR`].
    pub fn to_ros(&self) -> Covariance6 {
        let mut c = [0.0; 36];
        c[0] = self.xx;
        c[1] = self.xy;
        c[6] = self.xy;
        c[7] = self.yy;
        c[14] = UNOBSERVED_VARIANCE;
        c[21] = UNOBSERVED_VARIANCE;
        c[28] = UNOBSERVED_VARIANCE;
        c[35] = self.aa;
        c[5] = -self.xa;
        c[30] = -self.xa;
        c[11] = -self.ya;
        c[31] = -self.ya;
        floored(c)
    }
}

/// One sample interval's motion in `base_link`: forward speed and yaw rate with their
/// covariance, from the counts (eqs 6-8 with the constant transfer constants).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BaseTwist {
    /// Forward speed `ds/dt`, m/s.
    pub vx: f64,
    /// Yaw rate `-dalpha/dt`, rad/s (counter-clockwise positive).
    pub wz: f64,
    /// var(vx), (m/s)^2.
    pub var_vx: f64,
    /// var(wz), (rad/s)^2.
    pub var_wz: f64,
    /// cov(vx, wz), m rad/s^2.
    pub cov_vx_wz: f64,
}

impl BaseTwist {
    /// The twist of an interval of `dt` seconds in which the wheels turned `d_left`,
    /// `d_right` increments. Wheel distances `s_i = dGamma_i pi D_i / ticks_per_rev`;
    /// `ds = (s_1 + s_2)/2`, `dalpha = (s_1 - s_2)/track_width`. Their variances are the
    /// model's own inputs: paper `(delta_i |dGamma_i|)^2` plus the opposite-phase
    /// `(delta_diff |dGamma_1 - dGamma_2|)^2`; covariance model `kappa_i |s_i|`; both plus
    /// the quantisation of two count readings, `(pi D_i / ticks_per_rev)^2 / 6`, so that a
    /// chassis at rest reports a small, non-zero variance. `None` unless `dt > 0`.
    pub fn from_counts(p: &ChassisParams, d_left: i64, d_right: i64, dt: f64) -> Option<Self> {
        if dt.is_nan() || dt <= 0.0 {
            return None;
        }
        let ticks = f64::from(p.ticks_per_rev);
        let q = [PI * p.left_diameter / ticks, PI * p.right_diameter / ticks];
        let n = [d_left as f64, d_right as f64];
        let s = [n[0] * q[0], n[1] * q[1]];
        let w = p.track_width;
        let (mut var, var_e) = match p.uncertainty_model {
            UncertaintyModel::Paper => {
                let sq = |d: f32, k: f64| (f64::from(d) * k.abs()).powi(2);
                (
                    [sq(p.delta_left, n[0]), sq(p.delta_right, n[1])],
                    sq(p.delta_diff, n[0] - n[1]),
                )
            }
            UncertaintyModel::Covariance => (
                [
                    f64::from(p.kappa_left) * s[0].abs(),
                    f64::from(p.kappa_right) * s[1].abs(),
                ],
                0.0,
            ),
        };
        var[0] += q[0] * q[0] / 6.0;
        var[1] += q[1] * q[1] / 6.0;
        let dt2 = dt * dt;
        Some(Self {
            vx: 0.5 * (s[0] + s[1]) / dt,
            wz: -(s[0] - s[1]) / w / dt,
            var_vx: 0.25 * (var[0] + var[1]) / dt2,
            var_wz: (var[0] + var[1] + 4.0 * var_e) / (w * w * dt2),
            cov_vx_wz: -0.5 * (var[0] - var[1]) / (w * dt2),
        })
    }

    /// The twist covariance: row-major 6x6 over (vx, vy, vz, roll rate, pitch rate, yaw
    /// rate). `vy = 0` is the differential drive's constraint, given the variance of `vx`;
    /// vz, roll and pitch rates get [`UNOBSERVED_VARIANCE`]; the vx, vy and yaw rate
    /// variances are at least [`VARIANCE_FLOOR`].
    pub fn covariance(&self) -> Covariance6 {
        let mut c = [0.0; 36];
        c[0] = self.var_vx;
        c[7] = self.var_vx;
        c[14] = UNOBSERVED_VARIANCE;
        c[21] = UNOBSERVED_VARIANCE;
        c[28] = UNOBSERVED_VARIANCE;
        c[35] = self.var_wz;
        c[5] = self.cov_vx_wz;
        c[30] = self.cov_vx_wz;
        floored(c)
    }

    /// The covariance of an interval with no motion information (the first sample): every
    /// variance [`UNOBSERVED_VARIANCE`].
    pub fn unknown_covariance() -> Covariance6 {
        let mut c = [0.0; 36];
        for i in 0..6 {
            c[i * 7] = UNOBSERVED_VARIANCE;
        }
        Covariance6(c)
    }
}

/// Keeps `odom` continuous across `reset_pose` (REP-105): after a reset the published pose is
/// the unit's pose composed with the offset that maps the reset pose onto the last published
/// one, and the covariance keeps what had accumulated (propagated through the composition).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ContinuousOdom {
    /// Offset pose (ours: x, y, alpha): published = offset ∘ unit.
    offset: Pose,
    /// Covariance of the offset (the published covariance at the last reset).
    offset_cov: PoseCovariance,
    /// The last published pose and covariance.
    last: Option<(Pose, PoseCovariance)>,
    /// Resets seen.
    resets: u64,
}

/// Rotates `(x, y)` by `phi` clockwise (our heading sense).
fn rotate(phi: f64, x: f64, y: f64) -> (f64, f64) {
    let (s, c) = phi.sin_cos();
    (x * c + y * s, -x * s + y * c)
}

impl ContinuousOdom {
    /// Resets seen so far.
    pub fn resets(&self) -> u64 {
        self.resets
    }

    /// The unit's pose was reset to `unit` (the unit's sigmas restart from zero): the offset
    /// is chosen so that `unit` maps onto the last published pose. Returns the jump the unit
    /// made, `(dx, dy, dalpha)` in the published frame, when a pose had been published.
    pub fn reset(&mut self, unit: Pose) -> Option<(f64, f64, f64)> {
        let (last, last_cov) = self.last?;
        self.resets += 1;
        let jump_before = self.apply_pose(unit);
        let a = last.heading - unit.heading;
        let (rx, ry) = rotate(a, unit.x, unit.y);
        self.offset = Pose {
            x: last.x - rx,
            y: last.y - ry,
            heading: a,
        };
        self.offset_cov = last_cov;
        Some((
            jump_before.x - last.x,
            jump_before.y - last.y,
            jump_before.heading - last.heading,
        ))
    }

    fn apply_pose(&self, unit: Pose) -> Pose {
        let (rx, ry) = rotate(self.offset.heading, unit.x, unit.y);
        Pose {
            x: self.offset.x + rx,
            y: self.offset.y + ry,
            heading: self.offset.heading + unit.heading,
        }
    }

    /// The published pose and covariance of the unit's pose `unit` with covariance `cov`
    /// (first order: `J_o P_o J_o^T + J_u P_u J_u^T`, offset and unit errors independent).
    pub fn publish(&mut self, unit: Pose, cov: PoseCovariance) -> (Pose, PoseCovariance) {
        let out = if self.resets == 0 {
            (unit, cov)
        } else {
            let pose = self.apply_pose(unit);
            let (rx, ry) = rotate(self.offset.heading, unit.x, unit.y);
            // d(R(phi) u)/d(phi) = (ry, -rx) for the clockwise rotation.
            let jo = [[1.0, 0.0, ry], [0.0, 1.0, -rx], [0.0, 0.0, 1.0]];
            let (s, c) = self.offset.heading.sin_cos();
            let ju = [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]];
            let a = congruence(&jo, &self.offset_cov.matrix());
            let b = congruence(&ju, &cov.matrix());
            let mut m = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] = a[i][j] + b[i][j];
                }
            }
            (pose, PoseCovariance::from_matrix(&m))
        };
        self.last = Some(out);
        out
    }
}

/// `J P J^T` for 3x3 matrices.
fn congruence(j: &[[f64; 3]; 3], p: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut jp = [[0.0; 3]; 3];
    for i in 0..3 {
        for k in 0..3 {
            jp[i][k] = (0..3).map(|l| j[i][l] * p[l][k]).sum();
        }
    }
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for k in 0..3 {
            out[i][k] = (0..3).map(|l| jp[i][l] * j[k][l]).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn yaw_boundary_table() {
        // (heading, yaw): north, east, south, west, and cumulative turns.
        let table = [
            (0.0, FRAC_PI_2),
            (FRAC_PI_2, 0.0),
            (PI, -FRAC_PI_2),
            (-FRAC_PI_2, PI),
            (3.0 * FRAC_PI_2, PI),
            (2.0 * PI, FRAC_PI_2),
            (-4.0 * PI + FRAC_PI_2, 0.0),
            (1.0e4 * PI, FRAC_PI_2),
        ];
        for (h, y) in table {
            let got = yaw_of_heading(h);
            assert!(close(got, y, 1e-9), "heading {h}: yaw {got}, expected {y}");
            assert!(got > -PI && got <= PI);
        }
    }

    #[test]
    fn quaternion_points_base_link_x_along_the_heading() {
        for k in 0..64 {
            let h = -7.0 + 0.23 * k as f64;
            let q = quaternion_of_heading(h);
            assert!(q.w >= 0.0);
            assert!(close(q.z * q.z + q.w * q.w, 1.0, 1e-12));
            // base_link +x rotated by q: (1 - 2z^2, 2zw) = (east, north) of the heading.
            let (e, n) = (1.0 - 2.0 * q.z * q.z, 2.0 * q.z * q.w);
            assert!(close(e, h.sin(), 1e-9) && close(n, h.cos(), 1e-9), "{h}");
        }
    }

    #[test]
    fn pose_covariance_layout_and_signs() {
        let c = PoseCovariance {
            xx: 4.0,
            yy: 9.0,
            aa: 0.01,
            xy: 1.5,
            xa: 0.05,
            ya: -0.02,
        }
        .to_ros()
        .0;
        assert_eq!((c[0], c[7], c[35]), (4.0, 9.0, 0.01));
        assert_eq!((c[1], c[6]), (1.5, 1.5));
        assert_eq!((c[5], c[30], c[11], c[31]), (-0.05, -0.05, 0.02, 0.02));
        for i in [14, 21, 28] {
            assert_eq!(c[i], UNOBSERVED_VARIANCE);
        }
        for r in 0..6 {
            for k in 0..6 {
                assert_eq!(c[r * 6 + k], c[k * 6 + r], "symmetric");
                assert!(c[r * 6 + k].is_finite());
            }
        }
    }

    #[test]
    fn no_observed_variance_is_zero() {
        let c = PoseCovariance::default().to_ros().0;
        assert_eq!(
            (c[0], c[7], c[35]),
            (VARIANCE_FLOOR, VARIANCE_FLOOR, VARIANCE_FLOOR)
        );
        assert_eq!(
            (c[1], c[5], c[11]),
            (0.0, 0.0, 0.0),
            "off-diagonal terms as they are"
        );
        let big = PoseCovariance {
            xx: 2e-10,
            ..Default::default()
        };
        assert_eq!(big.to_ros().0[0], 2e-10, "above the floor: unchanged");
        let t = BaseTwist::default().covariance().0;
        assert_eq!(
            (t[0], t[7], t[35]),
            (VARIANCE_FLOOR, VARIANCE_FLOOR, VARIANCE_FLOOR)
        );
    }

    #[test]
    fn position_yaw_sign_matches_a_perturbation() {
        // A heading error e gives a yaw error -e: cov(x, yaw) = -cov(x, alpha).
        let (x, a) = (0.3, 0.7);
        let e = 1e-3;
        let (x2, a2) = (x + 2.0 * e, a + e); // x moves with alpha: cov(x, alpha) > 0
        let dyaw = yaw_of_heading(a2) - yaw_of_heading(a);
        assert!((x2 - x) * dyaw < 0.0);
    }

    #[test]
    fn twist_table() {
        let mut p = ChassisParams::DESIGNED;
        p.delta_diff = 0.0;
        let q = PI * p.left_diameter / f64::from(p.ticks_per_rev);
        let dt = 0.02;
        // Straight, on the spot (left forward: clockwise, wz < 0), reversing, at rest.
        let t = BaseTwist::from_counts(&p, 100, 100, dt).unwrap();
        assert!(close(t.vx, 100.0 * q / dt, 1e-12) && t.wz.abs() < 1e-12);
        let t = BaseTwist::from_counts(&p, 50, -50, dt).unwrap();
        assert!(t.vx.abs() < 1e-12 && close(t.wz, -100.0 * q / p.track_width / dt, 1e-9));
        let t = BaseTwist::from_counts(&p, -30, -30, dt).unwrap();
        assert!(t.vx < 0.0);
        let t = BaseTwist::from_counts(&p, 0, 0, dt).unwrap();
        assert_eq!((t.vx, t.wz), (0.0, 0.0));
        assert!(t.var_vx > 0.0 && t.var_wz > 0.0, "rest: quantisation only");
        assert!(close(t.var_vx, q * q / 6.0 / 2.0 / (dt * dt), 1e-18));
        assert!(BaseTwist::from_counts(&p, 1, 1, 0.0).is_none());
    }

    #[test]
    fn twist_covariance_is_the_propagated_wheel_variance() {
        let mut p = ChassisParams::DESIGNED;
        p.delta_left = 2e-6;
        p.delta_right = 1e-6;
        p.delta_diff = 5e-7;
        let (n1, n2, dt) = (400i64, 300i64, 0.02);
        let t = BaseTwist::from_counts(&p, n1, n2, dt).unwrap();
        let ticks = f64::from(p.ticks_per_rev);
        let q1 = PI * p.left_diameter / ticks;
        let q2 = PI * p.right_diameter / ticks;
        let v1 = (f64::from(p.delta_left) * 400.0).powi(2) + q1 * q1 / 6.0;
        let v2 = (f64::from(p.delta_right) * 300.0).powi(2) + q2 * q2 / 6.0;
        let ve = (f64::from(p.delta_diff) * 100.0).powi(2);
        let w = p.track_width;
        // J = [[1/2, 1/2, 0], [-1/w, 1/w, -2/w]] / dt over (s1, s2, e).
        assert!(close(t.var_vx, (v1 + v2) / 4.0 / (dt * dt), 1e-15));
        assert!(close(
            t.var_wz,
            (v1 + v2 + 4.0 * ve) / (w * w * dt * dt),
            1e-12
        ));
        assert!(close(
            t.cov_vx_wz,
            (-v1 + v2) / (2.0 * w) / (dt * dt),
            1e-15
        ));
        let c = t.covariance().0;
        assert_eq!((c[5], c[30]), (t.cov_vx_wz, t.cov_vx_wz));
        assert_eq!(c[7], c[0]);
    }

    #[test]
    fn reset_keeps_odom_continuous() {
        let mut o = ContinuousOdom::default();
        let cov = PoseCovariance {
            xx: 1e-4,
            yy: 2e-4,
            aa: 1e-5,
            xy: 1e-5,
            xa: 2e-6,
            ya: -1e-6,
        };
        let before = Pose {
            x: 3.0,
            y: 4.0,
            heading: 0.5,
        };
        assert_eq!(o.publish(before, cov), (before, cov));
        // The unit jumps to the origin with zero sigmas.
        let jump = o.reset(Pose::default()).unwrap();
        assert!(close(jump.0, -3.0, 1e-12) && close(jump.1, -4.0, 1e-12));
        let (p, c) = o.publish(Pose::default(), PoseCovariance::default());
        assert!(close(p.x, 3.0, 1e-12) && close(p.y, 4.0, 1e-12) && close(p.heading, 0.5, 1e-12));
        assert!(close(c.xx, cov.xx, 1e-15) && close(c.xa, cov.xa, 1e-15));
        // Then 1 m straight ahead in the unit's frame = 1 m along heading 0.5 in odom.
        let (p, c) = o.publish(
            Pose {
                x: 0.0,
                y: 1.0,
                heading: 0.0,
            },
            PoseCovariance {
                xx: 1e-6,
                ..Default::default()
            },
        );
        assert!(close(p.x, 3.0 + 0.5f64.sin(), 1e-12) && close(p.y, 4.0 + 0.5f64.cos(), 1e-12));
        // The offset's heading uncertainty now moves the position: var grows beyond the sum.
        assert!(c.xx > cov.xx + 1e-6 * 0.5f64.cos().powi(2));
        assert_eq!(o.resets(), 1);
        // No reset before anything was published.
        assert_eq!(ContinuousOdom::default().reset(Pose::default()), None);
    }
}
