//! `odoctl simulate`: a synthetic run written as SAMPLES and REFERENCE CSV.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};

use crate::config::{self as cfg};
use crate::csvio;
use crate::reference::cli::ReceiverArgs;
use crate::simulate::{self, default_truth, PathKind};

use super::create;

/// Options of `odoctl simulate`.
pub struct SimulateOptions {
    /// Output SAMPLES CSV.
    pub samples: PathBuf,
    /// Output REFERENCE CSV.
    pub reference: PathBuf,
    /// True parameters file.
    pub truth: Option<PathBuf>,
    /// `KEY=VALUE` overrides of the truth.
    pub sets: Vec<String>,
    /// Where to write the truth.
    pub truth_out: Option<PathBuf>,
    /// Path shape.
    pub path: PathKind,
    /// Path length (m).
    pub length: f64,
    /// Rate, speed, noise, start and seed.
    pub settings: simulate::SimSettings,
}

/// Most samples `simulate` writes (about 10 GB of CSV).
pub const MAX_SAMPLES: f64 = 1e8;

/// `odoctl simulate`.
pub fn simulate(o: &SimulateOptions, logs: &ReceiverArgs) -> Result<ExitCode> {
    let mut truth = match &o.truth {
        Some(p) => cfg::read_params(p, default_truth())?,
        None => default_truth(),
    };
    cfg::apply_sets(&mut truth, &o.sets)?;
    let truth = cfg::validated(truth, "true parameters")?;
    let run = &o.settings;
    if !(run.rate > 0.0 && run.rate <= 10_000.0) {
        bail!("--rate {}: must be in (0, 10000] Hz", run.rate);
    }
    if !(run.speed > 0.0 && run.speed <= 10.0) {
        bail!("--speed {}: must be in (0, 10] m/s", run.speed);
    }
    if o.length.is_nan()
        || o.length <= 0.0
        || !(run.slip >= 0.0 && run.slip_turn >= 0.0 && run.rtk_sigma >= 0.0)
    {
        bail!("--length must be positive, --slip, --slip-turn and --rtk-sigma non-negative");
    }
    // Each option is in range (main.rs, cli_values); together they must stay a finite run.
    let samples = o.length / run.speed * run.rate;
    if samples > MAX_SAMPLES {
        bail!(
            "--length {} m at --speed {} m/s and --rate {} Hz makes {samples:.3e} samples; at most {MAX_SAMPLES:e}",
            o.length,
            run.speed,
            run.rate
        );
    }
    let receiver = logs.receiver(run.rtk_sigma, run.heading_sigma, run.seed)?;
    let mut sim = simulate::simulate_path(o.path, o.length, truth, o.settings);
    logs.prepare(&mut sim, &receiver);
    logs.write(&sim, &receiver)?;
    let mut w = create(&o.samples)?;
    csvio::write_samples(&mut w, &sim.samples, csvio::SamplesLayout::Counts)?;
    w.flush()?;
    let mut w = create(&o.reference)?;
    csvio::write_reference(&mut w, &sim.reference)?;
    w.flush()?;
    if let Some(p) = &o.truth_out {
        let text = cfg::render_params(
            &truth,
            "odoctl simulate: the true parameters of the synthetic run",
            &[],
        );
        std::fs::write(p, text).with_context(|| format!("{}: cannot write", p.display()))?;
    }
    let travelled: f64 = sim
        .truth
        .windows(2)
        .map(|w| (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1))
        .sum();
    let turned: f64 = sim.truth.windows(2).map(|w| (w[1].2 - w[0].2).abs()).sum();
    crate::outln!(
        "simulated {} samples over {:.1} s: {:.1} m travelled, {:.0} deg turned; true left_diameter {}, right_diameter {}, track_width {}",
        sim.samples.len(),
        sim.samples.last().map_or(0.0, |s| s.t - sim.samples[0].t),
        travelled,
        turned.to_degrees(),
        truth.left_diameter,
        truth.right_diameter,
        truth.track_width
    );
    Ok(ExitCode::SUCCESS)
}
