//! The ROS names shared by `bridge` and the `--mcap` writers (docs/ROS.md, *Names*).

use clap::Args;

use crate::ros::names::NameOptions;

/// Frames, topics, joints and TF of the ROS 2 output (REP-105 defaults).
#[derive(Args, Clone, Debug)]
pub struct RosNameArgs {
    /// Namespace of the relative topic names (and of the bridge's node), e.g. `robot1`.
    #[arg(long, default_value = "")]
    pub namespace: String,
    /// Prefix of both frame ids, e.g. `robot1/` (`robot1/odom`, `robot1/base_link`).
    #[arg(long, default_value = "")]
    pub frame_prefix: String,
    /// Parent frame of the pose (REP-105).
    #[arg(long, default_value = "odom")]
    pub odom_frame: String,
    /// Frame of the chassis and of the twist (REP-105).
    #[arg(long, default_value = "base_link")]
    pub base_frame: String,
    /// Odometry topic (relative: under the namespace).
    #[arg(long, default_value = "odom")]
    pub odom_topic: String,
    /// TF topic.
    #[arg(long, default_value = "/tf")]
    pub tf_topic: String,
    /// Diagnostics topic.
    #[arg(long, default_value = "/diagnostics")]
    pub diagnostics_topic: String,
    /// Wheel joint states topic (relative: under the namespace).
    #[arg(long, default_value = "joint_states")]
    pub joint_states_topic: String,
    /// Joint name of the left wheel on the joint states topic.
    #[arg(long, default_value = "left_wheel_joint")]
    pub left_wheel_joint: String,
    /// Joint name of the right wheel on the joint states topic.
    #[arg(long, default_value = "right_wheel_joint")]
    pub right_wheel_joint: String,
    /// Publish no `odom -> base_link` transform (when another node, e.g.
    /// robot_localization, publishes it).
    #[arg(long)]
    pub no_tf: bool,
}

impl RosNameArgs {
    /// The options, with the bridge's node name `node` (a recording's is nominal).
    pub fn options(&self, node: &str) -> NameOptions {
        NameOptions {
            namespace: self.namespace.clone(),
            frame_prefix: self.frame_prefix.clone(),
            odom_frame: self.odom_frame.clone(),
            base_frame: self.base_frame.clone(),
            odom_topic: self.odom_topic.clone(),
            tf_topic: self.tf_topic.clone(),
            diagnostics_topic: self.diagnostics_topic.clone(),
            joint_states_topic: self.joint_states_topic.clone(),
            node: node.into(),
            left_joint: self.left_wheel_joint.clone(),
            right_joint: self.right_wheel_joint.clone(),
            tf: !self.no_tf,
        }
    }
}
