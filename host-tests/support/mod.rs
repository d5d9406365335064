//! The shared code of the host tests: the check of the documented bandwidth tables, the QEMU
//! helpers (booting the image, its serial link, the bit-exact replay check), the timing
//! tests' PPS simulation and the settings tests' simulated flash; the generator, the f64
//! reference model and the drives are `odo-testkit` (`host-tests/testkit/`).
// Each test binary uses a different part of this module.
#![allow(dead_code)]

pub mod budget;
pub mod pps_sim;
pub mod qemu;
pub mod settings;
