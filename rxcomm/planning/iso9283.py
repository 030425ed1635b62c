"""The ISO 9283 test cube and its test-plane paths (paper §4; ISO 9283:1998 §6.8, §7, §8).

`iso9283_cube` finds the largest cube (edges parallel to the base axes) the TCP reaches on one IK branch
away from singularities; `iso9283_paths` lays the standard's line, rectangle and circles in the cube's
inclined test plane as path specs; `pose_cycle_trajectory` is the pose test's plan through P1–P5
(`pose_cycle_joints`), each move timed by a caller's policy (`cycloidal_move`: joint limits only).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.errors import InfeasibleError, InputError
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.kinematics import BranchSelector, solve_branch_ik
from rxcomm.model.robot import Robot
from rxcomm.planning.path_ik import solve_path_ik
from rxcomm.planning.paths import build_path, rpy_matrix, unit_vector
from rxcomm.schemas.cell import Box
from rxcomm.schemas.path import Branch, Orientation, PathLimits, PathSpec


@dataclass(frozen=True)
class Iso9283Cube:
    """The test cube (base frame) and the points of its inclined test plane."""

    centre_m: np.ndarray
    side_m: float
    rpy_rad: tuple[float, float, float]
    plane_corners_m: np.ndarray  # [4, 3]: near-bottom left/right, far-top right/left
    points_m: dict[str, np.ndarray]  # P1..P5

    @property
    def corners_m(self) -> np.ndarray:
        h = self.side_m / 2
        signs = np.array([[sx, sy, sz] for sz in (-1, 1) for sy in (-1, 1) for sx in (-1, 1)])
        return self.centre_m + h * signs


def _cube_geometry(centre: np.ndarray, side: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Inclined plane through the bottom edge nearest the robot (−x) and the top edge farthest (+x).

    The direction "away from the robot" is the cube centre's direction from the J1 axis (x when on it).
    """
    h = side / 2
    radial = np.array([centre[0], centre[1], 0.0])
    ex = unit_vector(radial) if np.linalg.norm(radial) > 1e-9 else np.array([1.0, 0, 0])
    # Cube edges stay parallel to the base axes (ISO); pick the axis closest to the radial direction.
    ax = int(np.argmax(np.abs(ex[:2])))
    fwd = np.zeros(3)
    fwd[ax] = np.sign(ex[ax])
    side_dir = np.cross([0, 0, 1.0], fwd)
    up = np.array([0, 0, 1.0])
    a = centre - h * fwd - h * side_dir - h * up
    b = centre - h * fwd + h * side_dir - h * up
    c = centre + h * fwd + h * side_dir + h * up
    d = centre + h * fwd - h * side_dir + h * up
    corners = np.array([a, b, c, d])
    pts = {
        "P1": centre.copy(),
        "P2": a + 0.1 * (c - a),
        "P3": b + 0.1 * (d - b),
        "P4": c + 0.1 * (a - c),
        "P5": d + 0.1 * (b - d),
    }
    return corners, pts


def iso9283_cube(
    robot: Robot,
    rpy_rad: Sequence[float] = (np.pi, 0.0, 0.0),
    branch: Branch | None = None,
    workspace: Box | None = None,
    *,
    sigma_min_margin: float = 0.02,
    path_sigma_min: float = 0.05,
    radii_m: Sequence[float] | None = None,
    heights_m: Sequence[float] | None = None,
) -> Iso9283Cube:
    """The largest test cube (edges parallel to the base axes, centred on the base x axis) whose 27
    lattice points (corners, edge midpoints, face centres, centre) the TCP reaches with orientation
    `rpy_rad` on the IK `branch`, with the TCP Jacobian's smallest singular value ≥ `sigma_min_margin`
    and inside `workspace` when given, and whose test paths keep ≥ `path_sigma_min` (`paths_side`).
    Grid over centre radius and height, bisection on the side.
    """

    branch = branch or Branch()
    rot = rpy_matrix(rpy_rad)
    selector = BranchSelector(robot, branch)
    data = robot.create_data()
    reach = robot.reach_m
    radii = np.linspace(0.35, 0.75, 7) * reach if radii_m is None else np.asarray(radii_m)
    shoulder = robot.shoulder_height_m
    heights = shoulder + np.linspace(-0.5, 0.3, 7) * reach if heights_m is None else np.asarray(heights_m)
    lattice = np.array([[i, j, k] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], float)

    def reach_point(p: np.ndarray, q_from: np.ndarray, p_from: np.ndarray) -> np.ndarray | None:
        """IK of p on the branch by continuation from a solved point, in steps of ≤ 5 cm."""
        n = max(1, int(np.ceil(np.linalg.norm(p - p_from) / 0.05)))
        q = q_from
        for k in range(1, n + 1):
            res = solve_branch_ik(robot, data, pin.SE3(rot, p_from + (p - p_from) * k / n), selector, seed=q)
            if not res.ok:
                return None
            q = res.q
        return q

    def feasible(centre: np.ndarray, side: float, q_centre: np.ndarray) -> bool:
        pts = centre + side / 2 * lattice
        if workspace is not None and (
            np.any(pts < np.asarray(workspace.min_m)) or np.any(pts > np.asarray(workspace.max_m))
        ):
            return False
        for p in pts:
            q = reach_point(p, q_centre, centre)
            if q is None or selector.sigma_min(data, q) < sigma_min_margin:
                return False
        return True

    def paths_side(centre: np.ndarray, side: float, floor: float) -> float | None:
        """The largest side ≤ `side` (and > `floor`) whose test paths the path IK follows on the
        branch with σ_min ≥ `path_sigma_min`: the lattice points can all be clear while a path
        between them crosses a singularity (a UR-type arm's wrist, whose J6 lines up with J2–J4).
        That margin is 10× the planners': at σ_min 0.024 a line ended 2° from the wrist
        singularity, where a calibration turned J4 and J6 by 0.09 rad for the same TCP pose (the
        samples' paths keep ≥ 0.127)."""
        while side > max(floor, 0.05):
            cube = Iso9283Cube(centre, side, tuple(float(a) for a in rpy_rad), *_cube_geometry(centre, side))
            if all(_path_clear(robot, spec, path_sigma_min) for spec in iso9283_paths(cube, branch).values()):
                return side
            side *= 0.85
        return None

    best: tuple[float, np.ndarray] | None = None
    for r in radii:
        for z in heights:
            centre = np.array([r, 0.0, z])
            res = solve_branch_ik(robot, data, pin.SE3(rot, centre), selector, n_starts=32)
            q_c = res.q
            if not res.ok or selector.sigma_min(data, q_c) < sigma_min_margin:
                continue
            lo = 0.0 if best is None else best[0]
            if lo > 0 and not feasible(centre, lo, q_c):
                continue
            hi = 2 * reach
            for _ in range(14):
                mid = (lo + hi) / 2
                if feasible(centre, mid, q_c):
                    lo = mid
                else:
                    hi = mid
                if hi - lo < 5e-3:
                    break
            if best is None or lo > best[0]:
                side = paths_side(centre, lo, 0.0 if best is None else best[0])
                if side is not None:
                    best = (side, centre)
    if best is None or best[0] < 0.05:
        raise InputError(
            f"no test cube found with rpy {list(np.round(rpy_rad, 4))} on branch {branch.model_dump()}: "
            "the TCP cannot reach the search region with this orientation",
            field="rpy_rad",
        )
    side = float(np.floor(best[0] * 100) / 100)  # whole centimetres, a little inside the limit
    corners, pts = _cube_geometry(best[1], side)
    return Iso9283Cube(best[1], side, tuple(float(a) for a in rpy_rad), corners, pts)


def iso9283_cube_any_branch(
    robot: Robot, rpy_rad: Sequence[float] = (np.pi, 0.0, 0.0), workspace: Box | None = None
) -> tuple[Iso9283Cube, Branch]:
    """`iso9283_cube` on the default branch (front, elbow up, wrist positive) or, where that reaches no
    cube, the largest over the other seven: an arm whose wrist is built the other way round (the
    wrist-positive label is geometric) has its test cube only there. Where none does, the largest with
    the wrist label left out (either): an arm whose wrist turns the tool sideways by a yaw joint (MuJoCo
    Menagerie's WidowX AI: J5 ±90° across J4) holds the orientation across the cube's width only by
    yawing that joint through 0, so each wrist label reaches half the cube and neither the whole."""
    try:
        return iso9283_cube(robot, rpy_rad, Branch(), workspace), Branch()
    except InputError as first:

        def largest(wrists: tuple[str | None, ...]) -> list[tuple[Iso9283Cube, Branch]]:
            found = []
            for shoulder, elbow, wrist in itertools.product(("front", "back"), ("up", "down"), wrists):
                branch = Branch(shoulder=shoulder, elbow=elbow, wrist=wrist)
                if branch == Branch():
                    continue
                try:
                    found.append((iso9283_cube(robot, rpy_rad, branch, workspace), branch))
                except InputError:
                    continue
            return found

        found = largest(("positive", "negative")) or largest((None,))
        if not found:
            raise InputError(
                f"no test cube found with rpy {list(np.round(rpy_rad, 4))} on any IK branch: the TCP "
                "cannot reach the search region with this orientation",
                field="rpy_rad",
            ) from first
        return max(found, key=lambda cb: cb[0].side_m)


# How far a label's quantity (`BranchSelector.label_quantities`) must stay from its sign change along
# the test paths for the label to be written: 5× the 3.7 mrad a calibration moved the ARX L5's J5.
LABEL_MARGIN_RAD = 0.02


def calibration_safe_branch(robot: Robot, cube: Iso9283Cube, branch: Branch) -> Branch:
    """`branch` without the labels the cube's test paths (followed on `robot`, the nominal model) come
    within `LABEL_MARGIN_RAD` of flipping: there the label tells no two solutions apart, and a
    calibration's few mrad read the same configuration as the other label, so every planner refused
    the path on it (MuJoCo Menagerie's ARX L5, tool forward: its yaw wrist holds J5 at 0 along the
    whole test plane). A label left out means either (`Branch`)."""
    selector = BranchSelector(robot, branch)
    data = robot.create_data()
    margin = dict.fromkeys(("shoulder", "elbow", "wrist"), np.inf)
    for spec in iso9283_paths(cube, branch).values():
        for q in solve_path_ik(robot, build_path(spec), branch).q:
            for k, v in selector.label_quantities(data, q).items():
                margin[k] = min(margin[k], abs(v))
    return branch.model_copy(update={k: None for k, m in margin.items() if m < LABEL_MARGIN_RAD})


def _path_clear(robot: Robot, spec: PathSpec, sigma_min_margin: float) -> bool:
    try:
        solve_path_ik(robot, build_path(spec), spec.branch, sigma_min_margin=sigma_min_margin)
    except (InfeasibleError, InputError):
        return False
    return True


def iso9283_paths(
    cube: Iso9283Cube,
    branch: Branch | None = None,
    limits: PathLimits | None = None,
    large_circle_diameter_ratio: float = 0.8,
    small_circle_diameter_ratio: float = 0.1,
    corner_blend_m: float | None = None,
) -> dict[str, PathSpec]:
    """The ISO 9283 test-plane paths of a cube as path specs, by file stem:
    `iso9283-line` (P2→P4), `iso9283-rectangle` (P2-P3-P4-P5-P2, corners blended), `iso9283-circle-large`
    and `iso9283-circle-small` (about P1 in the test plane, starting towards P3−P2)."""
    branch = branch or Branch()
    limits = limits or PathLimits()
    p = {k: [round(float(x), 6) for x in v] for k, v in cube.points_m.items()}
    if corner_blend_m is None:  # 5 cm, or a quarter of the shortest edge on a small cube
        edge = min(np.linalg.norm(np.subtract(p[a], p[b])) for a, b in (("P2", "P3"), ("P3", "P4")))
        corner_blend_m = round(min(0.05, 0.25 * float(edge)), 4)
    c = cube.plane_corners_m
    normal = unit_vector(np.cross(c[1] - c[0], c[3] - c[0]))
    along = unit_vector(c[1] - c[0])
    orient = Orientation(mode="hold", rpy_rad=tuple(round(a, 12) for a in cube.rpy_rad))
    where = (
        f"ISO 9283 test plane of a {cube.side_m:.2f} m cube centred at "
        f"{[round(float(x), 3) for x in cube.centre_m]} m (base frame)"
    )
    common = dict(kind="rxcomm/Path", schema_version=1, orientation=orient, branch=branch, limits=limits)

    def circle(ratio: float) -> dict:
        return dict(
            type="circle",
            centre_m=p["P1"],
            normal=[round(float(x), 9) for x in normal],
            radius_m=round(ratio * cube.side_m / 2, 6),
            start_direction=[round(float(x), 9) for x in along],
            sweep_rad=2 * np.pi,
        )

    return {
        "iso9283-line": PathSpec(
            name="iso9283-line",
            description=f"Diagonal line P2→P4 of the {where}.",
            geometry={"type": "line", "start_m": p["P2"], "end_m": p["P4"]},
            **common,
        ),
        "iso9283-rectangle": PathSpec(
            name="iso9283-rectangle",
            description=f"Rectangle P2-P3-P4-P5-P2 of the {where}; corners blended ({corner_blend_m} m).",
            geometry={
                "type": "polyline",
                "points_m": [p["P2"], p["P3"], p["P4"], p["P5"], p["P2"]],
                "blend_radius_m": corner_blend_m,
            },
            **common,
        ),
        "iso9283-circle-large": PathSpec(
            name="iso9283-circle-large",
            description=f"Large circle (diameter {large_circle_diameter_ratio:.0%} of the edge) about P1, "
            f"{where}.",
            geometry=circle(large_circle_diameter_ratio),
            **common,
        ),
        "iso9283-circle-small": PathSpec(
            name="iso9283-circle-small",
            description=f"Small circle (diameter {small_circle_diameter_ratio:.0%} of the edge) about P1, "
            f"{where}.",
            geometry=circle(small_circle_diameter_ratio),
            **common,
        ),
    }


# --- the pose cycle (ISO 9283 §7.2.1: P1 → P5 → P4 → P3 → P2, n cycles) ------------------------
POSE_CYCLE_ORDER = ("P1", "P5", "P4", "P3", "P2")

MoveFn = Callable[[np.ndarray, np.ndarray], Trajectory]
"""A rest-to-rest joint move q_from → q_to sampled from t = 0: the timing policy (catalogue limits,
identified dynamics …) is the caller's."""


def pose_cycle_joints(robot: Robot, cube: Iso9283Cube, branch: Branch | None = None) -> dict[str, np.ndarray]:
    """Joint angles (rad) of P1–P5 with the cube's orientation on the IK `branch`, each solved by
    continuation from P1 (the same branch as the cube search)."""
    selector = BranchSelector(robot, branch or Branch())
    data = robot.create_data()
    rot = rpy_matrix(cube.rpy_rad)
    p1 = cube.points_m["P1"]
    res = solve_branch_ik(robot, data, pin.SE3(rot, p1), selector, n_starts=32)
    if not res.ok:
        raise InputError(
            f"P1 of the test cube is not reachable on the branch ({res.message})", field="branch"
        )
    q1 = res.q
    out = {"P1": q1}
    for name in POSE_CYCLE_ORDER[1:]:
        p, q = cube.points_m[name], q1
        for k in range(1, 11):
            res = solve_branch_ik(robot, data, pin.SE3(rot, p1 + (p - p1) * k / 10), selector, seed=q)
            if not res.ok:
                raise InputError(f"{name} of the test cube is not reachable on the branch", field="branch")
            q = res.q
        out[name] = q
    return out


def pose_cycle_trajectory(
    joints: dict[str, np.ndarray], n_cycles: int, dwell_s: float, move: MoveFn, sample_s: float
) -> tuple[Trajectory, list[str]]:
    """The pose-cycle plan: a dwell of `dwell_s` at P1, then `n_cycles` × (P5, P4, P3, P2, P1) each
    reached by `move` and held for `dwell_s` (the tracker measures in the dwell). Returns the
    trajectory (sampled every `sample_s`) and the poses in the order visited."""
    if n_cycles < 1 or dwell_s <= 0:
        raise InputError("needs n_cycles ≥ 1 and dwell_s > 0", field="n_cycles")
    order = ["P1"] + [p for _ in range(n_cycles) for p in (*POSE_CYCLE_ORDER[1:], "P1")]
    n_dwell = max(2, int(round(dwell_s / sample_s)))
    qs, qds, qdds = [], [], []

    def hold(q: np.ndarray) -> None:
        qs.append(np.tile(q, (n_dwell, 1)))
        qds.append(np.zeros((n_dwell, len(q))))
        qdds.append(np.zeros((n_dwell, len(q))))

    hold(joints[order[0]])
    for a, b in zip(order[:-1], order[1:], strict=True):
        m = move(joints[a], joints[b])
        if abs(float(np.median(np.diff(m.t))) - sample_s) > 1e-9 * max(1.0, sample_s):
            raise InputError(
                f"the move is sampled at {np.median(np.diff(m.t))} s, not {sample_s} s", field="move"
            )
        qs.append(m.q[1:])
        qds.append(m.qd[1:])
        qdds.append(m.qdd[1:])
        hold(joints[b])
    q = np.concatenate(qs)
    t = np.arange(len(q)) * sample_s
    return Trajectory(t, q, np.concatenate(qds), np.concatenate(qdds)), order


def cycloidal_move(qd_max: np.ndarray, qdd_max: np.ndarray, sample_s: float) -> MoveFn:
    """A synchronised rest-to-rest move with a cycloidal profile s = τ − sin(2πτ)/(2π) (acceleration
    zero at both ends, so the torque has no step), as short as the joint velocity and acceleration
    limits (rad/s, rad/s²; e.g. a maker's catalogue values) allow for the slowest joint: per joint
    T ≥ 2 Δ / qd_max and T ≥ sqrt(2π Δ / qdd_max)."""
    vmax, amax = np.asarray(qd_max, dtype=float), np.asarray(qdd_max, dtype=float)

    def move(q0: np.ndarray, q1: np.ndarray) -> Trajectory:
        dq = np.asarray(q1, dtype=float) - np.asarray(q0, dtype=float)
        d = np.abs(dq)
        duration = max(float(np.max(2 * d / vmax)), float(np.max(np.sqrt(2 * np.pi * d / amax))), sample_s)
        n = int(np.ceil(duration / sample_s))
        duration = n * sample_s
        tau = np.arange(n + 1) / n
        w = 2 * np.pi
        s = tau - np.sin(w * tau) / w
        sd = (1 - np.cos(w * tau)) / duration
        sdd = w * np.sin(w * tau) / duration**2
        t = tau * duration
        return Trajectory(t, q0 + np.outer(s, dq), np.outer(sd, dq), np.outer(sdd, dq))

    return move


def cube_from_rectangle(spec: PathSpec) -> Iso9283Cube:
    """The test cube back from its `iso9283-rectangle` path (P2, P3, P4, P5, P2): P2 and P4 lie a
    tenth of the diagonal C1–C3 in from its ends, P3 and P5 likewise on C2–C4, P1 is the centre."""
    pts = getattr(spec.geometry, "points_m", None)
    if pts is None or len(pts) != 5:
        raise InputError("an ISO 9283 rectangle has the points P2, P3, P4, P5, P2", field="geometry.points_m")
    p2, p3, p4, p5 = (np.asarray(p, dtype=float) for p in pts[:4])
    d13, d24 = (p4 - p2) / 0.8, (p5 - p3) / 0.8
    c1, c2 = p2 - 0.1 * d13, p3 - 0.1 * d24
    corners = np.array([c1, c2, c1 + d13, c2 + d24])
    centre = (p2 + p4) / 2
    side = float(np.linalg.norm(d13) / np.sqrt(3.0))
    rpy = spec.orientation.start
    points = {"P1": centre, "P2": p2, "P3": p3, "P4": p4, "P5": p5}
    return Iso9283Cube(centre, side, tuple(float(a) for a in rpy), corners, points)


def time_scaled(traj: Trajectory, duration_s: float, sample_s: float) -> Trajectory:
    """`traj` slowed (or sped up) uniformly in time to `duration_s`: q(t/k), q̇(t/k)/k, q̈(t/k)/k² with
    k = duration / its duration, resampled at `sample_s` (linear interpolation of the dense samples).
    The same joint path, so the same geometry; torques are left to the caller's model."""
    if duration_s <= 0:
        raise InputError("needs a positive duration", field="duration-s")
    k = duration_s / traj.duration_s
    t = np.arange(int(round(duration_s / sample_s)) + 1) * sample_s
    tau = np.minimum(t / k, traj.t[-1])

    def at(x: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(tau, traj.t, x[:, j]) for j in range(x.shape[1])])

    return Trajectory(t, at(traj.q), at(traj.qd) / k, at(traj.qdd) / k**2)


def repeat_cycles(
    traj: Trajectory, n_cycles: int, dwell_s: float, move: MoveFn, sample_s: float
) -> Trajectory:
    """`n_cycles` runs of a rest-to-rest trajectory (a test path) in one plan: each followed by a
    dwell, a return `move` to its start and a dwell (not after the last), so that one run log holds
    the standard's repeated cycles (the simulated cell's noise differs from cycle to cycle there,
    not from one fresh cell to the next)."""
    if n_cycles < 1 or dwell_s <= 0:
        raise InputError("needs n_cycles ≥ 1 and dwell_s > 0", field="n_cycles")
    if abs(float(np.median(np.diff(traj.t))) - sample_s) > 1e-9 * max(1.0, sample_s):
        raise InputError(f"the trajectory is sampled at {np.median(np.diff(traj.t))} s, not {sample_s} s")
    n_dwell = max(2, int(round(dwell_s / sample_s)))
    back = move(traj.q[-1], traj.q[0])
    zeros = np.zeros((n_dwell, traj.q.shape[1]))
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = [(traj.q, traj.qd, traj.qdd)]
    for _ in range(n_cycles - 1):
        parts.append((np.tile(traj.q[-1], (n_dwell, 1)), zeros, zeros))
        parts.append((back.q[1:], back.qd[1:], back.qdd[1:]))
        parts.append((np.tile(traj.q[0], (n_dwell, 1)), zeros, zeros))
        parts.append((traj.q[1:], traj.qd[1:], traj.qdd[1:]))
    q = np.concatenate([p[0] for p in parts])
    return Trajectory(
        np.arange(len(q)) * sample_s,
        q,
        np.concatenate([p[1] for p in parts]),
        np.concatenate([p[2] for p in parts]),
    )
