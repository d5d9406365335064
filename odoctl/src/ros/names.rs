//! Every ROS name the bridge and the recordings use, built in one place from the options:
//! frame ids (REP-105 defaults `odom`, `base_link`, with an optional prefix), topic names
//! (resolved against the namespace as ROS 2 resolves them), the node name, the wheel joint
//! names, and whether `/tf` is published. docs/ROS.md lists the options and defaults.

use anyhow::{bail, Result};

use super::conventions::{BASE_FRAME, ODOM_FRAME};

/// The names as given (unresolved): what `bridge` and the `--mcap` writers take as options.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NameOptions {
    /// Namespace of the node and of the relative topic names (`""` or `/robot1`).
    pub namespace: String,
    /// Prefix of both frame ids (`robot1/`), `""` for none.
    pub frame_prefix: String,
    /// Parent frame of the pose (REP-105: `odom`).
    pub odom_frame: String,
    /// Frame of the chassis and of the twist (REP-105: `base_link`).
    pub base_frame: String,
    /// `nav_msgs/Odometry` topic (relative: under the namespace).
    pub odom_topic: String,
    /// `tf2_msgs/TFMessage` topic.
    pub tf_topic: String,
    /// `diagnostic_msgs/DiagnosticArray` topic.
    pub diagnostics_topic: String,
    /// `sensor_msgs/JointState` topic.
    pub joint_states_topic: String,
    /// Node name (the bridge's).
    pub node: String,
    /// Joint name of the left wheel.
    pub left_joint: String,
    /// Joint name of the right wheel.
    pub right_joint: String,
    /// Publish `odom -> base_link` on the tf topic.
    pub tf: bool,
}

impl Default for NameOptions {
    fn default() -> Self {
        Self {
            namespace: String::new(),
            frame_prefix: String::new(),
            odom_frame: ODOM_FRAME.into(),
            base_frame: BASE_FRAME.into(),
            odom_topic: "odom".into(),
            tf_topic: "/tf".into(),
            diagnostics_topic: "/diagnostics".into(),
            joint_states_topic: "joint_states".into(),
            node: "odoctl_bridge".into(),
            left_joint: "left_wheel_joint".into(),
            right_joint: "right_wheel_joint".into(),
            tf: true,
        }
    }
}

/// The resolved names: fully qualified topic names, frame ids with their prefix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RosNames {
    /// Namespace, `/` or `/a/b`.
    pub namespace: String,
    /// Node name (without namespace).
    pub node: String,
    /// `header.frame_id` of `/odom` and `/tf`.
    pub odom_frame: String,
    /// `child_frame_id` of `/odom` and `/tf`.
    pub base_frame: String,
    /// Fully qualified topics.
    pub odom: String,
    /// The tf topic; `None` with `--no-tf`.
    pub tf: Option<String>,
    /// The diagnostics topic.
    pub diagnostics: String,
    /// The joint states topic.
    pub joint_states: String,
    /// The path so far / whole path: `<odom>/path`.
    pub path: String,
    /// The Foxglove 1-sigma ellipse: `<odom>/ellipse`.
    pub ellipse: String,
    /// The `reset_pose` service: `<namespace>/reset_pose`.
    pub reset_service: String,
    /// Joint names, left and right wheel.
    pub joints: [String; 2],
}

impl Default for RosNames {
    fn default() -> Self {
        Self::resolve(&NameOptions::default()).expect("the defaults are valid names")
    }
}

/// Checks one token of a ROS name: `[A-Za-z_][A-Za-z0-9_]*`, no `__`.
fn token_ok(t: &str) -> bool {
    !t.is_empty()
        && !t.starts_with(|c: char| c.is_ascii_digit())
        && t.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !t.contains("__")
}

/// `ns` as `/` or `/a/b`.
fn namespace(ns: &str) -> Result<String> {
    let t = ns.trim_matches('/');
    if t.is_empty() {
        return Ok("/".into());
    }
    if !t.split('/').all(token_ok) {
        bail!("namespace `{ns}`: not a ROS name (tokens of letters, digits and `_`, separated by `/`)");
    }
    Ok(format!("/{t}"))
}

/// `name` resolved against `ns` (`/` or `/a/b`): absolute names stay, relative ones go
/// under the namespace.
fn resolve_topic(what: &str, name: &str, ns: &str) -> Result<String> {
    let rel = name.strip_prefix('/').unwrap_or(name);
    if name.starts_with('~') {
        bail!("--{what} `{name}`: private names (`~`) are not supported; give the full name");
    }
    if rel.is_empty() || !rel.split('/').all(token_ok) {
        bail!("--{what} `{name}`: not a ROS topic name (tokens of letters, digits and `_`, separated by `/`)");
    }
    Ok(if name.starts_with('/') {
        name.to_string()
    } else if ns == "/" {
        format!("/{rel}")
    } else {
        format!("{ns}/{rel}")
    })
}

/// A frame id: non-empty, no leading `/` (tf2 refuses it), no white space.
fn frame(what: &str, prefix: &str, name: &str) -> Result<String> {
    let f = format!("{prefix}{name}");
    if name.is_empty() || f.starts_with('/') || f.chars().any(char::is_whitespace) {
        bail!("--{what} `{f}`: not a frame id (non-empty, no leading `/`, no spaces)");
    }
    Ok(f)
}

impl RosNames {
    /// Resolves and checks the options; a bad name is an error naming its option.
    pub fn resolve(o: &NameOptions) -> Result<Self> {
        let ns = namespace(&o.namespace)?;
        if !token_ok(&o.node) {
            bail!("--node-name `{}`: not a ROS node name", o.node);
        }
        for (what, j) in [
            ("left-wheel-joint", &o.left_joint),
            ("right-wheel-joint", &o.right_joint),
        ] {
            if j.is_empty() || j.chars().any(char::is_whitespace) {
                bail!("--{what} `{j}`: not a joint name (non-empty, no spaces)");
            }
        }
        if o.left_joint == o.right_joint {
            bail!(
                "--left-wheel-joint and --right-wheel-joint are both `{}`",
                o.left_joint
            );
        }
        let odom = resolve_topic("odom-topic", &o.odom_topic, &ns)?;
        let names = Self {
            odom_frame: frame("odom-frame", &o.frame_prefix, &o.odom_frame)?,
            base_frame: frame("base-frame", &o.frame_prefix, &o.base_frame)?,
            tf: if o.tf {
                Some(resolve_topic("tf-topic", &o.tf_topic, &ns)?)
            } else {
                None
            },
            diagnostics: resolve_topic("diagnostics-topic", &o.diagnostics_topic, &ns)?,
            joint_states: resolve_topic("joint-states-topic", &o.joint_states_topic, &ns)?,
            path: format!("{odom}/path"),
            ellipse: format!("{odom}/ellipse"),
            reset_service: resolve_topic("namespace", "reset_pose", &ns)?,
            joints: [o.left_joint.clone(), o.right_joint.clone()],
            node: o.node.clone(),
            namespace: ns,
            odom,
        };
        if names.odom_frame == names.base_frame {
            bail!(
                "--odom-frame and --base-frame are both `{}`",
                names.odom_frame
            );
        }
        Ok(names)
    }

    /// The name of a `/diagnostics` status of `component`: `node: component` (ROS 2's
    /// convention), with the namespace when there is one.
    pub fn status_name(&self, component: &str) -> String {
        if self.namespace == "/" {
            format!("{}: {component}", self.node)
        } else {
            format!("{}/{}: {component}", &self.namespace[1..], self.node)
        }
    }

    /// Splits a fully qualified name into (namespace, base name), as `ros2-client` takes it.
    pub fn split(full: &str) -> (&str, &str) {
        match full.rfind('/') {
            Some(0) | None => ("/", full.trim_start_matches('/')),
            Some(i) => (&full[..i], &full[i + 1..]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_rep_105() {
        let n = RosNames::default();
        assert_eq!(
            (n.odom_frame.as_str(), n.base_frame.as_str()),
            ("odom", "base_link")
        );
        assert_eq!(n.odom, "/odom");
        assert_eq!(n.tf.as_deref(), Some("/tf"));
        assert_eq!(n.diagnostics, "/diagnostics");
        assert_eq!(n.joint_states, "/joint_states");
        assert_eq!(
            (n.path.as_str(), n.ellipse.as_str()),
            ("/odom/path", "/odom/ellipse")
        );
        assert_eq!(n.reset_service, "/reset_pose");
        assert_eq!(
            n.status_name("odometry unit"),
            "odoctl_bridge: odometry unit"
        );
    }

    #[test]
    fn namespace_and_prefix() {
        let n = RosNames::resolve(&NameOptions {
            namespace: "robot1".into(),
            frame_prefix: "robot1/".into(),
            tf: false,
            ..Default::default()
        })
        .unwrap();
        assert_eq!(n.namespace, "/robot1");
        assert_eq!(
            (n.odom.as_str(), n.joint_states.as_str()),
            ("/robot1/odom", "/robot1/joint_states")
        );
        assert_eq!(n.diagnostics, "/diagnostics", "absolute names stay");
        assert_eq!(n.tf, None);
        assert_eq!(
            (n.odom_frame.as_str(), n.base_frame.as_str()),
            ("robot1/odom", "robot1/base_link")
        );
        assert_eq!(n.reset_service, "/robot1/reset_pose");
        assert_eq!(n.status_name("link"), "robot1/odoctl_bridge: link");
        assert_eq!(RosNames::split("/robot1/odom"), ("/robot1", "odom"));
        assert_eq!(RosNames::split("/odom"), ("/", "odom"));
    }

    #[test]
    fn bad_names_table() {
        let bad = |f: fn(&mut NameOptions)| {
            let mut o = NameOptions::default();
            f(&mut o);
            RosNames::resolve(&o).unwrap_err().to_string()
        };
        assert!(bad(|o| o.namespace = "9robot".into()).contains("namespace"));
        assert!(bad(|o| o.odom_topic = "odom topic".into()).contains("--odom-topic"));
        assert!(bad(|o| o.odom_topic = "~/odom".into()).contains("private"));
        assert!(bad(|o| o.tf_topic = "/a//b".into()).contains("--tf-topic"));
        assert!(bad(|o| o.joint_states_topic = "a__b".into()).contains("--joint-states-topic"));
        assert!(bad(|o| o.odom_frame = "/odom".into()).contains("--odom-frame"));
        assert!(bad(|o| o.frame_prefix = "/r/".into()).contains("--odom-frame"));
        assert!(bad(|o| o.base_frame = "odom".into()).contains("both"));
        assert!(bad(|o| o.node = "my-node".into()).contains("--node-name"));
        assert!(bad(|o| o.right_joint = "left_wheel_joint".into()).contains("both"));
        assert!(bad(|o| o.left_joint = String::new()).contains("--left-wheel-joint"));
    }
}
