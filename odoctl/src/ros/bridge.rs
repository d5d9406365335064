//! `odoctl bridge --port P`: the unit's live pose records as ROS 2 `/odom`, `/tf`,
//! `/joint_states` and `/diagnostics` over DDS (the `ros2-client` crate on RustDDS: no ROS
//! installation), with the conversions of docs/ROS.md (the same [`OdomStream`] as the
//! recordings) and the names of [`RosNames`]; a `reset_pose` service
//! ([`super::reset_service`]); discovery as the `ROS_...` variables ask
//! ([`super::discovery`], [`super::spdp_relay`]).
//!
//! QoS: reliable, volatile, keep last 10 (100 on `/tf`): what robot_localization, rviz and
//! tf2 listeners subscribe with by default (a reliable writer serves reliable and best-effort
//! readers). A record is published once: a repeated sequence number is dropped and counted,
//! and a lost link is reported on `/diagnostics` (ERROR, the link's status) and reconnected;
//! while no record arrives the status turns STALE and no pose is published. Across
//! reconnections the stamps stay on the unit's clock, and a record at or before the last
//! published one (sent again) is dropped as stale. With `--foxglove` the same messages, the
//! path so far and the 1-sigma ellipse go to a Foxglove WebSocket server
//! ([`super::foxglove`]).

use std::process::ExitCode;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, Result};
use odo_unit::protocol::{Message, PoseRecord};
use ros2_client::dds::rustdds::{DomainParticipantBuilder, RTPSEntity};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Context, MessageTypeName, Name, Node, NodeName, NodeOptions, QosProfile};

use super::conventions::{BaseTwist, PoseCovariance};
use super::discovery::{Discovery, Range};
use super::foxglove::{parse_address, FoxgloveServer};
use super::msgs::{self, level};
use super::names::RosNames;
use super::reset_service::ResetService;
use super::spdp_relay::{self, RelaySocket, SpdpRelay};
use super::stamps::gps_to_unix_nanos;
use super::stream::{Messages, OdomSample, OdomStream};
use crate::link::{self, Session};
use odo_unit::odometry::{ChassisParams, Pose};

/// What `odoctl bridge` does.
#[derive(Debug, Clone)]
pub struct BridgeOptions {
    /// Serial port or `tcp:HOST:PORT`.
    pub port: String,
    /// Baud rate of a serial port.
    pub baud: u32,
    /// The unit's parameters (for the twist from the counts).
    pub params: ChassisParams,
    /// Stop after this long.
    pub duration: Option<Duration>,
    /// Stop after this many published records.
    pub count: Option<u64>,
    /// Wait between reconnection attempts, and without records before the status turns
    /// STALE.
    pub retry: Duration,
    /// Serve the Foxglove WebSocket protocol on this `HOST:PORT` too.
    pub foxglove: Option<String>,
    /// Publish over DDS (ROS 2).
    pub dds: bool,
    /// Node, topic, frame and joint names; TF on or off.
    pub names: RosNames,
}

/// What a bridge run did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BridgeCounts {
    /// Records published on `/odom` and `/tf`.
    pub published: u64,
    /// Records dropped because their sequence number repeated the last one.
    pub repeated: u64,
    /// Connections lost (or refused) and retried.
    pub link_losses: u64,
    /// Records older than the last published one on the unit's clock (sent again after a
    /// reconnection), dropped.
    pub stale: u64,
}

fn host_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// Live stamps: the sample's UTC from the unit's time tag when valid (and the sample rate is
/// known), else the unit's MCU time carried onto the host's clock from the connection's first
/// record (continuous, and comparable with the other sensors' stamps).
#[derive(Debug, Clone, Copy)]
struct LiveStamps {
    rate: Option<f64>,
    origin: Option<(u64, u64)>,
}

/// What a record is, against the last one published.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Freshness {
    /// After the last one on the unit's clock: publish.
    New,
    /// The unit restarted since (its clock is younger than the time since the last record):
    /// publish, on a new clock origin.
    Restarted,
    /// At or before the last one on the unit's clock, from a unit that did not restart: an
    /// old record sent again; dropped.
    Stale,
}

/// `r` against the last published record `last`, received `since` ago.
fn freshness(r: &PoseRecord, last: Option<&PoseRecord>, since: Duration) -> Freshness {
    match last {
        None => Freshness::New,
        Some(l) if r.mcu_time_us > l.mcu_time_us => Freshness::New,
        Some(_) if u128::from(r.mcu_time_us) < since.as_micros() => Freshness::Restarted,
        Some(_) => Freshness::Stale,
    }
}

impl LiveStamps {
    fn stamp(&mut self, r: &PoseRecord) -> u64 {
        if let Some(rate) = self.rate.filter(|_| r.flags.time_valid) {
            let sub = f64::from(r.gnss.sample_in_second) / rate;
            if let Some(ns) = gps_to_unix_nanos(r.gnss.week, r.gnss.tow_ms, sub) {
                return ns;
            }
        }
        let (mcu0, host0) = *self.origin.get_or_insert((r.mcu_time_us, host_now_ns()));
        host0 + r.mcu_time_us.saturating_sub(mcu0) * 1000
    }
}

struct Publishers {
    odom: ros2_client::Publisher<msgs::Odometry>,
    tf: Option<ros2_client::Publisher<msgs::TfMessage>>,
    joints: ros2_client::Publisher<msgs::JointState>,
    diagnostics: ros2_client::Publisher<msgs::DiagnosticArray>,
}

fn dds<E: std::fmt::Debug>(what: &'static str) -> impl Fn(E) -> anyhow::Error {
    move |e| anyhow!("DDS: {what}: {e:?}")
}

/// The QoS of a topic (docs/ROS.md, *QoS*): reliable, volatile, keep last `depth`.
fn qos(depth: usize) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth })
}

/// A publisher of `T` (`pkg/msg/Type`) on the fully qualified `topic`.
fn publisher<T: serde::Serialize>(
    node: &mut Node,
    topic: &str,
    (pkg, ty): (&str, &str),
    depth: usize,
) -> Result<ros2_client::Publisher<T>> {
    let (ns, base) = RosNames::split(topic);
    let name = Name::new(ns, base).map_err(|e| anyhow!("DDS: topic name {topic}: {e:?}"))?;
    let t = node
        .create_topic(&name, MessageTypeName::new(pkg, ty), &qos(depth))
        .map_err(|e| anyhow!("DDS: topic {topic}: {e:?}"))?;
    node.create_publisher(&t, None)
        .map_err(|e| anyhow!("DDS: publisher {topic}: {e:?}"))
}

impl Publishers {
    fn new(node: &mut Node, names: &RosNames) -> Result<Self> {
        Ok(Self {
            odom: publisher(node, &names.odom, ("nav_msgs", "Odometry"), 10)?,
            tf: match &names.tf {
                Some(t) => Some(publisher(node, t, ("tf2_msgs", "TFMessage"), 100)?),
                None => None,
            },
            joints: publisher(node, &names.joint_states, ("sensor_msgs", "JointState"), 10)?,
            diagnostics: publisher(
                node,
                &names.diagnostics,
                ("diagnostic_msgs", "DiagnosticArray"),
                10,
            )?,
        })
    }

    fn status(&self, d: msgs::DiagnosticArray) -> Result<()> {
        self.diagnostics
            .publish(d)
            .map_err(dds("write /diagnostics"))
    }
}

/// The value of `key` in a `get` reply (`key = value` lines).
fn parse_value(text: &str, key: &str) -> Option<f64> {
    text.lines().find_map(|l| {
        let (k, v) = l.split_once('=')?;
        (k.trim() == key).then(|| v.trim().parse().ok())?
    })
}

/// Where the bridge publishes: DDS, the Foxglove WebSocket server, or both.
struct Outlets {
    dds: Option<Publishers>,
    foxglove: Option<FoxgloveServer>,
}

impl Outlets {
    fn sample(&mut self, m: Messages) -> Result<()> {
        if let Some(f) = &mut self.foxglove {
            f.sample(&m)?;
        }
        if let Some(p) = &self.dds {
            if let Some(d) = m.diagnostics {
                p.status(d)?;
            }
            p.odom.publish(m.odom).map_err(dds("write odom"))?;
            if let (Some(t), Some(tf)) = (&p.tf, m.tf) {
                t.publish(tf).map_err(dds("write tf"))?;
            }
            if let Some(j) = m.joints {
                p.joints.publish(j).map_err(dds("write joint_states"))?;
            }
        }
        Ok(())
    }

    fn status(&mut self, d: msgs::DiagnosticArray) -> Result<()> {
        if let Some(f) = &mut self.foxglove {
            f.status(&d)?;
        }
        if let Some(p) = &self.dds {
            p.status(d)?;
        }
        Ok(())
    }
}

/// How one connection ended.
enum Ended {
    /// Enough records or time.
    Done,
    /// The link failed or closed: why.
    Lost(String),
}

/// What the bridge keeps across connections.
struct State {
    stream: OdomStream,
    counts: BridgeCounts,
    stamps: LiveStamps,
    /// The last published record, its stamp and when it arrived.
    last: Option<(PoseRecord, u64, Instant)>,
    /// The `reset_pose` service (DDS only).
    reset: Option<ResetService>,
    /// The unit confirmed a `reset_pose` of the service: its next record carries the reset.
    reset_confirmed: bool,
}

/// The addresses of `ROS_STATIC_PEERS` (host names resolved).
fn peer_addresses(peers: &[String]) -> Result<Vec<std::net::IpAddr>> {
    use std::net::ToSocketAddrs;
    let mut out = Vec::new();
    for p in peers {
        let addrs = (p.as_str(), 0)
            .to_socket_addrs()
            .map_err(|e| anyhow!("ROS_STATIC_PEERS: `{p}`: not an address ({e})"))?;
        out.extend(addrs.map(|a| a.ip()));
    }
    Ok(out)
}

/// The DDS context for the discovery settings `d` (with the relay that carries its
/// announcements to unicast peers, kept alive beside it), `None` with the range `OFF` (no
/// other process could discover the bridge). `LOCALHOST`: RustDDS's multicast and advertised
/// locators on 127.0.0.1 only, announcements to the well-known ports on 127.0.0.1 and, by the
/// relay, to those of the local addresses other participants announce from; `SUBNET`:
/// multicast as well, and the static peers by the relay; `SYSTEM_DEFAULT`: RustDDS's defaults.
fn dds_context(d: &Discovery) -> Result<Option<(Context, Option<SpdpRelay>)>> {
    for w in &d.warnings {
        eprintln!("bridge: warning: {w}");
    }
    let builder = DomainParticipantBuilder::new(d.domain);
    let (builder, relay) = match d.range {
        Range::Off => return Ok(None),
        Range::Localhost => (
            builder
                .with_only_networks([std::net::Ipv4Addr::LOCALHOST])
                .same_host_loopback(true),
            true,
        ),
        Range::Subnet => (builder, !d.static_peers.is_empty()),
        Range::SystemDefault => (builder, false),
    };
    let mut peers = peer_addresses(&d.static_peers)?;
    if d.range == Range::Localhost {
        // As Cyclone DDS adds itself to its peers: this host's other addresses.
        peers.extend(spdp_relay::host_addresses());
    }
    // Without the relay the bridge still publishes; only unicast-only peers miss it.
    let socket = relay
        .then(|| RelaySocket::bind(d.domain))
        .transpose()
        .unwrap_or_else(|e| {
            eprintln!("bridge: warning: {e:#}; peers that discover by unicast only (ROS_STATIC_PEERS, Cyclone DDS with LOCALHOST) will not find the bridge");
            None
        });
    let participant = builder.build().map_err(dds("participant"))?;
    let mut prefix = [0u8; 12];
    prefix.copy_from_slice(&participant.guid().to_bytes()[..12]);
    let relay = socket.map(|s| s.start(prefix, peers)).transpose()?;
    let context = Context::from_domain_participant(participant).map_err(dds("context"))?;
    Ok(Some((context, relay)))
}

/// `odoctl bridge`.
pub fn run(o: &BridgeOptions) -> Result<ExitCode> {
    let mut outlets = Outlets {
        dds: None,
        foxglove: None,
    };
    // A bad address is refused before anything starts.
    let foxglove = o.foxglove.as_deref().map(parse_address).transpose()?;
    // Kept alive while publishing.
    let mut _node = None;
    let discovery = Discovery::from_env(|k| std::env::var(k).ok())?;
    let context = if o.dds {
        dds_context(&discovery)?
    } else {
        None
    };
    if o.dds && context.is_none() {
        if foxglove.is_none() {
            anyhow::bail!("ROS_AUTOMATIC_DISCOVERY_RANGE=OFF: no other process can discover the bridge, and there is no --foxglove: nothing to publish");
        }
        eprintln!("bridge: ROS_AUTOMATIC_DISCOVERY_RANGE=OFF: nothing published over DDS");
    }
    // Kept alive while publishing.
    let mut _relay = None;
    let mut reset = None;
    if let Some((context, relay)) = context {
        _relay = relay;
        let domain = discovery.domain;
        let n = &o.names;
        let mut node = context
            .new_node(
                NodeName::new(&n.namespace, &n.node).map_err(dds("node name"))?,
                NodeOptions::new(),
            )
            .map_err(dds("node"))?;
        outlets.dds = Some(Publishers::new(&mut node, n)?);
        reset = Some(ResetService::new(&mut node, n)?);
        _node = Some(node);
        eprintln!(
            "bridge: node {}{}{} publishing {} from {} (ROS 2 domain {domain}, discovery {:?})",
            n.namespace,
            if n.namespace == "/" { "" } else { "/" },
            n.node,
            topic_list(n, false),
            o.port,
            discovery.range
        );
    }
    if let Some((host, port)) = foxglove {
        let f = FoxgloveServer::start(&host, port, &o.names)?;
        let shown = if host.contains(':') {
            format!("[{host}]")
        } else {
            host.clone()
        };
        eprintln!(
            "bridge: Foxglove WebSocket server on ws://{shown}:{} ({}) from {}",
            f.port(),
            topic_list(&o.names, true),
            o.port
        );
        outlets.foxglove = Some(f);
    }
    let end = o.duration.map(|d| Instant::now() + d);
    let mut st = State {
        stream: OdomStream::new(None).with_names(o.names.clone()),
        counts: BridgeCounts::default(),
        stamps: LiveStamps {
            rate: None,
            origin: None,
        },
        last: None,
        reset,
        reset_confirmed: false,
    };
    loop {
        if end.is_some_and(|e| Instant::now() >= e) {
            break;
        }
        let ended = match link::open(&o.port, o.baud).and_then(|l| Session::new(l, None)) {
            Ok(mut s) => serve(o, &mut s, &mut outlets, &mut st, end)?,
            Err(e) => Ended::Lost(format!("cannot connect: {e:#}")),
        };
        match ended {
            Ended::Done => break,
            Ended::Lost(why) => {
                st.counts.link_losses += 1;
                st.stream.set_extra(link_values(&st.counts));
                let msg = format!("{why}; reconnecting every {:.1} s", o.retry.as_secs_f64());
                if let Some(r) = &mut st.reset {
                    r.fail_all(&format!("no link to the unit: {why}"));
                }
                eprintln!("bridge: {msg}");
                outlets.status(st.stream.status(host_now_ns(), level::ERROR, &msg)?)?;
                std::thread::sleep(o.retry);
            }
        }
    }
    let c = st.counts;
    eprintln!(
        "bridge: {} records published, {} repeated records dropped, {} stale records dropped, {} link losses",
        c.published, c.repeated, c.stale, c.link_losses
    );
    if let Some(r) = &st.reset {
        eprintln!(
            "bridge: {} reset_pose requests answered, {} pose resets absorbed (odom kept continuous)",
            r.answered(),
            st.stream.counts().resets
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The topics published, for the start message; with the Foxglove-only ones when `foxglove`.
fn topic_list(n: &RosNames, foxglove: bool) -> String {
    let mut t = vec![n.odom.as_str()];
    t.extend(n.tf.as_deref());
    t.extend([n.joint_states.as_str(), n.diagnostics.as_str()]);
    if foxglove {
        t.extend([n.path.as_str(), n.ellipse.as_str()]);
    }
    t.join(", ")
}

fn link_values(c: &BridgeCounts) -> Vec<(String, String)> {
    vec![
        ("published".into(), c.published.to_string()),
        ("repeated_records_dropped".into(), c.repeated.to_string()),
        ("stale_records_dropped".into(), c.stale.to_string()),
        ("link_losses".into(), c.link_losses.to_string()),
    ]
}

/// The `reset_pose` service's turn: a new request sends `reset_pose` to the unit (answered
/// when its reply arrives); one without a reply in time is answered as failed.
fn serve_reset(s: &mut Session, st: &mut State) -> Result<()> {
    let Some(rs) = &mut st.reset else {
        return Ok(());
    };
    rs.expire();
    if rs.poll() {
        if let Err(e) = s.send_line("reset_pose") {
            rs.fail_all(&format!("{e:#}"));
            return Err(e);
        }
    }
    Ok(())
}

/// Margin on the unit's clock for telling a restarted unit from an old record.
const RESTART_MARGIN: Duration = Duration::from_secs(1);

/// Publishes the records of one connection until it ends.
fn serve(
    o: &BridgeOptions,
    s: &mut Session,
    outlets: &mut Outlets,
    st: &mut State,
    end: Option<Instant>,
) -> Result<Ended> {
    // One `get` (every key): the sample rate for the stamps, and the increments per turn the
    // unit works with for the joint angles (else the given parameters').
    let settings = match s.command("get", o.retry.max(Duration::from_secs(1))) {
        Ok((true, text)) => text,
        Ok(_) => String::new(),
        Err(e) => return Ok(Ended::Lost(format!("link: {e:#}"))),
    };
    st.stamps.rate = parse_value(&settings, "rate");
    let ticks = parse_value(&settings, "ticks_per_rev").map(|t| t as u32);
    st.stream
        .set_ticks_per_rev(Some(ticks.unwrap_or(o.params.ticks_per_rev)));
    let mut stale = false;
    loop {
        let now = Instant::now();
        if end.is_some_and(|e| now >= e) {
            return Ok(Ended::Done);
        }
        if let Err(e) = serve_reset(s, st) {
            return Ok(Ended::Lost(format!("link lost: {e:#}")));
        }
        let wait = now + o.retry;
        let deadline = end.map_or(wait, |e| e.min(wait));
        let frame = match s.next_frame(Some(deadline)) {
            Ok(f) => f,
            Err(e) => return Ok(Ended::Lost(format!("link lost: {e:#}"))),
        };
        let r = match frame {
            Some(f) => match f.message {
                Message::Pose(r) => r,
                Message::Reply(r) => {
                    if let Some(rs) = &mut st.reset {
                        st.reset_confirmed |= rs.reply(r.ok, &r.text, r.more);
                    }
                    continue;
                }
                _ => continue,
            },
            None if s.closed() => return Ok(Ended::Lost("link lost: the unit closed it".into())),
            None => {
                if !stale && end.is_none_or(|e| Instant::now() < e) {
                    stale = true;
                    st.stream.set_extra(link_values(&st.counts));
                    let msg = format!("no pose record for {:.1} s", o.retry.as_secs_f64());
                    outlets.status(st.stream.status(host_now_ns(), level::STALE, &msg)?)?;
                }
                continue;
            }
        };
        let received = Instant::now();
        if st.last.is_some_and(|(p, _, _)| p.sequence == r.sequence) {
            st.counts.repeated += 1;
            continue;
        }
        let since = st
            .last
            .map_or(Duration::ZERO, |(_, _, t)| received.duration_since(t));
        let fresh = freshness(&r, st.last.as_ref().map(|l| &l.0), since + RESTART_MARGIN);
        match fresh {
            Freshness::New => {}
            // A new clock: re-anchored at this record, no twist across the restart.
            Freshness::Restarted => st.stamps.origin = None,
            Freshness::Stale => {
                st.counts.stale += 1;
                continue;
            }
        }
        stale = false;
        let stamp = st.stamps.stamp(&r);
        let prev = st.last.map(|(p, t, _)| (p, t));
        let zero = r.sigma_x == 0.0 && r.sigma_y == 0.0 && r.sigma_heading == 0.0;
        let was_moving = prev
            .is_some_and(|(p, _)| p.sigma_x != 0.0 || p.sigma_y != 0.0 || p.sigma_heading != 0.0);
        let twist = prev.filter(|_| fresh == Freshness::New).and_then(|(p, t)| {
            let dt = stamp.saturating_sub(t) as f64 * 1e-9;
            BaseTwist::from_counts(
                &o.params,
                r.gamma_left - p.gamma_left,
                r.gamma_right - p.gamma_right,
                dt,
            )
        });
        let sample = OdomSample {
            stamp_ns: stamp,
            pose: Pose {
                x: r.x,
                y: r.y,
                heading: r.heading,
            },
            cov: PoseCovariance::from_sigmas(
                r.sigma_x,
                r.sigma_y,
                r.sigma_heading,
                r.cov_xy,
                (0.0, 0.0),
            ),
            twist,
            flags: Some(r.flags.to_bits()),
            sequence: Some(u64::from(r.sequence)),
            overrange: false,
            // A reset: the one the service asked (the record after the unit's `ok`), or
            // sigmas back to zero (a `reset_pose` from elsewhere, a reboot).
            reset: std::mem::take(&mut st.reset_confirmed) || (zero && was_moving),
            counts: Some((r.gamma_left, r.gamma_right)),
        };
        st.stream.set_extra(link_values(&st.counts));
        let m = match st.stream.next(&sample) {
            Ok(m) => m,
            // A stamp before the last one: not published as new.
            Err(_) => {
                st.counts.stale += 1;
                continue;
            }
        };
        outlets.sample(m)?;
        st.counts.published += 1;
        st.last = Some((r, stamp, received));
        if o.count.is_some_and(|c| st.counts.published >= c) {
            return Ok(Ended::Done);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn freshness_table() {
        let at = |us| PoseRecord {
            mcu_time_us: us,
            ..Default::default()
        };
        let last = at(600_000_000);
        let s = Duration::from_secs;
        assert_eq!(freshness(&at(1), None, s(0)), Freshness::New);
        assert_eq!(
            freshness(&at(600_020_000), Some(&last), s(0)),
            Freshness::New
        );
        // Sent again after a 2 s gap: the unit's clock says it is old.
        assert_eq!(freshness(&last, Some(&last), s(2)), Freshness::Stale);
        assert_eq!(
            freshness(&at(599_000_000), Some(&last), s(2)),
            Freshness::Stale
        );
        // Up for 1.5 s after 3 s away: it restarted.
        assert_eq!(
            freshness(&at(1_500_000), Some(&last), s(3)),
            Freshness::Restarted
        );
    }

    #[test]
    fn rate_reply() {
        assert_eq!(parse_value("rate = 50\n", "rate"), Some(50.0));
        assert_eq!(parse_value("x = 1\nrate=100", "rate"), Some(100.0));
        assert_eq!(parse_value("rates = 5", "rate"), None);
        assert_eq!(
            parse_value("ticks_per_rev = 20000", "ticks_per_rev"),
            Some(20000.0)
        );
    }

    #[test]
    fn live_stamps_follow_the_tag_or_the_mcu_clock() {
        let mut r = PoseRecord {
            mcu_time_us: 5_000_000,
            ..Default::default()
        };
        let mut st = LiveStamps {
            rate: Some(50.0),
            origin: None,
        };
        let host = host_now_ns();
        let a = st.stamp(&r);
        assert!(a >= host && a - host < 1_000_000_000);
        r.mcu_time_us += 20_000;
        assert_eq!(st.stamp(&r), a + 20_000_000);
        r.flags.time_valid = true;
        r.gnss.week = 2300;
        r.gnss.tow_ms = 86_400_000;
        r.gnss.sample_in_second = 25;
        assert_eq!(
            st.stamp(&r),
            gps_to_unix_nanos(2300, 86_400_000, 0.5).unwrap()
        );
    }
}
