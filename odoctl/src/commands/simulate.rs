//! `odoctl simulate`: a synthetic run written as SAMPLES and REFERENCE CSV, and as receiver
//! logs (NMEA 0183, RTKLIB `.pos`) with `--nmea`, `--pos`.

use std::io::Write;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use odo_unit::odometry::ChassisParams;

use crate::cli::{PosTimeArg, ReceiverArgs, SimulateArgs, TrajectoryArgs};
use crate::config::{self as cfg};
use crate::csvio;
use crate::reference::geodetic::{parse_origin, Geodetic};
use crate::reference::simulated::{self, PosTime, ReceiverSim};
use crate::reference::simulated_trajectory::{trajectory_poses, TrajectorySim};
use crate::reference::{antenna_position, gps_time, parse_antenna, FixQuality};
use crate::reference::{mcap_pose, tum};
use crate::simulate::{self, default_truth, SimRun, SimSettings};

use super::create;

/// Most samples `simulate` writes (about 10 GB of CSV).
pub const MAX_SAMPLES: f64 = 1e8;

/// `odoctl simulate`.
pub fn run(a: &SimulateArgs) -> Result<ExitCode> {
    let logs = &a.receiver;
    let truth = true_params(a)?;
    let run = sim_settings(a);
    check_size(a.length, &run)?;
    let receiver = receiver(logs, run.rtk_sigma, run.heading_sigma, run.seed)?;
    let mut sim = simulate::simulate_path(a.path, a.length, truth, run);
    prepare(logs, &mut sim, &receiver);
    write_logs(logs, &sim, &receiver)?;
    write_trajectory(&a.trajectory, &sim, receiver.antenna, run.seed)?;
    let mut w = create(&a.samples)?;
    csvio::write_samples(&mut w, &sim.samples, csvio::SamplesLayout::Counts)?;
    w.flush()?;
    let mut w = create(&a.reference)?;
    csvio::write_reference(&mut w, &sim.reference)?;
    w.flush()?;
    if let Some(p) = &a.truth_out {
        let text = cfg::render_params(
            &truth,
            "odoctl simulate: the true parameters of the synthetic run",
            &[],
        );
        std::fs::write(p, text).with_context(|| format!("{}: cannot write", p.display()))?;
    }
    report(&sim, &truth);
    Ok(ExitCode::SUCCESS)
}

/// The true parameters: `--true` (or the default truth) with the `--set`s over it.
fn true_params(a: &SimulateArgs) -> Result<ChassisParams> {
    let mut truth = match &a.truth {
        Some(p) => cfg::read_params(p, default_truth())?,
        None => default_truth(),
    };
    cfg::apply_sets(&mut truth, &a.sets)?;
    cfg::validated(truth, "true parameters")
}

/// Rate, speed, noise, start and seed of the run.
fn sim_settings(a: &SimulateArgs) -> SimSettings {
    SimSettings {
        rate: a.rate,
        speed: a.speed,
        slip: a.slip,
        slip_corr: a.slip_corr,
        slip_turn: a.slip_turn,
        slip_turn_corr: a.slip_turn_corr,
        rtk_sigma: a.rtk_sigma,
        heading_sigma: (!a.no_heading).then(|| a.heading_sigma_deg.to_radians()),
        start: (a.x0, a.y0, a.heading0),
        seed: a.seed,
    }
}

/// Refuses a run that is not finite or too large to write.
fn check_size(length: f64, run: &SimSettings) -> Result<()> {
    if !(run.rate > 0.0 && run.rate <= 10_000.0) {
        bail!("--rate {}: must be in (0, 10000] Hz", run.rate);
    }
    if !(run.speed > 0.0 && run.speed <= 10.0) {
        bail!("--speed {}: must be in (0, 10] m/s", run.speed);
    }
    if length.is_nan()
        || length <= 0.0
        || !(run.slip >= 0.0 && run.slip_turn >= 0.0 && run.rtk_sigma >= 0.0)
    {
        bail!("--length must be positive, --slip, --slip-turn and --rtk-sigma non-negative");
    }
    // Each option is in range (cli::values); together they must stay a finite run.
    let samples = length / run.speed * run.rate;
    if samples > MAX_SAMPLES {
        bail!(
            "--length {} m at --speed {} m/s and --rate {} Hz makes {samples:.3e} samples; at most {MAX_SAMPLES:e}",
            length,
            run.speed,
            run.rate
        );
    }
    Ok(())
}

/// What was simulated, on stdout.
fn report(sim: &SimRun, truth: &ChassisParams) {
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
}

/// True when a receiver log is to be written.
fn logs_wanted(logs: &ReceiverArgs) -> bool {
    logs.nmea.is_some() || logs.pos.is_some()
}

/// The simulated receiver for a run of `rtk_sigma`, `heading_sigma` and `seed`.
fn receiver(
    logs: &ReceiverArgs,
    rtk_sigma: f64,
    heading_sigma: Option<f64>,
    seed: u64,
) -> Result<ReceiverSim> {
    let d = ReceiverSim::default();
    let antenna = match &logs.antenna {
        Some(s) => parse_antenna(s)?,
        None => (0.0, 0.0),
    };
    let origin: Geodetic = match &logs.origin {
        Some(s) => parse_origin(s)?,
        None => d.origin,
    };
    let gps_start = match &logs.gps_start {
        Some(s) => {
            let (w, t) = s
                .split_once(',')
                .and_then(|(w, t)| {
                    Some((w.trim().parse::<u32>().ok()?, t.trim().parse::<f64>().ok()?))
                })
                .filter(|(_, t)| (0.0..gps_time::WEEK).contains(t))
                .with_context(|| {
                    format!("--gps-start `{s}`: expected WEEK,TOW (TOW in 0..604800 s)")
                })?;
            f64::from(w) * gps_time::WEEK + t
        }
        None => d.gps_start,
    };
    if !(logs.gnss_rate > 0.0 && logs.gnss_rate <= 100.0) {
        bail!("--gnss-rate {}: must be in (0, 100] Hz", logs.gnss_rate);
    }
    if !(0.0..=1.0).contains(&logs.float_fraction)
        || logs.float_sigma.is_nan()
        || logs.float_sigma < 0.0
    {
        bail!("--float-fraction must be in 0..=1, --float-sigma non-negative");
    }
    Ok(ReceiverSim {
        origin,
        gps_start,
        rate: logs.gnss_rate,
        antenna,
        rtk_sigma,
        float_sigma: logs.float_sigma,
        float_fraction: logs.float_fraction,
        heading_sigma,
        seed,
    })
}

/// Before the CSVs are written: with a lever arm, the CSV reference becomes the antenna's
/// path (its noise kept); with receiver logs, the samples and the CSV reference carry GPS
/// time of week.
fn prepare(logs: &ReceiverArgs, run: &mut SimRun, sim: &ReceiverSim) {
    let (fwd, left) = sim.antenna;
    if fwd != 0.0 || left != 0.0 {
        for (r, &(x, y, h)) in run.reference.iter_mut().zip(&run.truth) {
            let (ax, ay) = antenna_position(x, y, h, fwd, left);
            r.x += ax - x;
            r.y += ay - y;
        }
    }
    if logs_wanted(logs) || logs.gps_start.is_some() {
        let (_, tow0) = gps_time::week_tow(sim.gps_start);
        for s in &mut run.samples {
            s.t += tow0;
        }
        for r in &mut run.reference {
            r.t += tow0;
        }
    }
}

/// Writes the receiver logs of a prepared run.
fn write_logs(logs: &ReceiverArgs, run: &SimRun, sim: &ReceiverSim) -> Result<()> {
    if !logs_wanted(logs) {
        return Ok(());
    }
    let (_, tow0) = gps_time::week_tow(sim.gps_start);
    let times: Vec<f64> = run.samples.iter().map(|s| s.t - tow0).collect();
    let epochs = simulated::receiver_epochs(&times, &run.truth, sim);
    if epochs.is_empty() {
        bail!("--gnss-rate {}: no sample falls on its epochs", sim.rate);
    }
    let leap = logs
        .leap_seconds
        .unwrap_or_else(|| gps_time::leap_seconds_at_gps(sim.gps_start));
    if let Some(p) = &logs.nmea {
        let mut w = create(p)?;
        simulated::write_nmea(&mut w, &epochs, leap)?;
        w.flush()?;
    }
    if let Some(p) = &logs.pos {
        let mut w = create(p)?;
        let t = match logs.pos_time {
            PosTimeArg::Calendar => PosTime::Calendar,
            PosTimeArg::WeekTow => PosTime::WeekTow,
        };
        simulated::write_pos(&mut w, &epochs, t)?;
        w.flush()?;
    }
    let floats = epochs
        .iter()
        .filter(|e| e.fix == FixQuality::RtkFloat)
        .count();
    crate::outln!(
        "receiver log: {} epochs at {} Hz ({floats} RTK float), antenna {:.3} m forward, {:.3} m left, origin {}, start {}",
        epochs.len(),
        sim.rate,
        sim.antenna.0,
        sim.antenna.1,
        sim.origin,
        gps_time::describe(sim.gps_start, leap)
    );
    Ok(())
}

/// Writes the trajectory references (`--tum`, `--mcap-reference`) of a prepared run, the
/// marker at `marker` (forward, left; m).
fn write_trajectory(a: &TrajectoryArgs, run: &SimRun, marker: (f64, f64), seed: u64) -> Result<()> {
    if a.tum.is_none() && a.mcap_reference.is_none() {
        return Ok(());
    }
    let frame: Vec<f64> = a
        .trajectory_frame
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .ok()
        .filter(|v: &Vec<f64>| v.len() == 3 && v.iter().all(|x| x.is_finite() && x.abs() < 1e6))
        .with_context(|| {
            format!(
                "--trajectory-frame `{}`: expected X,Y,DEG",
                a.trajectory_frame
            )
        })?;
    let sim = TrajectorySim {
        frame: (frame[0], frame[1], frame[2].to_radians()),
        marker,
        marker_yaw: a.marker_yaw_deg.to_radians(),
        every: a.trajectory_every as usize,
        sigma: a.trajectory_sigma,
        yaw_sigma: a.trajectory_yaw_sigma_deg.to_radians(),
        drift: a.trajectory_drift,
        time_offset: a.trajectory_time_offset,
        clock_ppm: a.trajectory_clock_ppm,
        seed,
    };
    let times: Vec<f64> = run.samples.iter().map(|s| s.t).collect();
    let poses = trajectory_poses(&times, &run.truth, &sim);
    if let Some(p) = &a.tum {
        let mut w = create(p)?;
        tum::write(&mut w, &poses)?;
        w.flush()?;
    }
    if let Some(p) = &a.mcap_reference {
        let f =
            std::fs::File::create(p).with_context(|| format!("{}: cannot create", p.display()))?;
        mcap_pose::write(std::io::BufWriter::new(f), &poses, "world", "marker")
            .with_context(|| format!("{}: cannot write", p.display()))?;
    }
    crate::outln!(
        "trajectory reference: {} poses, marker {:.3} m forward, {:.3} m left, yaw {:+.2} deg; frame {}; samples' t - stamp = {} s (middle), {} ppm",
        poses.len(),
        marker.0,
        marker.1,
        a.marker_yaw_deg,
        a.trajectory_frame,
        a.trajectory_time_offset,
        a.trajectory_clock_ppm
    );
    Ok(())
}
