//! A naive f32 implementation of the same step, with `libm::sinf`/`cosf`/`sqrtf` and plain
//! f32 state and sums: what one would write first, kept as the yardstick for cost and drift.

/// Naive f32 odometry and the paper's uncertainty.
pub struct NaiveIntegrator {
    c: [f32; 2],
    w: f32,
    delta: [f32; 2],
    /// East, metres.
    pub x: f32,
    /// North, metres.
    pub y: f32,
    /// Heading, radians.
    pub alpha: f32,
    /// Accumulated sigmas: x, y, alpha.
    pub sigma: [f32; 3],
}

impl NaiveIntegrator {
    /// Designed-like chassis: diameters and track in metres, increments per turn, delta.
    pub fn new(d: [f64; 2], w: f64, ticks: u32, delta: f32) -> Self {
        let c = |d: f64| (core::f64::consts::PI * d / f64::from(ticks)) as f32;
        Self {
            c: [c(d[0]), c(d[1])],
            w: w as f32,
            delta: [delta; 2],
            x: 0.0,
            y: 0.0,
            alpha: 0.0,
            sigma: [0.0; 3],
        }
    }

    /// One sample: eqs (6)-(15) and (19)-(28) in f32 with libm.
    #[inline(never)]
    pub fn step(&mut self, d: [i32; 2]) {
        let s1 = self.c[0] * d[0] as f32;
        let s2 = self.c[1] * d[1] as f32;
        let ds = 0.5 * (s1 + s2);
        let da = (s1 - s2) / self.w;
        let dd = if da.abs() < 1e-6 {
            ds
        } else {
            ds * 2.0 / da * libm::sinf(0.5 * da)
        };
        let th = self.alpha + 0.5 * da;
        let (sn, cs) = (libm::sinf(th), libm::cosf(th));
        // Uncertainty: the same derivatives, evaluated naively.
        let sig = [
            self.delta[0] * (d[0].unsigned_abs() as f32),
            self.delta[1] * (d[1].unsigned_abs() as f32),
        ];
        let half = 0.5 * da;
        let (sinc, dsinc) = if half.abs() < 1e-4 {
            (1.0, -half / 3.0)
        } else {
            (
                libm::sinf(half) / half,
                (half * libm::cosf(half) - libm::sinf(half)) / (half * half),
            )
        };
        let t = 0.5 * ds * dsinc / self.w;
        let ddd = [0.5 * sinc + t, 0.5 * sinc - t];
        let hw = 0.5 / self.w;
        let jx = [ddd[0] * sn + dd * cs * hw, ddd[1] * sn - dd * cs * hw];
        let jy = [ddd[0] * cs - dd * sn * hw, ddd[1] * cs + dd * sn * hw];
        let q = |j: [f32; 2]| {
            libm::sqrtf((j[0] * sig[0]) * (j[0] * sig[0]) + (j[1] * sig[1]) * (j[1] * sig[1]))
        };
        let sa = libm::sqrtf(sig[0] * sig[0] + sig[1] * sig[1]) / self.w;
        let sx = q(jx) + libm::fabsf(dd * cs * self.sigma[2]);
        let sy = q(jy) + libm::fabsf(dd * sn * self.sigma[2]);
        self.sigma[0] += sx;
        self.sigma[1] += sy;
        self.sigma[2] += sa;
        self.x += dd * sn;
        self.y += dd * cs;
        self.alpha += da;
    }
}
