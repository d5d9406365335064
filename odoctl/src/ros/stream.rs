//! The unit's samples as ROS 2 messages: the conversion shared by the MCAP recordings and
//! the live bridge (`/odom`, `/tf`, `/joint_states`, `/diagnostics` on the rules of
//! docs/ROS.md), with the frame ids and status names of [`RosNames`].

use anyhow::{anyhow, Result};
use odo_unit::protocol::StatusFlags;
use odo_unit::timing::SyncState;

use std::f64::consts::TAU;

use super::conventions::{quaternion_of_heading, BaseTwist, ContinuousOdom, PoseCovariance};
use super::msgs::{self, level};
use super::names::RosNames;
use odo_unit::odometry::{Pose, UncertaintyModel};

/// One sample to publish or record: the unit's pose (ours), its covariance, the interval's twist.
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
    /// The wheels' absolute counts (left, right; increments), when known.
    pub counts: Option<(i64, i64)>,
}

/// What a stream of samples has published so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StreamCounts {
    /// `/odom` (and `/tf`) messages.
    pub odom: u64,
    /// `/diagnostics` messages.
    pub diagnostics: u64,
    /// `reset_pose` jumps absorbed to keep `odom` continuous.
    pub resets: u64,
    /// Samples not integrated (over-range).
    pub overrange: u64,
}

/// The messages of one sample.
#[derive(Debug, Clone, PartialEq)]
pub struct Messages {
    /// `/odom`.
    pub odom: msgs::Odometry,
    /// `/tf`; `None` with `--no-tf`.
    pub tf: Option<msgs::TfMessage>,
    /// `/joint_states`, when the counts and the increments per turn are known.
    pub joints: Option<msgs::JointState>,
    /// `/diagnostics`, when due.
    pub diagnostics: Option<msgs::DiagnosticArray>,
}

/// Converts samples one after the other: keeps `odom` continuous across resets and decides
/// when a `/diagnostics` status is due (first sample, a change, at least once per second).
#[derive(Debug, Clone, Default)]
pub struct OdomStream {
    continuity: ContinuousOdom,
    last_diag: Option<(u64, u8, String)>,
    last_stamp: Option<u64>,
    counts: StreamCounts,
    model: Option<UncertaintyModel>,
    extra: Vec<(String, String)>,
    names: RosNames,
    ticks_per_rev: Option<u32>,
    /// Stamp and counts of the last sample, for the wheel velocities.
    last_counts: Option<(u64, (i64, i64))>,
}

pub(crate) fn header(stamp_ns: u64, frame: &str) -> Result<msgs::Header> {
    Ok(msgs::Header {
        stamp: msgs::Time::from_nanos(stamp_ns)
            .ok_or_else(|| anyhow!("stamp {stamp_ns} ns beyond int32 seconds"))?,
        frame_id: frame.into(),
    })
}

pub(crate) fn ros_pose(p: &Pose) -> msgs::Pose {
    msgs::Pose {
        position: msgs::Point {
            x: p.x,
            y: p.y,
            z: 0.0,
        },
        orientation: quaternion_of_heading(p.heading),
    }
}

impl OdomStream {
    /// A stream; `model`, when given, is named in the diagnostics instead of the one the
    /// unit's status word names (a replay's model).
    pub fn new(model: Option<UncertaintyModel>) -> Self {
        Self {
            model,
            ..Default::default()
        }
    }

    /// The same stream with these names (frames, status names, TF on or off).
    pub fn with_names(mut self, names: RosNames) -> Self {
        self.names = names;
        self
    }

    /// The names in use.
    pub fn names(&self) -> &RosNames {
        &self.names
    }

    /// Increments per wheel turn (x4 decoded), for `/joint_states`; without it no joint
    /// states are made.
    pub fn set_ticks_per_rev(&mut self, ticks: Option<u32>) {
        self.ticks_per_rev = ticks.filter(|t| *t > 0);
    }

    /// Key-values added to every status (the bridge's link counters).
    pub fn set_extra(&mut self, extra: Vec<(String, String)>) {
        self.extra = extra;
    }

    /// What has been converted so far.
    pub fn counts(&self) -> StreamCounts {
        self.counts
    }

    /// The messages of one sample: `/odom`, `/tf` and, when due, `/diagnostics`. Stamps must
    /// not decrease.
    pub fn next(&mut self, s: &OdomSample) -> Result<Messages> {
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
            header: header(s.stamp_ns, &self.names.odom_frame)?,
            child_frame_id: self.names.base_frame.clone(),
            pose: msgs::PoseWithCovariance {
                pose: ros_pose(&pose),
                covariance: cov.to_ros(),
            },
            twist: msgs::TwistWithCovariance {
                twist,
                covariance: twist_cov,
            },
        };
        let tf = self.names.tf.is_some().then(|| msgs::TfMessage {
            transforms: vec![msgs::TransformStamped {
                header: odom.header.clone(),
                child_frame_id: odom.child_frame_id.clone(),
                transform: msgs::Transform {
                    translation: odom.pose.pose.position,
                    rotation: odom.pose.pose.orientation,
                },
            }],
        });
        let joints = self.joints(s)?;
        self.counts.odom += 1;
        self.counts.overrange += u64::from(s.overrange);
        self.counts.resets = self.continuity.resets();
        let diagnostics = self.diagnose(s, jump)?;
        Ok(Messages {
            odom,
            tf,
            joints,
            diagnostics,
        })
    }

    /// The wheels' joint states: position `2 pi counts / ticks_per_rev` (rad), velocity the
    /// change over the sample interval (rad/s; empty without an interval, as the twist).
    fn joints(&mut self, s: &OdomSample) -> Result<Option<msgs::JointState>> {
        let (Some(ticks), Some(c)) = (self.ticks_per_rev, s.counts) else {
            return Ok(None);
        };
        let prev = self.last_counts.replace((s.stamp_ns, c));
        let rad = |n: i64| TAU * n as f64 / f64::from(ticks);
        let velocity = match prev {
            Some((t, p)) if s.twist.is_some() && s.stamp_ns > t => {
                let dt = (s.stamp_ns - t) as f64 * 1e-9;
                vec![rad(c.0 - p.0) / dt, rad(c.1 - p.1) / dt]
            }
            _ => Vec::new(),
        };
        Ok(Some(msgs::JointState {
            header: header(s.stamp_ns, "")?,
            name: self.names.joints.to_vec(),
            position: vec![rad(c.0), rad(c.1)],
            velocity,
            effort: Vec::new(),
        }))
    }

    fn diagnose(
        &mut self,
        s: &OdomSample,
        jump: Option<(f64, f64, f64)>,
    ) -> Result<Option<msgs::DiagnosticArray>> {
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
            if f.sync == SyncState::Holdover {
                problems.push((level::WARN, "PPS lost (holdover)".into()));
            }
            values.push((
                "sync".into(),
                match f.sync {
                    SyncState::FreeRunning => "free_running",
                    SyncState::Locked => "pps_locked",
                    SyncState::Holdover => "holdover",
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
            self.counts.overrange.to_string(),
        ));
        values.push(("pose_resets".into(), self.counts.resets.to_string()));
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
            return Ok(None);
        }
        values.extend(self.extra.iter().cloned());
        self.counts.diagnostics += 1;
        self.last_diag = Some((s.stamp_ns, lvl, message.clone()));
        let name = self.names.status_name(UNIT_STATUS);
        Ok(Some(status_array(
            s.stamp_ns,
            (lvl, &name, UNIT_HARDWARE),
            message,
            values,
        )?))
    }

    /// The link's status (the bridge's, a source of its own beside the unit's): `level`,
    /// `message`, stamped `stamp_ns`. The next sample's status follows it whatever its
    /// content.
    pub fn status(
        &mut self,
        stamp_ns: u64,
        level: u8,
        message: &str,
    ) -> Result<msgs::DiagnosticArray> {
        self.last_diag = None;
        self.counts.diagnostics += 1;
        let name = self.names.status_name(LINK_STATUS);
        status_array(
            stamp_ns,
            (level, &name, LINK_HARDWARE),
            message.to_string(),
            self.extra.clone(),
        )
    }
}

/// Component of the unit's status (name `<node>: odometry unit`).
pub const UNIT_STATUS: &str = "odometry unit";
/// Component of the bridge's link status (name `<node>: link`).
pub const LINK_STATUS: &str = "link";
/// `hardware_id` of the unit's status.
const UNIT_HARDWARE: &str = "odo-unit";
/// `hardware_id` of the link's status.
const LINK_HARDWARE: &str = "odoctl";

/// One status (level, name, hardware id) in an array.
fn status_array(
    stamp_ns: u64,
    (level, name, hardware_id): (u8, &str, &str),
    message: String,
    values: Vec<(String, String)>,
) -> Result<msgs::DiagnosticArray> {
    Ok(msgs::DiagnosticArray {
        header: header(stamp_ns, "")?,
        status: vec![msgs::DiagnosticStatus {
            level,
            name: name.into(),
            message,
            hardware_id: hardware_id.into(),
            values: values
                .into_iter()
                .map(|(key, value)| msgs::KeyValue { key, value })
                .collect(),
        }],
    })
}
