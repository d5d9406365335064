"""Writes a TUM trajectory as a ROS 2 MCAP recording with the mcap-ros2-support writer:
/mocap/pose (geometry_msgs/msg/PoseStamped), /slam/odom (nav_msgs/msg/Odometry) and /tf
(tf2_msgs/msg/TFMessage, map -> marker, beside an unrelated map -> odom transform), each
with the pose's stamp as header stamp and log time.

usage: write_trajectory.py IN.tum OUT.mcap
"""

import sys

from mcap_ros2.writer import Writer

TIME = "int32 sec\nuint32 nanosec\n"
HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
POINT = "float64 x\nfloat64 y\nfloat64 z\n"
QUAT = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
POSE = "Point position\nQuaternion orientation\n"
SEP = "=" * 80 + "\n"


def schema_text(main, deps):
    return main + "".join(SEP + "MSG: " + n + "\n" + t for n, t in deps)


HDR = [("std_msgs/Header", HEADER), ("builtin_interfaces/Time", TIME)]
PS = [("geometry_msgs/Pose", POSE), ("geometry_msgs/Point", POINT),
      ("geometry_msgs/Quaternion", QUAT)]
POSE_STAMPED = schema_text("std_msgs/Header header\nPose pose\n", HDR + PS)
ODOMETRY = schema_text(
    "std_msgs/Header header\nstring child_frame_id\n"
    "geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
    HDR
    + [("geometry_msgs/PoseWithCovariance", "Pose pose\nfloat64[36] covariance\n")]
    + PS
    + [("geometry_msgs/TwistWithCovariance", "Twist twist\nfloat64[36] covariance\n"),
       ("geometry_msgs/Twist", "Vector3 linear\nVector3 angular\n"),
       ("geometry_msgs/Vector3", POINT)],
)
TF = schema_text(
    "geometry_msgs/TransformStamped[] transforms\n",
    [("geometry_msgs/TransformStamped",
      "std_msgs/Header header\nstring child_frame_id\nTransform transform\n")]
    + HDR
    + [("geometry_msgs/Transform", "Vector3 translation\nQuaternion rotation\n"),
       ("geometry_msgs/Vector3", POINT), ("geometry_msgs/Quaternion", QUAT)],
)


def main():
    src, dst = sys.argv[1], sys.argv[2]
    with open(dst, "wb") as f:
        w = Writer(f)
        s_pose = w.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED)
        s_odom = w.register_msgdef("nav_msgs/msg/Odometry", ODOMETRY)
        s_tf = w.register_msgdef("tf2_msgs/msg/TFMessage", TF)
        for line in open(src):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            t, x, y, z, qx, qy, qz, qw = line.split()
            sec, frac = t.split(".")
            frac = (frac + "000000000")[:9]
            ns = int(sec) * 1_000_000_000 + int(frac)
            stamp = {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}
            pose = {
                "position": {"x": float(x), "y": float(y), "z": float(z)},
                "orientation": {"x": float(qx), "y": float(qy), "z": float(qz), "w": float(qw)},
            }
            header = {"stamp": stamp, "frame_id": "map"}
            w.write_message("/mocap/pose", s_pose, {"header": header, "pose": pose}, ns, ns)
            w.write_message("/slam/odom", s_odom, {
                "header": header, "child_frame_id": "marker",
                "pose": {"pose": pose, "covariance": [0.0] * 36},
                "twist": {"twist": {"linear": {"x": 0.0, "y": 0.0, "z": 0.0},
                                    "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
                          "covariance": [0.0] * 36},
            }, ns, ns)
            other = {"header": header, "child_frame_id": "odom",
                     "transform": {"translation": {"x": 1.0, "y": 2.0, "z": 0.0},
                                   "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
            mine = {"header": header, "child_frame_id": "marker",
                    "transform": {"translation": pose["position"],
                                  "rotation": pose["orientation"]}}
            w.write_message("/tf", s_tf, {"transforms": [other, mine]}, ns, ns)
        w.finish()


if __name__ == "__main__":
    main()
