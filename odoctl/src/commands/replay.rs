//! `odoctl replay`: recorded counts through the core integrator, printed or written (and,
//! with `--mcap`, recorded as ROS 2 topics).

use std::io::{BufWriter, Write};
use std::path::Path;
use std::process::ExitCode;

use anyhow::{bail, Result};
use odo_unit::odometry::Pose;

use crate::cli::ReplayArgs;
use crate::config::{self as cfg};
use crate::csvio;
use crate::replay as rp;

use super::create;

/// `odoctl replay`: the MCAP recording first when `--mcap` is given, then the replay.
pub fn run(a: &ReplayArgs) -> Result<ExitCode> {
    let (config, sets) = (a.params.config.as_deref(), &a.params.sets);
    let start = (a.x, a.y, a.heading);
    if let Some(m) = &a.mcap {
        let names = crate::ros::names::RosNames::resolve(&a.ros.options("odoctl"))?;
        crate::ros::export::replay_hook(m, &a.samples, config, sets, start, names)?;
    }
    replay(&a.samples, config, sets, start, a.check, a.out.as_deref())
}

/// Replays `samples` from `start` (x, y, heading) to `out` (stdout when `None`); with `check`,
/// compares with the unit's pose columns (exit code 1 on a difference).
pub fn replay(
    samples: &Path,
    config: Option<&Path>,
    sets: &[String],
    start: (f64, f64, f64),
    check: bool,
    out: Option<&Path>,
) -> Result<ExitCode> {
    let params = cfg::load(config, sets)?;
    let s = csvio::read_samples(samples)?;
    let rows = rp::replay(
        &params,
        &s,
        Pose {
            x: start.0,
            y: start.1,
            heading: start.2,
        },
    )?;
    match out {
        Some(p) => {
            let mut w = create(p)?;
            rp::write_replay(&mut w, &rows)?;
            w.flush()?;
        }
        None => {
            let stdout = std::io::stdout();
            let mut w = BufWriter::new(stdout.lock());
            rp::write_replay(&mut w, &rows)?;
            w.flush()?;
        }
    }
    if check {
        let c = rp::check_against_unit(&s, &rows);
        if c.compared == 0 {
            bail!("{}: --check: the file carries no unit pose columns (x, y, heading, sigma_x, sigma_y, sigma_heading)", samples.display());
        }
        if c.mismatches > 0 {
            eprintln!(
                "replay --check: {} of {} rows differ from the unit's records; first: {}",
                c.mismatches,
                c.compared,
                c.first.unwrap_or_default()
            );
            return Ok(ExitCode::FAILURE);
        }
        eprintln!(
            "replay --check: all {} rows match the unit's records bit for bit",
            c.compared
        );
    }
    Ok(ExitCode::SUCCESS)
}
