//! Indoor calibration accuracy, as Markdown tables for docs/RESULTS.md (`bench/run`):
//! `odo-bench indoor DIR`. Figures only: nothing here fails on noise.
//!
//! - Trajectory references ([`CASES`]: motion capture, with the default 10 m sub-trajectories
//!   and with 3 m ones, SLAM at 10 and 20 Hz, and RTK on the same runs for comparison): runs of the release `odoctl` (`$ODOCTL`, else the `odoctl` beside this
//!   binary), `simulate --path room --tum` (laps within 8 x 8 m) then `calibrate
//!   --fit-antenna` with the clock estimated (RTK: against the run's reference CSV), files in
//!   DIR; per seed the path's laps, the reference frame, the marker's yaw, the clock offset and
//!   the clock rate differ.
//! - The square test: five clockwise and five counter-clockwise 4 m squares and a 10 m
//!   straight simulated in-process, end positions measured to 2 mm and the squares' end
//!   headings to 0.5 degrees, read and fitted as `odoctl umbmark` reads and fits them.
//!
//! Per estimate: the mean error to the truth with its standard error (the errors' standard
//! deviation over the square root of the seed count: a mean within two of them is what that
//! many seeds give by chance, one beyond three asks for more seeds before it is called a
//! bias), the RMS error, the RMS
//! reported standard error (SE), and the share of the seeds whose error is within 2 and within
//! 3 reported SE. `BENCH_INDOOR_SEEDS` sets one seed count for every table.

use std::f64::consts::FRAC_PI_2;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use odoctl::commands::umbmark;
use odoctl::csvio;
use odoctl::simulate::{default_truth, simulate, Rng, Segment, SimOptions, SimSettings};

use crate::odoctl_binary::odoctl;

/// The marker's lever arm from the axle centre of every trajectory run: forward, left (m).
const MARKER: (f64, f64) = (0.25, -0.08);

/// A simulated trajectory reference: its label, whether the run is calibrated against the
/// simulator's RTK reference CSV instead (8 mm, 0.5 degrees, the unit's clock) for comparison,
/// the samples' rate (Hz), a pose every this many samples, position noise (m), yaw noise
/// (degrees), drift (m/sqrt(s), `simulate --trajectory-drift`), length (m), seeds by default,
/// and `calibrate --subtrajectory-length` (m).
struct Case {
    label: &'static str,
    rtk: bool,
    rate: f64,
    every: u32,
    sigma: f64,
    yaw_sigma_deg: f64,
    drift: f64,
    length: f64,
    seeds: u64,
    subtrajectory: f64,
}

/// The trajectory references of the tables.
const CASES: [Case; 6] = [
    Case {
        label: "RTK",
        rtk: true,
        rate: 100.0,
        every: 1,
        sigma: 0.0005,
        yaw_sigma_deg: 0.1,
        drift: 0.0,
        length: 300.0,
        seeds: 20,
        subtrajectory: 10.0,
    },
    Case {
        label: "motion capture",
        rtk: false,
        rate: 100.0,
        every: 1,
        sigma: 0.0005,
        yaw_sigma_deg: 0.1,
        drift: 0.0,
        length: 300.0,
        seeds: 20,
        subtrajectory: 10.0,
    },
    Case {
        label: "motion capture, 3 m sub-trajectories",
        rtk: false,
        rate: 100.0,
        every: 1,
        sigma: 0.0005,
        yaw_sigma_deg: 0.1,
        drift: 0.0,
        length: 300.0,
        seeds: 20,
        subtrajectory: 3.0,
    },
    Case {
        label: "SLAM without drift",
        rtk: false,
        rate: 100.0,
        every: 10,
        sigma: 0.01,
        yaw_sigma_deg: 0.5,
        drift: 0.0,
        length: 300.0,
        seeds: 8,
        subtrajectory: 10.0,
    },
    Case {
        label: "SLAM with drift",
        rtk: false,
        rate: 100.0,
        every: 10,
        sigma: 0.01,
        yaw_sigma_deg: 0.5,
        drift: 0.001,
        length: 300.0,
        seeds: 8,
        subtrajectory: 10.0,
    },
    Case {
        label: "SLAM with drift at 20 Hz",
        rtk: false,
        rate: 100.0,
        every: 5,
        sigma: 0.01,
        yaw_sigma_deg: 0.5,
        drift: 0.001,
        length: 300.0,
        seeds: 8,
        subtrajectory: 10.0,
    },
];

/// Errors and reported standard errors of one estimate over the seeds.
#[derive(Default)]
struct Stat {
    sum: f64,
    sq: f64,
    sq_se: f64,
    within2: usize,
    within3: usize,
    n: usize,
}

impl Stat {
    /// Adds one estimate's error and its reported standard error (the same unit); not an
    /// error that is not finite (an estimate the reference does not give).
    fn add(&mut self, error: f64, se: f64) {
        if !error.is_finite() {
            return;
        }
        self.sum += error;
        self.sq += error * error;
        self.sq_se += se * se;
        self.within2 += usize::from(error.abs() <= 2.0 * se);
        self.within3 += usize::from(error.abs() <= 3.0 * se);
        self.n += 1;
    }

    /// `| mean error | SE of the mean | RMS error | RMS SE | within 2 SE | within 3 SE |` with
    /// `decimals`; the mean's SE is the errors' sample standard deviation over `sqrt(n)`.
    fn cells(&self, decimals: usize) -> String {
        let n = self.n.max(1) as f64;
        let mean = self.sum / n;
        let variance = (self.sq - n * mean * mean).max(0.0) / (n - 1.0).max(1.0);
        format!(
            "{:+.decimals$} | {:.decimals$} | {:.decimals$} | {:.decimals$} | {:.0} % | {:.0} %",
            mean,
            (variance / n).sqrt(),
            (self.sq / n).sqrt(),
            (self.sq_se / n).sqrt(),
            100.0 * self.within2 as f64 / n,
            100.0 * self.within3 as f64 / n
        )
    }
}

fn seeds(default: u64) -> u64 {
    std::env::var("BENCH_INDOOR_SEEDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(default)
}

/// Runs `odoctl ARGS`; its stdout, or the failure's stderr.
fn run_odoctl(args: &[&str]) -> Result<String, String> {
    let o = Command::new(odoctl())
        .args(args)
        .output()
        .map_err(|e| format!("{}: {e}", odoctl().display()))?;
    if o.status.success() {
        Ok(String::from_utf8_lossy(&o.stdout).into_owned())
    } else {
        Err(String::from_utf8_lossy(&o.stderr).into_owned())
    }
}

/// The clock line of `calibrate`'s stdout: (offset s, its SE, rate ppm, its SE).
fn clock_line(stdout: &str) -> Option<[f64; 4]> {
    let line = stdout.lines().find(|l| l.contains("samples' t = stamp"))?;
    let nums: Vec<f64> = line
        .split("samples' t = stamp")
        .nth(1)?
        .split(|c: char| c.is_whitespace() || c == '(' || c == ')')
        .filter_map(|w| w.parse::<f64>().ok())
        .collect();
    (nums.len() >= 4).then(|| [nums[0], nums[1], nums[2], nums[3]])
}

/// One trajectory run's (errors, SEs): left, right, track, marker forward, marker left (mm),
/// clock offset (ms), clock rate (ppm).
fn trajectory_seed(case: &Case, dir: &Path, seed: u64) -> Result<([f64; 7], [f64; 7]), String> {
    let s = |n: &str| dir.join(n).to_str().expect("UTF-8 path").to_string();
    let sf = seed as f64;
    let frame = format!("{},{},{}", sf * 1.7 - 4.0, 3.0 - sf, seed * 47 % 360);
    let yaw = format!("{}", (seed * 83 % 360) as f64 - 180.0);
    let offset = -1.7e9 - sf * 12.345 - 0.0037;
    let ppm = (seed * 17 % 101) as f64 - 50.0;
    let (rate, every, sigma, yaw_sigma, drift, length) = (
        case.rate.to_string(),
        case.every.to_string(),
        case.sigma.to_string(),
        case.yaw_sigma_deg.to_string(),
        case.drift.to_string(),
        case.length.to_string(),
    );
    let (offset_s, ppm_s, seed_s) = (offset.to_string(), ppm.to_string(), seed.to_string());
    let subtrajectory = case.subtrajectory.to_string();
    let marker = format!("{},{}", MARKER.0, MARKER.1);
    let (samples, reference, tum, out) = (s("run.csv"), s("ref.csv"), s("run.tum"), s("out.toml"));
    run_odoctl(&[
        "simulate",
        "--seed",
        &seed_s,
        "--path",
        "room",
        "--length",
        &length,
        "--rate",
        &rate,
        "--samples",
        &samples,
        "--reference",
        &reference,
        "--tum",
        &tum,
        "--antenna",
        &marker,
        "--marker-yaw-deg",
        &yaw,
        "--trajectory-frame",
        &frame,
        "--trajectory-every",
        &every,
        "--trajectory-sigma",
        &sigma,
        "--trajectory-yaw-sigma-deg",
        &yaw_sigma,
        "--trajectory-drift",
        &drift,
        "--trajectory-time-offset",
        &offset_s,
        "--trajectory-clock-ppm",
        &ppm_s,
    ])?;
    let stdout = run_odoctl(&[
        "calibrate",
        "--samples",
        &samples,
        "--reference",
        if case.rtk { &reference } else { &tum },
        "--out",
        &out,
        "--no-delta",
        "--fit-antenna",
        "--subtrajectory-length",
        &subtrajectory,
    ])?;
    let [eo, so, er, sr] = if case.rtk {
        [offset, 0.0, ppm, 0.0].map(|v| v + f64::NAN)
    } else {
        clock_line(&stdout).ok_or("no clock line in calibrate's output")?
    };
    let text = std::fs::read_to_string(&out).map_err(|e| format!("{out}: {e}"))?;
    let t: toml::Table = text.parse().map_err(|e| format!("{out}: {e}"))?;
    let fit = t.get("fit").and_then(|f| f.as_table()).ok_or("no [fit]")?;
    let num = |tab: &toml::Table, k: &str| tab.get(k).and_then(|v| v.as_float());
    let truth = default_truth();
    let est = ["left_diameter", "right_diameter", "track_width"]
        .map(|k| num(&t, k))
        .into_iter()
        .chain(["antenna_forward", "antenna_left"].map(|k| num(fit, k)))
        .collect::<Option<Vec<f64>>>()
        .ok_or("an estimate is missing")?;
    let se = [
        "left_diameter_se",
        "right_diameter_se",
        "track_width_se",
        "antenna_forward_se",
        "antenna_left_se",
    ]
    .map(|k| num(fit, k))
    .into_iter()
    .collect::<Option<Vec<f64>>>()
    .ok_or("a standard error is missing")?;
    let true5 = [
        truth.left_diameter,
        truth.right_diameter,
        truth.track_width,
        MARKER.0,
        MARKER.1,
    ];
    let mut e = [0.0; 7];
    let mut u = [0.0; 7];
    for k in 0..5 {
        e[k] = (est[k] - true5[k]) * 1e3;
        u[k] = se[k] * 1e3;
    }
    (e[5], u[5]) = ((eo - offset) * 1e3, so * 1e3);
    (e[6], u[6]) = (er - ppm, sr);
    Ok((e, u))
}

/// The rows of the trajectory tables: label, unit, decimals, the motion-capture target.
const TRAJECTORY_ROWS: [(&str, &str, usize, &str); 7] = [
    ("left diameter", "mm", 4, "0.02 mm"),
    ("right diameter", "mm", 4, "0.02 mm"),
    ("track width", "mm", 3, "0.1 mm"),
    ("marker forward", "mm", 3, "2 mm"),
    ("marker left", "mm", 3, "2 mm"),
    ("time offset", "ms", 4, "1 ms"),
    ("clock rate", "ppm", 3, "-"),
];

/// The table of one trajectory reference over its seeds.
fn trajectory_table(case: &Case, root: &Path) {
    let n = seeds(case.seeds);
    let dir = root.join(case.label.replace(' ', "_"));
    std::fs::create_dir_all(&dir).expect("the scratch directory");
    let mut stats: [Stat; 7] = Default::default();
    let mut failed = 0;
    for seed in 1..=n {
        match trajectory_seed(case, &dir, seed) {
            Ok((e, u)) => {
                for k in 0..7 {
                    stats[k].add(e[k], u[k]);
                }
            }
            Err(e) => {
                failed += 1;
                eprintln!("{}, seed {seed}: {e}", case.label);
            }
        }
    }
    let failed = if failed > 0 {
        format!(" ({failed} failed, left out)")
    } else {
        String::new()
    };
    if case.rtk {
        println!(
            "RTK, for comparison: the motion-capture runs calibrated against the simulator's reference CSV at the marker instead (8 mm horizontal RMS, heading noise 0.5 degrees, {} Hz on the unit's clock); seeds 1 to {n}{failed}.",
            case.rate
        );
    } else {
        println!(
            "{}: {} m of laps within 8 x 8 m (`simulate --path room`) at 0.5 m/s, samples at {} Hz, poses at {} Hz, position noise {} mm RMS, yaw noise {} degrees, {}; sub-trajectories of {} m; seeds 1 to {n}{failed}.",
            capitalised(case.label),
            case.length,
            case.rate,
            case.rate / case.every as f64,
            case.sigma * 1e3,
            case.yaw_sigma_deg,
            if case.drift > 0.0 {
                format!(
                    "a drift of the positions by a random walk of {} mm/sqrt(s) per axis (RMS {:.0} mm after 100 s)",
                    case.drift * 1e3,
                    case.drift * 1e4
                )
            } else {
                "no drift".into()
            },
            case.subtrajectory,
        );
    }
    println!();
    println!("| estimate | mean error | SE of the mean | RMS error | RMS reported SE | within 2 SE | within 3 SE | target (RMS error) |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |");
    for ((label, unit, decimals, target), s) in TRAJECTORY_ROWS.iter().zip(&stats) {
        let target = if case.label.starts_with("motion capture") {
            target
        } else {
            "-"
        };
        if s.n == 0 {
            continue;
        }
        println!("| {label} ({unit}) | {} | {target} |", s.cells(*decimals));
    }
    println!();
}

fn capitalised(s: &str) -> String {
    let mut c = s.chars();
    c.next()
        .map_or(String::new(), |f| f.to_uppercase().chain(c).collect())
}

/// Writes a simulated run of `segments` as SAMPLES CSV; returns its true end (forward, left,
/// heading change counter-clockwise) from the start.
fn square_run(path: &Path, segments: Vec<Segment>, seed: u64) -> (f64, f64, f64) {
    let sim = simulate(&SimOptions {
        truth: default_truth(),
        segments,
        settings: SimSettings {
            start: (0.0, 0.0, 0.0),
            seed,
            ..SimSettings::default()
        },
    });
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).expect("a scratch file"));
    csvio::write_samples(&mut w, &sim.samples, csvio::SamplesLayout::Counts)
        .expect("the samples written");
    w.flush().expect("the samples written");
    let (x, y, h) = *sim.truth.last().expect("a run");
    (y, -x, -odoctl::stats::wrap_angle(h))
}

/// The square's segments: four sides of 4 m, each followed by a spin of `turn` (rad,
/// clockwise).
fn square(turn: f64) -> Vec<Segment> {
    (0..4)
        .flat_map(|_| [Segment::Straight(4.0), Segment::Spin(turn)])
        .collect()
}

/// Simulates the square test of `seed` in `dir`; returns the measurements file.
fn square_test(dir: &Path, seed: u64) -> PathBuf {
    let mut rng = Rng::new(seed ^ 0xAB);
    let (sigma, heading_sigma) = (0.002, 0.5f64);
    let mut toml = format!("side = 4.0\nsigma = {sigma}\nheading_sigma_deg = {heading_sigma}\n");
    let mut entry = |name: &str, direction: &str, (f, l, h): (f64, f64, f64), rng: &mut Rng| {
        let (f, l) = (f + sigma * rng.normal(), l + sigma * rng.normal());
        toml.push_str(&format!(
            "\n[[run]]\nsamples = \"{name}\"\ndirection = \"{direction}\"\nforward = {f}\nleft = {l}\n"
        ));
        if direction != "straight" {
            let h = h.to_degrees() + heading_sigma * rng.normal();
            toml.push_str(&format!("heading_deg = {h}\n"));
        }
    };
    for k in 0..5u64 {
        let cw = square_run(
            &dir.join(format!("cw{k}.csv")),
            square(FRAC_PI_2),
            seed * 100 + k,
        );
        entry(&format!("cw{k}.csv"), "cw", cw, &mut rng);
        let ccw = square_run(
            &dir.join(format!("ccw{k}.csv")),
            square(-FRAC_PI_2),
            seed * 100 + 50 + k,
        );
        entry(&format!("ccw{k}.csv"), "ccw", ccw, &mut rng);
    }
    let s = square_run(
        &dir.join("straight.csv"),
        vec![Segment::Straight(10.0)],
        seed * 100 + 99,
    );
    entry("straight.csv", "straight", s, &mut rng);
    let p = dir.join("measurements.toml");
    std::fs::write(&p, toml).expect("the measurements file");
    p
}

/// The square test's table over its seeds.
fn square_table(root: &Path) {
    let n = seeds(40);
    let dir = root.join("square");
    std::fs::create_dir_all(&dir).expect("the scratch directory");
    let t = default_truth();
    let truth = [t.left_diameter, t.right_diameter, t.track_width];
    let initial = odo_unit::odometry::ChassisParams::DESIGNED;
    let mut stats: [Stat; 4] = Default::default();
    let (mut failed, mut slip) = (0, 0);
    for seed in 1..=n {
        let m = square_test(&dir, seed);
        let fit = umbmark::read_runs(&m, &initial)
            .and_then(|(runs, sigmas, _)| umbmark::fit(&initial, &runs, sigmas));
        let f = match fit {
            Ok(f) => f,
            Err(e) => {
                failed += 1;
                eprintln!("square test, seed {seed}: {e}");
                continue;
            }
        };
        let p = &f.params;
        let est = [p.left_diameter, p.right_diameter, p.track_width];
        for k in 0..3 {
            stats[k].add((est[k] - truth[k]) * 1e3, f.se[k] * 1e3);
        }
        // The ratio's SE as `umbmark` prints it (Ed).
        let ed = est[1] / est[0];
        let ed_se = ed
            * ((f.se[0] / est[0]).powi(2) + (f.se[1] / est[1]).powi(2)
                - 2.0 * f.correlations[0] * f.se[0] * f.se[1] / (est[0] * est[1]))
                .max(0.0)
                .sqrt();
        stats[3].add((ed - truth[1] / truth[0]) * 1e4, ed_se * 1e4);
        slip += usize::from(f.kappa > 0.0);
    }
    println!(
        "Square test: five clockwise and five counter-clockwise squares of 4 m (spins at the corners) and a 10 m straight per seed, the simulator's defaults (slip 0.1 % over 0.1 m), end positions measured with 2 mm noise per coordinate and the squares' end headings with 0.5 degrees, fitted from the designed geometry; seeds 1 to {n}{}; slip added to the measurement errors (chi-square above its degrees of freedom) on {slip} of {}.",
        if failed > 0 {
            format!(" ({failed} failed, left out)")
        } else {
            String::new()
        },
        n as usize - failed
    );
    println!();
    println!("| estimate | mean error | SE of the mean | RMS error | RMS reported SE | within 2 SE | within 3 SE | target (RMS error) |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |");
    for ((label, decimals, target), s) in [
        ("left diameter (mm)", 4, "-"),
        ("right diameter (mm)", 4, "-"),
        ("track width (mm)", 3, "0.5 mm"),
        ("diameter ratio right / left (1e-4)", 3, "2 (2e-4)"),
    ]
    .iter()
    .zip(&stats)
    {
        println!("| {label} | {} | {target} |", s.cells(*decimals));
    }
}

/// `odo-bench indoor DIR`: the trajectory tables and the square test's, scratch files in DIR.
pub fn run(dir: &Path) {
    for case in &CASES {
        trajectory_table(case, dir);
    }
    square_table(dir);
}
