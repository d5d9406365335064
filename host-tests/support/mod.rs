//! The QEMU helpers of the host tests (booting the image, its serial link, the bit-exact
//! replay check); the generator, the f64 reference model and the drives are `odo-testkit`
//! (`host-tests/testkit/`).
// Each test binary uses a different part of this module.
#![allow(dead_code)]

pub mod qemu;
