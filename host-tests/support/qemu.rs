//! Booting the firmware's `qemu` image for the end-to-end tests; shared by `host-tests/` and
//! `odoctl/tests/` (included there by path).
//!
//! The image is `$ODO_QEMU_IMAGE` or `<repo>/target/qemu/thumbv7em-none-eabihf/release/odo-unit`
//! (`cargo build --release --features qemu --target-dir target/qemu`); QEMU is
//! `$QEMU_SYSTEM_ARM` or `qemu-system-arm` on the PATH. Without either the test is skipped
//! with a message, unless `ODO_QEMU_REQUIRED=1` (as in CI), which makes it fail.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

/// QEMU running the image, killed when dropped. Its USART2 (the host link) is a TCP server
/// on 127.0.0.1:`port` that waits for one connection before the firmware runs.
pub struct Qemu {
    child: Child,
    /// TCP port of the unit's USART2.
    pub port: u16,
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The `qemu` image of the repository at `repo`.
pub fn image(repo: &Path) -> PathBuf {
    std::env::var_os("ODO_QEMU_IMAGE")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo.join("target/qemu/thumbv7em-none-eabihf/release/odo-unit"))
}

/// `qemu-system-arm`, if installed.
pub fn qemu_binary() -> Option<PathBuf> {
    if let Some(q) = std::env::var_os("QEMU_SYSTEM_ARM") {
        return Some(PathBuf::from(q));
    }
    std::env::var_os("PATH")?
        .to_str()?
        .split(':')
        .map(|d| Path::new(d).join("qemu-system-arm"))
        .find(|p| p.is_file())
}

/// The port QEMU reports in its `waiting for connection on: disconnected:tcp:127.0.0.1:PORT,...`
/// line, once it listens; every other line of its standard error is passed on.
///
/// QEMU binds port 0 and names the port the kernel gave it, so no port is chosen before
/// QEMU holds it: a port probed by a test and closed again can be probed (briefly listened
/// on) by a parallel test, whose connection attempts would land there.
fn listening_port(stderr: std::process::ChildStderr) -> Option<u16> {
    use std::io::{BufRead, BufReader};
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut tx = Some(tx);
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let port = line
                .split_once("disconnected:tcp:127.0.0.1:")
                .and_then(|(_, rest)| rest.split(',').next())
                .and_then(|p| p.parse::<u16>().ok());
            match (port, tx.take()) {
                (Some(port), Some(t)) => {
                    let _ = t.send(port);
                }
                (_, t) => {
                    eprintln!("{line}");
                    tx = t;
                }
            }
        }
    });
    rx.recv_timeout(std::time::Duration::from_secs(20)).ok()
}

/// Boots the image of `repo` on `netduinoplus2` with `-icount shift=0,sleep=off`
/// (deterministic, faster than real time), or returns `None` after saying why `test` is
/// skipped; panics instead when `ODO_QEMU_REQUIRED=1`.
pub fn boot(repo: &Path, test: &str) -> Option<Qemu> {
    let required = std::env::var("ODO_QEMU_REQUIRED").is_ok_and(|v| v == "1");
    let image = image(repo);
    let missing = match qemu_binary() {
        None => Some("qemu-system-arm not found (apt-get install qemu-system-arm)".to_string()),
        Some(_) if !image.is_file() => Some(format!(
            "no image at {} (cargo build --release --features qemu --target-dir target/qemu)",
            image.display()
        )),
        Some(_) => None,
    };
    if let Some(why) = missing {
        assert!(!required, "{why}, and ODO_QEMU_REQUIRED=1");
        eprintln!("SKIPPED {test}: {why}");
        return None;
    }
    let qemu = qemu_binary()?;
    let mut child = Command::new(qemu)
        .args([
            "-machine",
            "netduinoplus2",
            "-display",
            "none",
            "-nodefaults",
        ])
        .args(["-icount", "shift=0,sleep=off"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-serial", "null", "-serial"])
        .arg("tcp:127.0.0.1:0,server=on,wait=on")
        .arg("-kernel")
        .arg(&image)
        .stdin(Stdio::null())
        .stdout(Stdio::null()) // defmt frames over semihosting (binary)
        .stderr(Stdio::piped())
        .spawn()
        .expect("start QEMU");
    let stderr = child.stderr.take().expect("QEMU's standard error");
    let Some(port) = listening_port(stderr) else {
        let _ = child.kill();
        panic!("QEMU named no listening port within 20 s: {:?}", child.wait());
    };
    Some(Qemu { child, port })
}

/// A frame from the reader thread, or the end of the stream with the decoder's counters.
enum Event {
    Frame(Box<odo_unit::protocol::Frame>),
    Closed(odo_unit::protocol::DecoderStats),
}

/// The host side of the unit's link: a reader thread decodes frames with the core's
/// `FrameDecoder`; every frame is kept by kind, in order.
pub struct UnitLink {
    stream: std::net::TcpStream,
    rx: std::sync::mpsc::Receiver<Event>,
    deadline: std::time::Instant,
    /// Pose records received so far.
    pub records: Vec<odo_unit::protocol::PoseRecord>,
    /// Status heartbeats received so far.
    pub heartbeats: Vec<odo_unit::protocol::Status>,
    /// Frame sequence numbers of every frame.
    pub seqs: Vec<u32>,
    /// DeviceInfo frames received.
    pub device_info: usize,
    /// Every frame, in order.
    pub frames: Vec<odo_unit::protocol::Frame>,
    /// Every byte received, in order (frames of other protocols included).
    pub raw: std::sync::Arc<std::sync::Mutex<Vec<u8>>>,
}

impl UnitLink {
    /// Connects to QEMU's USART2 on 127.0.0.1:`port` (retrying while QEMU starts); every
    /// later wait fails the test after `limit` of wall-clock time from now.
    pub fn connect(port: u16, limit: std::time::Duration) -> Self {
        use std::io::Read;
        use std::time::{Duration, Instant};
        let start = Instant::now();
        let stream = loop {
            match std::net::TcpStream::connect(("127.0.0.1", port)) {
                Ok(s) => break s,
                Err(_) if start.elapsed() < Duration::from_secs(20) => {
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err(e) => panic!("cannot connect to QEMU's USART2 on port {port}: {e}"),
            }
        };
        let (tx, rx) = std::sync::mpsc::channel();
        let mut reader = stream.try_clone().expect("clone socket");
        let raw = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let tap = std::sync::Arc::clone(&raw);
        std::thread::spawn(move || {
            let mut decoder = odo_unit::protocol::FrameDecoder::new();
            let mut buf = [0u8; 4096];
            loop {
                let n = reader.read(&mut buf).unwrap_or(0);
                if n == 0 {
                    let _ = tx.send(Event::Closed(decoder.stats()));
                    return;
                }
                if let Ok(mut t) = tap.lock() {
                    t.extend_from_slice(&buf[..n]);
                }
                for &b in &buf[..n] {
                    if let Some(Ok(frame)) = decoder.push(b) {
                        if tx.send(Event::Frame(Box::new(frame))).is_err() {
                            return;
                        }
                    }
                }
            }
        });
        Self {
            stream,
            rx,
            deadline: start + limit,
            records: Vec::new(),
            heartbeats: Vec::new(),
            seqs: Vec::new(),
            device_info: 0,
            frames: Vec::new(),
            raw,
        }
    }

    /// The next frame (also filed in `records`, `heartbeats`, `seqs`, `device_info`).
    pub fn next_frame(&mut self) -> odo_unit::protocol::Frame {
        use odo_unit::protocol::Message;
        use std::sync::mpsc::RecvTimeoutError;
        let left = self
            .deadline
            .saturating_duration_since(std::time::Instant::now());
        match self.rx.recv_timeout(left) {
            Ok(Event::Frame(f)) => {
                self.seqs.push(f.seq);
                match &f.message {
                    Message::Pose(r) => self.records.push(*r),
                    Message::Status(s) => self.heartbeats.push(*s),
                    Message::DeviceInfo(_) => self.device_info += 1,
                    Message::Reply(_) | Message::Gnss(_) => {}
                }
                self.frames.push((*f).clone());
                *f
            }
            Ok(Event::Closed(stats)) => panic!("link closed by QEMU ({stats:?})"),
            Err(RecvTimeoutError::Timeout) => panic!("no frame before the deadline"),
            Err(RecvTimeoutError::Disconnected) => panic!("reader thread ended"),
        }
    }

    /// Sends raw bytes (no reply awaited).
    pub fn send_bytes(&mut self, bytes: &[u8]) {
        use std::io::Write;
        self.stream.write_all(bytes).expect("send bytes");
    }

    /// Sends a command line; returns (ok, text) of its reply, all chunks joined.
    pub fn command(&mut self, line: &str) -> (bool, String) {
        use std::io::Write;
        self.stream
            .write_all(format!("{line}\r\n").as_bytes())
            .expect("send command");
        let mut text = String::new();
        loop {
            if let odo_unit::protocol::Message::Reply(r) = self.next_frame().message {
                text.push_str(&r.text);
                if !r.more {
                    println!("> {line}\n{text}");
                    return (r.ok, text);
                }
            }
        }
    }
}

/// Replays the raw counts of `records` through the core integrator, starting at the first
/// record's counts and pose (which must carry zero sigmas, as after a `reset_pose`), and
/// asserts that every later record's pose and sigmas equal the replay's bit for bit: the
/// firmware and the host run the same integer and IEEE-754 arithmetic. Returns the distance
/// the replay drove, metres.
pub fn assert_replay_bit_exact(
    params: &odo_unit::odometry::ChassisParams,
    records: &[odo_unit::protocol::PoseRecord],
) -> f64 {
    use odo_unit::odometry::{IndexRefs, Integrator, Pose, WheelCounts};
    let counts = |r: &odo_unit::protocol::PoseRecord| WheelCounts {
        left: r.gamma_left,
        right: r.gamma_right,
    };
    let first = records.first().expect("records to replay");
    let start = Pose {
        x: first.x,
        y: first.y,
        heading: first.heading,
    };
    let mut integrator = Integrator::new(params, counts(first), start).expect("valid parameters");
    let mut distance = 0.0f64;
    for r in &records[1..] {
        let refs = IndexRefs {
            left: r.flags.left.index_seen.then_some(r.index_left),
            right: r.flags.right.index_seen.then_some(r.index_right),
        };
        let before = integrator.pose();
        assert!(!integrator.step(counts(r), refs).overrange);
        let (pose, sigma) = (integrator.pose(), integrator.sigma());
        distance += (pose.x - before.x).hypot(pose.y - before.y);
        let got = (
            [r.x, r.y, r.heading],
            [r.sigma_x, r.sigma_y, r.sigma_heading, r.cov_xy],
        );
        let want = (
            [pose.x, pose.y, pose.heading],
            [sigma.x, sigma.y, sigma.heading, sigma.cov_xy],
        );
        let same = got
            .0
            .iter()
            .zip(&want.0)
            .all(|(a, b)| a.to_bits() == b.to_bits())
            && got
                .1
                .iter()
                .zip(&want.1)
                .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(
            same,
            "record {}: firmware {got:?} != replay {want:?}",
            r.sequence
        );
    }
    distance
}
