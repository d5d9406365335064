//! The ROS 2 messages of the recordings, their `ros2msg` schema texts and their CDR encoding.
//!
//! The structs mirror the `.msg` definitions field for field (serde serialises fields in
//! declaration order, which is the CDR order); the `cdr` crate writes XCDR1 little-endian with
//! the 4-byte encapsulation header `00 01 00 00` and aligns each primitive to its size from
//! the end of that header, as rosbag2 and every DDS vendor do. A schema text is the message's
//! definition followed by each dependency after a line of 80 `=` and a `MSG: pkg/Type` line.

use anyhow::{anyhow, Result};
use serde::ser::{Serialize, SerializeTuple, Serializer};

/// `builtin_interfaces/msg/Time`: seconds and nanoseconds since the Unix epoch (or since the
/// unit started, for MCU stamps; see docs/ROS.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Time {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds, `0..1e9`.
    pub nanosec: u32,
}

impl Time {
    /// The time of `ns` nanoseconds; `None` beyond `int32` seconds.
    pub fn from_nanos(ns: u64) -> Option<Self> {
        Some(Self {
            sec: i32::try_from(ns / 1_000_000_000).ok()?,
            nanosec: (ns % 1_000_000_000) as u32,
        })
    }

    /// Nanoseconds (the MCAP log time).
    pub fn nanos(&self) -> u64 {
        self.sec as u64 * 1_000_000_000 + u64::from(self.nanosec)
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct Header {
    /// Time of the data.
    pub stamp: Time,
    /// Frame the data is expressed in.
    pub frame_id: String,
}

/// `geometry_msgs/msg/Point` (m).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Point {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Vector3`.
pub type Vector3 = Point;

/// `geometry_msgs/msg/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `geometry_msgs/msg/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Pose {
    /// Position (m).
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// A `float64[36]` covariance, row-major 6x6 (serialised without a length, as a fixed array).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Covariance6(pub [f64; 36]);

impl Serialize for Covariance6 {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

/// `geometry_msgs/msg/PoseWithCovariance`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PoseWithCovariance {
    /// Pose.
    pub pose: Pose,
    /// Covariance over (x, y, z, rotation about x, y, z).
    pub covariance: Covariance6,
}

/// `geometry_msgs/msg/Twist`.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Twist {
    /// m/s.
    pub linear: Vector3,
    /// rad/s.
    pub angular: Vector3,
}

/// `geometry_msgs/msg/TwistWithCovariance`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TwistWithCovariance {
    /// Twist.
    pub twist: Twist,
    /// Covariance over (vx, vy, vz, wx, wy, wz).
    pub covariance: Covariance6,
}

/// `nav_msgs/msg/Odometry`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Odometry {
    /// Stamp and the pose's frame (`odom`).
    pub header: Header,
    /// The twist's frame (`base_link`).
    pub child_frame_id: String,
    /// Pose in `header.frame_id`.
    pub pose: PoseWithCovariance,
    /// Twist in `child_frame_id`.
    pub twist: TwistWithCovariance,
}

/// `geometry_msgs/msg/Transform`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Transform {
    /// m.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// Child frame.
    pub child_frame_id: String,
    /// Child pose in the parent frame.
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TfMessage {
    /// Transforms.
    pub transforms: Vec<TransformStamped>,
}

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct KeyValue {
    /// Key.
    pub key: String,
    /// Value.
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus` levels.
pub mod level {
    /// OK.
    pub const OK: u8 = 0;
    /// WARN.
    pub const WARN: u8 = 1;
    /// ERROR.
    pub const ERROR: u8 = 2;
    /// STALE.
    pub const STALE: u8 = 3;
}

/// `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct DiagnosticStatus {
    /// One of [`level`].
    pub level: u8,
    /// Name of the component.
    pub name: String,
    /// Human summary.
    pub message: String,
    /// Hardware identifier.
    pub hardware_id: String,
    /// Values.
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DiagnosticArray {
    /// Stamp.
    pub header: Header,
    /// Statuses.
    pub status: Vec<DiagnosticStatus>,
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PoseStamped {
    /// Stamp and frame.
    pub header: Header,
    /// Pose.
    pub pose: Pose,
}

/// `nav_msgs/msg/Path`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Path {
    /// Stamp and frame.
    pub header: Header,
    /// Poses in order.
    pub poses: Vec<PoseStamped>,
}

/// `sensor_msgs/msg/JointState`: one entry per joint in each non-empty array.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct JointState {
    /// Stamp (no frame).
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Positions, rad.
    pub position: Vec<f64>,
    /// Velocities, rad/s (empty when unknown).
    pub velocity: Vec<f64>,
    /// Efforts (empty: not measured).
    pub effort: Vec<f64>,
}

/// CDR (XCDR1, little-endian, with the encapsulation header) of a message.
pub fn encode<T: Serialize>(msg: &T) -> Result<Vec<u8>> {
    cdr::serialize::<_, _, cdr::CdrLe>(msg, cdr::Infinite).map_err(|e| anyhow!("CDR: {e}"))
}

// The .msg definitions (ROS 2 Humble to Rolling; comments left out).
const TIME: &str = "int32 sec\nuint32 nanosec\n";
const HEADER: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";
const POINT: &str = "float64 x\nfloat64 y\nfloat64 z\n";
const VECTOR3: &str = "float64 x\nfloat64 y\nfloat64 z\n";
const QUATERNION: &str = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";
const POSE: &str = "Point position\nQuaternion orientation\n";
const POSE_COV: &str = "Pose pose\nfloat64[36] covariance\n";
const TWIST: &str = "Vector3  linear\nVector3  angular\n";
const TWIST_COV: &str = "Twist twist\nfloat64[36] covariance\n";
const ODOMETRY: &str = "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n";
const TRANSFORM: &str = "Vector3 translation\nQuaternion rotation\n";
const TRANSFORM_STAMPED: &str =
    "std_msgs/Header header\nstring child_frame_id\nTransform transform\n";
const TF_MESSAGE: &str = "geometry_msgs/TransformStamped[] transforms\n";
const KEY_VALUE: &str = "string key\nstring value\n";
const DIAGNOSTIC_STATUS: &str = "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\nstring message\nstring hardware_id\nKeyValue[] values\n";
const DIAGNOSTIC_ARRAY: &str = "std_msgs/Header header\nDiagnosticStatus[] status\n";
const POSE_STAMPED: &str = "std_msgs/Header header\nPose pose\n";
const PATH: &str = "std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses\n";
const JOINT_STATE: &str = "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n";

/// Builds a `ros2msg` schema text: the main definition, then each dependency.
fn schema(main: &str, deps: &[(&str, &str)]) -> String {
    let mut s = main.to_string();
    for (name, text) in deps {
        s.push_str(&"=".repeat(80));
        s.push_str("\nMSG: ");
        s.push_str(name);
        s.push('\n');
        s.push_str(text);
    }
    s
}

/// A message type of the recordings: its ROS 2 name and `ros2msg` schema text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MsgType {
    /// `nav_msgs/msg/Odometry`.
    Odometry,
    /// `tf2_msgs/msg/TFMessage`.
    TfMessage,
    /// `diagnostic_msgs/msg/DiagnosticArray`.
    DiagnosticArray,
    /// `nav_msgs/msg/Path`.
    Path,
    /// `geometry_msgs/msg/PoseStamped`.
    PoseStamped,
    /// `sensor_msgs/msg/JointState`.
    JointState,
}

impl MsgType {
    /// The schema name, `pkg/msg/Type`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Odometry => "nav_msgs/msg/Odometry",
            Self::TfMessage => "tf2_msgs/msg/TFMessage",
            Self::DiagnosticArray => "diagnostic_msgs/msg/DiagnosticArray",
            Self::Path => "nav_msgs/msg/Path",
            Self::PoseStamped => "geometry_msgs/msg/PoseStamped",
            Self::JointState => "sensor_msgs/msg/JointState",
        }
    }

    /// The `ros2msg` schema text (definition and dependencies).
    pub fn schema(self) -> String {
        let header = [
            ("std_msgs/Header", HEADER),
            ("builtin_interfaces/Time", TIME),
        ];
        let pose = [
            ("geometry_msgs/Pose", POSE),
            ("geometry_msgs/Point", POINT),
            ("geometry_msgs/Quaternion", QUATERNION),
        ];
        match self {
            Self::Odometry => {
                let mut d = header.to_vec();
                d.push(("geometry_msgs/PoseWithCovariance", POSE_COV));
                d.extend(pose);
                d.push(("geometry_msgs/TwistWithCovariance", TWIST_COV));
                d.push(("geometry_msgs/Twist", TWIST));
                d.push(("geometry_msgs/Vector3", VECTOR3));
                schema(ODOMETRY, &d)
            }
            Self::TfMessage => {
                let mut d = vec![("geometry_msgs/TransformStamped", TRANSFORM_STAMPED)];
                d.extend(header);
                d.push(("geometry_msgs/Transform", TRANSFORM));
                d.push(("geometry_msgs/Vector3", VECTOR3));
                d.push(("geometry_msgs/Quaternion", QUATERNION));
                schema(TF_MESSAGE, &d)
            }
            Self::DiagnosticArray => {
                let mut d = header.to_vec();
                d.push(("diagnostic_msgs/DiagnosticStatus", DIAGNOSTIC_STATUS));
                d.push(("diagnostic_msgs/KeyValue", KEY_VALUE));
                schema(DIAGNOSTIC_ARRAY, &d)
            }
            Self::Path => {
                let mut d = header.to_vec();
                d.push(("geometry_msgs/PoseStamped", POSE_STAMPED));
                d.extend(pose);
                schema(PATH, &d)
            }
            Self::PoseStamped => {
                let mut d = header.to_vec();
                d.extend(pose);
                schema(POSE_STAMPED, &d)
            }
            Self::JointState => schema(JOINT_STATE, &header),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_header_layout() {
        // Encapsulation header, int32 sec, uint32 nanosec, string (u32 length with the
        // terminating zero, bytes, zero).
        let h = Header {
            stamp: Time { sec: 1, nanosec: 2 },
            frame_id: "odom".into(),
        };
        assert_eq!(
            encode(&h).unwrap(),
            [0, 1, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 5, 0, 0, 0, b'o', b'd', b'o', b'm', 0]
        );
    }

    #[test]
    fn f64_aligned_from_the_payload_start() {
        // After a 5-byte string (4 + 2 bytes), a float64 is padded to offset 8 of the payload.
        #[derive(serde::Serialize)]
        struct S {
            s: String,
            x: f64,
        }
        let b = encode(&S {
            s: "a".into(),
            x: 1.0,
        })
        .unwrap();
        assert_eq!(b.len(), 4 + 8 + 8);
        assert_eq!(&b[4..10], &[2, 0, 0, 0, b'a', 0]);
        assert_eq!(&b[10..12], &[0, 0]);
        assert_eq!(&b[12..], &1.0f64.to_le_bytes());
    }

    #[test]
    fn covariance_is_a_fixed_array() {
        let mut c = [0.0; 36];
        c[35] = 2.0;
        let b = encode(&Covariance6(c)).unwrap();
        assert_eq!(b.len(), 4 + 36 * 8);
        assert_eq!(&b[4 + 35 * 8..], &2.0f64.to_le_bytes());
    }

    #[test]
    fn schemas_list_each_dependency_once() {
        for t in [
            MsgType::Odometry,
            MsgType::TfMessage,
            MsgType::DiagnosticArray,
            MsgType::Path,
            MsgType::JointState,
        ] {
            let s = t.schema();
            let names: Vec<&str> = s.lines().filter_map(|l| l.strip_prefix("MSG: ")).collect();
            let mut sorted = names.clone();
            sorted.sort_unstable();
            sorted.dedup();
            assert_eq!(sorted.len(), names.len(), "{}", t.name());
            assert!(names.contains(&"builtin_interfaces/Time"), "{}", t.name());
        }
    }

    #[test]
    fn joint_state_layout() {
        // Header (stamp 0, frame ""), then sequences: u32 count, elements; the float64s
        // aligned to 8 from the payload start.
        let j = JointState {
            header: Header::default(),
            name: vec!["l".into()],
            position: vec![1.5],
            velocity: vec![],
            effort: vec![],
        };
        let b = encode(&j).unwrap();
        // Payload offsets (+4 in `b`): stamp 0..8, frame_id "" (length 1, NUL) 8..13; name
        // count at 16, "l" 20..26; position count at 28, its float64 at 32 (8-aligned);
        // velocity and effort counts at 40 and 44.
        assert_eq!(&b[20..24], &1u32.to_le_bytes());
        assert_eq!(&b[24..30], &[2, 0, 0, 0, b'l', 0]);
        assert_eq!(&b[32..36], &1u32.to_le_bytes());
        assert_eq!(&b[36..44], &1.5f64.to_le_bytes());
        assert_eq!(&b[44..], &[0, 0, 0, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn time_from_nanos() {
        let t = Time::from_nanos(1_700_000_000_123_456_789).unwrap();
        assert_eq!((t.sec, t.nanosec), (1_700_000_000, 123_456_789));
        assert_eq!(t.nanos(), 1_700_000_000_123_456_789);
        assert_eq!(Time::from_nanos(u64::MAX), None);
    }
}
