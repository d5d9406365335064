//! A simulated trajectory reference (motion capture, SLAM) of the simulated chassis, written as
//! a TUM file or a ROS 2 MCAP recording (`odoctl simulate --tum FILE --mcap-reference FILE`):
//! the pose of a marker at the lever arm `(forward, left)` from the axle centre, in a frame
//! turned and shifted from the simulation's, on a clock offset from the samples', optionally
//! drifting as a SLAM trajectory does.

use super::antenna_position;
use super::trajectory::{wrap, TrajectoryPose};
use crate::simulate::Rng;

/// How the simulated trajectory reference sees the run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectorySim {
    /// The reference frame: a point at `p` in the simulation's plane is at
    /// `R(rotation) p + (x, y)` in it, `R` counter-clockwise (m, m, rad).
    pub frame: (f64, f64, f64),
    /// Marker position from the axle centre: forward, left (m).
    pub marker: (f64, f64),
    /// Marker yaw from the chassis' forward axis, counter-clockwise (rad).
    pub marker_yaw: f64,
    /// A pose every this many samples.
    pub every: usize,
    /// Horizontal RMS noise of the positions (m).
    pub sigma: f64,
    /// Noise of the yaw (rad).
    pub yaw_sigma: f64,
    /// Slow drift of the positions: a random walk of each axis growing by this many metres
    /// per square root of a second of the samples' time (m/sqrt(s)); 0: none.
    pub drift: f64,
    /// Samples' `t` minus the stamp at the middle of the stamps (s): what `calibrate
    /// --time-offset` takes.
    pub time_offset: f64,
    /// d(samples' t)/d(stamp) - 1 (ppm): what `calibrate --clock-ppm` takes.
    pub clock_ppm: f64,
    /// Seed of the noise.
    pub seed: u64,
}

/// The marker's poses at every `every`-th sample instant: `times` the samples' `t` (s), `truth`
/// the true centre pose at each (x, y, heading clockwise from +y).
pub fn trajectory_poses(
    times: &[f64],
    truth: &[(f64, f64, f64)],
    sim: &TrajectorySim,
) -> Vec<TrajectoryPose> {
    let mut rng = Rng::new(sim.seed ^ 0x7A_3EC7_0A11);
    // The drift's own generator: the noise is the same with or without it.
    let mut walk = Rng::new(sim.seed ^ 0xD1_2F7E_0A11);
    let (mut drift, mut t_prev) = ((0.0, 0.0), times.first().copied().unwrap_or(0.0));
    let (fx, fy, rot) = sim.frame;
    let (s, c) = rot.sin_cos();
    let axis = sim.sigma / std::f64::consts::SQRT_2;
    // Samples' t = s + offset + r (s - s_mid), s_mid the middle of the stamps.
    let every = sim.every.max(1);
    let last = (times.len().max(1) - 1) / every * every;
    let (d, r) = (sim.time_offset, sim.clock_ppm * 1e-6);
    let s_mid = 0.5 * (times.first().unwrap_or(&0.0) + times.get(last).unwrap_or(&0.0)) - d;
    let mut out = Vec::new();
    for (k, (t, &(x, y, h))) in times.iter().zip(truth).enumerate() {
        if k % every != 0 {
            continue;
        }
        let (mx, my) = antenna_position(x, y, h, sim.marker.0, sim.marker.1);
        let (mx, my) = (mx + axis * rng.normal(), my + axis * rng.normal());
        if sim.drift > 0.0 {
            let step = sim.drift * (t - t_prev).max(0.0).sqrt();
            drift = (
                drift.0 + step * walk.normal(),
                drift.1 + step * walk.normal(),
            );
            t_prev = *t;
        }
        let (mx, my) = (mx + drift.0, my + drift.1);
        // Chassis yaw counter-clockwise from +x, then the frame's turn and the marker's.
        let yaw = wrap(std::f64::consts::FRAC_PI_2 - h + rot + sim.marker_yaw)
            + sim.yaw_sigma * rng.normal();
        out.push(TrajectoryPose {
            t: (t - d + r * s_mid) / (1.0 + r),
            position: [c * mx - s * my + fx, s * mx + c * my + fy, 0.0],
            orientation: [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()],
            line: out.len() + 1,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::trajectory::{heading_of_yaw, yaw};

    #[test]
    fn frame_marker_and_clock() {
        let sim = TrajectorySim {
            frame: (3.0, -2.0, std::f64::consts::FRAC_PI_2),
            marker: (0.5, 0.0),
            marker_yaw: 0.25,
            every: 2,
            sigma: 0.0,
            yaw_sigma: 0.0,
            drift: 0.0,
            time_offset: 10.0,
            clock_ppm: 0.0,
            seed: 1,
        };
        // Heading 0: facing +y; the marker 0.5 m ahead at (1, 2.5); turned 90 deg ccw: (-2.5, 1).
        let p = trajectory_poses(&[0.0, 0.02, 0.04], &[(1.0, 2.0, 0.0); 3], &sim);
        assert_eq!(p.len(), 2);
        assert!((p[1].t - (0.04 - 10.0)).abs() < 1e-12);
        assert!((p[0].position[0] - 0.5).abs() < 1e-12, "{:?}", p[0]);
        assert!((p[0].position[1] - -1.0).abs() < 1e-12, "{:?}", p[0]);
        // Yaw: chassis +y = 90 deg, + 90 frame + marker.
        let y = yaw(p[0].orientation).unwrap();
        assert!((wrap(y - (std::f64::consts::PI + 0.25))).abs() < 1e-12);
        assert!(heading_of_yaw(y).is_finite());
    }

    #[test]
    fn drift_is_a_random_walk_beside_the_same_noise() {
        let mut sim = TrajectorySim {
            frame: (0.0, 0.0, 0.0),
            marker: (0.0, 0.0),
            marker_yaw: 0.0,
            every: 1,
            sigma: 0.001,
            yaw_sigma: 0.0,
            drift: 0.0,
            time_offset: 0.0,
            clock_ppm: 0.0,
            seed: 3,
        };
        let times: Vec<f64> = (0..10_000).map(|k| k as f64 * 0.01).collect();
        let truth = vec![(0.0, 0.0, 0.0); times.len()];
        let still = trajectory_poses(&times, &truth, &sim);
        sim.drift = 0.002;
        let drifting = trajectory_poses(&times, &truth, &sim);
        let gap = |k: usize| {
            let (a, b) = (still[k].position, drifting[k].position);
            (a[0] - b[0]).hypot(a[1] - b[1])
        };
        // The noise is unchanged; the walk starts at 0 and stays within 5 sigma of 100 s.
        assert_eq!(gap(0), 0.0);
        let bound = 5.0 * 0.002 * 100f64.sqrt() * std::f64::consts::SQRT_2;
        assert!(gap(9_999) > 0.0 && gap(9_999) < bound, "{}", gap(9_999));
        assert!((still[5].position[0] - drifting[5].position[0]).abs() < 0.002);
    }
}
