//! `odoctl bridge --mavlink`: the unit's pose records as MAVLink 2 `ODOMETRY` (and a
//! `HEARTBEAT` each second) for a flight controller, for the companion-computer set-up
//! (docs/MAVLINK.md). The frames come from the same encoder as the firmware's `output =
//! mavlink` (`odo_unit::mavlink`).

use std::io::Write;
use std::net::UdpSocket;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use odo_unit::mavlink::{FrameBuf, Ids, MavlinkOut, MAX_FRAME_LEN};
use odo_unit::odometry::ChassisParams;
use odo_unit::protocol::{Message, PoseRecord};

use crate::link::{self, Session};

/// Where the frames go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Target {
    /// UDP datagrams, one frame each, to `HOST:PORT` (`udpout:HOST:PORT`, as MAVProxy and
    /// mavlink-router name it).
    UdpOut(String),
    /// A serial port at a baud rate (`serial:PATH:BAUD`).
    Serial(String, u32),
}

impl Target {
    /// Parses `udpout:HOST:PORT` or `serial:PATH:BAUD`.
    pub fn parse(text: &str) -> Result<Self> {
        if let Some(addr) = text.strip_prefix("udpout:") {
            let (host, port) = addr
                .rsplit_once(':')
                .ok_or_else(|| anyhow!("--mavlink {text}: expected udpout:HOST:PORT"))?;
            port.parse::<u16>()
                .map_err(|_| anyhow!("--mavlink {text}: `{port}` is not a UDP port"))?;
            if host.is_empty() {
                bail!("--mavlink {text}: no host");
            }
            Ok(Self::UdpOut(addr.to_string()))
        } else if let Some(rest) = text.strip_prefix("serial:") {
            let (path, baud) = rest
                .rsplit_once(':')
                .ok_or_else(|| anyhow!("--mavlink {text}: expected serial:PATH:BAUD"))?;
            let baud = baud
                .parse::<u32>()
                .ok()
                .filter(|b| *b > 0)
                .ok_or_else(|| anyhow!("--mavlink {text}: `{baud}` is not a baud rate"))?;
            Ok(Self::Serial(path.to_string(), baud))
        } else {
            bail!("--mavlink {text}: expected udpout:HOST:PORT or serial:PATH:BAUD")
        }
    }

    fn open(&self) -> Result<Box<dyn Write>> {
        match self {
            Self::UdpOut(addr) => {
                let socket = UdpSocket::bind(if addr.starts_with('[') {
                    "[::]:0"
                } else {
                    "0.0.0.0:0"
                })?;
                socket
                    .connect(addr)
                    .with_context(|| format!("udpout:{addr}: cannot reach"))?;
                Ok(Box::new(Datagrams(socket)))
            }
            Self::Serial(path, baud) => Ok(Box::new(
                serialport::new(path, *baud)
                    .timeout(Duration::from_millis(100))
                    .open()
                    .with_context(|| format!("serial:{path}: cannot open"))?,
            )),
        }
    }
}

/// One frame per `write`, one datagram each.
struct Datagrams(UdpSocket);

impl Write for Datagrams {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        // A receiver not listening yet (ICMP port unreachable) is not an error of ours.
        match self.0.send(buf) {
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => Ok(buf.len()),
            r => r,
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Records to frames: the core's encoder, with the pose resets found in the records. A
/// reset restarts the unit's uncertainty at 0, while between resets `sigma_heading` grows
/// with every step (the covariance model's geometry and slip terms can shrink it, but only
/// gradually); so a record whose `sigma_heading` is below half the previous record's, or
/// whose three sigmas are zero after a record with a non-zero one, is the first after a reset
/// (the reset's own sample, or a later one when `output_divider` skipped it).
pub struct Converter {
    out: MavlinkOut,
    params: ChassisParams,
    ids: Ids,
    resets: u32,
    last: Option<(bool, f32)>,
}

impl Converter {
    /// Frames with `ids`, velocities from the counts with `params`.
    pub fn new(params: ChassisParams, ids: Ids) -> Self {
        Self {
            out: MavlinkOut::new(),
            params,
            ids,
            resets: 0,
            last: None,
        }
    }

    /// The `ODOMETRY` frame of `r`.
    pub fn odometry(&mut self, r: &PoseRecord) -> Vec<u8> {
        let zero = r.sigma_x == 0.0 && r.sigma_y == 0.0 && r.sigma_heading == 0.0;
        if let Some((had_sigma, heading)) = self.last {
            if (zero && had_sigma) || r.sigma_heading < 0.5 * heading {
                self.resets += 1;
            }
        }
        self.last = Some((!zero, r.sigma_heading));
        let mut buf: FrameBuf = [0; MAX_FRAME_LEN + 1];
        let n = self
            .out
            .odometry(r, &self.params, self.resets, self.ids, &mut buf);
        self.out.sent(true);
        buf[..n].to_vec()
    }

    /// The `HEARTBEAT` frame.
    pub fn heartbeat(&mut self) -> Vec<u8> {
        let mut buf: FrameBuf = [0; MAX_FRAME_LEN + 1];
        let n = self.out.heartbeat(self.ids, &mut buf);
        self.out.sent(true);
        buf[..n].to_vec()
    }
}

/// What `bridge --mavlink` needs.
pub struct MavlinkOptions {
    /// The unit's link.
    pub port: String,
    /// Its baud rate (serial ports).
    pub baud: u32,
    /// The chassis parameters, for the velocity from the counts.
    pub params: ChassisParams,
    /// Where the frames go.
    pub target: Target,
    /// System and component id.
    pub ids: Ids,
    /// Stop after this long.
    pub duration: Option<Duration>,
    /// Stop after this many records.
    pub count: Option<u64>,
}

/// Runs the bridge until `duration`, `count`, or the unit closes the link.
pub fn run(o: &MavlinkOptions) -> Result<ExitCode> {
    let mut sink = o.target.open()?;
    let mut session = Session::new(link::open(&o.port, o.baud)?, None)?;
    let mut conv = Converter::new(o.params, o.ids);
    eprintln!("bridge: MAVLink ODOMETRY from {} to {:?}", o.port, o.target);
    let end = o.duration.map(|d| Instant::now() + d);
    let (mut records, mut heartbeats) = (0u64, 0u64);
    let mut next_heartbeat = Instant::now();
    while o.count.is_none_or(|c| records < c) {
        if Instant::now() >= next_heartbeat {
            sink.write_all(&conv.heartbeat())?;
            heartbeats += 1;
            next_heartbeat += Duration::from_secs(1);
        }
        let deadline = end.map_or(next_heartbeat, |e| e.min(next_heartbeat));
        match session.next_frame(Some(deadline))? {
            Some(f) => {
                if let Message::Pose(r) = f.message {
                    sink.write_all(&conv.odometry(&r))?;
                    records += 1;
                }
            }
            None if session.closed() || end.is_some_and(|e| Instant::now() >= e) => break,
            None => {}
        }
    }
    eprintln!("bridge: {records} ODOMETRY and {heartbeats} HEARTBEAT frames sent");
    Ok(ExitCode::SUCCESS)
}

/// `odoctl bridge --mavlink TARGET`: the bridge's arguments to [`run`] (ids: the unit's
/// defaults, `mavlink_sysid` 1 and `mavlink_compid` 197).
pub fn bridge(a: &crate::cli::BridgeArgs, target: &str) -> Result<ExitCode> {
    let duration = a
        .duration
        .map(|d| {
            Duration::try_from_secs_f64(d)
                .map_err(|_| anyhow!("--duration {d}: not a duration in seconds"))
        })
        .transpose()?;
    run(&MavlinkOptions {
        port: a.port.port.clone(),
        baud: a.port.baud,
        params: crate::config::load(a.params.config.as_deref(), &a.params.sets)?,
        target: Target::parse(target)?,
        ids: Ids::of(&odo_unit::settings::Settings::DEFAULT),
        duration,
        count: a.count,
    })
}
