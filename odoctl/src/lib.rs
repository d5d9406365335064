//! `odoctl`, the host tool of the odometry unit: live stream and configuration over a serial
//! port or TCP (QEMU), replay of recorded counts through the core integrator, simulation, and
//! the paper's calibration against an RTK GNSS reference (Jilek, Burian, Kriz).
//!
//! The library holds everything the binary does, so the tests can reach it; the odometry
//! itself is always `odo_unit`'s integrator, never a copy.
// Unsafe code only in `memory` (one allocator setting, through libc) and `interrupt` (the
// Ctrl-C handler, through libc).
#![deny(unsafe_code)]
#![warn(missing_docs)]

/// `println!` that ignores write errors (a closed pipe, as with `odoctl ... | head`, ends the
/// output quietly instead of panicking).
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

pub mod calib;
pub mod cancel;
pub mod cli;
pub mod commands;
pub mod config;
pub mod csvio;
pub mod interrupt;
pub mod link;
pub mod mavlink;
pub mod memory;
pub mod optim;
pub mod plots;
pub mod reference;
pub mod replay;
pub mod ros;
pub mod simulate;
pub mod stats;
pub mod text;
