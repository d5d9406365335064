//! The subcommands, one module each: a command reads its files, calls the library and prints
//! or writes the result. `main.rs` parses the command line ([`crate::cli`]) and calls
//! the command's `run`.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};

use crate::cli::ReferenceArgs;
use crate::reference::geodetic::parse_origin;
use crate::reference::{OriginChoice, ReferenceOptions};

pub mod bridge;
pub mod calibrate;
pub mod config;
pub mod decode;
pub mod monitor;
pub mod record;
pub mod replay;
pub mod simulate;
pub mod validate;
pub mod validate_ensemble;

/// A buffered new file, or an error naming it.
fn create(path: &Path) -> Result<BufWriter<File>> {
    Ok(BufWriter::new(File::create(path).with_context(|| {
        format!("{}: cannot create", path.display())
    })?))
}

/// Helper for errors about files.
pub fn file_err(path: &Path, e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("{}: {e}", path.display())
}

/// How `--reference` is read: the loader's options from its command-line options.
pub fn reference_options(args: &ReferenceArgs) -> Result<ReferenceOptions> {
    if !(0..=100).contains(&args.leap_seconds) {
        bail!("--leap-seconds {}: must be in 0..=100", args.leap_seconds);
    }
    Ok(ReferenceOptions {
        format: args.reference_format,
        min_fix: args.min_fix,
        origin: match &args.origin {
            Some(s) => OriginChoice::Given(parse_origin(s)?),
            None => OriginChoice::OpeningStandstill,
        },
        leap_seconds: args.leap_seconds,
    })
}
