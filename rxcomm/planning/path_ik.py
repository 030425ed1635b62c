"""Inverse kinematics along a Cartesian path: one continuous IK branch, q(σ) as a C² joint spline.

The start configuration is chosen by branch (shoulder front/back, elbow up/down, wrist J5 sign) or as
the solution nearest to a given q; the branch is then followed by predictor–corrector continuation
(predictor q + q'·h with q' = J⁻¹·[p'; ω'], corrector Newton on the SE(3) error) with a step that
adapts so no joint moves more than `max_step_rad` between knots. The knots become a not-a-knot cubic
spline q(σ) — the geometric path that time parametrisation works on (toppra needs q, q', q'').

Pass a calibrated `Robot` (e.g. `ErrorModel.apply(robot)`) to honour a calibration: everything here
uses `robot.model` as given.

Failures are named by σ range: an unreachable stretch (`InfeasibleError` with the σ interval found by a
reachability scan), a stretch closer to a singularity than `sigma_min_margin` (the smallest singular
value of the TCP Jacobian, angular rows × 1 m, and the joints that move in its null direction), a joint
limit (joint and σ).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
from scipy.interpolate import CubicSpline

from rxcomm.errors import InfeasibleError
from rxcomm.model.ik import NEWTON_TOL, newton, within_limits
from rxcomm.model.kinematics import ORIENTATION_LENGTH_M, BranchSelector, solve_branch_ik
from rxcomm.model.robot import Robot
from rxcomm.planning.paths import CartesianPath
from rxcomm.schemas.path import Branch

# The TCP Jacobian's smallest singular value a path may come down to (CpSettings' default too).
SIGMA_MIN_MARGIN = 0.005


@dataclass(frozen=True, eq=False)
class JointPath:
    """q(σ) along a Cartesian path: knots, their C² spline, and the singularity margin per knot."""

    path: CartesianPath
    sigma: np.ndarray  # knots, m
    q: np.ndarray  # [K, n] joint angles at the knots, rad
    sigma_min: np.ndarray  # [K] smallest singular value of the TCP Jacobian
    labels: dict[str, str]
    spline: CubicSpline = field(repr=False)

    @property
    def length_m(self) -> float:
        return float(self.sigma[-1])

    def __call__(self, s, order: int = 0) -> np.ndarray:
        return self.spline(s, order)

    @property
    def q_start(self) -> np.ndarray:
        return self.q[0]

    @property
    def q_goal(self) -> np.ndarray:
        return self.q[-1]

    @property
    def min_sigma_min(self) -> tuple[float, float]:
        """(smallest σ_min along the path, σ where it occurs in m)."""
        i = int(np.argmin(self.sigma_min))
        return float(self.sigma_min[i]), float(self.sigma[i])


def _ranges(s: np.ndarray, bad: np.ndarray) -> list[tuple[float, float]]:
    """Contiguous σ intervals where `bad` holds."""
    out = []
    i = 0
    while i < len(s):
        if bad[i]:
            j = i
            while j + 1 < len(s) and bad[j + 1]:
                j += 1
            out.append((float(s[i]), float(s[j])))
            i = j + 1
        else:
            i += 1
    return out


def _fmt_ranges(r: list[tuple[float, float]]) -> str:
    return ", ".join(f"σ ∈ [{a:.4f}, {b:.4f}] m" if b > a else f"σ = {a:.4f} m" for a, b in r)


def reachability_scan(
    robot: Robot, path: CartesianPath, selector: BranchSelector, n: int = 33
) -> list[tuple[float, float]]:
    """σ intervals (on a grid of n points) where no IK solution on the branch exists within limits."""
    data = robot.create_data()
    s = np.linspace(0, path.length_m, n)
    bad = np.zeros(n, dtype=bool)
    prev = None
    for i, pose in enumerate(path.poses(s)):
        res = solve_branch_ik(robot, data, pose, selector, seed=prev) if prev is not None else None
        if res is None or not res.ok:
            res = solve_branch_ik(robot, data, pose, selector, n_starts=12)
        bad[i] = not res.ok
        prev = res.q if res.ok else None
    return _ranges(s, bad)


def _null_joints(selector: BranchSelector, data: pin.Data, q: np.ndarray) -> str:
    jac = selector.jacobian(data, q).copy()
    jac[3:] *= ORIENTATION_LENGTH_M
    v = np.linalg.svd(jac)[2][-1]
    names = selector.robot.joint_names
    big = [names[j] for j in np.flatnonzero(np.abs(v) > 0.3 * np.abs(v).max())]
    return " and ".join(big)


def solve_path_ik(
    robot: Robot,
    path: CartesianPath,
    branch: Branch | None = None,
    q_near: np.ndarray | None = None,
    *,
    max_step_m: float = 0.005,
    max_step_rad: float = 0.02,
    sigma_min_margin: float = SIGMA_MIN_MARGIN,
) -> JointPath:
    """IK along `path` on one continuous branch; see the module docstring. Raises InfeasibleError."""
    selector = BranchSelector(robot, None if q_near is not None else branch)
    data = robot.create_data()
    length = path.length_m
    pose0 = path.poses([0.0])[0]
    start = solve_branch_ik(robot, data, pose0, selector, near=q_near)
    if not start.ok:
        what = (
            f"near q = {np.round(q_near, 3).tolist()}"
            if q_near is not None
            else f"on branch {_branch_text(branch)}"
        )
        ranges = reachability_scan(robot, path, selector)
        raise InfeasibleError(
            f"path {path.name!r}: the start pose is unreachable {what} within the joint limits"
            + (f"; unreachable stretches: {_fmt_ranges(ranges)}" if ranges else "")
        )
    q = start.q
    labels = selector.labels(data, q)
    follow = BranchSelector(robot, Branch(**labels))
    ss, qs, sm = [0.0], [q], [follow.sigma_min(data, q)]
    s, h = 0.0, min(max_step_m, length / 20)
    while s < length - 1e-12:
        h = min(h, length - s)
        jac = follow.jacobian(data, q)
        try:
            qd = np.linalg.solve(jac, path.twist_rate([s])[0])
        except np.linalg.LinAlgError:
            qd = np.zeros(robot.n)
        target = path.poses([s + h])[0]
        q_new, err = newton(robot, data, target, q + qd * h)
        jump = float(np.max(np.abs(q_new - q)))
        if err > NEWTON_TOL * 100 or jump > max_step_rad:
            if h > 1e-6:
                h /= 2
                continue
            _raise_stuck(robot, path, follow, data, s, q, q_new, err)
        if not within_limits(robot, q_new):
            j = int(np.argmax(np.maximum(robot.q_min - q_new, q_new - robot.q_max)))
            raise InfeasibleError(
                f"path {path.name!r}: {robot.joint_names[j]} reaches its limit "
                f"[{robot.q_min[j]:.3f}, {robot.q_max[j]:.3f}] rad at σ = {s + h:.4f} m "
                f"of {length:.4f} m (q = {q_new[j]:.3f} rad) on branch {_branch_text(Branch(**labels))}"
            )
        s += h
        q = q_new
        ss.append(s)
        qs.append(q)
        sm.append(follow.sigma_min(data, q))
        if jump < max_step_rad / 3:
            h = min(h * 1.5, max_step_m)
    ss_a, qs_a, sm_a = np.array(ss), np.array(qs), np.array(sm)
    singular = sm_a < sigma_min_margin
    if singular.any():
        i = int(np.argmin(sm_a))
        raise InfeasibleError(
            f"path {path.name!r} passes through a singularity: σ_min of the TCP Jacobian < "
            f"{sigma_min_margin} at {_fmt_ranges(_ranges(ss_a, singular))} (minimum {sm_a[i]:.2e} at "
            f"σ = {ss_a[i]:.4f} m; {_null_joints(follow, data, qs_a[i])} move without moving the TCP)"
        )
    spline = CubicSpline(ss_a, qs_a, bc_type="not-a-knot")
    return JointPath(path, ss_a, qs_a, sm_a, labels, spline)


def _branch_text(branch: Branch | None) -> str:
    if branch is None:
        return "any"
    return ", ".join(f"{k} {v}" for k, v in branch.model_dump().items() if v is not None) or "any"


def _raise_stuck(robot, path, selector, data, s, q, q_new, err) -> None:
    """Continuation cannot advance past σ = s: the path leaves the reachable workspace on this branch
    (its boundary is itself singular: the arm stretches), or crosses a singularity inside it."""
    ranges = [
        r for r in reachability_scan(robot, path, BranchSelector(robot, selector.branch)) if r[1] >= s - 1e-9
    ]
    if ranges:
        raise InfeasibleError(
            f"path {path.name!r} is unreachable on branch {_branch_text(selector.branch)} at "
            f"{_fmt_ranges(ranges)} (IK stops at σ = {s:.4f} m of {path.length_m:.4f} m, where "
            f"{_null_joints(selector, data, q)} reach the edge of the workspace)"
        )
    sm = selector.sigma_min(data, q)
    raise InfeasibleError(
        f"path {path.name!r} passes through a singularity near σ = {s:.4f} m: the IK branch cannot "
        f"be followed (σ_min = {sm:.2e}; {_null_joints(selector, data, q)} move without moving the TCP)"
    )
