//! Test support shared by the host tests (`host-tests/`), `odoctl`'s tests and the benchmarks
//! (`bench/`): the random generator ([`Rng`], also the one `odoctl simulate` draws from), the
//! f64 reference model of the paper's equations ([`reference`]), drive generators
//! ([`drive`]) and a chassis with out-of-round wheels ([`wobbly_wheels`]).
//!
//! `no_std` without the default `std` feature (the benchmark on the Cortex-M4 uses the
//! generator only).
#![cfg_attr(not(feature = "std"), no_std)]
#![warn(missing_docs)]

#[cfg(feature = "std")]
extern crate std;

#[cfg(feature = "std")]
pub mod drive;
#[cfg(feature = "std")]
pub mod reference;
mod rng;

pub use rng::Rng;

use odo_unit::odometry::{ChassisParams, WheelHarmonics};

/// The designed chassis with out-of-round wheels: per-angle wheel functions of eqs (3)-(5)
/// (three harmonics each, up to 2e-3 relative) for the wheel-function tests and benchmarks.
pub fn wobbly_wheels() -> ChassisParams {
    ChassisParams {
        left_wheel: WheelHarmonics {
            cos: [0.002, -0.0005, 0.0001],
            sin: [0.001, 0.0003, 0.0],
        },
        right_wheel: WheelHarmonics {
            cos: [-0.001, 0.0, 0.0002],
            sin: [0.0015, -0.0002, 0.0001],
        },
        ..ChassisParams::DESIGNED
    }
}
