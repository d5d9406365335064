//! `odoctl bridge --foxglove`: the live pose on a Foxglove WebSocket server, so that the
//! Foxglove app shows the chassis move. The server speaks the documented Foxglove WebSocket
//! protocol (subprotocol `foxglove.websocket.v1`, or its SDK name `foxglove.sdk.v1`):
//! `serverInfo`, `advertise`, `status` and binary `messageData` out; `subscribe` and
//! `unsubscribe` in.
//!
//! Channels (docs/ROS.md): `/odom`, `/tf` and `/diagnostics` are the bridge's ROS 2 messages
//! themselves (`ros2msg` schemas, `cdr` encoding, the bytes of the MCAP recordings); the path
//! so far is `/odom/path` (`nav_msgs/msg/Path`, as in the recordings); the 1-sigma position
//! ellipse is `/odom/ellipse` (`foxglove.SceneUpdate` in JSON: ROS has no ellipse message).

use std::collections::{BTreeMap, HashMap};
use std::io::ErrorKind;
use std::net::{TcpListener, TcpStream};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{anyhow, Context as _, Result};
use serde_json::{json, Value};
use tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tungstenite::http::{HeaderValue, StatusCode};
use tungstenite::{Message as WsMessage, WebSocket};

use super::msgs::{self, MsgType};
use super::names::RosNames;
use super::stream::Messages;

/// The subprotocols accepted, preferred first: the protocol's documented name and the name
/// the Foxglove SDK gives the same protocol.
pub const SUBPROTOCOLS: [&str; 2] = ["foxglove.websocket.v1", "foxglove.sdk.v1"];

/// Points on the ellipse's outline.
pub const ELLIPSE_POINTS: usize = 72;
/// Poses kept in `/odom/path`; beyond, every second one is dropped and the spacing doubles.
pub const PATH_CAPACITY: usize = 4096;
/// Initial spacing of the path's poses (m, or rad of yaw).
pub const PATH_STEP: f64 = 0.01;
/// `/odom/path` is published at most this often (ns of sample stamps).
pub const PATH_PERIOD_NS: u64 = 500_000_000;

/// The 1-sigma ellipse of a 2x2 position covariance: semi-axes `a >= b` (m) and the angle of
/// `a` from +x (east), counter-clockwise (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipse {
    /// Major semi-axis, m.
    pub a: f64,
    /// Minor semi-axis, m.
    pub b: f64,
    /// Angle of the major axis from +x, rad, in (-pi/2, pi/2].
    pub angle: f64,
}

impl Ellipse {
    /// From var(x), var(y) (m^2) and cov(x, y) (m^2).
    pub fn from_covariance(xx: f64, yy: f64, xy: f64) -> Self {
        let mean = 0.5 * (xx + yy);
        let r = (0.5 * (xx - yy)).hypot(xy);
        Self {
            a: (mean + r).max(0.0).sqrt(),
            b: (mean - r).max(0.0).sqrt(),
            angle: 0.5 * (2.0 * xy).atan2(xx - yy),
        }
    }

    /// The outline in the ellipse's own axes (major along x), closed by a line loop.
    pub fn outline(&self) -> Vec<Point3> {
        (0..ELLIPSE_POINTS)
            .map(|i| {
                let t = std::f64::consts::TAU * i as f64 / ELLIPSE_POINTS as f64;
                Point3 {
                    x: self.a * t.cos(),
                    y: self.b * t.sin(),
                    z: 0.0,
                }
            })
            .collect()
    }
}

/// The path so far, thinned to a bounded size: a pose is kept when it is `step` or more from
/// the last kept one (position in m, or yaw in rad); at [`PATH_CAPACITY`] every second kept
/// pose is dropped and `step` doubles. The latest pose always ends the published path.
#[derive(Debug, Clone, Default)]
pub struct PathSoFar {
    kept: Vec<msgs::PoseStamped>,
    step: f64,
}

fn yaw(q: &msgs::Quaternion) -> f64 {
    2.0 * q.z.atan2(q.w)
}

impl PathSoFar {
    /// An empty path.
    pub fn new() -> Self {
        Self {
            kept: Vec::new(),
            step: PATH_STEP,
        }
    }

    /// Adds the latest pose.
    pub fn push(&mut self, p: &msgs::PoseStamped) {
        let far = self.kept.last().is_none_or(|l| {
            let d = (p.pose.position.x - l.pose.position.x)
                .hypot(p.pose.position.y - l.pose.position.y);
            let mut dyaw = (yaw(&p.pose.orientation) - yaw(&l.pose.orientation)).abs();
            if dyaw > std::f64::consts::PI {
                dyaw = std::f64::consts::TAU - dyaw;
            }
            d >= self.step || dyaw >= self.step
        });
        if far {
            if self.kept.len() >= PATH_CAPACITY {
                let mut i = 0;
                self.kept.retain(|_| {
                    i += 1;
                    i % 2 == 1
                });
                self.step *= 2.0;
            }
            self.kept.push(p.clone());
        }
    }

    /// The path message: the kept poses, then `latest` when it was not kept.
    pub fn message(&self, latest: &msgs::PoseStamped) -> msgs::Path {
        let mut poses = self.kept.clone();
        if poses.last() != Some(latest) {
            poses.push(latest.clone());
        }
        msgs::Path {
            header: latest.header.clone(),
            poses,
        }
    }
}

/// A point of a scene primitive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point3 {
    /// m.
    pub x: f64,
    /// m.
    pub y: f64,
    /// m.
    pub z: f64,
}

fn time_json(ns: u64) -> Value {
    json!({ "sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000 })
}

/// The `/odom/ellipse` scene (`foxglove.SceneUpdate`, JSON) of one `/odom`: the outline (a
/// line loop) and a translucent disc, centred on the position, the major axis along the
/// pose's orientation, in `odom`.
pub fn ellipse_scene(odom: &msgs::Odometry, stamp_ns: u64) -> Value {
    let frame = odom.header.frame_id.as_str();
    let c = &odom.pose.covariance.0;
    let e = Ellipse::from_covariance(c[0], c[7], c[1]);
    let pose = json!({
        "position": { "x": odom.pose.pose.position.x, "y": odom.pose.pose.position.y, "z": 0.0 },
        "orientation": { "x": 0.0, "y": 0.0, "z": (0.5 * e.angle).sin(), "w": (0.5 * e.angle).cos() },
    });
    let points: Vec<Value> = e
        .outline()
        .iter()
        .map(|p| json!({ "x": p.x, "y": p.y, "z": p.z }))
        .collect();
    json!({
        "deletions": [],
        "entities": [{
            "timestamp": time_json(stamp_ns),
            "frame_id": frame,
            "id": "position_1sigma",
            "lifetime": { "sec": 0, "nsec": 0 },
            "frame_locked": false,
            "metadata": [
                { "key": "semi_major_m", "value": format!("{:e}", e.a) },
                { "key": "semi_minor_m", "value": format!("{:e}", e.b) },
            ],
            "arrows": [], "cubes": [], "spheres": [], "triangles": [], "texts": [], "models": [],
            "lines": [{
                "type": 1,
                "pose": pose,
                "thickness": 2.0,
                "scale_invariant": true,
                "points": points,
                "color": { "r": 1.0, "g": 0.45, "b": 0.0, "a": 1.0 },
                "colors": [],
                "indices": [],
            }],
            "cylinders": [{
                "pose": pose,
                "size": { "x": 2.0 * e.a, "y": 2.0 * e.b, "z": 0.001 },
                "bottom_scale": 1.0,
                "top_scale": 1.0,
                "color": { "r": 1.0, "g": 0.45, "b": 0.0, "a": 0.3 },
            }],
        }],
    })
}

/// The JSON schema of the `foxglove.SceneUpdate` fields we send.
fn scene_update_schema() -> String {
    let num = json!({ "type": "number" });
    let time = json!({ "type": "object", "properties": { "sec": { "type": "integer" }, "nsec": { "type": "integer" } } });
    let xyz = json!({ "type": "object", "properties": { "x": num, "y": num, "z": num } });
    let quat =
        json!({ "type": "object", "properties": { "x": num, "y": num, "z": num, "w": num } });
    let color =
        json!({ "type": "object", "properties": { "r": num, "g": num, "b": num, "a": num } });
    let pose = json!({ "type": "object", "properties": { "position": xyz, "orientation": quat } });
    let line = json!({ "type": "object", "properties": {
        "type": { "type": "integer", "description": "0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST" },
        "pose": pose, "thickness": num, "scale_invariant": { "type": "boolean" },
        "points": { "type": "array", "items": xyz }, "color": color,
        "colors": { "type": "array", "items": color }, "indices": { "type": "array", "items": { "type": "integer" } },
    }});
    let cylinder = json!({ "type": "object", "properties": {
        "pose": pose, "size": xyz, "bottom_scale": num, "top_scale": num, "color": color,
    }});
    let any = json!({ "type": "array", "items": { "type": "object" } });
    json!({
        "title": "foxglove.SceneUpdate",
        "type": "object",
        "properties": {
            "deletions": any,
            "entities": { "type": "array", "items": { "type": "object", "properties": {
                "timestamp": time, "frame_id": { "type": "string" }, "id": { "type": "string" },
                "lifetime": time, "frame_locked": { "type": "boolean" },
                "metadata": { "type": "array", "items": { "type": "object", "properties": {
                    "key": { "type": "string" }, "value": { "type": "string" } } } },
                "arrows": any, "cubes": any, "spheres": any, "triangles": any, "texts": any, "models": any,
                "lines": { "type": "array", "items": line },
                "cylinders": { "type": "array", "items": cylinder },
            } } },
        },
    })
    .to_string()
}

/// One advertised channel.
struct ChannelInfo {
    id: u32,
    topic: String,
    encoding: &'static str,
    schema_name: &'static str,
    schema: String,
    schema_encoding: &'static str,
}

const ODOM: u32 = 1;
const TF: u32 = 2;
const DIAGNOSTICS: u32 = 3;
const PATH: u32 = 4;
const ELLIPSE: u32 = 5;
const JOINTS: u32 = 6;

fn channels(names: &RosNames) -> Vec<ChannelInfo> {
    let ros = |id, topic: &str, t: MsgType| ChannelInfo {
        id,
        topic: topic.into(),
        encoding: "cdr",
        schema_name: t.name(),
        schema: t.schema(),
        schema_encoding: "ros2msg",
    };
    let mut c = vec![ros(ODOM, &names.odom, MsgType::Odometry)];
    if let Some(tf) = &names.tf {
        c.push(ros(TF, tf, MsgType::TfMessage));
    }
    c.extend([
        ros(DIAGNOSTICS, &names.diagnostics, MsgType::DiagnosticArray),
        ros(PATH, &names.path, MsgType::Path),
        ros(JOINTS, &names.joint_states, MsgType::JointState),
        ChannelInfo {
            id: ELLIPSE,
            topic: names.ellipse.clone(),
            encoding: "json",
            schema_name: "foxglove.SceneUpdate",
            schema: scene_update_schema(),
            schema_encoding: "jsonschema",
        },
    ]);
    c
}

/// What the publisher hands each client's thread.
#[derive(Debug, Clone)]
enum Outgoing {
    /// A message on a channel: (channel, log time ns, payload).
    Data(u32, u64, Arc<Vec<u8>>),
    /// A protocol text message (status, removeStatus).
    Text(Arc<String>),
}

/// Messages queued per client; beyond, the oldest are not waited for: new ones are dropped
/// for that client and counted.
const CLIENT_QUEUE: usize = 1024;

struct Shared {
    clients: Vec<SyncSender<Outgoing>>,
    dropped: u64,
    /// The server statuses currently shown, by id (text of the `status` message), for new
    /// clients.
    status: BTreeMap<String, Arc<String>>,
    /// `serverInfo` and `advertise`, sent to each new client.
    hello: [Arc<String>; 2],
}

/// The bridge's Foxglove WebSocket server.
pub struct FoxgloveServer {
    port: u16,
    shared: Arc<Mutex<Shared>>,
    so_far: PathSoFar,
    last_path_ns: Option<u64>,
}

/// Splits `HOST:PORT` (`[::1]:8765` for IPv6).
pub fn parse_address(addr: &str) -> Result<(String, u16)> {
    let (host, port) = addr
        .rsplit_once(':')
        .ok_or_else(|| anyhow!("--foxglove `{addr}`: not HOST:PORT"))?;
    let port = port
        .parse::<u16>()
        .map_err(|_| anyhow!("--foxglove `{addr}`: `{port}` is not a TCP port"))?;
    let host = host.trim_start_matches('[').trim_end_matches(']');
    if host.is_empty() {
        anyhow::bail!("--foxglove `{addr}`: no host");
    }
    Ok((host.to_string(), port))
}

fn lock(shared: &Mutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    shared
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The handshake: accept the first subprotocol of ours the client offers, else refuse (400).
// The signature of tungstenite's handshake callback.
#[allow(clippy::result_large_err)]
fn negotiate(req: &Request, mut res: Response) -> Result<Response, ErrorResponse> {
    let offered: Vec<String> = req
        .headers()
        .get_all("sec-websocket-protocol")
        .iter()
        .filter_map(|h| h.to_str().ok())
        .flat_map(|h| h.split(',').map(|p| p.trim().to_string()))
        .collect();
    match SUBPROTOCOLS
        .iter()
        .find(|p| offered.iter().any(|o| o == *p))
    {
        Some(p) => {
            res.headers_mut()
                .insert("sec-websocket-protocol", HeaderValue::from_static(p));
            Ok(res)
        }
        None => {
            let mut e = ErrorResponse::new(Some(format!(
                "subprotocol {} or {} expected\n",
                SUBPROTOCOLS[0], SUBPROTOCOLS[1]
            )));
            *e.status_mut() = StatusCode::BAD_REQUEST;
            Err(e)
        }
    }
}

fn server_info(names: &RosNames) -> String {
    json!({
        "op": "serverInfo",
        "name": "odoctl bridge",
        "capabilities": [],
        "supportedEncodings": [],
        "metadata": { "frame_id": names.odom_frame, "conventions": "REP-103/105, docs/ROS.md" },
        "sessionId": format!("{}", std::process::id()),
    })
    .to_string()
}

fn advertise(names: &RosNames) -> String {
    let chans: Vec<Value> = channels(names)
        .into_iter()
        .map(|c| {
            json!({
                "id": c.id, "topic": c.topic, "encoding": c.encoding,
                "schemaName": c.schema_name, "schema": c.schema,
                "schemaEncoding": c.schema_encoding,
            })
        })
        .collect();
    json!({ "op": "advertise", "channels": chans }).to_string()
}

/// Serves one client: the handshake, `serverInfo` and `advertise`, then its subscriptions.
fn serve_client(stream: TcpStream, shared: Arc<Mutex<Shared>>) {
    let _ = stream.set_nodelay(true);
    let Ok(mut ws) = tungstenite::accept_hdr(stream, negotiate) else {
        return;
    };
    let (tx, rx) = sync_channel(CLIENT_QUEUE);
    let hello: Vec<Arc<String>> = {
        let mut s = lock(&shared);
        s.clients.push(tx);
        s.hello.iter().chain(s.status.values()).cloned().collect()
    };
    for t in hello {
        if ws.send(WsMessage::text(t.as_str())).is_err() {
            return;
        }
    }
    if ws
        .get_ref()
        .set_read_timeout(Some(Duration::from_millis(5)))
        .is_err()
    {
        return;
    }
    let _ = client_loop(&mut ws, &rx);
    let _ = ws.close(None);
    let _ = ws.flush();
}

/// Until the client goes: its `subscribe`/`unsubscribe` requests in, its messages out.
fn client_loop(ws: &mut WebSocket<TcpStream>, rx: &Receiver<Outgoing>) -> Result<()> {
    // channel -> subscription id
    let mut subs: HashMap<u32, u32> = HashMap::new();
    loop {
        loop {
            match rx.try_recv() {
                Ok(Outgoing::Data(ch, t, payload)) => {
                    if let Some(id) = subs.get(&ch) {
                        let mut b = Vec::with_capacity(13 + payload.len());
                        b.push(0x01);
                        b.extend_from_slice(&id.to_le_bytes());
                        b.extend_from_slice(&t.to_le_bytes());
                        b.extend_from_slice(&payload);
                        ws.write(WsMessage::binary(b))?;
                    }
                }
                Ok(Outgoing::Text(t)) => ws.write(WsMessage::text(t.as_str()))?,
                Err(std::sync::mpsc::TryRecvError::Empty) => break,
                Err(std::sync::mpsc::TryRecvError::Disconnected) => return Ok(()),
            }
        }
        ws.flush()?;
        match ws.read() {
            Ok(WsMessage::Text(t)) => {
                let Ok(v) = serde_json::from_str::<Value>(t.as_str()) else {
                    continue;
                };
                match v["op"].as_str() {
                    Some("subscribe") => {
                        for s in v["subscriptions"].as_array().into_iter().flatten() {
                            if let (Some(id), Some(ch)) =
                                (s["id"].as_u64(), s["channelId"].as_u64())
                            {
                                subs.insert(ch as u32, id as u32);
                            }
                        }
                    }
                    Some("unsubscribe") => {
                        for id in v["subscriptionIds"].as_array().into_iter().flatten() {
                            subs.retain(|_, s| Some(u64::from(*s)) != id.as_u64());
                        }
                    }
                    _ => {}
                }
            }
            Ok(WsMessage::Close(_)) => return Ok(()),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(e) => return Err(e.into()),
        }
    }
}

impl FoxgloveServer {
    /// Starts the server on `host:port` (port 0: any free port), its channels named by
    /// `names`.
    pub fn start(host: &str, port: u16, names: &RosNames) -> Result<Self> {
        let listener = TcpListener::bind((host, port))
            .with_context(|| format!("Foxglove WebSocket server on {host}:{port}"))?;
        let port = listener.local_addr()?.port();
        let shared = Arc::new(Mutex::new(Shared {
            clients: Vec::new(),
            dropped: 0,
            status: BTreeMap::new(),
            hello: [Arc::new(server_info(names)), Arc::new(advertise(names))],
        }));
        let accept = Arc::clone(&shared);
        std::thread::Builder::new()
            .name("foxglove-accept".into())
            .spawn(move || {
                for stream in listener.incoming().flatten() {
                    let s = Arc::clone(&accept);
                    let _ = std::thread::Builder::new()
                        .name("foxglove-client".into())
                        .spawn(move || serve_client(stream, s));
                }
            })?;
        Ok(Self {
            port,
            shared,
            so_far: PathSoFar::new(),
            last_path_ns: None,
        })
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Messages not delivered to a client whose queue was full.
    pub fn dropped(&self) -> u64 {
        lock(&self.shared).dropped
    }

    fn send(&self, o: Outgoing) {
        let mut s = lock(&self.shared);
        let mut dropped = 0;
        s.clients.retain(|c| match c.try_send(o.clone()) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) => {
                dropped += 1;
                true
            }
            Err(TrySendError::Disconnected(_)) => false,
        });
        s.dropped += dropped;
    }

    fn data(&self, channel: u32, ns: u64, payload: Vec<u8>) {
        self.send(Outgoing::Data(channel, ns, Arc::new(payload)));
    }

    /// Publishes one sample's messages, the ellipse, and the path when due.
    pub fn sample(&mut self, m: &Messages) -> Result<()> {
        let ns = m.odom.header.stamp.nanos();
        self.data(ODOM, ns, msgs::encode(&m.odom)?);
        if let Some(tf) = &m.tf {
            self.data(TF, ns, msgs::encode(tf)?);
        }
        if let Some(j) = &m.joints {
            self.data(JOINTS, ns, msgs::encode(j)?);
        }
        if let Some(d) = &m.diagnostics {
            self.status(d)?;
        }
        self.data(
            ELLIPSE,
            ns,
            ellipse_scene(&m.odom, ns).to_string().into_bytes(),
        );
        let latest = msgs::PoseStamped {
            header: m.odom.header.clone(),
            pose: m.odom.pose.pose,
        };
        self.so_far.push(&latest);
        if self
            .last_path_ns
            .is_none_or(|l| ns.saturating_sub(l) >= PATH_PERIOD_NS)
        {
            self.last_path_ns = Some(ns);
            self.data(PATH, ns, msgs::encode(&self.so_far.message(&latest))?);
        }
        Ok(())
    }

    /// Publishes a `/diagnostics` array; each ERROR or STALE status in it also goes out as
    /// a server `status` (level error) whose id is the status's name (`<node>: link` for the
    /// link, `<node>: odometry unit` for the unit's own faults), which the Foxglove app lists
    /// under its problems; removed when an OK or WARN status of the same name follows.
    pub fn status(&mut self, d: &msgs::DiagnosticArray) -> Result<()> {
        self.data(DIAGNOSTICS, d.header.stamp.nanos(), msgs::encode(d)?);
        let mut texts = Vec::new();
        let mut shared = lock(&self.shared);
        for st in &d.status {
            if st.level >= msgs::level::ERROR {
                let t = Arc::new(
                    json!({ "op": "status", "level": 2, "message": st.message, "id": st.name })
                        .to_string(),
                );
                shared.status.insert(st.name.clone(), Arc::clone(&t));
                texts.push(t);
            } else if shared.status.remove(&st.name).is_some() {
                texts.push(Arc::new(
                    json!({ "op": "removeStatus", "statusIds": [st.name] }).to_string(),
                ));
            }
        }
        drop(shared);
        for t in texts {
            self.send(Outgoing::Text(t));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn on_ellipse(e: &Ellipse, xx: f64, yy: f64, xy: f64) {
        let (s, c) = e.angle.sin_cos();
        let det = xx * yy - xy * xy;
        for p in e.outline() {
            let (x, y) = (c * p.x - s * p.y, s * p.x + c * p.y);
            // p^T Sigma^-1 p = 1, without the inverse: p^T adj(Sigma) p = det.
            let q = yy * x * x - 2.0 * xy * x * y + xx * y * y;
            assert!((q - det).abs() <= 1e-9 * det, "{q} {det}");
        }
    }

    #[test]
    fn ellipse_boundary_table() {
        // Axis-aligned, rotated, circular, degenerate.
        let e = Ellipse::from_covariance(4.0, 1.0, 0.0);
        assert_eq!((e.a, e.b, e.angle), (2.0, 1.0, 0.0));
        let e = Ellipse::from_covariance(1.0, 4.0, 0.0);
        assert_eq!((e.a, e.b), (2.0, 1.0));
        assert!((e.angle - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        let e = Ellipse::from_covariance(2.0, 2.0, 1.0);
        assert!((e.a - 3f64.sqrt()).abs() < 1e-15 && (e.b - 1.0).abs() < 1e-15);
        assert!((e.angle - std::f64::consts::FRAC_PI_4).abs() < 1e-15);
        on_ellipse(&e, 2.0, 2.0, 1.0);
        on_ellipse(
            &Ellipse::from_covariance(1e-6, 3e-6, -1e-6),
            1e-6,
            3e-6,
            -1e-6,
        );
        let e = Ellipse::from_covariance(0.0, 0.0, 0.0);
        assert_eq!((e.a, e.b), (0.0, 0.0));
        // Perfectly correlated: a line segment (b = 0), no NaN.
        let e = Ellipse::from_covariance(1.0, 1.0, 1.0);
        assert!((e.a - 2f64.sqrt()).abs() < 1e-15 && e.b == 0.0);
    }

    fn pose_at(x: f64, yaw: f64) -> msgs::PoseStamped {
        msgs::PoseStamped {
            header: msgs::Header {
                stamp: msgs::Time { sec: 0, nanosec: 0 },
                frame_id: "odom".into(),
            },
            pose: msgs::Pose {
                position: msgs::Point { x, y: 0.0, z: 0.0 },
                orientation: msgs::Quaternion {
                    x: 0.0,
                    y: 0.0,
                    z: (0.5 * yaw).sin(),
                    w: (0.5 * yaw).cos(),
                },
            },
        }
    }

    #[test]
    fn path_is_spaced_bounded_and_ends_at_the_latest_pose() {
        let mut p = PathSoFar::new();
        for i in 0..10 {
            p.push(&pose_at(i as f64 * 0.004, 0.0));
        }
        // 0, 0.012, 0.024, 0.036 kept; the latest (0.036) already last.
        let m = p.message(&pose_at(9.0 * 0.004, 0.0));
        assert_eq!(m.poses.len(), 4);
        let m = p.message(&pose_at(0.037, 0.0));
        assert_eq!(m.poses.len(), 5);
        // Turning on the spot is kept too.
        p.push(&pose_at(0.036, 0.02));
        assert_eq!(p.kept.len(), 5);
        let mut p = PathSoFar::new();
        for i in 0..3 * PATH_CAPACITY {
            p.push(&pose_at(i as f64 * 0.01, 0.0));
        }
        assert!(p.kept.len() <= PATH_CAPACITY);
        assert!(p.kept.len() > PATH_CAPACITY / 2);
        let xs: Vec<f64> = p.kept.iter().map(|q| q.pose.position.x).collect();
        assert!(xs.windows(2).all(|w| w[1] > w[0]));
        assert_eq!(xs[0], 0.0);
    }

    #[test]
    fn addresses() {
        assert_eq!(
            parse_address("127.0.0.1:8765").unwrap(),
            ("127.0.0.1".into(), 8765)
        );
        assert_eq!(parse_address("[::1]:0").unwrap(), ("::1".into(), 0));
        assert!(parse_address("8765").is_err());
        assert!(parse_address("localhost:99999").is_err());
        assert!(parse_address(":1").is_err());
    }
}
