//! Numerical fidelity on the host: the integrator's fixed-point arithmetic (bit-identical to
//! the target's: integers, and IEEE f32 without fused operations) and a naive f32 integrator,
//! each against the f64 reference model of the paper (`odo_testkit::reference`), after 1, 10
//! and 100 km of the testkit's drive (`odo_testkit::drive::Drive`) at 50 Hz.

use odo_testkit::drive::Drive;
use odo_testkit::reference::Reference;
use odo_testkit::Rng;
use odo_unit::odometry::{ChassisParams, IndexRefs, Integrator, Pose, WheelCounts};

use crate::markdown::{number, thousands};
use crate::naive::NaiveIntegrator;

/// Prints the fidelity table (Markdown, for docs/RESULTS.md).
pub fn run() {
    let p = ChassisParams {
        left_diameter: 0.2608,
        right_diameter: 0.2607,
        track_width: 0.5656,
        ..ChassisParams::DESIGNED
    };
    let mut integ = match Integrator::new(&p, WheelCounts::default(), Pose::default()) {
        Ok(i) => i,
        Err(e) => {
            eprintln!("fidelity: bad parameters: {e}");
            std::process::exit(1);
        }
    };
    let mut reference = Reference::new(&p, [0, 0], Pose::default());
    let c = reference.c;
    let mut naive = NaiveIntegrator::new(
        [p.left_diameter, p.right_diameter],
        p.track_width,
        p.ticks_per_rev,
        0.0,
    );
    let mut drive = Drive::new(Rng::new(2026), 1.0 / c[0], 50.0);
    let mut g = [0i64; 2];
    let mut path = 0.0f64;
    let mut samples = 0u64;
    println!(
        "The testkit's drive at 50 Hz (about 1 m/s: straights, arcs, pivots, reversing); the \
         encoder resolves {:.4} mm per increment.",
        c[0] * 1e3
    );
    println!();
    println!("| path | samples | fixed-point position error | fixed-point heading error | naive f32 position error | naive f32 heading error |");
    println!("| --- | --- | --- | --- | --- | --- |");
    for target_km in [1.0f64, 10.0, 100.0] {
        while path < target_km * 1000.0 {
            let d = drive.next().expect("an endless drive");
            g = [g[0] + d[0], g[1] + d[1]];
            integ.step(
                WheelCounts {
                    left: g[0],
                    right: g[1],
                },
                IndexRefs::default(),
            );
            reference.step(g, [None, None]);
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
            "| {target_km:.0} km | {} | {} m | {} rad | {} m | {} rad |",
            thousands(samples),
            number(fixed_pos),
            number(fixed_head),
            number(naive_pos),
            number(naive_head)
        );
    }
}
