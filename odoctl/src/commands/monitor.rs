//! `odoctl monitor`: the live pose stream as a table, with the link's health.

use std::io::Write;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use odo_unit::protocol::Message;

use crate::cli::MonitorArgs;
use crate::link::{describe, health, open, table_row, Session, TABLE_HEADER};

/// `odoctl monitor`.
pub fn run(a: &MonitorArgs) -> Result<ExitCode> {
    monitor(&a.port.port, a.port.baud, a.duration, a.count, a.every)
}

/// The live pose stream as a table until `duration`, `count` records or the end of the link.
pub fn monitor(
    port: &str,
    baud: u32,
    duration: Option<f64>,
    count: Option<u64>,
    every: u64,
) -> Result<ExitCode> {
    let mut s = Session::new(open(port, baud)?, None)?;
    let end = duration.map(|d| Instant::now() + Duration::from_secs_f64(d));
    let mut out = std::io::stdout().lock();
    writeln!(out, "{TABLE_HEADER}")?;
    let mut last_report = Instant::now();
    let mut n = 0u64;
    while let Some(f) = s.next_frame(end)? {
        match &f.message {
            Message::Pose(r) => {
                if n.is_multiple_of(every.max(1)) {
                    writeln!(out, "{}", table_row(r))?;
                }
                n += 1;
                if count.is_some_and(|c| n >= c) {
                    break;
                }
            }
            _ => {
                if let Some(d) = describe(&f) {
                    writeln!(out, "{d}")?;
                }
            }
        }
        if last_report.elapsed() >= Duration::from_secs(5) {
            writeln!(out, "# link: {}", health(&s.decoder_stats(), &s.stats))?;
            last_report = Instant::now();
        }
        out.flush()?;
    }
    writeln!(out, "# link: {}", health(&s.decoder_stats(), &s.stats))?;
    out.flush()?;
    if s.closed() {
        bail!("the unit closed the connection after {n} pose records");
    }
    Ok(ExitCode::SUCCESS)
}
