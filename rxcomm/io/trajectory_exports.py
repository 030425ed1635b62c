"""Trajectory and run-log exports beside the CSV: the ROS 2 ``JointTrajectory`` YAML and the ROS 2 bag,
and each export's re-read figure: the written file read back by a reader that is not the writer
(PyYAML for the YAML, Python's csv module for the CSV, ``mcap-ros2-support``'s CDR decoder for the
bag) and compared sample by sample with the source. Each call returns its summary (what, the file,
the re-read figure) for `rxcomm export`'s console and parity table.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rxcomm.errors import InputError
from rxcomm.io.csv_export import comment_lines, csv_joint_names, write_trajectory_csv
from rxcomm.io.mcap_io import read_mcap
from rxcomm.io.ros2_bag import NS, BagWriter, read_bag, stamps_ns
from rxcomm.io.ros2_trajectory import TIME_PRECISION_S, write_ros2_trajectory
from rxcomm.io.trajectory import TOPIC, Trajectory, load_trajectory_named
from rxcomm.schemas.plain import sha256_file
from rxcomm.schemas.run_log import TRACKER_TOPIC

FIELDS = ("q", "qd", "qdd", "tau_ff")


def _max_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)), initial=0.0))


def _source(source: Path) -> tuple[Trajectory, dict[str, Any], list[str], list[str]]:
    traj, env, names = load_trajectory_named(source)
    names = names or [f"joint{j + 1}" for j in range(traj.dof)]
    return traj, env, names, comment_lines(env, source, sha256_file(source))


def _reread(reader: str, values: float, time_s: float, precision: str) -> dict[str, Any]:
    return {
        "reader": reader,
        "max_value_difference": values,
        "max_time_difference_s": time_s,
        "precision": precision,
        "exact": values == 0.0 and time_s == 0.0,
    }


def export_trajectory_csv(source: str | Path, out: str | Path) -> dict[str, Any]:
    """A trajectory MCAP as the controller CSV; re-read with Python's csv module."""
    source, out = Path(source), Path(out)
    traj, _, names, comments = _source(source)
    write_trajectory_csv(out, traj, names, comments)
    with out.open(newline="") as f:
        rows = list(csv.reader(line for line in f if not line.startswith("#")))
    header, body = rows[0], np.array([[float(x) for x in r] for r in rows[1:]])
    if csv_joint_names(header) != names or body.shape != (traj.n, 1 + 4 * traj.dof):
        raise InputError(f"re-read {body.shape} with joints {csv_joint_names(header)}", file=out)
    ref = np.column_stack([traj.t, *(getattr(traj, f) for f in FIELDS)])
    d = _max_diff(body[:, 1:], ref[:, 1:])
    return {"re-read": _reread("python csv", d, _max_diff(body[:, 0], traj.t), "bit-exact (17 digits)")}


def export_trajectory_ros2(source: str | Path, out: str | Path) -> dict[str, Any]:
    """A trajectory MCAP as a JointTrajectory YAML; re-read by PyYAML's libyaml parser (times ±0.5 ns)."""
    source, out = Path(source), Path(out)
    traj, _, names, comments = _source(source)
    write_ros2_trajectory(out, traj, names, comments)
    doc = yaml.load(out.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    pts = doc["points"]
    if doc["joint_names"] != names or len(pts) != traj.n:
        raise InputError(f"re-read {len(pts)} points for joints {doc['joint_names']}", file=out)
    keys = ("positions", "velocities", "accelerations", "effort")
    back = {k: np.array([p[k] for p in pts], dtype=float) for k in keys}
    t = np.array([p["time_from_start"]["sec"] + p["time_from_start"]["nanosec"] / NS for p in pts])
    d = max(_max_diff(back[k], getattr(traj, f)) for k, f in zip(keys, FIELDS, strict=True))
    dt = _max_diff(t, traj.t - traj.t[0])
    precision = f"values bit-exact (17 digits); time_from_start integer ns (±{TIME_PRECISION_S * 1e9:g} ns)"
    return {"re-read": _reread("PyYAML (libyaml)", d, dt, precision)}


def _bag_check(
    out: Path, topic: str, names: list[str], stamps: np.ndarray, position: np.ndarray
) -> dict[str, Any]:
    msgs = [(ns, m) for tp, ns, m in read_bag(out) if tp == topic]
    if len(msgs) != len(stamps) or any(list(m.name) != names for _, m in msgs):
        raise InputError(f"re-read {len(msgs)} {topic} messages, wrote {len(stamps)}", file=out)
    st = np.array([m.header.stamp.sec * NS + m.header.stamp.nanosec for _, m in msgs], dtype=np.int64)
    pos = np.array([list(m.position) for _, m in msgs])
    dt = float(np.max(np.abs(st - stamps), initial=0)) / NS
    return _reread(
        "mcap-ros2-support (CDR)", _max_diff(pos, position), dt, "bit-exact (float64, stamps in ns)"
    )


def export_trajectory_bag(source: str | Path, out: str | Path) -> dict[str, Any]:
    """A trajectory MCAP as a ROS 2 bag: /joint_states, planned q, q̇, τ_ff, stamped as the plan."""
    source, out = Path(source), Path(out)
    contents = read_mcap(source, topics=[TOPIC])
    traj, _, names, _ = _source(source)
    stamps = stamps_ns(contents.time_origin_ns, traj.t)
    bag = BagWriter()
    bag.joint_states("/joint_states", stamps, names, traj.q, traj.qd, traj.tau_ff)
    bag.finish(out)
    return {"topics": bag.counts, "re-read": _bag_check(out, "/joint_states", names, stamps, traj.q)}


def export_run_log_bag(
    source: str | Path,
    out: str | Path,
    tracker_in_root: tuple[str, Sequence[float], Sequence[float]] | None = None,
) -> dict[str, Any]:
    """A run log as a ROS 2 bag (module docstring of `rxcomm.io.ros2_bag`); ``tracker_in_root``
    (root link name, xyz m, quaternion wxyz): the tracker frame for /tf_static."""
    source, out = Path(source), Path(out)
    from rxcomm.io.run_log import read_run_log

    log = read_run_log(source)  # what a run log is, checked
    origin = read_mcap(source, topics=[TRACKER_TOPIC]).time_origin_ns
    j = log.joints
    names = list(j.constants.get("joint_names") or [f"joint{k + 1}" for k in range(j.q_actual.shape[1])])
    stamps = stamps_ns(origin, j.t)
    bag = BagWriter()
    if tracker_in_root is not None:
        root, xyz, wxyz = tracker_in_root
        bag.static_transform(int(stamps[0]), root, "tracker", xyz, wxyz)
    bag.joint_states("/joint_states", stamps, names, j.q_actual, None, j.tau_actual)
    bag.joint_states("/joint_states_demand", stamps, names, j.q_demand, j.qd_demand, j.tau_ff)
    if log.tracker is not None and len(log.tracker):
        tr = log.tracker
        bag.poses("/tracker/tcp_pose", stamps_ns(origin, tr.t), "tracker", tr.position_m, tr.quaternion_wxyz)
    bag.finish(out)
    return {"topics": bag.counts, "re-read": _bag_check(out, "/joint_states", names, stamps, j.q_actual)}


def export_run_log_csv(source: str | Path, out: str | Path) -> dict[str, Any]:
    """A run log's /run/joints as CSV (`rxcomm.io.csv_export`); re-read with Python's csv module,
    every column against its field (an empty cell is a value not measured, NaN in the log)."""
    from rxcomm.io.csv_export import export_run_log_csv as write
    from rxcomm.io.run_log import read_run_log

    source, out = Path(source), Path(out)
    write(source, out)
    j = read_run_log(source).joints
    from rxcomm.schemas.run_log import JOINT_FIELDS

    cols = [j.fields[k] for k in JOINT_FIELDS if k in j.fields]  # the CSV's column order
    ref = [j.t] + [c[:, None] if c.ndim == 1 else c for c in cols]
    ref_table = np.column_stack(ref)
    with out.open(newline="") as f:
        rows = list(csv.reader(line for line in f if not line.startswith("#")))
    body = np.array([[float(x) if x else np.nan for x in r] for r in rows[1:]])
    if body.shape != ref_table.shape:
        raise InputError(f"re-read {body.shape}, the log has {ref_table.shape}", file=out)
    both = np.isfinite(body) & np.isfinite(ref_table)
    if not np.array_equal(np.isfinite(body), np.isfinite(ref_table)):
        raise InputError("re-read: a cell empty in one and not the other", file=out)
    d = _max_diff(body[:, 1:][both[:, 1:]], ref_table[:, 1:][both[:, 1:]])
    return {"re-read": _reread("python csv", d, _max_diff(body[:, 0], j.t), "bit-exact (17 digits)")}
