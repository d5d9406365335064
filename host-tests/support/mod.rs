//! Shared helpers of the host tests.
// Each test binary uses a different part of this module.
#![allow(dead_code)]

pub mod qemu;
