//! `odoctl decode`: a captured raw byte stream decoded to a SAMPLES CSV.

use std::io::{BufWriter, Write};
use std::path::Path;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};

use crate::cli::DecodeArgs;
use crate::link::{decode_bytes, health};

/// `odoctl decode`.
pub fn run(a: &DecodeArgs) -> Result<ExitCode> {
    decode(&a.file, a.out.as_deref())
}

/// Decodes the raw capture `file` to `out` (stdout when `None`); reports on stderr.
pub fn decode(file: &Path, out: Option<&Path>) -> Result<ExitCode> {
    let bytes = std::fs::read(file).with_context(|| format!("{}: cannot read", file.display()))?;
    let stdout: Option<Box<dyn Write>> = match out {
        Some(_) => None,
        None => Some(Box::new(BufWriter::new(std::io::stdout().lock()))),
    };
    let (recorded, d, s) = decode_bytes(&bytes, out, stdout)?;
    eprint!("{}: {}", file.display(), recorded.report());
    eprintln!(
        "{}: {} pose records; {}",
        file.display(),
        recorded.rows(),
        health(&d, &s)
    );
    if recorded.rows() == 0 {
        bail!(
            "{}: no pose record in {} bytes",
            file.display(),
            bytes.len()
        );
    }
    if recorded.unwritten > 0 {
        bail!(
            "{}: {} records after a restart not written (give --out FILE to write each segment)",
            file.display(),
            recorded.unwritten
        );
    }
    Ok(ExitCode::SUCCESS)
}
