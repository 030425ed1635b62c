"""From run logs with a tracker channel to the ISO 9283 criteria of one robot state.

- A **pose-cycle log** (`rxcomm.planning.iso9283.pose_cycle_waypoints` run by `run`): the dwells are
  the setpoint runs with zero commanded velocity lasting ≥ `min_dwell_s`; the attained pose of a
  dwell is the mean of the tracker samples over its last `measure_fraction` (the arm should have
  settled there: `settle_drift_m`, how far it still moved, is in the AP_p/RP_l notes);
  a dwell belongs to the test pose P1–P5 its commanded TCP (nominal FK of q_demand) is within
  `match_m` of (other dwells, such as a start pose, are ignored).
- A **path log** (one cycle of an ISO 9283 path, or n cycles with return moves and dwells between,
  `rxcomm.planning.iso9283.repeat_cycles`): each move from the path's start to its end is a cycle,
  its tracker samples the attained path; the command path is the path spec's geometry sampled at
  `n_points` points (the first and last 1 % of its length left out: the arm starts and stops
  there); the command speed is the speed of the nominal FK of q_demand, the attained one the
  tracker's.

Poses are mapped from the tracker frame into the robot base frame with `base_in_tracker` (the
nominal base placement the calibration and the controller's model refer to).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from rxcomm.acceptance.alignment import velocity_on_grid
from rxcomm.acceptance.criteria import (
    corner_overshoot,
    path_criteria,
    pose_criteria,
    velocity_criteria,
)
from rxcomm.errors import InputError
from rxcomm.io.run_log import read_run_log
from rxcomm.model.kinematics import frame_placement
from rxcomm.model.robot import Robot
from rxcomm.planning.iso9283 import Iso9283Cube, cube_from_rectangle
from rxcomm.planning.paths import build_curve, rpy_matrix
from rxcomm.schemas.iso9283 import CRITERIA_UNITS, POSES, Criterion, EvaluationSettings
from rxcomm.schemas.path import PathSpec
from rxcomm.schemas.run_log import TRACKER_TOPIC

COMMAND_SPEED_STEP_S = 0.004  # s between the FK samples of the command speed


@dataclass(frozen=True)
class TrackedLog:
    """A run log's joints and its tracker samples in the robot base frame."""

    name: str
    t_joint: np.ndarray
    q_demand: np.ndarray
    t: np.ndarray  # tracker samples on the joint log's time axis
    position_m: np.ndarray  # [k, 3] base frame
    rotation: np.ndarray | None  # [k, 3, 3] base frame (None: position-only tracker)


def tracked_log(path: str | Path, base_in_tracker: pin.SE3) -> TrackedLog:
    """Read a run log with a ``/run/tracker`` channel; InputError when it has none."""
    path = Path(path)
    log = read_run_log(path, fields=("q_demand",))
    tr = log.tracker
    if tr is None or len(tr) < 2:
        raise InputError(
            "no tracker samples: run it on a cell whose tracker measures during motion, or import a "
            "tracker CSV (docs/tracker-csv.md)",
            file=path,
            field=TRACKER_TOPIC,
        )
    r_tb, t_tb = base_in_tracker.rotation, base_in_tracker.translation
    p = (np.asarray(tr.position_m) - t_tb) @ r_tb  # R_tbᵀ (p − t_tb), row-wise
    quat = np.asarray(tr.quaternion_wxyz, dtype=float)
    rot = None
    if np.all(np.isfinite(quat)):
        rot = r_tb.T @ Rotation.from_quat(quat[:, [1, 2, 3, 0]]).as_matrix()
    return TrackedLog(
        path.name, np.asarray(log.joints.t), np.asarray(log.joints.q_demand), np.asarray(tr.t), p, rot
    )


def _fk(robot: Robot, qs: np.ndarray) -> np.ndarray:
    data = robot.create_data()
    return np.array([frame_placement(robot, data, q, robot.tcp_frame_id).translation for q in qs])


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index runs where `mask` is True."""
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def settle_drift_m(position_m: np.ndarray) -> float:
    """How far the arm still moved across a dwell's measuring window: the distance between the means
    of its first and its last fifth of tracker samples (a steady drift of d reads 0.8·d; the means
    keep the tracker's noise out). ISO 9283 measures a settled arm: a drift near the RP it reports
    says the dwell is too short."""
    p = np.asarray(position_m, float)
    n = max(1, len(p) // 5)
    return float(np.linalg.norm(p[-n:].mean(axis=0) - p[:n].mean(axis=0)))


def pose_dwells_s(log: TrackedLog, s: EvaluationSettings) -> list[float]:
    """The durations of a pose-cycle log's dwells (zero commanded velocity ≥ `min_dwell_s`), s: the
    test condition ISO 9283 asks a report to state (the measuring window is their last
    `measure_fraction`). The plan's first dwell counts too: it is a dwell at P1 like the others."""
    dt = float(np.median(np.diff(log.t_joint)))
    still = np.all(np.abs(np.diff(log.q_demand, axis=0)) < 1e-12, axis=1)
    return [(b - a) * dt for a, b in _runs(still) if (b - a) * dt >= s.min_dwell_s]


def attained_poses(
    robot: Robot, log: TrackedLog, points_m: Mapping[str, np.ndarray], s: EvaluationSettings
) -> dict[str, tuple[np.ndarray, np.ndarray | None, np.ndarray]]:
    """Per test pose: the attained positions [n, 3] and rotations [n, 3, 3] (or None) of its dwells,
    and each dwell's `settle_drift_m` [n]."""
    dt = float(np.median(np.diff(log.t_joint)))
    still = np.all(np.abs(np.diff(log.q_demand, axis=0)) < 1e-12, axis=1)
    runs = [(a, b) for a, b in _runs(still) if (b - a) * dt >= s.min_dwell_s]
    if s.skip_first_dwell:
        runs = runs[1:]
    if not runs:
        return {}
    cmd = _fk(robot, np.array([log.q_demand[a] for a, _ in runs]))
    names = list(points_m)
    pts = np.array([points_m[k] for k in names])
    out: dict[str, tuple[list, list, list]] = {}
    for (a, b), c in zip(runs, cmd, strict=True):
        d = np.linalg.norm(pts - c, axis=1)
        i = int(np.argmin(d))
        if d[i] > s.match_m:
            continue
        t0, t1 = log.t_joint[a], log.t_joint[min(b, len(log.t_joint) - 1)]
        sel = (log.t >= t1 - s.measure_fraction * (t1 - t0)) & (log.t <= t1)
        if not sel.any():
            continue
        pos, rots, drift = out.setdefault(names[i], ([], [], []))
        pos.append(log.position_m[sel].mean(axis=0))
        drift.append(settle_drift_m(log.position_m[sel]))
        if log.rotation is not None:
            rots.append(Rotation.from_matrix(log.rotation[sel]).mean().as_matrix())
    return {
        k: (np.array(p), np.array(r) if log.rotation is not None and r else None, np.array(d))
        for k, (p, r, d) in out.items()
    }


@dataclass(frozen=True)
class PathCycle:
    position_m: np.ndarray  # attained path (tracker, base frame)
    speed_m_per_s: np.ndarray  # attained speed at the samples
    command_speed_m_per_s: np.ndarray  # nominal FK(q_demand) speed at the same instants


def path_cycles(robot: Robot, log: TrackedLog, spec: PathSpec, s: EvaluationSettings) -> list[PathCycle]:
    """The cycles of a test path in one log: each move between dwells (zero commanded velocity for
    ≥ `min_dwell_s`, or the log's ends) whose command TCP starts within `match_m` of the path's start,
    ends within it of the path's end and travels at least half the path's length (a return move the
    other way is not a cycle, nor, on a closed path such as a circle, the few setpoints of a return
    move that is a rounding step between two dwells). A log of one path run is one cycle."""
    dt = float(np.median(np.diff(log.t_joint)))
    # the command speed from FK every ~COMMAND_SPEED_STEP_S: it is smooth, and FK of every setpoint
    # of a campaign would be most of its time
    step = max(1, int(round(COMMAND_SPEED_STEP_S / dt)))
    idx = np.unique(np.append(np.arange(0, len(log.t_joint), step), len(log.t_joint) - 1))
    p_cmd = _fk(robot, log.q_demand[idx])
    v_cmd_grid = np.linalg.norm(np.gradient(p_cmd, log.t_joint[idx], axis=0), axis=1)
    curve = build_curve(spec.geometry)
    start, end = curve.eval(np.array([0.0]), 0)[0], curve.eval(np.array([curve.length_m]), 0)[0]
    still = np.all(np.abs(np.diff(log.q_demand, axis=0)) < 1e-12, axis=1)
    dwells = [(a, b) for a, b in _runs(still) if (b - a) * dt >= s.min_dwell_s]
    bounds = [0, *(i for a, b in dwells for i in (a, b)), len(log.t_joint) - 1]
    v_att_all = np.linalg.norm(velocity_on_grid(log.t, log.position_m, log.t, s.velocity_window_s), axis=1)
    out = []
    for a, b in zip(bounds[::2], bounds[1::2], strict=True):
        if b <= a:
            continue
        ends = _fk(robot, log.q_demand[[a, b]])
        if np.linalg.norm(ends[0] - start) > s.match_m or np.linalg.norm(ends[1] - end) > s.match_m:
            continue
        on = (idx >= a) & (idx <= b)
        if np.sum(np.linalg.norm(np.diff(p_cmd[on], axis=0), axis=1)) < 0.5 * curve.length_m:
            continue
        sel = (log.t >= log.t_joint[a]) & (log.t <= log.t_joint[b])
        t = log.t[sel]
        out.append(PathCycle(log.position_m[sel], v_att_all[sel], np.interp(t, log.t_joint[idx], v_cmd_grid)))
    return out


def command_path(spec: PathSpec, n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(points [m, 3], unit tangents [m, 3], a dense polyline of the whole path, length m)."""
    curve = build_curve(spec.geometry)
    length = float(curve.length_m)
    sv = np.linspace(0.01, 0.99, n_points) * length
    pts, tan = curve.eval(sv, 0), curve.eval(sv, 1)
    dense = curve.eval(np.linspace(0.0, length, max(200, int(length / 1e-3))), 0)
    return pts, tan / np.linalg.norm(tan, axis=1, keepdims=True), dense, length


def _criterion(key: str, target: str, value, n, speed, log, note: str = "") -> Criterion:
    v = None if value is None else float(value)
    return Criterion(
        key=key,
        target=target,
        value=v,
        unit=CRITERIA_UNITS[key],
        cycles=n,
        command_speed_m_per_s=speed,
        log=log,
        note=note,
    )


def pose_entries(
    robot: Robot,
    logs: Sequence[TrackedLog],
    points_m: Mapping[str, np.ndarray],
    rot_cmd: np.ndarray,
    s: EvaluationSettings,
) -> list[Criterion]:
    """AP_p, AP_a/b/c, RP_l, RP_a/b/c at P1–P5 from pose-cycle logs ("not measured" without)."""
    merged: dict[str, tuple[list, list, list]] = {}
    names = ",".join(lg.name for lg in logs) or None
    for lg in logs:
        for k, (p, r, d) in attained_poses(robot, lg, points_m, s).items():
            mp, mr, md = merged.setdefault(k, ([], [], []))
            mp.extend(p)
            mr.extend([] if r is None else r)
            md.extend(d)
    out: list[Criterion] = []
    for name in POSES:
        if name not in merged:
            why = "no pose-cycle log" if not logs else f"no dwell at {name} in the logs"
            out += [_criterion(k, name, None, None, None, names, why) for k in _POSE_KEYS]
            continue
        p, r, drift = merged[name]
        rot = np.array(r) if len(r) == len(p) else None
        settle = f"settling: the arm moved up to {1e3 * max(drift):.3g} mm across a measuring window"
        c = pose_criteria(np.array(p), points_m[name], rot, rot_cmd if rot is not None else None)
        few = "" if c.n >= 2 else "one cycle: no standard deviation"
        abc = [None] * 3 if c.AP_abc is None else list(c.AP_abc)
        rabc = [None] * 3 if c.RP_abc is None else list(c.RP_abc)
        vals = {"AP_p": c.AP_p, "RP_l": c.RP_l, "AP_a": abc[0], "AP_b": abc[1], "AP_c": abc[2]}
        vals |= {"RP_a": rabc[0], "RP_b": rabc[1], "RP_c": rabc[2]}
        for k in _POSE_KEYS:
            note = few if vals[k] is None and k.startswith("RP") else ""
            note = note or (settle if k in ("AP_p", "RP_l") else "")
            if vals[k] is None and k[-1] in "abc" and rot is None:
                note = "position-only tracker data"
            out.append(_criterion(k, name, vals[k], c.n, None, names, note))
    return out


_POSE_KEYS = ("AP_p", "AP_a", "AP_b", "AP_c", "RP_l", "RP_a", "RP_b", "RP_c")


SPEED_GROUP_TOLERANCE = 0.05  # cycles whose command speeds differ by less are one speed of a path test


def speed_groups(speeds: Sequence[float]) -> list[list[int]]:
    """Indices of cycles grouped by command speed (ISO 9283 tests a path at 100, 50 and 10 % of the
    rated speed): sorted, a new group where a speed exceeds the group's first by more than
    `SPEED_GROUP_TOLERANCE`; fastest group first."""
    order = sorted(range(len(speeds)), key=lambda i: -speeds[i])
    groups: list[list[int]] = []
    for i in order:
        if groups and speeds[groups[-1][0]] - speeds[i] <= SPEED_GROUP_TOLERANCE * speeds[groups[-1][0]]:
            groups[-1].append(i)
        else:
            groups.append([i])
    return groups


def _plateau_speed(c: PathCycle, plateau: float = 0.98) -> float:
    v = c.command_speed_m_per_s
    return float(np.median(v[v >= plateau * np.max(v)]))


def path_entries(
    robot: Robot, target: str, spec: PathSpec | None, logs: Sequence[TrackedLog], s: EvaluationSettings
) -> list[Criterion]:
    """AT_p, RT_p, AV, RV (and CO on the rectangle) of one test path from its cycles' logs, one set
    per command speed the cycles ran at (`speed_groups`)."""
    keys = ["AT_p", "RT_p", "AV", "RV"] + (["CO"] if target == "iso9283-rectangle" else [])
    names = ",".join(lg.name for lg in logs) or None
    if not logs or spec is None:
        why = "no path log" if not logs else "no path spec"
        return [_criterion(k, target, None, None, None, names, why) for k in keys]
    cycles = [c for lg in logs for c in path_cycles(robot, lg, spec, s)]
    if not cycles:
        why = f"no move from the path's start to its end (within {s.match_m} m) in the logs"
        return [_criterion(k, target, None, None, None, names, why) for k in keys]
    pts, tan, dense, _ = command_path(spec, s.n_points)
    out = []
    for group in speed_groups([_plateau_speed(c) for c in cycles]):
        cyc = [cycles[i] for i in group]
        pc = path_criteria(pts, tan, [c.position_m for c in cyc])
        vc = velocity_criteria([c.speed_m_per_s for c in cyc], [c.command_speed_m_per_s for c in cyc])
        n, v = len(cyc), vc.command_speed_m_per_s
        few = "one cycle: no standard deviation"
        out += [
            _criterion("AT_p", target, pc.AT_p, n, v, names),
            _criterion("RT_p", target, pc.RT_p, n, v, names, few if pc.RT_p is None else ""),
            _criterion("AV", target, vc.AV, n, v, names),
            _criterion("RV", target, vc.RV, n, v, names, few if vc.RV is None else ""),
        ]
        if "CO" in keys:
            corners = np.asarray(spec.geometry.points_m[1:-1], dtype=float)  # P3, P4, P5
            nxt = np.diff(np.asarray(spec.geometry.points_m[1:], dtype=float), axis=0)
            co, _ = corner_overshoot(dense, corners, nxt, [c.position_m for c in cyc], s.corner_zone_m)
            out.append(_criterion("CO", target, co, n, v, names))
    return out


PATH_TARGETS = ("iso9283-line", "iso9283-circle-large", "iso9283-circle-small", "iso9283-rectangle")


@dataclass(frozen=True)
class Conditions:
    """What the logs say about how the tests ran: the pose test's median dwell and measuring window
    (None without a pose log)."""

    pose_dwell_s: float | None
    measuring_window_s: float | None


def evaluate(
    robot: Robot,
    specs: Mapping[str, PathSpec],
    base_in_tracker: pin.SE3,
    pose_logs: Sequence[str | Path],
    path_logs: Mapping[str, Sequence[str | Path]],
    settings: EvaluationSettings | None = None,
) -> tuple[Iso9283Cube, list[Criterion], Conditions]:
    """Every criterion of one robot state: the test cube (from the `iso9283-rectangle` spec), the
    entries at P1–P5 and on each test path (logs not given are "not measured") and the test
    conditions the logs show."""
    s = settings or EvaluationSettings()
    if "iso9283-rectangle" not in specs:
        raise InputError(
            "the ISO 9283 path specs need iso9283-rectangle (it defines the cube)", field="paths"
        )
    cube = cube_from_rectangle(specs["iso9283-rectangle"])
    rot_cmd = rpy_matrix(cube.rpy_rad)
    poses = [tracked_log(p, base_in_tracker) for p in pose_logs]
    out = pose_entries(robot, poses, cube.points_m, rot_cmd, s)
    for target in PATH_TARGETS:
        logs = [tracked_log(p, base_in_tracker) for p in path_logs.get(target, ())]
        out += path_entries(robot, target, specs.get(target), logs, s)
    dwells = [d for lg in poses for d in pose_dwells_s(lg, s)]
    dwell = float(np.median(dwells)) if dwells else None
    window = None if dwell is None else s.measure_fraction * dwell
    return cube, out, Conditions(dwell, window)
