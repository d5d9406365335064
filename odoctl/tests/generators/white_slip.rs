//! A second simulator, written apart from `odoctl::simulate` so that the calibration is not
//! judged only on data shaped like its own simulator's: its own random numbers, paths drawn as
//! a random curvature (gentle) or as tight turns and spins, a speed that varies, white wheel
//! slip whose variance grows with each wheel's own distance, and a reference at 10 Hz with
//! independent position and heading noise.
//!
//! - **Motion**: 1 kHz steps of exact constant-curvature motion of the axle centre; wheel 1
//!   (left) travels `ds + dh b / 2`, wheel 2 (right) `ds - dh b / 2` (heading clockwise).
//! - **Slip**: each wheel's encoder turns by its travel plus a normal error of variance
//!   `q^2 |travel|` (m^2), independent step to step and wheel to wheel: a random walk of
//!   `q` m per sqrt(m) of the wheel's own travel.
//! - **Encoders**: `ticks_per_rev` increments per turn of the true diameter, sampled at 50 Hz;
//!   no index line.
//! - **Reference**: every 5th sample (10 Hz), the true centre with a normal error of
//!   `sigma_axis` per axis and a heading with a normal error of `heading_sigma`.

use std::f64::consts::PI;

use odo_unit::odometry::ChassisParams;
use odoctl::csvio::{RefPoint, Sample};
use odoctl::simulate::SimRun;

/// The kinds of path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Course {
    /// Random curvature of radius mostly above 3 m, speed 0.5-1.1 m/s: a calibration drive.
    Gentle,
    /// Straights of 1-4 m between turns of radius 0.3-1.2 m through 60-300 deg and spins on
    /// the spot: a validation drive that turns far more than the calibration.
    Tight,
}

/// What the generator simulates.
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    /// The chassis driven.
    pub truth: ChassisParams,
    /// Slip: wheel-distance random walk (m per sqrt(m)).
    pub q: f64,
    /// Reference position noise per axis (m).
    pub sigma_axis: f64,
    /// Reference heading noise (rad).
    pub heading_sigma: f64,
}

/// splitmix64 with Box-Muller normals.
struct Random(u64);

impl Random {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1).
    fn uniform(&mut self) -> f64 {
        ((self.next() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn normal(&mut self) -> f64 {
        (-2.0 * self.uniform().ln()).sqrt() * (2.0 * PI * self.uniform()).cos()
    }
}

/// One stretch of driving: duration (s), centre speed (m/s), heading rate (rad/s, clockwise).
type Leg = (f64, f64, f64);

/// The legs of a course of about `length` m of centre travel, with 1 s at rest at each end.
fn legs(course: Course, length: f64, rng: &mut Random) -> Vec<Leg> {
    let mut out = vec![(1.0, 0.0, 0.0)];
    let mut travelled = 0.0;
    match course {
        Course::Gentle => {
            // Curvature: an Ornstein-Uhlenbeck process over distance (0.2 1/m rms, 4 m
            // correlation), in 0.5 m legs; speed drifts between 0.5 and 1.1 m/s.
            let (mut k, mut v): (f64, f64) = (0.0, 0.8);
            while travelled < length {
                let step = 0.5;
                let a = (-step / 4.0f64).exp();
                k = a * k + (1.0 - a * a).sqrt() * 0.2 * rng.normal();
                v = (v + 0.05 * rng.normal()).clamp(0.5, 1.1);
                out.push((step / v, v, v * k.clamp(-0.33, 0.33)));
                travelled += step;
            }
        }
        Course::Tight => {
            while travelled < length {
                let straight = 1.0 + 3.0 * rng.uniform();
                let v = 0.4 + 0.3 * rng.uniform();
                out.push((straight / v, v, 0.0));
                travelled += straight;
                let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
                let angle = (60.0 + 240.0 * rng.uniform()).to_radians();
                if rng.uniform() < 0.25 {
                    // A spin on the spot at 0.8 rad/s.
                    out.push((angle / 0.8, 0.0, sign * 0.8));
                } else {
                    let radius = 0.3 + 0.9 * rng.uniform();
                    out.push((angle * radius / v, v, sign * v / radius));
                    travelled += angle * radius;
                }
            }
        }
    }
    out.push((1.0, 0.0, 0.0));
    out
}

/// Drives a course of about `length` m from `start` (x, y, heading) with the generator's own
/// random numbers of `seed`.
pub fn run(course: Course, length: f64, s: &Settings, start: (f64, f64, f64), seed: u64) -> SimRun {
    let mut rng = Random(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ 0x5A17);
    let plan = legs(course, length, &mut rng);
    let rate = 50.0;
    let sub = 20u32;
    let dt = 1.0 / (rate * f64::from(sub));
    let b = s.truth.track_width;
    let per_metre = [s.truth.left_diameter, s.truth.right_diameter]
        .map(|d| f64::from(s.truth.ticks_per_rev) / (PI * d));
    let mut turn = [
        0.25 + 5000.0 * rng.uniform(),
        -0.75 - 5000.0 * rng.uniform(),
    ];
    let (mut x, mut y, mut h) = start;
    let mut out = SimRun {
        samples: Vec::new(),
        reference: Vec::new(),
        truth: Vec::new(),
    };
    let mut n = 0u64;
    let mut record = |n: u64, x: f64, y: f64, h: f64, turn: &[f64; 2], rng: &mut Random| {
        let t = n as f64 / rate;
        out.samples.push(Sample {
            t,
            left: turn[0].floor() as i64,
            right: turn[1].floor() as i64,
            ..Sample::default()
        });
        if n.is_multiple_of(5) {
            let wrapped = (h + s.heading_sigma * rng.normal() + PI).rem_euclid(2.0 * PI) - PI;
            out.reference.push(RefPoint {
                t,
                x: x + s.sigma_axis * rng.normal(),
                y: y + s.sigma_axis * rng.normal(),
                heading: Some(wrapped),
                sigma_h: None,
            });
        }
        out.truth.push((x, y, h));
    };
    record(0, x, y, h, &turn, &mut rng);
    let mut step = 0u64;
    for (duration, v, w) in plan {
        let steps = (duration / dt).round().max(1.0) as u64;
        for _ in 0..steps {
            let (ds, dh) = (v * dt, w * dt);
            let chord = if dh.abs() > 1e-12 {
                2.0 * ds / dh * (dh / 2.0).sin()
            } else {
                ds
            };
            let mid = h + dh / 2.0;
            x += chord * mid.sin();
            y += chord * mid.cos();
            h += dh;
            for (i, travel) in [ds + dh * b / 2.0, ds - dh * b / 2.0]
                .into_iter()
                .enumerate()
            {
                let slip = s.q * travel.abs().sqrt() * rng.normal();
                turn[i] += (travel + slip) * per_metre[i];
            }
            step += 1;
            if step.is_multiple_of(u64::from(sub)) {
                n += 1;
                record(n, x, y, h, &turn, &mut rng);
            }
        }
    }
    out
}
