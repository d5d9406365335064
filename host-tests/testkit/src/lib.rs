//! Test support shared by the host tests (`host-tests/`), `odoctl`'s tests and the benchmarks
//! (`bench/`): the random generator ([`Rng`], also the one `odoctl simulate` draws from), the
//! f64 reference model of the paper's equations ([`reference`]) and drive generators
//! ([`drive`]).
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
