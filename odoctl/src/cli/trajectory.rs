//! The options of `simulate` that write a trajectory reference (motion capture, SLAM).

use std::path::PathBuf;

use clap::Args;

use super::values as v;

/// Trajectory references of a simulated run (`simulate`).
#[derive(Debug, Clone, Args)]
pub struct TrajectoryArgs {
    /// Also write the reference as a TUM trajectory (`timestamp tx ty tz qx qy qz qw`) of the
    /// marker at `--antenna`.
    #[arg(long, value_name = "FILE")]
    pub tum: Option<PathBuf>,
    /// Also write it as a ROS 2 MCAP recording: `/reference/pose` (PoseStamped),
    /// `/reference/odom` (Odometry) and `/tf` (TFMessage, `world` -> `marker`).
    #[arg(long, value_name = "FILE")]
    pub mcap_reference: Option<PathBuf>,
    /// The trajectory's frame, `X,Y,DEG`: a point p of the simulation's plane is at
    /// R(DEG) p + (X, Y) in it (R counter-clockwise).
    #[arg(
        long,
        value_name = "X,Y,DEG",
        default_value = "0,0,0",
        allow_hyphen_values = true
    )]
    pub trajectory_frame: String,
    /// The marker's yaw from the chassis' forward axis (degrees, counter-clockwise).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::angle_deg)]
    pub marker_yaw_deg: f64,
    /// A trajectory pose every this many samples.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub trajectory_every: u32,
    /// Horizontal RMS noise of the trajectory's positions (m).
    #[arg(long, default_value_t = 0.0005, allow_negative_numbers = true, value_parser = v::sigma_m)]
    pub trajectory_sigma: f64,
    /// Noise of the trajectory's yaw (degrees).
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true, value_parser = v::sigma_deg)]
    pub trajectory_yaw_sigma_deg: f64,
    /// Slow drift of the trajectory's positions, as a SLAM trajectory drifts: a random walk of
    /// each axis growing by this many metres per square root of a second (m/sqrt(s)).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::sigma_m)]
    pub trajectory_drift: f64,
    /// The samples' t minus the trajectory's stamp at the middle of the stamps (s): what
    /// `calibrate --time-offset` takes.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::time_offset)]
    pub trajectory_time_offset: f64,
    /// d(samples' t)/d(stamp) - 1 of the trajectory's clock (ppm): what `calibrate --clock-ppm`
    /// takes.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = v::clock_ppm)]
    pub trajectory_clock_ppm: f64,
}
