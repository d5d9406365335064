//! Helpers shared by the integration tests: simulated runs, and a fake unit that speaks the
//! core's protocol (pose records from the core integrator, replies from the core's command
//! executor) over TCP, as the QEMU image does.
#![allow(dead_code)]

use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use odo_unit::console::{execute, Action, LineAssembler};
use odo_unit::odometry::{
    ChassisParams, IndexRefs, Integrator, Pose, UncertaintyModel, WheelCounts,
};
use odo_unit::protocol::{
    CommandReply, FrameEncoder, GnssSentence, Message, PoseRecord, StatusFlags, WheelStatus,
    MAX_ENCODED_FRAME,
};
use odo_unit::settings::Settings;
use odoctl::calib::{self, Calibration, CalibrationOptions, UncertaintyFit};
use odoctl::csvio::Sample;
use odoctl::simulate::{self, PathKind, SimRun, SimSettings};

/// `left_diameter`, `right_diameter`, `track_width` of `p` (m).
pub fn lengths(p: &ChassisParams) -> [f64; 3] {
    [p.left_diameter, p.right_diameter, p.track_width]
}

/// The odoctl binary.
pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_odoctl")
}

/// Runs odoctl with `args`.
pub fn odoctl(args: &[&str]) -> Output {
    Command::new(bin())
        .args(args)
        .output()
        .expect("odoctl runs")
}

/// Asserts that odoctl succeeded (else fails showing its stdout and stderr); returns its stdout.
#[track_caller]
pub fn success_stdout(o: &Output) -> String {
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// A fresh scratch directory under the target dir.
pub fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The default true chassis of `simulate`.
pub fn truth() -> ChassisParams {
    simulate::default_truth()
}

/// A simulated run with the tool's default noise.
pub fn sim(kind: PathKind, length: f64, seed: u64) -> SimRun {
    sim_turn_slip(kind, length, seed, 0.0)
}

/// A simulated run with the tool's default noise plus opposite-phase slip when turning
/// (`simulate --slip-turn`, correlation 1 m of differential travel).
pub fn sim_turn_slip(kind: PathKind, length: f64, seed: u64, slip_turn: f64) -> SimRun {
    let settings = SimSettings {
        slip_turn,
        start: (3.0, -2.0, 0.3),
        seed,
        ..Default::default()
    };
    simulate::simulate_path(kind, length, truth(), settings)
}

/// Pose records as the firmware makes them: the first at the integrator's creation (pose 0,
/// zero sigmas), then one per sample after `step`.
pub fn records(params: &ChassisParams, samples: &[Sample]) -> Vec<PoseRecord> {
    let c = |s: &Sample| WheelCounts {
        left: s.left,
        right: s.right,
    };
    let refs = |s: &Sample| IndexRefs {
        left: s.left_index,
        right: s.right_index,
    };
    let mut integ = Integrator::new(params, c(&samples[0]), Pose::default()).unwrap();
    let mut out = Vec::new();
    for (i, s) in samples.iter().enumerate() {
        if i > 0 {
            integ.step(c(s), refs(s));
        }
        out.push(record(i as u32, s, &integ));
    }
    out
}

fn record(seq: u32, s: &Sample, integ: &Integrator) -> PoseRecord {
    let p = integ.pose();
    let sg = integ.sigma();
    PoseRecord {
        sequence: seq,
        flags: StatusFlags {
            left: WheelStatus {
                index_seen: s.left_index.is_some(),
                // The sample's left encoder fault bit (PROTOCOL.md, status word bit 3).
                fault: s.flags.is_some_and(|f| f & (1 << 3) != 0),
                ..Default::default()
            },
            right: WheelStatus {
                index_seen: s.right_index.is_some(),
                ..Default::default()
            },
            ..Default::default()
        },
        mcu_time_us: (s.t * 1e6).round() as u64,
        x: p.x,
        y: p.y,
        heading: p.heading,
        sigma_x: sg.x,
        sigma_y: sg.y,
        sigma_heading: sg.heading,
        cov_xy: sg.cov_xy,
        gamma_left: s.left,
        gamma_right: s.right,
        index_left: s.left_index.unwrap_or(0),
        index_right: s.right_index.unwrap_or(0),
        ..Default::default()
    }
}

/// Encodes messages as a byte stream.
pub fn encode(msgs: impl IntoIterator<Item = Message>) -> Vec<u8> {
    let mut enc = FrameEncoder::new();
    let mut out = Vec::new();
    let mut buf = [0u8; MAX_ENCODED_FRAME];
    for m in msgs {
        let n = enc.encode(&m, &mut buf).unwrap();
        out.extend_from_slice(&buf[..n]);
    }
    out
}

/// A fake unit on 127.0.0.1: answers command lines with the core's executor and streams the
/// pose records of `samples` (integrated by the core with its working settings), one every
/// `period`. Serves one connection, and stops when the client closes it or after 30 s.
pub fn fake_unit(samples: Vec<Sample>, period: Duration) -> (u16, JoinHandle<Settings>) {
    fake_unit_with_gnss(samples, period, Vec::new())
}

/// [`fake_unit`] that also forwards GNSS sentences: each `(k, sentence)` right after the
/// record of sample `k` (in the order given).
pub fn fake_unit_with_gnss(
    samples: Vec<Sample>,
    period: Duration,
    gnss: Vec<(usize, GnssSentence)>,
) -> (u16, JoinHandle<Settings>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let handle = std::thread::spawn(move || {
        let (mut sock, _) = listener.accept().unwrap();
        sock.set_read_timeout(Some(Duration::from_millis(1)))
            .unwrap();
        let mut settings = Settings::DEFAULT;
        let mut lines = LineAssembler::new();
        let mut enc = FrameEncoder::new();
        let mut buf = [0u8; MAX_ENCODED_FRAME];
        let c = |s: &Sample| WheelCounts {
            left: s.left,
            right: s.right,
        };
        let mut integ: Option<Integrator> = None;
        let mut reset: Option<Pose> = None;
        let mut next = 0usize;
        let mut sent_gnss = 0usize;
        let started = Instant::now();
        let mut last = Instant::now();
        let mut send = |sock: &mut std::net::TcpStream, m: Message| -> bool {
            let n = enc.encode(&m, &mut buf).unwrap();
            sock.write_all(&buf[..n]).is_ok()
        };
        // A heartbeat first, as a unit that is up sends them.
        let status = odo_unit::protocol::Status {
            rate_hz: 50,
            samples_lost: 1,
            merged_samples: 2,
            gnss_rx_lost: 3,
            ..Default::default()
        };
        send(&mut sock, status.into());
        'serve: while started.elapsed() < Duration::from_secs(30) {
            let mut rx = [0u8; 256];
            match sock.read(&mut rx) {
                Ok(0) => break,
                Ok(n) => {
                    for &b in &rx[..n] {
                        let Some(Ok(line)) = lines.push(b) else {
                            continue;
                        };
                        let line = line.to_string();
                        let (reply, action) = execute(&line, &mut settings);
                        if let Action::ResetPose { x, y, heading } = action {
                            reset = Some(Pose { x, y, heading });
                        }
                        if matches!(action, Action::SettingsChanged) {
                            if let Some(i) = &mut integ {
                                i.set_params(&settings.chassis).unwrap();
                            }
                        }
                        for chunk in CommandReply::chunks(reply.ok, &reply.text) {
                            if !send(&mut sock, chunk.into()) {
                                break 'serve;
                            }
                        }
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(_) => break,
            }
            if next < samples.len() && last.elapsed() >= period {
                last = Instant::now();
                let s = &samples[next];
                match &mut integ {
                    None => {
                        integ = Some(
                            Integrator::new(
                                &settings.chassis,
                                c(s),
                                reset.take().unwrap_or_default(),
                            )
                            .unwrap(),
                        )
                    }
                    Some(i) => {
                        if let Some(p) = reset.take() {
                            i.rebase_counts(c(s));
                            i.reset_pose(p);
                        } else {
                            i.step(
                                c(s),
                                IndexRefs {
                                    left: s.left_index,
                                    right: s.right_index,
                                },
                            );
                        }
                    }
                }
                let r = record(next as u32, s, integ.as_ref().unwrap());
                if !send(&mut sock, r.into()) {
                    break;
                }
                while gnss.get(sent_gnss).is_some_and(|(k, _)| *k <= next) {
                    if !send(&mut sock, Message::Gnss(gnss[sent_gnss].1.clone())) {
                        break 'serve;
                    }
                    sent_gnss += 1;
                }
                next += 1;
            }
        }
        settings
    });
    (port, handle)
}

/// Reads a whole file to a string.
pub fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap()
}

/// Whether python3 can `import` the modules `imports` (`"gpxpy, pyubx2"`): the independent
/// readers some tests check our files with. Without them the test named `test` skips, saying
/// so on stderr (past the harness's capture) with the pip `packages` to install, unless
/// `ODO_PY_REQUIRED=1` (CI), which makes a missing reader a failure.
pub fn python_has(test: &str, imports: &str, packages: &str) -> bool {
    let ok = Command::new("python3")
        .args(["-c", &format!("import {imports}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var("ODO_PY_REQUIRED").as_deref() != Ok("1"),
            "ODO_PY_REQUIRED=1 but python3 cannot import {imports} (python3 -m pip install {packages})"
        );
        let _ = writeln!(
            std::io::stderr(),
            "{test}: skipped: python3 cannot import {imports} (python3 -m pip install {packages})"
        );
    }
    ok
}

/// The default calibration of `sim` with the covariance model only, and its likelihood fit.
pub fn calibrate_covariance(sim: &SimRun) -> (Calibration, UncertaintyFit) {
    let c = calib::calibrate(
        &sim.samples,
        &sim.reference,
        ("s", "r"),
        &ChassisParams::DESIGNED,
        &CalibrationOptions {
            models: vec![UncertaintyModel::Covariance],
            ..CalibrationOptions::default()
        },
    )
    .unwrap();
    let u = c
        .uncertainty
        .iter()
        .find(|u| u.criterion == calib::UncertaintyCriterion::Likelihood)
        .expect("a likelihood fit")
        .clone();
    (c, u)
}

/// `odoctl calibrate --no-delta --quiet EXTRA` of a run into `out`: (left, right, track, antenna
/// forward, antenna left) estimates and their standard errors (the antenna's 0 when held).
pub fn calibrate_result(
    samples: &str,
    reference: &str,
    out: &str,
    extra: &[&str],
) -> ([f64; 5], [f64; 5]) {
    let mut args = vec![
        "calibrate",
        "--samples",
        samples,
        "--reference",
        reference,
        "--out",
        out,
        "--no-delta",
        "--quiet",
    ];
    args.extend_from_slice(extra);
    success_stdout(&odoctl(&args));
    let t: toml::Table = read(std::path::Path::new(out)).parse().unwrap();
    let fit = t["fit"].as_table().unwrap();
    let get = |tab: &toml::Table, k: &str| tab.get(k).and_then(|v| v.as_float()).unwrap_or(0.0);
    (
        [
            get(&t, "left_diameter"),
            get(&t, "right_diameter"),
            get(&t, "track_width"),
            get(fit, "antenna_forward"),
            get(fit, "antenna_left"),
        ],
        [
            "left_diameter_se",
            "right_diameter_se",
            "track_width_se",
            "antenna_forward_se",
            "antenna_left_se",
        ]
        .map(|k| get(fit, k)),
    )
}
