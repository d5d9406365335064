//! Hardware-free core of the odometry unit.
//!
//! Everything here is plain `no_std` Rust with no HAL, no `cortex-m` and no `defmt`, so the
//! firmware (`src/main.rs`) and the host tool (`odoctl`) share one implementation and the
//! host tests (`host-tests/`) exercise exactly the code that runs on the STM32F401.
//!
//! It implements Jilek, Burian, Kriz, "Odometry Calibration of a Chassis with Differential
//! Steering": odometry by eqs (1)-(15), uncertainty by eqs (19)-(28).
//!
//! Conventions everywhere: wheel 1 = left, wheel 2 = right; x east, y north; heading alpha = 0
//! along +y, growing clockwise (dx = d sin alpha, dy = d cos alpha); SI units (metres,
//! radians, seconds); `delta` in metres per increment.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Errors are returned, never unwrapped, in code that runs on the unit.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub(crate) mod bytes;
pub mod console;
pub mod crc;
pub mod decimal;
pub mod mavlink;
pub mod odometry;
pub mod protocol;
pub mod settings;
pub mod timing;
pub mod unit;
