//! The paper's odometry (eqs 1-15, with the per-angle wheel function of eqs 3-5) and
//! uncertainty (eqs 19-28) in f64 with std trigonometry, written straight from Jilek, Burian,
//! Kriz: what the core's fixed-point and f32 integrator is checked and benchmarked against.

use std::f64::consts::{PI, TAU};

use odo_unit::odometry::{ChassisParams, Pose, WheelHarmonics};

/// The paper's odometry and uncertainty in f64.
#[derive(Debug, Clone)]
pub struct Reference {
    /// Metres per increment of each wheel (eq 2).
    pub c: [f64; 2],
    /// Track width (m).
    pub w: f64,
    /// Uncertainty coefficients `delta_left`, `delta_right` (m per increment).
    pub delta: [f64; 2],
    /// Wheel diameters (m).
    pub diameter: [f64; 2],
    /// Per-angle wheel functions of eqs (3)-(5).
    pub harmonics: [WheelHarmonics; 2],
    /// Increments per wheel turn.
    pub ticks: f64,
    /// Absolute counts at the last step.
    pub counts: [i64; 2],
    /// x (m, east).
    pub x: f64,
    /// y (m, north).
    pub y: f64,
    /// Heading (rad, clockwise from +y).
    pub alpha: f64,
    /// sigma of x (m), eqs (19)-(28).
    pub sigma_x: f64,
    /// sigma of y (m).
    pub sigma_y: f64,
    /// sigma of the heading (rad).
    pub sigma_alpha: f64,
}

impl Reference {
    /// The reference at `counts` and `pose` with zero sigmas.
    pub fn new(p: &ChassisParams, counts: [i64; 2], pose: Pose) -> Self {
        let ticks = f64::from(p.ticks_per_rev);
        Self {
            c: [PI * p.left_diameter / ticks, PI * p.right_diameter / ticks],
            w: p.track_width,
            delta: [f64::from(p.delta_left), f64::from(p.delta_right)],
            diameter: [p.left_diameter, p.right_diameter],
            harmonics: [p.left_wheel, p.right_wheel],
            ticks,
            counts,
            x: pose.x,
            y: pose.y,
            alpha: pose.heading,
            sigma_x: 0.0,
            sigma_y: 0.0,
            sigma_alpha: 0.0,
        }
    }

    /// Eq (4)'s sum F_w of wheel i at absolute count g, with the index latched at `index`.
    pub fn summed_wheel_function(&self, i: usize, g: i64, index: Option<i64>) -> f64 {
        let linear = self.c[i] * g as f64;
        let Some(index) = index else { return linear };
        let theta = TAU * ((g - index).rem_euclid(self.ticks as i64)) as f64 / self.ticks;
        let h = &self.harmonics[i];
        let mut r = 0.0;
        for k in 0..3 {
            let n = (k + 1) as f64;
            r += self.diameter[i] / 2.0
                * (f64::from(h.cos[k]) / n * (n * theta).sin()
                    - f64::from(h.sin[k]) / n * (n * theta).cos());
        }
        linear + r
    }

    /// One sample: the absolute `counts` and the index latches `index` of each wheel.
    pub fn step(&mut self, counts: [i64; 2], index: [Option<i64>; 2]) {
        // Eq (1) and eq (5).
        let dg = [counts[0] - self.counts[0], counts[1] - self.counts[1]];
        let s = [
            self.summed_wheel_function(0, counts[0], index[0])
                - self.summed_wheel_function(0, self.counts[0], index[0]),
            self.summed_wheel_function(1, counts[1], index[1])
                - self.summed_wheel_function(1, self.counts[1], index[1]),
        ];
        self.counts = counts;
        // Eqs (7)-(15).
        let (ds, da) = ((s[0] + s[1]) / 2.0, (s[0] - s[1]) / self.w);
        let dd = chord(ds, da);
        let theta = self.alpha + da / 2.0;
        let (dx, dy) = (dd * theta.sin(), dd * theta.cos());
        // Eqs (19)-(28) with analytic f64 derivatives w.r.t. the wheel distances.
        let sig = [
            self.delta[0] * dg[0].abs() as f64,
            self.delta[1] * dg[1].abs() as f64,
        ];
        let j = jacobian_f64(s, self.alpha, self.w);
        let quad = |d: [f64; 2]| ((d[0] * sig[0]).powi(2) + (d[1] * sig[1]).powi(2)).sqrt();
        let s_da = quad(j[0]);
        let s_dx = quad(j[1]) + (dd * theta.cos() * self.sigma_alpha).abs();
        let s_dy = quad(j[2]) + (dd * theta.sin() * self.sigma_alpha).abs();
        self.sigma_alpha += s_da;
        self.sigma_x += s_dx;
        self.sigma_y += s_dy;
        self.x += dx;
        self.y += dy;
        self.alpha += da;
    }
}

/// Eqs (9)-(10): the chord of an arc of length `ds` turning by `da`.
pub fn chord(ds: f64, da: f64) -> f64 {
    if da == 0.0 {
        ds
    } else {
        ds * 2.0 / da * (da / 2.0).sin()
    }
}

/// (dalpha, dx, dy) of eqs (7)-(12) as functions of the wheel distances.
pub fn increments(s: [f64; 2], alpha: f64, w: f64) -> [f64; 3] {
    let (ds, da) = ((s[0] + s[1]) / 2.0, (s[0] - s[1]) / w);
    let dd = chord(ds, da);
    [
        da,
        dd * (alpha + da / 2.0).sin(),
        dd * (alpha + da / 2.0).cos(),
    ]
}

/// Analytic partial derivatives of `increments` w.r.t. s_1, s_2 (rows dalpha, dx, dy).
pub fn jacobian_f64(s: [f64; 2], alpha: f64, w: f64) -> [[f64; 2]; 3] {
    let (ds, da) = ((s[0] + s[1]) / 2.0, (s[0] - s[1]) / w);
    let x = da / 2.0;
    let (sinc, dsinc) = if x.abs() < 1e-4 {
        (1.0 - x * x / 6.0, -x / 3.0)
    } else {
        (x.sin() / x, (x * x.cos() - x.sin()) / (x * x))
    };
    let dd = ds * sinc;
    let theta = alpha + x;
    let ddd = [
        0.5 * sinc + ds * dsinc * 0.5 / w,
        0.5 * sinc - ds * dsinc * 0.5 / w,
    ];
    let dth = [0.5 / w, -0.5 / w];
    let mut j = [[0.0; 2]; 3];
    for i in 0..2 {
        j[0][i] = if i == 0 { 1.0 / w } else { -1.0 / w };
        j[1][i] = ddd[i] * theta.sin() + dd * theta.cos() * dth[i];
        j[2][i] = ddd[i] * theta.cos() - dd * theta.sin() * dth[i];
    }
    j
}
