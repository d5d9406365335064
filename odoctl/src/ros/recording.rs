//! MCAP recordings of the odometry as ROS 2 topics (ros2msg schemas, CDR messages), readable
//! by `ros2 bag play`, Foxglove and any MCAP reader.
//!
//! Topics (the defaults of [`RosNames`]): `/odom` (`nav_msgs/msg/Odometry`, one per sample),
//! `/tf` (`tf2_msgs/msg/TFMessage`, odom -> base_link, one per sample, unless TF is off),
//! `/joint_states` (`sensor_msgs/msg/JointState`, one per sample when the counts and the
//! increments per turn are known), `/diagnostics` (`diagnostic_msgs/msg/DiagnosticArray`,
//! on a change of the unit's status and at least once per second), and on request paths
//! (`nav_msgs/msg/Path`) such as `/odom/path` and `/reference/path`. The file's metadata
//! record `odoctl` says where the stamps come from and how the conventions were applied.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::Path as FsPath;

use anyhow::{anyhow, Context, Result};

use super::msgs::{self, MsgType};
use super::names::RosNames;
pub use super::stream::OdomSample;
use super::stream::{header, ros_pose, OdomStream, StreamCounts};
use odo_unit::odometry::{Pose, UncertaintyModel};

/// What a finished recording holds: the stream's counts and the paths written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecordingSummary {
    /// `/odom` (and `/tf`) messages, `/diagnostics` messages, resets, over-range samples.
    pub stream: StreamCounts,
    /// Path messages.
    pub paths: u64,
}

struct Channel {
    id: u16,
    sequence: u32,
}

/// An MCAP file being written.
pub struct McapRecording<W: Write + Seek> {
    writer: mcap::Writer<W>,
    odom: Channel,
    tf: Option<Channel>,
    joints: Option<Channel>,
    diagnostics: Channel,
    path_schema: Option<u16>,
    paths: BTreeMap<String, Channel>,
    stream: OdomStream,
    paths_written: u64,
}

/// Opens `path` for a recording; `metadata` is written as the `odoctl` metadata record.
pub fn create(
    path: &FsPath,
    metadata: &BTreeMap<String, String>,
) -> Result<McapRecording<BufWriter<File>>> {
    let f = File::create(path).with_context(|| format!("{}: cannot create", path.display()))?;
    McapRecording::new(BufWriter::new(f), metadata)
        .with_context(|| format!("{}: MCAP", path.display()))
}

/// Opens `path` for a recording with `names` (topics, frames, TF on or off).
pub fn create_with(
    path: &FsPath,
    metadata: &BTreeMap<String, String>,
    names: RosNames,
) -> Result<McapRecording<BufWriter<File>>> {
    let f = File::create(path).with_context(|| format!("{}: cannot create", path.display()))?;
    McapRecording::with_names(BufWriter::new(f), metadata, names)
        .with_context(|| format!("{}: MCAP", path.display()))
}

fn mcap_err(e: mcap::McapError) -> anyhow::Error {
    anyhow!("MCAP: {e}")
}

impl<W: Write + Seek> McapRecording<W> {
    /// Starts a recording on `w` with the standard channels and the default names.
    pub fn new(w: W, metadata: &BTreeMap<String, String>) -> Result<Self> {
        Self::with_names(w, metadata, RosNames::default())
    }

    /// Starts a recording on `w` with the standard channels named by `names`.
    pub fn with_names(w: W, metadata: &BTreeMap<String, String>, names: RosNames) -> Result<Self> {
        let mut writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .profile("ros2")
            .library(concat!("odoctl ", env!("CARGO_PKG_VERSION")))
            .create(w)
            .map_err(mcap_err)?;
        let mut channel = |t: MsgType, topic: &str| -> Result<Channel> {
            let schema = writer
                .add_schema(t.name(), "ros2msg", t.schema().as_bytes())
                .map_err(mcap_err)?;
            let id = writer
                .add_channel(schema, topic, "cdr", &BTreeMap::new())
                .map_err(mcap_err)?;
            Ok(Channel { id, sequence: 0 })
        };
        let odom = channel(MsgType::Odometry, &names.odom)?;
        let tf = match &names.tf {
            Some(t) => Some(channel(MsgType::TfMessage, t)?),
            None => None,
        };
        let diagnostics = channel(MsgType::DiagnosticArray, &names.diagnostics)?;
        writer
            .write_metadata(&mcap::records::Metadata {
                name: "odoctl".into(),
                metadata: metadata.clone(),
            })
            .map_err(mcap_err)?;
        Ok(Self {
            writer,
            odom,
            tf,
            joints: None,
            diagnostics,
            path_schema: None,
            paths: BTreeMap::new(),
            stream: OdomStream::new(None).with_names(names),
            paths_written: 0,
        })
    }

    /// The uncertainty model that filled the covariances (a replay's), named in the
    /// diagnostics instead of the one the unit's status word names.
    pub fn set_model(&mut self, model: UncertaintyModel) {
        let names = self.stream.names().clone();
        self.stream = OdomStream::new(Some(model)).with_names(names);
    }

    /// Increments per wheel turn, for `/joint_states` (none without it).
    pub fn set_ticks_per_rev(&mut self, ticks: u32) {
        self.stream.set_ticks_per_rev(Some(ticks));
    }

    /// The names in use.
    pub fn names(&self) -> &RosNames {
        self.stream.names()
    }

    fn put(writer: &mut mcap::Writer<W>, ch: &mut Channel, stamp: u64, data: &[u8]) -> Result<()> {
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: ch.id,
                    sequence: ch.sequence,
                    log_time: stamp,
                    publish_time: stamp,
                },
                data,
            )
            .map_err(mcap_err)?;
        ch.sequence = ch.sequence.wrapping_add(1);
        Ok(())
    }

    /// Records one sample on `/odom`, `/tf`, `/joint_states` and, when due, `/diagnostics`.
    /// Stamps must not decrease.
    pub fn push(&mut self, s: &OdomSample) -> Result<()> {
        let m = self.stream.next(s)?;
        Self::put(
            &mut self.writer,
            &mut self.odom,
            s.stamp_ns,
            &msgs::encode(&m.odom)?,
        )?;
        if let (Some(ch), Some(tf)) = (&mut self.tf, &m.tf) {
            Self::put(&mut self.writer, ch, s.stamp_ns, &msgs::encode(tf)?)?;
        }
        if let Some(j) = &m.joints {
            if self.joints.is_none() {
                let t = MsgType::JointState;
                let schema = self
                    .writer
                    .add_schema(t.name(), "ros2msg", t.schema().as_bytes())
                    .map_err(mcap_err)?;
                let topic = self.stream.names().joint_states.clone();
                let id = self
                    .writer
                    .add_channel(schema, &topic, "cdr", &BTreeMap::new())
                    .map_err(mcap_err)?;
                self.joints = Some(Channel { id, sequence: 0 });
            }
            if let Some(ch) = &mut self.joints {
                Self::put(&mut self.writer, ch, s.stamp_ns, &msgs::encode(j)?)?;
            }
        }
        if let Some(d) = &m.diagnostics {
            Self::put(
                &mut self.writer,
                &mut self.diagnostics,
                s.stamp_ns,
                &msgs::encode(d)?,
            )?;
        }
        Ok(())
    }

    /// Records a whole path (poses in `odom`, ours) as one `nav_msgs/msg/Path` on `topic`,
    /// stamped with its last pose's stamp.
    pub fn path(&mut self, topic: &str, poses: &[(u64, Pose)]) -> Result<()> {
        let Some(&(last, _)) = poses.last() else {
            return Ok(());
        };
        let schema = match self.path_schema {
            Some(s) => s,
            None => {
                let t = MsgType::Path;
                let s = self
                    .writer
                    .add_schema(t.name(), "ros2msg", t.schema().as_bytes())
                    .map_err(mcap_err)?;
                self.path_schema = Some(s);
                s
            }
        };
        if !self.paths.contains_key(topic) {
            let id = self
                .writer
                .add_channel(schema, topic, "cdr", &BTreeMap::new())
                .map_err(mcap_err)?;
            self.paths
                .insert(topic.to_string(), Channel { id, sequence: 0 });
        }
        let frame = self.stream.names().odom_frame.clone();
        let msg = msgs::Path {
            header: header(last, &frame)?,
            poses: poses
                .iter()
                .map(|(t, p)| {
                    Ok(msgs::PoseStamped {
                        header: header(*t, &frame)?,
                        pose: ros_pose(p),
                    })
                })
                .collect::<Result<_>>()?,
        };
        let ch = self.paths.get_mut(topic).expect("inserted above");
        Self::put(&mut self.writer, ch, last, &msgs::encode(&msg)?)?;
        self.paths_written += 1;
        Ok(())
    }

    /// Writes the summary and index; the file is complete.
    pub fn finish(mut self) -> Result<RecordingSummary> {
        self.writer.finish().map_err(mcap_err)?;
        let mut w = self.writer.into_inner();
        w.flush()?;
        Ok(RecordingSummary {
            stream: self.stream.counts(),
            paths: self.paths_written,
        })
    }
}
