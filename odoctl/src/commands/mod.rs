//! The subcommands, one module each: a command reads its files, calls the library and prints
//! or writes the result. `main.rs` parses the command line ([`crate::cli`]) and calls
//! the command's `run`.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};

use crate::calib;
use crate::cli::ReferenceArgs;
use crate::reference::geodetic::parse_origin;
use crate::reference::{OriginChoice, ReferenceOptions};

pub mod bridge;
pub mod calibrate;
pub mod config;
pub mod decode;
pub mod live;
pub mod live_batch;
pub mod monitor;
pub mod pool;
pub mod record;
pub mod recording;
pub mod reference;
pub mod replay;
pub mod simulate;
pub mod umbmark;
pub mod validate;
pub mod validate_ensemble;

/// A buffered new file, or an error naming it.
fn create(path: &Path) -> Result<BufWriter<File>> {
    Ok(BufWriter::new(File::create(path).with_context(|| {
        format!("{}: cannot create", path.display())
    })?))
}

/// The antenna lever arm `(forward, left)` (m) of a calibration result (`[fit]`), (0, 0)
/// without one; printed when there is one. `validate` and its ensemble apply it to the runs.
fn lever_arm(config: Option<&Path>) -> Result<(f64, f64)> {
    let antenna = match config {
        Some(p) => calib::read_lever_arm(p)?,
        None => (0.0, 0.0),
    };
    if antenna != (0.0, 0.0) {
        crate::outln!(
            "antenna lever arm from {}: {:.4} m forward, {:.4} m left of the axle centre",
            config.map_or(String::new(), |p| p.display().to_string()),
            antenna.0,
            antenna.1
        );
    }
    Ok(antenna)
}

/// Helper for errors about files.
pub fn file_err(path: &Path, e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("{}: {e}", path.display())
}

/// How `--reference` is read: the loader's options from its command-line options.
pub fn reference_options(args: &ReferenceArgs) -> Result<ReferenceOptions> {
    if let Some(l) = args.leap_seconds.filter(|l| !(0..=100).contains(l)) {
        bail!("--leap-seconds {l}: must be in 0..=100");
    }
    Ok(ReferenceOptions {
        format: args.reference_format,
        min_fix: args.min_fix,
        origin: match &args.origin {
            Some(s) => OriginChoice::Given(parse_origin(s)?),
            None => OriginChoice::OpeningStandstill,
        },
        leap_seconds: args.leap_seconds,
        mcap: crate::reference::mcap_pose::McapSelect {
            topic: args.reference_topic.clone(),
            frames: args
                .reference_frames
                .as_deref()
                .map(crate::reference::mcap_pose::parse_frames)
                .transpose()?,
        },
        time_offset: args.time_offset,
        clock_ppm: args.clock_ppm,
    })
}
