//! `odoctl bridge` received by an independent DDS subscriber: Eclipse Cyclone DDS through the
//! Python `cyclonedds` package with the ROS 2 types written from the .msg definitions
//! (tests/ros/dds_subscriber.py), on 127.0.0.1, against the fake unit on TCP. Skipped with a
//! message when python3 or `cyclonedds` is missing, unless `ODO_PY_REQUIRED=1` (CI).

mod common;

use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Write as _};
use std::path::Path;
use std::process::{Child, Command, Stdio};

use common::scratch;
use odo_unit::odometry::ChassisParams;
use odoctl::simulate::PathKind;

/// Whether the independent reader can run ([`common::python_has`]).
fn cyclonedds_ready() -> bool {
    common::python_has("ros_bridge", "cyclonedds.domain", "cyclonedds")
}

/// Starts the subscriber on `domain` and waits until its readers exist.
fn subscriber(domain: u16, args: &[&str]) -> Child {
    subscriber_with(domain, args, None)
}

/// The subscriber with the Cyclone DDS configuration `config` (`CYCLONEDDS_URI`).
fn subscriber_with(domain: u16, args: &[&str], config: Option<&str>) -> Child {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ros/dds_subscriber.py");
    let mut cmd = Command::new("python3");
    if let Some(c) = config {
        cmd.env("CYCLONEDDS_URI", c);
    }
    let mut child = cmd
        .arg(script)
        .args(args)
        .env("ROS_DOMAIN_ID", domain.to_string())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 runs");
    let mut line = String::new();
    BufReader::new(child.stdout.as_mut().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert_eq!(line.trim(), "ready", "subscriber did not start");
    child
}

fn finish(child: Child) -> String {
    let o = child.wait_with_output().unwrap();
    common::success_stdout(&o)
}

/// The unit's records of `samples` as the subscriber's `--expect` CSV in `dir`.
fn expect_csv(dir: &Path, samples: &[odoctl::csvio::Sample]) -> std::path::PathBuf {
    // The fake unit integrates with its defaults, the designed parameters.
    let records = common::records(&ChassisParams::DESIGNED, samples);
    let mut e =
        String::from("x,y,heading,sigma_x,sigma_y,sigma_heading,cov_xy,gamma_left,gamma_right\n");
    for r in &records {
        let _ = writeln!(
            e,
            "{:?},{:?},{:?},{:?},{:?},{:?},{:?},{},{}",
            r.x,
            r.y,
            r.heading,
            r.sigma_x,
            r.sigma_y,
            r.sigma_heading,
            r.cov_xy,
            r.gamma_left,
            r.gamma_right
        );
    }
    let expect = dir.join("expect.csv");
    std::fs::write(&expect, e).unwrap();
    expect
}

/// The Cyclone DDS configuration rmw_cyclonedds (Jazzy) makes for
/// `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`: no multicast, participant indices, the
/// well-known ports of localhost as peers.
const CYCLONE_LOCALHOST: &str = "<CycloneDDS><Domain><General><AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex><Peers><Peer address=\"localhost\"/></Peers></Discovery></Domain></CycloneDDS>";

/// Runs the bridge against a fake unit with the environment `env` and checks 80 records at a
/// subscriber configured by `config`; the bridge must report the discovery range `range`.
fn discovered_with(domain: u16, config: &str, env: &[(&str, &str)], range: &str) {
    let sim = common::sim(PathKind::Validation, 10.0, 13);
    let samples: Vec<_> = sim.samples[..300].to_vec();
    let dir = scratch(&format!("ros_bridge_discovery_{domain}"));
    let expect = expect_csv(&dir, &samples);
    let args = [
        "--expect",
        expect.to_str().unwrap(),
        "--count",
        "80",
        "--timeout",
        "25",
    ];
    let sub = subscriber_with(domain, &args, Some(config));
    let (port, unit) = common::fake_unit(samples, std::time::Duration::from_millis(20));
    let o = Command::new(common::bin())
        .args(["bridge", "--port", &format!("tcp:127.0.0.1:{port}")])
        .args(["--count", "250"])
        .env("ROS_DOMAIN_ID", domain.to_string())
        .envs(env.iter().copied())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains(&format!("discovery {range}")), "{err}");
    unit.join().unwrap();
    let out = finish(sub);
    assert!(out.contains("dds_subscriber: ok"), "{out}");
    eprintln!("{env:?}: {}", out.trim());
}

#[test]
fn localhost_range_reaches_cyclone_configured_as_rmw_cyclonedds_configures_it() {
    if !cyclonedds_ready() {
        return;
    }
    discovered_with(
        71,
        CYCLONE_LOCALHOST,
        &[("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")],
        "Localhost",
    );
    // Humble's variable means the same range.
    discovered_with(
        72,
        CYCLONE_LOCALHOST,
        &[("ROS_LOCALHOST_ONLY", "1")],
        "Localhost",
    );
    // OFF: nobody could discover the bridge; without --foxglove it has nothing to do.
    let o = Command::new(common::bin())
        .args(["bridge", "--port", "tcp:127.0.0.1:1", "--duration", "1"])
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("OFF"), "{err}");
}

#[test]
fn bridge_publishes_the_units_records_to_an_independent_dds_subscriber() {
    if !cyclonedds_ready() {
        return;
    }
    let sim = common::sim(PathKind::Validation, 10.0, 12);
    let samples: Vec<_> = sim.samples[..400].to_vec();
    // The fake unit integrates with its defaults, the designed parameters.
    let records = common::records(&ChassisParams::DESIGNED, &samples);
    let dir = scratch("ros_bridge");
    let mut e =
        String::from("x,y,heading,sigma_x,sigma_y,sigma_heading,cov_xy,gamma_left,gamma_right\n");
    for r in &records {
        let _ = writeln!(
            e,
            "{:?},{:?},{:?},{:?},{:?},{:?},{:?},{},{}",
            r.x,
            r.y,
            r.heading,
            r.sigma_x,
            r.sigma_y,
            r.sigma_heading,
            r.cov_xy,
            r.gamma_left,
            r.gamma_right
        );
    }
    let expect = dir.join("expect.csv");
    std::fs::write(&expect, e).unwrap();
    let domain = 61;
    let sub = subscriber(
        domain,
        &[
            "--expect",
            expect.to_str().unwrap(),
            "--count",
            "50",
            "--timeout",
            "40",
        ],
    );
    let (port, unit) = common::fake_unit(samples, std::time::Duration::from_millis(20));
    let o = Command::new(common::bin())
        .args(["bridge", "--port", &format!("tcp:127.0.0.1:{port}")])
        .args(["--count", "250"])
        .env("ROS_DOMAIN_ID", domain.to_string())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("250 records published"), "{err}");
    unit.join().unwrap();
    let out = finish(sub);
    assert!(out.contains("dds_subscriber: ok"), "{out}");
    eprintln!("{}", out.trim());
}

#[test]
fn bridge_without_a_unit_reports_the_lost_link_and_publishes_no_pose() {
    if !cyclonedds_ready() {
        return;
    }
    let domain = 62;
    let sub = subscriber(
        domain,
        &["--expect-error", "cannot connect", "--timeout", "30"],
    );
    let o = Command::new(common::bin())
        .args([
            "bridge",
            "--port",
            "tcp:127.0.0.1:1",
            "--duration",
            "4",
            "--retry",
            "0.5",
        ])
        .env("ROS_DOMAIN_ID", domain.to_string())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("0 records published") && err.contains("cannot connect"),
        "{err}"
    );
    let out = finish(sub);
    assert!(out.contains("ERROR"), "{out}");
    // A bad domain is refused.
    let o = Command::new(common::bin())
        .args(["bridge", "--port", "tcp:127.0.0.1:1", "--duration", "1"])
        .env("ROS_DOMAIN_ID", "999")
        .output()
        .unwrap();
    assert!(!o.status.success());
}

/// Runs `reset_client.py` against the service of namespace `ns` on `domain`.
fn reset_call(domain: u16, ns: &str) -> String {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ros/reset_client.py");
    let o = Command::new("python3")
        .arg(script)
        .args(["--ns", ns, "--timeout", "15"])
        .env("ROS_DOMAIN_ID", domain.to_string())
        .output()
        .expect("python3 runs");
    common::success_stdout(&o)
}

#[test]
fn two_namespaced_bridges_on_one_domain_and_the_reset_service() {
    if !cyclonedds_ready() {
        return;
    }
    let domain = 74;
    let dir = scratch("ros_bridge_two");
    let one: Vec<_> = common::sim(PathKind::Validation, 10.0, 14).samples[..400].to_vec();
    let two: Vec<_> = common::sim(PathKind::Validation, 10.0, 15).samples[..400].to_vec();
    // robot2's subscriber checks every /robot2/odom against robot2's unit: a message of
    // robot1 there (whose unit is reset meanwhile) would match none of its records.
    let expect = expect_csv(&dir, &two);
    let sub = subscriber(
        domain,
        &[
            "--expect",
            expect.to_str().unwrap(),
            "--count",
            "150",
            "--timeout",
            "25",
            "--ns",
            "robot2",
            "--frame-prefix",
            "robot2/",
        ],
    );
    // robot1's odom stays continuous across the reset the service asks.
    let sub1 = subscriber(
        domain,
        &[
            "--max-step",
            "0.05",
            "--count",
            "250",
            "--timeout",
            "25",
            "--ns",
            "robot1",
            "--frame-prefix",
            "robot1/",
        ],
    );
    let bridge = |port: u16, ns: &str| {
        Command::new(common::bin())
            .args(["bridge", "--port", &format!("tcp:127.0.0.1:{port}")])
            .args(["--count", "300", "--namespace", ns])
            .args(["--frame-prefix", &format!("{ns}/")])
            .env("ROS_DOMAIN_ID", domain.to_string())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (p1, u1) = common::fake_unit(one, std::time::Duration::from_millis(20));
    let (p2, u2) = common::fake_unit(two, std::time::Duration::from_millis(20));
    let b1 = bridge(p1, "robot1");
    let b2 = bridge(p2, "robot2");
    // The service of robot1, called as ROS 2 (rmw_cyclonedds) calls it.
    let call = reset_call(domain, "robot1");
    assert!(call.contains("success=True"), "{call}");
    let wait = |b: Child| {
        let o = b.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{err}");
        err
    };
    let e1 = wait(b1);
    let e2 = wait(b2);
    u1.join().unwrap();
    u2.join().unwrap();
    assert!(
        e1.contains("1 reset_pose requests answered, 1 pose resets absorbed"),
        "{e1}"
    );
    assert!(
        e2.contains("0 reset_pose requests answered, 0 pose resets absorbed"),
        "{e2}"
    );
    let out = finish(sub);
    assert!(out.contains("dds_subscriber: ok"), "{out}");
    let out1 = finish(sub1);
    assert!(out1.contains("1 reset WARNs"), "{out1}");
    eprintln!("{}\n{}\n{}", call.trim(), out.trim(), out1.trim());
}

#[test]
fn static_peers_reach_a_subscriber_that_knows_only_unicast_peers() {
    if !cyclonedds_ready() {
        return;
    }
    // This host's address on its network, as another machine would know it.
    let Some(ip) = netdev::get_interfaces()
        .into_iter()
        .filter(|i| i.is_up() && !i.is_loopback())
        .find_map(|i| i.ipv4.first().map(|n| n.addr().to_string()))
    else {
        let _ = writeln!(
            std::io::stderr(),
            "static peers: skipped: no network address"
        );
        return;
    };
    // A subscriber without multicast whose only peer is that address (rmw_cyclonedds's
    // SUBNET range with ROS_STATIC_PEERS, multicast unavailable as between most hosts).
    let config = format!(
        "<CycloneDDS><Domain><General><AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex><Peers><Peer address=\"{ip}\"/></Peers></Discovery></Domain></CycloneDDS>"
    );
    discovered_with(73, &config, &[("ROS_STATIC_PEERS", ip.as_str())], "Subnet");
}
