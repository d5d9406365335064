//! Benchmarks of the odometry core.
//!
//! On the target (`thumbv7em-none-eabihf`, run under QEMU with `-icount shift=0,sleep=off`,
//! where an untouched TIM2 counter advances one per executed instruction): instructions per
//! integrator step split into odometry and uncertainty, the covariance model, a naive
//! `libm::sinf`/`cosf` f32 version of the same step, the frame encoder, the command parser,
//! and the stack used by one step. On the host: numerical fidelity of the integrator
//! against an f64 reference after 1, 10 and 100 km, beside a naive f32 integrator; and
//! (`odo-bench calibrate [accuracy|speed]`, host) the accuracy and the speed of `odoctl`'s
//! calibration on simulated runs; (`odo-bench indoor DIR`, host) the accuracy of the
//! calibration against motion capture and SLAM trajectories and of the square test;
//! (`odo-bench live DIR`, host) the live calibration's update cost, end-to-final time and
//! agreement with the batch calibration on a 3 km drive.
//!
//! Every table is printed as Markdown: `bench/run` runs them and writes docs/RESULTS.md.
#![cfg_attr(target_os = "none", no_std, no_main)]

mod inputs;
mod naive;

#[cfg(not(target_os = "none"))]
mod calibration;
#[cfg(not(target_os = "none"))]
mod cpu_time;
#[cfg(not(target_os = "none"))]
mod fidelity;
#[cfg(not(target_os = "none"))]
mod indoor;
#[cfg(not(target_os = "none"))]
mod live;
#[cfg(not(target_os = "none"))]
mod markdown;
#[cfg(not(target_os = "none"))]
mod odoctl_binary;
#[cfg(not(target_os = "none"))]
mod stdout_capture;

/// `odo-bench` prints the fidelity table; `odo-bench calibrate [accuracy|speed]` the
/// calibration's accuracy and speed tables (both without a second argument); `odo-bench
/// indoor DIR` the indoor calibration's accuracy tables (scratch files in DIR); `odo-bench live
/// DIR` the live calibration's section.
#[cfg(not(target_os = "none"))]
fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("calibrate") {
        // As odoctl's main does (odoctl::memory), so the in-process figures are odoctl's.
        odoctl::memory::keep_freed_memory();
        calibration::run(args.get(1).map(String::as_str));
    } else if args.first().map(String::as_str) == Some("indoor") {
        let dir = args.get(1).map_or_else(
            || std::env::temp_dir().join("odo-bench-indoor"),
            std::path::PathBuf::from,
        );
        indoor::run(&dir);
    } else if args.first().map(String::as_str) == Some("live") {
        let dir = args.get(1).map_or_else(
            || std::env::temp_dir().join("odo-bench-live"),
            std::path::PathBuf::from,
        );
        live::run(&dir);
    } else {
        fidelity::run();
    }
}

#[cfg(target_os = "none")]
mod target;
#[cfg(target_os = "none")]
mod target_protocol;
