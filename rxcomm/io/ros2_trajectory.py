"""A trajectory as a ROS 2 ``trajectory_msgs/msg/JointTrajectory`` YAML, and back.

The file is the message as ``ros2 topic pub TOPIC trajectory_msgs/msg/JointTrajectory "$(cat F)"`` and
a ``control_msgs/action/FollowJointTrajectory`` goal's ``trajectory`` take it: ``header`` (stamp 0:
start on receipt, ``frame_id`` empty), ``joint_names`` (the robot's order), ``points`` with
``positions`` (rad), ``velocities`` (rad/s), ``accelerations`` (rad/s²), ``effort`` (N·m: the
feed-forward torque τ_ff on the joint side of the gearbox, i.e. link torque, not motor torque) and
``time_from_start`` as ``{sec, nanosec}`` (integers; time from the first sample, rounded to the
nanosecond). Values are written with 17 significant digits: a float64 reads back bit-exact; times to
±0.5 ns. ``#`` comment lines at the top say where the file came from and these conventions.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_text
from rxcomm.io.trajectory import InvalidTrajectory, Trajectory

NS = 1_000_000_000
TIME_PRECISION_S = 0.5e-9  # time_from_start is integer nanoseconds
CONVENTIONS = (
    "trajectory_msgs/msg/JointTrajectory; positions rad, velocities rad/s, accelerations rad/s^2, "
    "effort N*m = feed-forward torque tau_ff on the joint (link) side of the gearbox; "
    "time_from_start from the first sample, integer sec + nanosec"
)


def _vec(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:.17g}" for x in v) + "]"


def _time(t_s: float) -> tuple[int, int]:
    ns = round(t_s * NS)
    return ns // NS, ns % NS


def ros2_trajectory_text(traj: Trajectory, joint_names: Sequence[str], comments: Sequence[str] = ()) -> str:
    """The YAML text (written by hand, flow-style vectors, so a 10⁵-point plan writes in seconds)."""
    if len(joint_names) != traj.dof:
        raise InvalidTrajectory("joint_names", f"{len(joint_names)} names for {traj.dof} joints")
    lines = [f"# {c}" for c in (*comments, CONVENTIONS)]
    lines += [
        "header:",
        "  stamp: {sec: 0, nanosec: 0}",
        "  frame_id: ''",
        "joint_names: [" + ", ".join(f"'{n}'" for n in joint_names) + "]",
        "points:",
    ]
    t0 = traj.t[0]
    for i in range(traj.n):
        sec, nsec = _time(float(traj.t[i] - t0))
        lines += [
            f"- positions: {_vec(traj.q[i])}",
            f"  velocities: {_vec(traj.qd[i])}",
            f"  accelerations: {_vec(traj.qdd[i])}",
            f"  effort: {_vec(traj.tau_ff[i])}",
            f"  time_from_start: {{sec: {sec}, nanosec: {nsec}}}",
        ]
    return "\n".join(lines) + "\n"


def write_ros2_trajectory(
    path: str | Path, traj: Trajectory, joint_names: Sequence[str], comments: Sequence[str] = ()
) -> Path:
    return atomic_write_text(path, ros2_trajectory_text(traj, joint_names, comments))


def is_ros2_trajectory(doc: Any) -> bool:
    return isinstance(doc, dict) and "joint_names" in doc and "points" in doc and "kind" not in doc


def _column(path: Path, points: list[Any], key: str, dof: int, required: bool) -> np.ndarray:
    out = np.zeros((len(points), dof))
    for i, p in enumerate(points):
        v = p.get(key) if isinstance(p, dict) else None
        if v is None or (isinstance(v, list) and not v and not required):
            if required:
                raise InputError(f"point {i} has no {key}", file=path, field=f"points[{i}].{key}")
            continue  # an empty optional field (JointTrajectory allows it): zeros
        if not isinstance(v, list) or len(v) != dof:
            raise InputError(
                f"point {i}: {key} must list {dof} numbers (one per joint name)",
                file=path,
                field=f"points[{i}].{key}",
            )
        try:
            out[i] = [float(x) for x in v]
        except (TypeError, ValueError) as e:
            raise InputError(f"point {i}: {key}: {e}", file=path, field=f"points[{i}].{key}") from e
    return out


def read_ros2_trajectory(path: str | Path) -> tuple[Trajectory, list[str]]:
    """(trajectory, joint names) of a JointTrajectory YAML (this module's or any with the message's
    fields); velocities/accelerations/effort may be empty (zeros). InputError names point and field."""
    path = Path(path)
    try:
        doc = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except (OSError, yaml.YAMLError) as e:
        raise InputError(f"cannot read as YAML: {e}", file=path) from e
    if not is_ros2_trajectory(doc):
        raise InputError("not a JointTrajectory (no joint_names and points)", file=path)
    names, points = doc["joint_names"], doc["points"]
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise InputError("joint_names must be a list of names", file=path, field="joint_names")
    if not isinstance(points, list) or len(points) < 1:
        raise InputError("no points", file=path, field="points")
    dof = len(names)
    t = np.zeros(len(points))
    for i, p in enumerate(points):
        tfs = p.get("time_from_start") if isinstance(p, dict) else None
        if not isinstance(tfs, dict) or not {"sec", "nanosec"} <= set(tfs):
            raise InputError(
                "time_from_start must be {sec, nanosec}", file=path, field=f"points[{i}].time_from_start"
            )
        t[i] = int(tfs["sec"]) + int(tfs["nanosec"]) / NS
    q = _column(path, points, "positions", dof, True)
    qd, qdd, tau = (_column(path, points, k, dof, False) for k in ("velocities", "accelerations", "effort"))
    try:
        return Trajectory(t, q, qd, qdd, tau), list(names)
    except InvalidTrajectory as e:
        raise InputError(e.reason, file=path, field=f"points.{e.field}") from e
