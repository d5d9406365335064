//! `odoctl bridge --foxglove` received by a client we did not write into the bridge: a Python
//! client written from the Foxglove WebSocket protocol's documentation (the `websockets`
//! package; CDR decoded by `mcap-ros2-support` from the advertised schemas;
//! tests/ros/foxglove_client.py), against fake units on TCP: one that streams, and one whose
//! link drops mid-stream and comes back (it closes and reopens its listener, then sends its
//! last records again). Skipped with a message when python3 or the packages are missing,
//! unless `ODO_PY_REQUIRED=1` (CI).

mod common;

use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Read, Write as _};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::scratch;
use odo_unit::console::{execute, LineAssembler};
use odo_unit::odometry::ChassisParams;
use odo_unit::protocol::{CommandReply, FrameEncoder, Message, PoseRecord, MAX_ENCODED_FRAME};
use odo_unit::settings::Settings;
use odoctl::simulate::PathKind;

/// Whether the independent reader can run ([`common::python_has`]).
fn client_ready() -> bool {
    common::python_has(
        "ros_foxglove",
        "websockets, mcap_ros2._dynamic",
        "websockets mcap-ros2-support",
    )
}

fn expect_csv(dir: &Path, records: &[PoseRecord]) -> PathBuf {
    let mut e = String::from("t_us,x,y,heading,sigma_x,sigma_y,sigma_heading,cov_xy\n");
    for r in records {
        let _ = writeln!(
            e,
            "{},{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
            r.mcu_time_us, r.x, r.y, r.heading, r.sigma_x, r.sigma_y, r.sigma_heading, r.cov_xy
        );
    }
    let p = dir.join("expect.csv");
    std::fs::write(&p, e).unwrap();
    p
}

/// Starts `odoctl bridge --no-dds --foxglove 127.0.0.1:0 ARGS` and reads the server's port
/// from its first lines.
fn bridge(args: &[&str]) -> (Child, u16, Vec<String>) {
    let mut child = Command::new(common::bin())
        .args(["bridge", "--no-dds", "--foxglove", "127.0.0.1:0"])
        .args(args)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let mut seen = Vec::new();
    let port = loop {
        let l = lines.next().expect("bridge printed its address").unwrap();
        seen.push(l.clone());
        if let Some(rest) = l.split("ws://127.0.0.1:").nth(1) {
            break rest.split(' ').next().unwrap().parse().unwrap();
        }
    };
    // The rest of stderr, read on a thread so that the bridge never blocks on it.
    let rest = std::thread::spawn(move || lines.map_while(Result::ok).collect::<Vec<_>>());
    child.stderr = None;
    BRIDGE_ERR.with(|c| *c.borrow_mut() = Some(rest));
    (child, port, seen)
}

thread_local! {
    static BRIDGE_ERR: std::cell::RefCell<Option<std::thread::JoinHandle<Vec<String>>>> =
        const { std::cell::RefCell::new(None) };
}

fn bridge_stderr() -> String {
    BRIDGE_ERR
        .with(|c| c.borrow_mut().take())
        .map(|h| h.join().unwrap().join("\n"))
        .unwrap_or_default()
}

fn client(port: u16, expect: &Path, args: &[&str]) -> String {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ros/foxglove_client.py");
    let o = Command::new("python3")
        .arg(script)
        .args(["--url", &format!("ws://127.0.0.1:{port}")])
        .args(["--expect", expect.to_str().unwrap()])
        .args(args)
        .output()
        .unwrap();
    let out = common::success_stdout(&o);
    assert!(out.contains("foxglove_client: ok"), "{out}");
    out
}

#[test]
fn bridge_serves_the_pose_path_and_ellipse_to_a_foxglove_protocol_client() {
    if !client_ready() {
        return;
    }
    let sim = common::sim(PathKind::Validation, 10.0, 21);
    let mut samples: Vec<_> = sim.samples[..500].to_vec();
    // From record 150 on the unit reports a left encoder fault: a server status under the
    // unit's id, not the link's.
    for s in &mut samples[150..] {
        s.flags = Some(1 << 3);
    }
    let records = common::records(&ChassisParams::DESIGNED, &samples);
    let dir = scratch("ros_foxglove");
    let expect = expect_csv(&dir, &records);
    let (port, unit) = common::fake_unit(samples, Duration::from_millis(20));
    let (mut b, ws_port, _) = bridge(&["--port", &format!("tcp:127.0.0.1:{port}")]);
    let out = client(
        ws_port,
        &expect,
        &[
            "--min-odom",
            "200",
            "--timeout",
            "40",
            "--expect-unit-status",
            "left encoder fault",
        ],
    );
    b.kill().unwrap();
    b.wait().unwrap();
    let _ = unit.join();
    eprintln!("{}", out.trim());
    // A client without our subprotocol is refused by the handshake.
    let (mut b, ws_port, _) = bridge(&["--port", "tcp:127.0.0.1:1", "--retry", "0.2"]);
    let mut s = std::net::TcpStream::connect(("127.0.0.1", ws_port)).unwrap();
    write!(
        s,
        "GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Protocol: other\r\n\r\n"
    )
    .unwrap();
    let mut reply = String::new();
    let _ = s.read_to_string(&mut reply);
    assert!(reply.starts_with("HTTP/1.1 400"), "{reply}");
    b.kill().unwrap();
    b.wait().unwrap();
}

/// A unit whose link drops after record `drop_at`: it closes the connection and its
/// listener, is away for `away`, listens again on the same port and, on the new connection,
/// first sends its last `resend` records again (as a serial buffer would), then goes on with
/// the record of the present time (the unit kept running: the records of `away` are lost).
/// Answers command lines with the core's executor; streams after the first one.
fn dropping_unit(
    records: Vec<PoseRecord>,
    period: Duration,
    drop_at: usize,
    away: Duration,
    resend: usize,
) -> (u16, std::thread::JoinHandle<()>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let h = std::thread::spawn(move || {
        let mut settings = Settings::DEFAULT;
        let mut enc = FrameEncoder::new();
        let mut buf = [0u8; MAX_ENCODED_FRAME];
        let mut listener = Some(listener);
        let mut next = 0usize;
        let skipped = (away.as_secs_f64() / period.as_secs_f64()).round() as usize;
        for round in 0..2 {
            let l = listener.take().unwrap_or_else(|| {
                std::thread::sleep(away);
                TcpListener::bind(("127.0.0.1", port)).unwrap()
            });
            let (mut sock, _) = l.accept().unwrap();
            drop(l);
            sock.set_read_timeout(Some(Duration::from_millis(1)))
                .unwrap();
            let mut lines = LineAssembler::new();
            let mut send = |sock: &mut std::net::TcpStream, m: Message| -> bool {
                let n = enc.encode(&m, &mut buf).unwrap();
                sock.write_all(&buf[..n]).is_ok()
            };
            let mut queue: Vec<usize> = if round == 0 {
                (0..=drop_at).collect()
            } else {
                let back = next - resend;
                (back..next).chain(next + skipped..records.len()).collect()
            };
            queue.reverse();
            let started = Instant::now();
            let mut last = Instant::now();
            // Records start once the bridge's first command is answered, so that none is
            // sent while it waits for the reply (which would make the counts below vary).
            let mut answered = false;
            while started.elapsed() < Duration::from_secs(30) {
                let mut rx = [0u8; 256];
                match sock.read(&mut rx) {
                    Ok(0) => return,
                    Ok(n) => {
                        for &b in &rx[..n] {
                            if let Some(Ok(line)) = lines.push(b) {
                                let line = line.to_string();
                                let (reply, _) = execute(&line, &mut settings);
                                for c in CommandReply::chunks(reply.ok, &reply.text) {
                                    send(&mut sock, c.into());
                                }
                                answered = true;
                            }
                        }
                    }
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) => {}
                    Err(_) => return,
                }
                if answered && last.elapsed() >= period {
                    last = Instant::now();
                    let Some(i) = queue.pop() else {
                        break;
                    };
                    if !send(&mut sock, records[i].into()) {
                        return;
                    }
                    next = next.max(i + 1);
                }
            }
            // Round 0: the link drops here (the socket closes).
        }
    });
    (port, h)
}

#[test]
fn bridge_reports_a_dropped_link_reconnects_and_never_republishes_an_old_pose() {
    if !client_ready() {
        return;
    }
    let sim = common::sim(PathKind::Validation, 10.0, 22);
    let samples: Vec<_> = sim.samples[..420].to_vec();
    // A unit that has been up for 10 minutes: its clock is far past the time away.
    let records: Vec<PoseRecord> = common::records(&ChassisParams::DESIGNED, &samples)
        .into_iter()
        .map(|r| PoseRecord {
            mcu_time_us: r.mcu_time_us + 600_000_000,
            ..r
        })
        .collect();
    let dir = scratch("ros_foxglove_drop");
    let expect = expect_csv(&dir, &records);
    let period = Duration::from_millis(20);
    let (port, unit) = dropping_unit(records.clone(), period, 199, Duration::from_millis(1500), 3);
    // Published: records 0..=199, then 275..420 (1.5 s = 75 records away).
    let (mut b, ws_port, _) = bridge(&[
        "--port",
        &format!("tcp:127.0.0.1:{port}"),
        "--retry",
        "0.3",
        "--count",
        "345",
        "--duration",
        "30",
    ]);
    let out = client(
        ws_port,
        &expect,
        &[
            "--min-odom",
            "150",
            "--until-records",
            "400",
            "--timeout",
            "40",
            "--expect-status",
            "link lost",
            "--expect-status",
            "cannot connect",
        ],
    );
    unit.join().unwrap();
    assert!(b.wait().unwrap().success());
    let err = bridge_stderr();
    eprintln!("{}\n{err}", out.trim());
    // Record 199 again: repeated; 197 and 198 again: older than the last one published.
    assert!(
        err.contains("345 records published, 1 repeated records dropped, 2 stale records dropped"),
        "{err}"
    );
    assert!(err.contains("link lost: the unit closed it"), "{err}");
    // The gap shows in the records received: one jump over the records of the time away.
    assert!(out.contains(" 1 gaps"), "{out}");
}
