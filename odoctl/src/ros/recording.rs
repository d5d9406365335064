//! MCAP recordings of the odometry as ROS 2 topics (ros2msg schemas, CDR messages), readable
//! by `ros2 bag play`, Foxglove and any MCAP reader.
//!
//! Topics: `/odom` (`nav_msgs/msg/Odometry`, one per sample), `/tf` (`tf2_msgs/msg/TFMessage`,
//! odom -> base_link, one per sample), `/diagnostics` (`diagnostic_msgs/msg/DiagnosticArray`,
//! on a change of the unit's status and at least once per second), and on request paths
//! (`nav_msgs/msg/Path`) such as `/odom/path` and `/reference/path`. The file's metadata
//! record `odoctl` says where the stamps come from and how the conventions were applied.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::Path as FsPath;

use anyhow::{anyhow, Context, Result};
use odo_core::protocol::{StatusFlags, SyncMode};

use super::conventions::{
    quaternion_of_heading, BaseTwist, ContinuousOdom, PoseCovariance, BASE_FRAME, ODOM_FRAME,
};
use super::msgs::{self, level, MsgType};
use crate::core_api::{Pose, UncertaintyModel};

/// One sample to record: the unit's pose (ours), its covariance, the interval's twist.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OdomSample {
    /// Header stamp, nanoseconds (see [`super::stamps`]).
    pub stamp_ns: u64,
    /// The unit's pose (x east, y north, heading clockwise from north, cumulative).
    pub pose: Pose,
    /// Its covariance.
    pub cov: PoseCovariance,
    /// Motion since the previous sample; `None` for the first sample.
    pub twist: Option<BaseTwist>,
    /// The unit's status word, when known.
    pub flags: Option<u32>,
    /// The unit's sample sequence number, when known.
    pub sequence: Option<u64>,
    /// The sample exceeded the integrator's step limits and was not integrated.
    pub overrange: bool,
    /// The unit's pose was reset (`reset_pose`) at this sample.
    pub reset: bool,
}

/// What a finished recording holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecordingSummary {
    /// `/odom` (and `/tf`) messages.
    pub odom: u64,
    /// `/diagnostics` messages.
    pub diagnostics: u64,
    /// Path messages.
    pub paths: u64,
    /// `reset_pose` jumps absorbed to keep `odom` continuous.
    pub resets: u64,
    /// Samples not integrated (over-range).
    pub overrange: u64,
}

struct Channel {
    id: u16,
    sequence: u32,
}

/// An MCAP file being written.
pub struct McapRecording<W: Write + Seek> {
    writer: mcap::Writer<W>,
    odom: Channel,
    tf: Channel,
    diagnostics: Channel,
    path_schema: Option<u16>,
    paths: BTreeMap<String, Channel>,
    continuity: ContinuousOdom,
    last_diag: Option<(u64, u8, String)>,
    last_stamp: Option<u64>,
    summary: RecordingSummary,
    model: Option<UncertaintyModel>,
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

fn mcap_err(e: mcap::McapError) -> anyhow::Error {
    anyhow!("MCAP: {e}")
}

fn header(stamp_ns: u64, frame: &str) -> Result<msgs::Header> {
    Ok(msgs::Header {
        stamp: msgs::Time::from_nanos(stamp_ns)
            .ok_or_else(|| anyhow!("stamp {stamp_ns} ns beyond int32 seconds"))?,
        frame_id: frame.into(),
    })
}

fn ros_pose(p: &Pose) -> msgs::Pose {
    msgs::Pose {
        position: msgs::Point {
            x: p.x,
            y: p.y,
            z: 0.0,
        },
        orientation: quaternion_of_heading(p.heading),
    }
}

impl<W: Write + Seek> McapRecording<W> {
    /// Starts a recording on `w` with the three standard channels.
    pub fn new(w: W, metadata: &BTreeMap<String, String>) -> Result<Self> {
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
        let odom = channel(MsgType::Odometry, "/odom")?;
        let tf = channel(MsgType::TfMessage, "/tf")?;
        let diagnostics = channel(MsgType::DiagnosticArray, "/diagnostics")?;
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
            diagnostics,
            path_schema: None,
            paths: BTreeMap::new(),
            continuity: ContinuousOdom::default(),
            last_diag: None,
            last_stamp: None,
            summary: RecordingSummary::default(),
            model: None,
        })
    }

    /// The uncertainty model that filled the covariances (a replay's), named in the
    /// diagnostics instead of the one the unit's status word names.
    pub fn set_model(&mut self, model: UncertaintyModel) {
        self.model = Some(model);
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

    /// Records one sample on `/odom`, `/tf` and, when due, `/diagnostics`. Stamps must not
    /// decrease.
    pub fn push(&mut self, s: &OdomSample) -> Result<()> {
        if self.last_stamp.is_some_and(|l| s.stamp_ns < l) {
            anyhow::bail!(
                "stamps must not decrease ({} ns after {} ns)",
                s.stamp_ns,
                self.last_stamp.unwrap_or(0)
            );
        }
        self.last_stamp = Some(s.stamp_ns);
        let jump = if s.reset {
            self.continuity.reset(s.pose)
        } else {
            None
        };
        let (pose, cov) = self.continuity.publish(s.pose, s.cov);
        let (twist, twist_cov) = match &s.twist {
            Some(t) => (
                msgs::Twist {
                    linear: msgs::Vector3 {
                        x: t.vx,
                        y: 0.0,
                        z: 0.0,
                    },
                    angular: msgs::Vector3 {
                        x: 0.0,
                        y: 0.0,
                        z: t.wz,
                    },
                },
                t.covariance(),
            ),
            None => (msgs::Twist::default(), BaseTwist::unknown_covariance()),
        };
        let odom = msgs::Odometry {
            header: header(s.stamp_ns, ODOM_FRAME)?,
            child_frame_id: BASE_FRAME.into(),
            pose: msgs::PoseWithCovariance {
                pose: ros_pose(&pose),
                covariance: cov.to_ros(),
            },
            twist: msgs::TwistWithCovariance {
                twist,
                covariance: twist_cov,
            },
        };
        let tf = msgs::TfMessage {
            transforms: vec![msgs::TransformStamped {
                header: odom.header.clone(),
                child_frame_id: BASE_FRAME.into(),
                transform: msgs::Transform {
                    translation: odom.pose.pose.position,
                    rotation: odom.pose.pose.orientation,
                },
            }],
        };
        Self::put(
            &mut self.writer,
            &mut self.odom,
            s.stamp_ns,
            &msgs::encode(&odom)?,
        )?;
        Self::put(
            &mut self.writer,
            &mut self.tf,
            s.stamp_ns,
            &msgs::encode(&tf)?,
        )?;
        self.summary.odom += 1;
        self.summary.overrange += u64::from(s.overrange);
        self.summary.resets = self.continuity.resets();
        self.diagnose(s, jump)
    }

    fn diagnose(&mut self, s: &OdomSample, jump: Option<(f64, f64, f64)>) -> Result<()> {
        let flags = s.flags.and_then(|b| StatusFlags::from_bits(b).ok());
        let mut problems: Vec<(u8, String)> = Vec::new();
        let mut values: Vec<(String, String)> = Vec::new();
        if let Some(f) = &flags {
            for (name, w) in [("left", &f.left), ("right", &f.right)] {
                if w.fault {
                    problems.push((level::ERROR, format!("{name} encoder fault")));
                }
                if w.index_mismatch {
                    problems.push((level::WARN, format!("{name} index count mismatch")));
                }
                values.push((format!("{name}_fault"), w.fault.to_string()));
                values.push((format!("{name}_index_seen"), w.index_seen.to_string()));
                values.push((
                    format!("{name}_index_mismatch"),
                    w.index_mismatch.to_string(),
                ));
                values.push((format!("{name}_calibrated"), w.calibrated.to_string()));
            }
            if f.sync == SyncMode::Holdover {
                problems.push((level::WARN, "PPS lost (holdover)".into()));
            }
            values.push((
                "sync".into(),
                match f.sync {
                    SyncMode::FreeRunning => "free_running",
                    SyncMode::PpsLocked => "pps_locked",
                    SyncMode::Holdover => "holdover",
                }
                .into(),
            ));
            values.push(("time_valid".into(), f.time_valid.to_string()));
        }
        if s.overrange {
            problems.push((level::WARN, "sample over range, not integrated".into()));
        }
        if let Some((dx, dy, da)) = jump {
            problems.push((
                level::WARN,
                format!("reset_pose: the unit's pose jumped by ({dx:.4} m, {dy:.4} m, {da:.5} rad); odom continues"),
            ));
        }
        let model = self.model.or(flags.map(|f| f.model));
        if let Some(m) = model {
            values.push((
                "uncertainty_model".into(),
                crate::config::model_name(m).into(),
            ));
        }
        if let Some(q) = s.sequence {
            values.push(("sequence".into(), q.to_string()));
        }
        values.push((
            "overrange_samples".into(),
            self.summary.overrange.to_string(),
        ));
        values.push(("pose_resets".into(), self.summary.resets.to_string()));
        let lvl = problems.iter().map(|p| p.0).max().unwrap_or(level::OK);
        let message = if problems.is_empty() {
            "ok".to_string()
        } else {
            problems
                .iter()
                .map(|p| p.1.as_str())
                .collect::<Vec<_>>()
                .join("; ")
        };
        let due = match &self.last_diag {
            None => true,
            Some((t, l, m)) => {
                *l != lvl || *m != message || s.stamp_ns.saturating_sub(*t) >= 1_000_000_000
            }
        };
        if !due {
            return Ok(());
        }
        let msg = msgs::DiagnosticArray {
            header: header(s.stamp_ns, "")?,
            status: vec![msgs::DiagnosticStatus {
                level: lvl,
                name: "odometry unit".into(),
                message: message.clone(),
                hardware_id: "odo-unit".into(),
                values: values
                    .into_iter()
                    .map(|(key, value)| msgs::KeyValue { key, value })
                    .collect(),
            }],
        };
        Self::put(
            &mut self.writer,
            &mut self.diagnostics,
            s.stamp_ns,
            &msgs::encode(&msg)?,
        )?;
        self.summary.diagnostics += 1;
        self.last_diag = Some((s.stamp_ns, lvl, message));
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
        let msg = msgs::Path {
            header: header(last, ODOM_FRAME)?,
            poses: poses
                .iter()
                .map(|(t, p)| {
                    Ok(msgs::PoseStamped {
                        header: header(*t, ODOM_FRAME)?,
                        pose: ros_pose(p),
                    })
                })
                .collect::<Result<_>>()?,
        };
        let ch = self.paths.get_mut(topic).expect("inserted above");
        Self::put(&mut self.writer, ch, last, &msgs::encode(&msg)?)?;
        self.summary.paths += 1;
        Ok(())
    }

    /// Writes the summary and index; the file is complete.
    pub fn finish(mut self) -> Result<RecordingSummary> {
        self.writer.finish().map_err(mcap_err)?;
        let mut w = self.writer.into_inner();
        w.flush()?;
        Ok(self.summary)
    }
}
