//! Link to the unit (placeholder).
#![allow(missing_docs)]
use anyhow::{bail, Result};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
pub enum ConfigAction {
    Get(Option<String>),
    Set(String, String),
    Save,
    Push(PathBuf, bool),
    Raw(String),
}
pub fn monitor(_p: &str, _b: u32, _d: Option<f64>, _c: Option<u64>, _e: u64) -> Result<ExitCode> {
    bail!("todo")
}
pub fn record(
    _p: &str,
    _b: u32,
    _o: &Path,
    _r: Option<&Path>,
    _d: Option<f64>,
    _c: Option<u64>,
    _x: bool,
) -> Result<ExitCode> {
    bail!("todo")
}
pub fn decode(_f: &Path, _o: Option<&Path>) -> Result<ExitCode> {
    bail!("todo")
}
pub fn config(_p: &str, _b: u32, _a: ConfigAction) -> Result<ExitCode> {
    bail!("todo")
}
