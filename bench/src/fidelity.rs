//! Numerical fidelity on the host: the integrator's fixed-point arithmetic (bit-identical to
//! the target's: integers, and IEEE f32 without fused operations) and a naive f32 integrator,
//! each against an f64 implementation of eqs (6)-(15), after 1, 10 and 100 km of a synthetic
//! drive at 50 Hz at about 1 m/s.

use odo_core::odometry::{ChassisParams, IndexRefs, Integrator, Pose, WheelCounts};
use std::f64::consts::PI;

use crate::inputs::Rng;
use crate::naive::NaiveIntegrator;

/// Eqs (6)-(15) in f64.
struct Reference {
    c: [f64; 2],
    w: f64,
    x: f64,
    y: f64,
    alpha: f64,
}

impl Reference {
    fn step(&mut self, d: [i64; 2]) {
        let (s1, s2) = (self.c[0] * d[0] as f64, self.c[1] * d[1] as f64);
        let (ds, da) = ((s1 + s2) / 2.0, (s1 - s2) / self.w);
        let dd = if da == 0.0 {
            ds
        } else {
            ds * 2.0 / da * (da / 2.0).sin()
        };
        let th = self.alpha + da / 2.0;
        self.x += dd * th.sin();
        self.y += dd * th.cos();
        self.alpha += da;
    }
}

/// Prints the fidelity table.
pub fn run() {
    let p = ChassisParams {
        left_diameter: 0.2608,
        right_diameter: 0.2607,
        track_width: 0.5656,
        ..ChassisParams::DESIGNED
    };
    let c = [
        PI * p.left_diameter / 20_000.0,
        PI * p.right_diameter / 20_000.0,
    ];
    let mut integ = match Integrator::new(&p, WheelCounts::default(), Pose::default()) {
        Ok(i) => i,
        Err(e) => {
            eprintln!("fidelity: bad parameters: {e}");
            std::process::exit(1);
        }
    };
    let mut reference = Reference {
        c,
        w: p.track_width,
        x: 0.0,
        y: 0.0,
        alpha: 0.0,
    };
    let mut naive = NaiveIntegrator::new(
        [p.left_diameter, p.right_diameter],
        p.track_width,
        20_000,
        0.0,
    );
    let mut rng = Rng(2026);
    let mut g = [0i64; 2];
    let mut path = 0.0f64;
    let mut samples = 0u64;
    let (mut speed, mut left) = ([0.0f64; 2], 0u32);
    let mut acc = [0.0f64; 2];
    println!("fidelity: synthetic drive at 50 Hz, about 1 m/s, straights, arcs, pivots, reversing");
    println!(
        "fidelity: encoder resolution {:.4} mm per increment",
        c[0] * 1e3
    );
    println!("| path | samples | fixed-point position error | fixed-point heading error | naive f32 position error | naive f32 heading error |");
    println!("| --- | --- | --- | --- | --- | --- |");
    for target_km in [1.0f64, 10.0, 100.0] {
        while path < target_km * 1000.0 {
            if left == 0 {
                left = 50 + (rng.next() % 1500) as u32;
                let v = 0.3 + 1.2 * ((rng.next() >> 11) as f64 / (1u64 << 53) as f64);
                let v = if rng.next().is_multiple_of(10) { -v } else { v };
                speed = match rng.next() % 6 {
                    0 | 1 => [v, v],
                    2 => [v, 0.6 * v],
                    3 => [0.6 * v, v],
                    4 => [0.3 * v, -0.3 * v],
                    _ => [0.0, 0.0],
                };
            }
            left -= 1;
            let mut d = [0i64; 2];
            for i in 0..2 {
                acc[i] += speed[i] / c[i] / 50.0;
                d[i] = acc[i].round() as i64;
                acc[i] -= d[i] as f64;
            }
            g = [g[0] + d[0], g[1] + d[1]];
            integ.step(
                WheelCounts {
                    left: g[0],
                    right: g[1],
                },
                IndexRefs::default(),
            );
            reference.step(d);
            naive.step([d[0] as i32, d[1] as i32]);
            path += (c[0] * d[0].abs() as f64 + c[1] * d[1].abs() as f64) / 2.0;
            samples += 1;
        }
        let pose = integ.pose();
        let fixed_pos = (pose.x - reference.x).hypot(pose.y - reference.y);
        let fixed_head = (pose.heading - reference.alpha).abs();
        let naive_pos = (f64::from(naive.x) - reference.x).hypot(f64::from(naive.y) - reference.y);
        let naive_head = (f64::from(naive.alpha) - reference.alpha).abs();
        println!(
            "| {target_km:.0} km | {samples} | {:.2e} m | {:.2e} rad | {:.2e} m | {:.2e} rad |",
            fixed_pos, fixed_head, naive_pos, naive_head
        );
    }
}
