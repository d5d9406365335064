//! A trajectory from a ROS 2 recording (MCAP, rosbag2's storage): one topic of
//! `geometry_msgs/msg/PoseStamped`, `nav_msgs/msg/Odometry` (its pose) or
//! `tf2_msgs/msg/TFMessage` (the transforms from a parent to a child frame), as motion-capture
//! drivers and SLAM stacks publish them. The messages are CDR (XCDR1, either byte order,
//! aligned from the end of the 4-byte encapsulation header, as [`crate::ros::msgs`] writes
//! them); the stamp is the message header's (the transform's), not the log time.

use std::collections::{BTreeMap, BTreeSet};
use std::io::{Seek, Write};

use anyhow::{anyhow, bail, Context, Result};

use super::trajectory::{self, TrajectoryPose};
use crate::ros::msgs::{self, MsgType};

/// The MCAP file magic.
pub const MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// The message types read, by schema name.
const POSE_STAMPED: &str = "geometry_msgs/msg/PoseStamped";
const ODOMETRY: &str = "nav_msgs/msg/Odometry";
const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";

/// Which poses of a recording are the reference (`--reference-topic`, `--reference-frames`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct McapSelect {
    /// The topic; `None`: the only topic of one of the three types (a `TFMessage` topic only
    /// with `frames`).
    pub topic: Option<String>,
    /// For a `TFMessage` topic: the parent and the child frame (a leading `/` is ignored).
    pub frames: Option<(String, String)>,
}

/// Parses `PARENT,CHILD` (`--reference-frames`).
pub fn parse_frames(s: &str) -> Result<(String, String)> {
    match s.split_once(',') {
        Some((p, c)) if !p.trim().is_empty() && !c.trim().is_empty() && !c.contains(',') => {
            Ok((frame(p.trim()).into(), frame(c.trim()).into()))
        }
        _ => bail!("--reference-frames `{s}`: expected PARENT,CHILD (two frame ids)"),
    }
}

fn frame(s: &str) -> &str {
    s.trim_start_matches('/')
}

/// A CDR reader over one message.
struct Cdr<'a> {
    body: &'a [u8],
    pos: usize,
    little: bool,
}

impl<'a> Cdr<'a> {
    fn new(data: &'a [u8]) -> Result<Self> {
        let little = match data {
            [0, 1, _, _, ..] => true,
            [0, 0, _, _, ..] => false,
            _ => bail!(
                "not plain CDR (encapsulation header {:02x?})",
                &data[..data.len().min(4)]
            ),
        };
        Ok(Self {
            body: &data[4..],
            pos: 0,
            little,
        })
    }

    fn take<const N: usize>(&mut self) -> Result<[u8; N]> {
        self.pos = self.pos.div_ceil(N) * N;
        let b = self.body.get(self.pos..self.pos + N).ok_or_else(|| {
            anyhow!(
                "message ends at byte {} of {}",
                self.pos + 4,
                self.body.len() + 4
            )
        })?;
        self.pos += N;
        let mut a: [u8; N] = b.try_into().expect("N bytes");
        if !self.little {
            a.reverse();
        }
        Ok(a)
    }

    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take::<4>()?))
    }

    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take::<8>()?))
    }

    fn string(&mut self) -> Result<String> {
        let n = self.u32()? as usize;
        let b = self
            .body
            .get(self.pos..self.pos.saturating_add(n))
            .ok_or_else(|| anyhow!("string of {n} bytes past the message's end"))?;
        self.pos += n;
        let b = b.strip_suffix(&[0]).unwrap_or(b);
        Ok(String::from_utf8_lossy(b).into_owned())
    }

    /// `std_msgs/Header`: the stamp (s) and the frame id.
    fn header(&mut self) -> Result<(f64, String)> {
        let sec = self.u32()? as i32;
        let nanosec = self.u32()?;
        Ok((f64::from(sec) + f64::from(nanosec) * 1e-9, self.string()?))
    }

    /// Position and orientation (7 float64).
    fn pose(&mut self) -> Result<([f64; 3], [f64; 4])> {
        let mut p = [0.0; 3];
        for v in &mut p {
            *v = self.f64()?;
        }
        let mut q = [0.0; 4];
        for v in &mut q {
            *v = self.f64()?;
        }
        Ok((p, q))
    }
}

/// One decoded pose: stamp (s), parent frame, child frame (empty for PoseStamped), position,
/// quaternion.
type Decoded = (f64, String, String, [f64; 3], [f64; 4]);

/// The poses of one message of `schema`.
fn decode(schema: &str, data: &[u8]) -> Result<Vec<Decoded>> {
    let mut c = Cdr::new(data)?;
    match schema {
        POSE_STAMPED => {
            let (t, parent) = c.header()?;
            let (p, q) = c.pose()?;
            Ok(vec![(t, parent, String::new(), p, q)])
        }
        ODOMETRY => {
            let (t, parent) = c.header()?;
            let child = c.string()?;
            let (p, q) = c.pose()?;
            Ok(vec![(t, parent, child, p, q)])
        }
        TF_MESSAGE => {
            let n = c.u32()? as usize;
            if n > data.len() {
                bail!("{n} transforms in {} bytes", data.len());
            }
            let mut out = Vec::with_capacity(n);
            for _ in 0..n {
                let (t, parent) = c.header()?;
                let child = c.string()?;
                let (p, q) = c.pose()?;
                out.push((t, parent, child, p, q));
            }
            Ok(out)
        }
        other => bail!("unsupported type {other}"),
    }
}

/// What a recording's topics are: topic -> schema name.
fn topics(bytes: &[u8]) -> Result<BTreeMap<String, String>> {
    let summary = mcap::Summary::read(bytes)
        .map_err(|e| anyhow!("{e}"))?
        .map(|s| {
            s.channels
                .values()
                .map(|c| {
                    let schema = c.schema.as_ref().map_or("", |s| s.name.as_str());
                    (c.topic.clone(), schema.to_string())
                })
                .collect::<BTreeMap<_, _>>()
        });
    if let Some(t) = summary.filter(|t| !t.is_empty()) {
        return Ok(t);
    }
    // No summary: one pass over the messages.
    let mut t = BTreeMap::new();
    for m in mcap::MessageStream::new(bytes).map_err(|e| anyhow!("{e}"))? {
        let m = m.map_err(|e| anyhow!("{e}"))?;
        let schema = m.channel.schema.as_ref().map_or("", |s| s.name.as_str());
        t.entry(m.channel.topic.clone())
            .or_insert_with(|| schema.to_string());
    }
    Ok(t)
}

fn list(topics: &BTreeMap<String, String>) -> String {
    if topics.is_empty() {
        return "none".into();
    }
    topics
        .iter()
        .map(|(t, s)| format!("{t} ({s})"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The topic to read and its schema name.
fn choose_topic(
    file: &str,
    all: &BTreeMap<String, String>,
    sel: &McapSelect,
) -> Result<(String, String)> {
    let readable = |s: &str| [POSE_STAMPED, ODOMETRY, TF_MESSAGE].contains(&s);
    if let Some(t) = &sel.topic {
        let Some(schema) = all.get(t) else {
            bail!(
                "{file}: no topic `{t}` (--reference-topic); topics: {}",
                list(all)
            );
        };
        if !readable(schema) {
            bail!(
                "{file}: topic `{t}` is `{schema}`, not {POSE_STAMPED}, {ODOMETRY} or {TF_MESSAGE}"
            );
        }
        return Ok((t.clone(), schema.clone()));
    }
    let candidates: Vec<(&String, &String)> = all
        .iter()
        .filter(|(_, s)| readable(s) && (sel.frames.is_some() || s.as_str() != TF_MESSAGE))
        .collect();
    match candidates[..] {
        [(t, s)] => Ok((t.clone(), s.clone())),
        _ => bail!(
            "{file}: choose the reference with --reference-topic (and --reference-frames \
             PARENT,CHILD for a {TF_MESSAGE}); topics: {}",
            list(all)
        ),
    }
}

/// Reads the poses of the selected topic of an MCAP recording, in log-time order (the order
/// of the file for equal log times); `file` names it in messages. A missing topic, one of
/// another type, a message that does not decode, a TF topic without the frames asked for, and
/// the checks of [`trajectory::check`] (message N is the N-th pose of the topic) are errors
/// naming the file and topic. Returns the poses and a note of what was read.
pub fn parse(file: &str, bytes: &[u8], sel: &McapSelect) -> Result<(Vec<TrajectoryPose>, String)> {
    let all = topics(bytes).with_context(|| format!("{file}: not a readable MCAP file"))?;
    let (topic, schema) = choose_topic(file, &all, sel)?;
    let frames = match (&sel.frames, schema.as_str()) {
        (Some(f), _) => Some(f.clone()),
        (None, TF_MESSAGE) => {
            bail!("{file}: topic `{topic}` is a {TF_MESSAGE}: give --reference-frames PARENT,CHILD")
        }
        (None, _) => None,
    };
    let mut stamped = Vec::new();
    let mut pairs = BTreeSet::new();
    let mut messages = 0usize;
    let stream = mcap::MessageStream::new(bytes).map_err(|e| anyhow!("{file}: {e}"))?;
    for m in stream {
        let m = m.map_err(|e| anyhow!("{file}: {e}"))?;
        if m.channel.topic != topic {
            continue;
        }
        messages += 1;
        if m.channel.message_encoding != "cdr" {
            bail!(
                "{file}: topic `{topic}` is encoded `{}`, not cdr",
                m.channel.message_encoding
            );
        }
        let decoded = decode(&schema, &m.data)
            .map_err(|e| anyhow!("{file}: topic `{topic}` message {messages}: {e}"))?;
        for (t, parent, child, p, q) in decoded {
            if let Some((fp, fc)) = &frames {
                if frame(&parent) != fp || frame(&child) != fc {
                    pairs.insert(format!("{parent} -> {child}"));
                    continue;
                }
            }
            stamped.push((m.log_time, t, p, q));
        }
    }
    if stamped.is_empty() {
        let seen: Vec<String> = pairs.into_iter().take(10).collect();
        bail!(
            "{file}: topic `{topic}` has no pose{} ({messages} messages{})",
            frames
                .as_ref()
                .map_or(String::new(), |(p, c)| format!(" from `{p}` to `{c}`")),
            if seen.is_empty() {
                String::new()
            } else {
                format!("; transforms seen: {}", seen.join(", "))
            }
        );
    }
    stamped.sort_by_key(|s| s.0);
    let poses: Vec<TrajectoryPose> = stamped
        .into_iter()
        .enumerate()
        .map(|(k, (_, t, p, q))| TrajectoryPose {
            t,
            position: p,
            orientation: q,
            line: k + 1,
        })
        .collect();
    trajectory::check(&format!("{file}: topic `{topic}`"), "message", &poses)?;
    let note = format!(
        "topic {topic} ({schema}{}): {} poses from {messages} messages",
        frames.map_or(String::new(), |(p, c)| format!(", {p} -> {c}")),
        poses.len()
    );
    Ok((poses, note))
}

/// Writes poses as a ROS 2 MCAP recording with three topics of the same poses:
/// `/reference/pose` (PoseStamped in `frame`), `/reference/odom` (Odometry, child `child`) and
/// `/tf` (TFMessage, `frame` -> `child`); stamps and log times are the poses' `t`
/// (non-negative seconds).
pub fn write<W: Write + Seek>(
    w: W,
    poses: &[TrajectoryPose],
    frame: &str,
    child: &str,
) -> Result<()> {
    let err = |e: mcap::McapError| anyhow!("MCAP: {e}");
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("ros2")
        .library(concat!("odoctl ", env!("CARGO_PKG_VERSION")))
        .create(w)
        .map_err(err)?;
    let mut channel = |t: MsgType, topic: &str| -> Result<u16> {
        let schema = writer
            .add_schema(t.name(), "ros2msg", t.schema().as_bytes())
            .map_err(err)?;
        writer
            .add_channel(schema, topic, "cdr", &BTreeMap::new())
            .map_err(err)
    };
    let ids = [
        channel(MsgType::PoseStamped, "/reference/pose")?,
        channel(MsgType::Odometry, "/reference/odom")?,
        channel(MsgType::TfMessage, "/tf")?,
    ];
    for (k, p) in poses.iter().enumerate() {
        let ns = (p.t * 1e9).round();
        let stamp = msgs::Time::from_nanos(ns as u64)
            .filter(|_| ns >= 0.0)
            .ok_or_else(|| anyhow!("stamp {} s out of range", p.t))?;
        let header = msgs::Header {
            stamp,
            frame_id: frame.into(),
        };
        let pose = msgs::Pose {
            position: msgs::Point {
                x: p.position[0],
                y: p.position[1],
                z: p.position[2],
            },
            orientation: msgs::Quaternion {
                x: p.orientation[0],
                y: p.orientation[1],
                z: p.orientation[2],
                w: p.orientation[3],
            },
        };
        let data = [
            msgs::encode(&msgs::PoseStamped {
                header: header.clone(),
                pose,
            })?,
            msgs::encode(&msgs::Odometry {
                header: header.clone(),
                child_frame_id: child.into(),
                pose: msgs::PoseWithCovariance {
                    pose,
                    covariance: msgs::Covariance6([0.0; 36]),
                },
                twist: msgs::TwistWithCovariance {
                    twist: msgs::Twist::default(),
                    covariance: msgs::Covariance6([0.0; 36]),
                },
            })?,
            msgs::encode(&msgs::TfMessage {
                transforms: vec![msgs::TransformStamped {
                    header,
                    child_frame_id: child.into(),
                    transform: msgs::Transform {
                        translation: pose.position,
                        rotation: pose.orientation,
                    },
                }],
            })?,
        ];
        for (id, d) in ids.iter().zip(&data) {
            writer
                .write_to_known_channel(
                    &mcap::records::MessageHeader {
                        channel_id: *id,
                        sequence: k as u32,
                        log_time: stamp.nanos(),
                        publish_time: stamp.nanos(),
                    },
                    d,
                )
                .map_err(err)?;
        }
    }
    writer.finish().map_err(err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn poses() -> Vec<TrajectoryPose> {
        (0..5)
            .map(|k| TrajectoryPose {
                t: 100.0 + 0.01 * k as f64,
                position: [k as f64 * 0.1, -2.0, 0.25],
                orientation: [0.0, 0.0, 0.1 * k as f64, 1.0],
                line: k + 1,
            })
            .collect()
    }

    fn written() -> Vec<u8> {
        let mut c = std::io::Cursor::new(Vec::new());
        write(&mut c, &poses(), "world", "marker").unwrap();
        c.into_inner()
    }

    #[test]
    fn each_type_reads_back_the_poses_written() {
        let bytes = written();
        assert!(bytes.starts_with(MAGIC));
        for (topic, frames) in [
            ("/reference/pose", None),
            ("/reference/odom", None),
            ("/tf", Some(("world".to_string(), "marker".to_string()))),
        ] {
            let sel = McapSelect {
                topic: Some(topic.into()),
                frames,
            };
            let (p, note) = parse("r.mcap", &bytes, &sel).unwrap();
            assert!(note.contains("5 poses from 5 messages"), "{note}");
            for (a, b) in p.iter().zip(poses()) {
                assert!((a.t - b.t).abs() < 1e-9, "{topic}");
                assert_eq!((a.position, a.orientation), (b.position, b.orientation));
            }
        }
    }

    #[test]
    fn selection_errors_name_file_and_topic() {
        let bytes = written();
        let table = [
            (
                McapSelect::default(),
                "choose the reference with --reference-topic",
            ),
            (
                McapSelect {
                    topic: Some("/nope".into()),
                    frames: None,
                },
                "r.mcap: no topic `/nope`",
            ),
            (
                McapSelect {
                    topic: Some("/tf".into()),
                    frames: None,
                },
                "give --reference-frames",
            ),
            (
                McapSelect {
                    topic: Some("/tf".into()),
                    frames: Some(("map".into(), "marker".into())),
                },
                "transforms seen: world -> marker",
            ),
        ];
        for (sel, want) in table {
            let e = parse("r.mcap", &bytes, &sel).unwrap_err().to_string();
            assert!(e.contains(want), "{sel:?}: {e}");
        }
        assert!(parse("r.mcap", b"\x89MCAP0\r\nxx", &McapSelect::default()).is_err());
        assert_eq!(
            parse_frames("/world, marker").unwrap(),
            ("world".into(), "marker".into())
        );
        assert!(parse_frames("world").is_err());
    }

    #[test]
    fn cdr_big_endian_and_truncated() {
        // PoseStamped, big-endian: stamp 3 s 5e8 ns, frame "m", pose.
        let mut b = vec![0u8, 0, 0, 0];
        b.extend(3u32.to_be_bytes());
        b.extend(500_000_000u32.to_be_bytes());
        b.extend(2u32.to_be_bytes());
        b.extend(b"m\0");
        b.extend([0u8; 2]); // to 8-byte alignment (body offset 16)
        for v in [1.0f64, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0] {
            b.extend(v.to_be_bytes());
        }
        let d = decode(POSE_STAMPED, &b).unwrap();
        assert_eq!(d[0].0, 3.5);
        assert_eq!(d[0].1, "m");
        assert_eq!((d[0].3, d[0].4), ([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0]));
        let e = decode(POSE_STAMPED, &b[..40]).unwrap_err().to_string();
        assert!(e.contains("message ends"), "{e}");
        assert!(decode(POSE_STAMPED, &[1, 0]).is_err());
    }
}
