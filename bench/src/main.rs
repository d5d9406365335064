//! Benchmarks of the odometry core.
//!
//! On the target (`thumbv7em-none-eabihf`, run under QEMU with `-icount shift=0,sleep=off`,
//! where an untouched TIM2 counter advances one per executed instruction): instructions per
//! integrator step split into odometry and uncertainty, the covariance model, a naive
//! `libm::sinf`/`cosf` f32 version of the same step, the frame encoder, the command parser,
//! and the stack used by one step. On the host: numerical fidelity of the integrator
//! against an f64 reference after 1, 10 and 100 km, beside a naive f32 integrator; and
//! (`odo-bench calibrate`, host) the speed of `odoctl`'s calibration on simulated runs.
//!
//! `bench/run` builds and runs both and prints the tables.
#![cfg_attr(target_os = "none", no_std, no_main)]

mod inputs;
mod naive;

#[cfg(not(target_os = "none"))]
mod calibration;
#[cfg(not(target_os = "none"))]
mod fidelity;

/// `odo-bench` prints the fidelity table; `odo-bench calibrate` the calibration speed
/// (`odoctl`'s eq 16 fit and whole calibration on simulated runs).
#[cfg(not(target_os = "none"))]
fn main() {
    if std::env::args().nth(1).as_deref() == Some("calibrate") {
        // As odoctl's main does (odoctl::memory), so the in-process figures are odoctl's.
        odoctl::memory::keep_freed_memory();
        calibration::run();
    } else {
        fidelity::run();
    }
}

#[cfg(target_os = "none")]
mod target;
#[cfg(target_os = "none")]
mod target_protocol;
