"""A run log or a trajectory as a ROS 2 bag (MCAP storage, CDR messages), for ROS 2 tooling
(``ros2 bag play``/``info``, PlotJuggler, Foxglove). Encoded by ``mcap-ros2-support``.

Topics (``header.stamp`` = the source's message time, epoch; the bag's log time the same):

- ``/joint_states`` (``sensor_msgs/msg/JointState``, every sample, the robot's joint names): a run log's
  measured state (position = ``q_actual`` rad, velocity empty (not measured), effort = ``tau_actual``
  N·m joint side); a trajectory's planned state (position q, velocity q̇, effort τ_ff, joint side);
- ``/joint_states_demand`` (run logs, ``sensor_msgs/msg/JointState``): position ``q_demand``, velocity
  ``qd_demand``, effort ``tau_ff`` (the feed-forward sent);
- ``/tracker/tcp_pose`` (run logs with tracker data, ``geometry_msgs/msg/PoseStamped``, frame
  ``tracker``): the TCP measured by the tracker, m and unit quaternion;
- ``/tf_static`` (``tf2_msgs/msg/TFMessage``, one message at the start, given a calibration): the
  tracker frame in the robot's root link frame (parent = root link, child ``tracker``), so the measured
  TCP shows on the robot.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rxcomm.io.files import atomic_write_bytes

NS = 1_000_000_000
_HEADER = """================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
_QUAT = """================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""
MSGDEFS = {
    "sensor_msgs/msg/JointState": "std_msgs/Header header\nstring[] name\nfloat64[] position\n"
    "float64[] velocity\nfloat64[] effort\n" + _HEADER,
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose\n"
    + _HEADER
    + "================================================================================\n"
    "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n"
    "================================================================================\n"
    "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n" + _QUAT,
    "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n"
    "================================================================================\n"
    "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n"
    "geometry_msgs/Transform transform\n"
    + _HEADER
    + "================================================================================\n"
    "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"
    "================================================================================\n"
    "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n" + _QUAT,
}


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // NS, "nanosec": ns % NS}


def _list(v: np.ndarray | None) -> list[float]:
    return [] if v is None else [float(x) for x in v]


class BagWriter:
    """The bag in memory, written atomically by :meth:`finish` (a bag is small next to its log)."""

    def __init__(self) -> None:
        import io

        from mcap_ros2.writer import Writer

        self._buf = io.BytesIO()
        self._w = Writer(self._buf)
        self._schemas = {k: self._w.register_msgdef(k, v) for k, v in MSGDEFS.items()}
        self.counts: dict[str, int] = {}

    def write(self, topic: str, datatype: str, ns: int, msg: dict[str, Any]) -> None:
        self._w.write_message(topic, self._schemas[datatype], msg, log_time=ns, publish_time=ns)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def joint_states(
        self,
        topic: str,
        stamps_ns: np.ndarray,
        names: Sequence[str],
        position: np.ndarray,
        velocity: np.ndarray | None,
        effort: np.ndarray | None,
    ) -> None:
        names = list(names)
        for i, ns in enumerate(stamps_ns.tolist()):
            msg = {
                "header": {"stamp": _stamp(ns), "frame_id": ""},
                "name": names,
                "position": _list(position[i]),
                "velocity": _list(None if velocity is None else velocity[i]),
                "effort": _list(None if effort is None else effort[i]),
            }
            self.write(topic, "sensor_msgs/msg/JointState", ns, msg)

    def poses(self, topic: str, stamps_ns: np.ndarray, frame: str, xyz: np.ndarray, wxyz: np.ndarray) -> None:
        for i, ns in enumerate(stamps_ns.tolist()):
            p, q = xyz[i], wxyz[i]
            msg = {
                "header": {"stamp": _stamp(ns), "frame_id": frame},
                "pose": {
                    "position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
                    "orientation": {"x": float(q[1]), "y": float(q[2]), "z": float(q[3]), "w": float(q[0])},
                },
            }
            self.write(topic, "geometry_msgs/msg/PoseStamped", ns, msg)

    def static_transform(
        self, ns: int, parent: str, child: str, xyz: Sequence[float], wxyz: Sequence[float]
    ) -> None:
        tf = {
            "header": {"stamp": _stamp(ns), "frame_id": parent},
            "child_frame_id": child,
            "transform": {
                "translation": dict(zip("xyz", map(float, xyz), strict=True)),
                "rotation": {
                    "x": float(wxyz[1]),
                    "y": float(wxyz[2]),
                    "z": float(wxyz[3]),
                    "w": float(wxyz[0]),
                },
            },
        }
        self.write("/tf_static", "tf2_msgs/msg/TFMessage", ns, {"transforms": [tf]})

    def finish(self, path: str | Path) -> Path:
        self._w.finish()
        return atomic_write_bytes(path, self._buf.getvalue())


def stamps_ns(origin_ns: int, t_s: np.ndarray) -> np.ndarray:
    """Epoch ns of the times t_s (s from ``origin_ns``), as the source's messages were stamped."""
    return origin_ns + np.round(np.asarray(t_s, dtype=float) * NS).astype(np.int64)


def read_bag(path: str | Path) -> list[tuple[str, int, Any]]:
    """(topic, log time ns, decoded message) of every message, in file order, by ``mcap-ros2-support``."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [
            (ch.topic, m.log_time, dec)
            for _, ch, m, dec in reader.iter_decoded_messages(log_time_order=False)
        ]
