//! The subcommands behind the command line (`main.rs` only parses arguments): each reads its
//! files, calls the library and prints or writes the result.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use anyhow::{anyhow, Context, Result};

mod calibrate;
mod replay;
mod simulate;
mod validate;
mod validate_ensemble;

pub use crate::link::{config, decode, monitor, record, ConfigAction};
pub use calibrate::{calibrate, CalibrateOptions, GeometryArgs};
pub use replay::replay;
pub use simulate::{simulate, SimulateOptions};
pub use validate::{validate, validation_report};
pub use validate_ensemble::{read_run_list, validate_ensemble, EnsembleOptions};

fn create(path: &Path) -> Result<BufWriter<File>> {
    Ok(BufWriter::new(File::create(path).with_context(|| {
        format!("{}: cannot create", path.display())
    })?))
}

/// Helper for errors about files.
pub fn file_err(path: &Path, e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("{}: {e}", path.display())
}
