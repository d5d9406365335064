//! `odoctl bridge --port P`: the unit's live pose records as ROS 2 `/odom`, `/tf` and
//! `/diagnostics` over DDS (the `ros2-client` crate on RustDDS: no ROS installation), with the
//! conversions of docs/ROS.md (the same [`OdomStream`] as the recordings).
//!
//! QoS: reliable, volatile, keep last 10 on `/odom` and `/diagnostics`, keep last 100 on
//! `/tf`: what robot_localization, rviz and tf2 listeners subscribe with by default (a
//! reliable writer serves reliable and best-effort readers). A record is published once:
//! a repeated sequence number is dropped and counted, and a lost link is reported on
//! `/diagnostics` (ERROR) and reconnected; while no record arrives the status turns STALE and
//! no pose is published.

use std::process::ExitCode;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, Result};
use odo_core::protocol::{Message, PoseRecord};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, QosProfile,
};

use super::conventions::{BaseTwist, PoseCovariance};
use super::msgs::{self, level};
use super::stamps::gps_to_unix_nanos;
use super::stream::{OdomSample, OdomStream};
use crate::link::{self, Session};
use odo_core::odometry::{ChassisParams, Pose};

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
    tf: ros2_client::Publisher<msgs::TfMessage>,
    diagnostics: ros2_client::Publisher<msgs::DiagnosticArray>,
}

fn dds<E: std::fmt::Debug>(what: &'static str) -> impl Fn(E) -> anyhow::Error {
    move |e| anyhow!("DDS: {what}: {e:?}")
}

impl Publishers {
    fn new(node: &mut Node) -> Result<Self> {
        let qos = |depth| {
            QosProfile::publisher_default()
                .reliability_reliable(WhenFull::DEFAULT)
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth })
        };
        let name = |n: &str| Name::new("/", n).map_err(dds("topic name"));
        let odom = node
            .create_topic(
                &name("odom")?,
                MessageTypeName::new("nav_msgs", "Odometry"),
                &qos(10),
            )
            .map_err(dds("topic /odom"))?;
        let tf = node
            .create_topic(
                &name("tf")?,
                MessageTypeName::new("tf2_msgs", "TFMessage"),
                &qos(100),
            )
            .map_err(dds("topic /tf"))?;
        let diagnostics = node
            .create_topic(
                &name("diagnostics")?,
                MessageTypeName::new("diagnostic_msgs", "DiagnosticArray"),
                &qos(10),
            )
            .map_err(dds("topic /diagnostics"))?;
        Ok(Self {
            odom: node
                .create_publisher(&odom, None)
                .map_err(dds("publisher /odom"))?,
            tf: node
                .create_publisher(&tf, None)
                .map_err(dds("publisher /tf"))?,
            diagnostics: node
                .create_publisher(&diagnostics, None)
                .map_err(dds("publisher /diagnostics"))?,
        })
    }

    fn status(&self, d: msgs::DiagnosticArray) -> Result<()> {
        self.diagnostics
            .publish(d)
            .map_err(dds("write /diagnostics"))
    }
}

fn parse_rate(text: &str) -> Option<f64> {
    text.lines().find_map(|l| {
        let (k, v) = l.split_once('=')?;
        (k.trim() == "rate").then(|| v.trim().parse().ok())?
    })
}

/// How one connection ended.
enum Ended {
    /// Enough records or time.
    Done,
    /// The link failed or closed: why.
    Lost(String),
}

/// `odoctl bridge`.
pub fn run(o: &BridgeOptions) -> Result<ExitCode> {
    let domain = match std::env::var("ROS_DOMAIN_ID") {
        Ok(v) if !v.trim().is_empty() => v
            .trim()
            .parse::<u16>()
            .ok()
            .filter(|d| *d <= 232)
            .ok_or_else(|| anyhow!("ROS_DOMAIN_ID `{v}` is not a domain (0..=232)"))?,
        _ => 0,
    };
    let context =
        Context::with_options(ContextOptions::new().domain_id(domain)).map_err(dds("context"))?;
    let mut node = context
        .new_node(
            NodeName::new("/", "odoctl_bridge").map_err(dds("node name"))?,
            NodeOptions::new(),
        )
        .map_err(dds("node"))?;
    let publishers = Publishers::new(&mut node)?;
    let end = o.duration.map(|d| Instant::now() + d);
    let mut stream = OdomStream::new(None);
    let mut counts = BridgeCounts::default();
    eprintln!(
        "bridge: publishing /odom, /tf, /diagnostics from {} (ROS 2 domain {domain})",
        o.port
    );
    loop {
        if end.is_some_and(|e| Instant::now() >= e) {
            break;
        }
        let ended = match link::open(&o.port, o.baud).and_then(|l| Session::new(l, None)) {
            Ok(mut s) => serve(o, &mut s, &publishers, &mut stream, &mut counts, end)?,
            Err(e) => Ended::Lost(format!("cannot connect: {e:#}")),
        };
        match ended {
            Ended::Done => break,
            Ended::Lost(why) => {
                counts.link_losses += 1;
                stream.set_extra(link_values(&counts));
                let msg = format!("{why}; reconnecting every {:.1} s", o.retry.as_secs_f64());
                eprintln!("bridge: {msg}");
                publishers.status(stream.status(host_now_ns(), level::ERROR, &msg)?)?;
                std::thread::sleep(o.retry);
            }
        }
    }
    eprintln!(
        "bridge: {} records published, {} repeated records dropped, {} link losses",
        counts.published, counts.repeated, counts.link_losses
    );
    Ok(ExitCode::SUCCESS)
}

fn link_values(c: &BridgeCounts) -> Vec<(String, String)> {
    vec![
        ("published".into(), c.published.to_string()),
        ("repeated_records_dropped".into(), c.repeated.to_string()),
        ("link_losses".into(), c.link_losses.to_string()),
    ]
}

/// Publishes the records of one connection until it ends.
fn serve(
    o: &BridgeOptions,
    s: &mut Session,
    publishers: &Publishers,
    stream: &mut OdomStream,
    counts: &mut BridgeCounts,
    end: Option<Instant>,
) -> Result<Ended> {
    let rate = match s.command("get rate", o.retry.max(Duration::from_secs(1))) {
        Ok((true, text)) => parse_rate(&text),
        Ok(_) => None,
        Err(e) => return Ok(Ended::Lost(format!("link: {e:#}"))),
    };
    let mut stamps = LiveStamps { rate, origin: None };
    let mut prev: Option<(PoseRecord, u64)> = None;
    let mut stale = false;
    loop {
        let now = Instant::now();
        if end.is_some_and(|e| now >= e) {
            return Ok(Ended::Done);
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
                _ => continue,
            },
            None if s.closed() => return Ok(Ended::Lost("link lost: the unit closed it".into())),
            None => {
                if !stale && end.is_none_or(|e| Instant::now() < e) {
                    stale = true;
                    stream.set_extra(link_values(counts));
                    let msg = format!("no pose record for {:.1} s", o.retry.as_secs_f64());
                    publishers.status(stream.status(host_now_ns(), level::STALE, &msg)?)?;
                }
                continue;
            }
        };
        if prev.is_some_and(|(p, _)| p.sequence == r.sequence) {
            counts.repeated += 1;
            continue;
        }
        stale = false;
        let stamp = stamps.stamp(&r);
        let zero = r.sigma_x == 0.0 && r.sigma_y == 0.0 && r.sigma_heading == 0.0;
        let was_moving = prev
            .is_some_and(|(p, _)| p.sigma_x != 0.0 || p.sigma_y != 0.0 || p.sigma_heading != 0.0);
        let twist = prev.and_then(|(p, t)| {
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
                r.sigma_xy,
                (0.0, 0.0),
            ),
            twist,
            flags: Some(r.flags.to_bits()),
            sequence: Some(u64::from(r.sequence)),
            overrange: false,
            reset: zero && was_moving,
        };
        stream.set_extra(link_values(counts));
        let m = match stream.next(&sample) {
            Ok(m) => m,
            // A stamp before the last one (the unit restarted its clock): not published as new.
            Err(_) => {
                counts.repeated += 1;
                continue;
            }
        };
        publishers
            .odom
            .publish(m.odom)
            .map_err(dds("write /odom"))?;
        publishers.tf.publish(m.tf).map_err(dds("write /tf"))?;
        if let Some(d) = m.diagnostics {
            publishers.status(d)?;
        }
        counts.published += 1;
        prev = Some((r, stamp));
        if o.count.is_some_and(|c| counts.published >= c) {
            return Ok(Ended::Done);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_reply() {
        assert_eq!(parse_rate("rate = 50\n"), Some(50.0));
        assert_eq!(parse_rate("x = 1\nrate=100"), Some(100.0));
        assert_eq!(parse_rate("rates = 5"), None);
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
