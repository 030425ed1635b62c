"""The one inverse kinematics: the closed form where the arm has one (`rxcomm.model.opw`, a
spherical-wrist 6R arm), refined by Newton on the model given (a calibrated one too), and a numeric
multi-start only where no closed form applies.

`solve_ik(robot, target, seed=…/near=…, accept=…)` is the entry every caller uses (path IK, the
ISO 9283 paths, plan-ptp's TCP poses, `inverse_kinematics`); `ik_solutions(robot, target)` gives every
branch of a pose. Its result is an `IkResult`: the solvers' one convention (`rxcomm.errors.SolveStatus`
and a message), the joint angles and their pose error. From a seed, Newton first (~8 µs a step); the
closed form when Newton fails or crosses to another branch (near a singularity it can).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg.lapack import dgesv as _dgesv

from rxcomm.errors import InfeasibleError, SolveOutcome, SolveStatus
from rxcomm.model.opw import analytic_solutions, same_branch, spherical_wrist, wrap_angle
from rxcomm.model.robot import Robot

NEWTON_TOL = 1e-11  # ‖log6 error‖ (m, rad) accepted as a solution
ACCEPT_TOL = NEWTON_TOL * 100


@dataclass(frozen=True)
class IkResult:
    """How an IK solve ended, in the solvers' one convention (`SolveStatus` + message, as `outcome`),
    and its joint angles: the solution when ``ok``, else the seed (or reference). The errors are
    those of ``q``'s TCP pose from the target (m, rad)."""

    q: np.ndarray
    status: SolveStatus
    position_error_m: float
    orientation_error_rad: float
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status is SolveStatus.SOLVED

    converged = ok

    @property
    def outcome(self) -> SolveOutcome:
        return SolveOutcome(self.status, self.message)

    def raise_if_failed(self, what: str = "target pose") -> IkResult:
        """Return self when solved, else raise `InfeasibleError` (exit 3) naming the error left."""
        if not self.ok:
            raise InfeasibleError(
                f"inverse kinematics failed for the {what} ({self.status.value}): {self.message}; "
                f"{self.position_error_m * 1e3:.3f} mm / {math.degrees(self.orientation_error_rad):.3f}° "
                "left at the returned q"
            )
        return self


def newton(
    robot: Robot, data: pin.Data, target: pin.SE3, q: np.ndarray, iters: int = 12, max_step_rad: float = 0.5
) -> tuple[np.ndarray, float]:
    """Newton on the SE(3) error in the TCP frame from ``q``, in the caller's scratch ``data``; returns
    (q, error norm), and leaves ``data`` at the returned q. Steps ≤ ``max_step_rad`` keep the iterate
    near its start (and on its branch). LAPACK's dgesv directly: np.linalg.solve's checks cost 3 µs
    of the ~8 µs an iteration takes."""
    m, fid = robot.model, robot.tcp_frame_id
    err = math.inf
    for _ in range(iters):
        pin.computeJointJacobians(m, data, q)  # the forward kinematics and every joint's Jacobian
        e = pin.log6(pin.updateFramePlacement(m, data, fid).actInv(target)).vector
        err = math.hypot(*e.tolist())  # floats in Python: numpy's per-call overhead is µs here
        if err < NEWTON_TOL:
            break
        _, _, dq, info = _dgesv(pin.getFrameJacobian(m, data, fid, pin.LOCAL), e)
        if info != 0:  # singular Jacobian
            return q, math.inf
        step = max(map(abs, dq.tolist()))
        if step > max_step_rad:
            dq *= max_step_rad / step
        q = q + dq
    return q, err


def within_limits(robot: Robot, q: np.ndarray) -> bool:
    """Every joint within its limits (1e-9 rad slack); a Python loop: 1 µs against numpy's 5."""
    lo, hi = robot.q_min.tolist(), robot.q_max.tolist()
    return all(a - 1e-9 <= x <= b + 1e-9 for x, a, b in zip(q.tolist(), lo, hi, strict=True))


_scratch = threading.local()


def scratch_data(robot: Robot) -> pin.Data:
    """A Pinocchio Data of ``robot``'s model for this thread, reused across calls (creating one costs
    ~25 µs, as much as the IK itself)."""
    cache = _scratch.__dict__.setdefault("data", {})
    key = id(robot.model)
    if key not in cache or cache[key][0] is not robot.model:
        cache[key] = (robot.model, robot.model.createData())
    return cache[key][1]


def nearest_turn(robot: Robot, q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``q`` with each joint shifted by whole turns to the value nearest ``ref`` within the limits
    (a joint with no such value is left as it is)."""
    turns = np.round((ref - q) / (2 * math.pi)) + np.array([[0.0], [-1.0], [1.0]])
    cand = q + 2 * math.pi * turns  # [3, n]
    valid = (cand >= robot.q_min - 1e-9) & (cand <= robot.q_max + 1e-9)
    dist = np.where(valid, np.abs(cand - ref), np.inf)
    best = dist.argmin(axis=0)
    cols = np.arange(q.size)
    return np.where(valid[best, cols], cand[best, cols], q)


def _multi_start(robot: Robot, data: pin.Data, target: pin.SE3, n_starts: int) -> list[np.ndarray]:
    """The fallback without a closed form: Newton from ``n_starts`` deterministic starts (half of them
    facing the target), the converged ones."""
    rng = np.random.default_rng(0)
    lo, hi = robot.q_min, robot.q_max
    p = target.translation
    q1 = math.atan2(p[1], p[0])
    found = []
    for k in range(n_starts):
        q0 = rng.uniform(np.maximum(lo, -math.pi), np.minimum(hi, math.pi))
        if k % 2 == 0:
            q0[0] = wrap_angle(q1 if k % 4 == 0 else q1 + math.pi)
        q, err = newton(robot, data, target, q0, iters=40)
        if err <= ACCEPT_TOL:
            found.append(q)
    return found


def ik_solutions(
    robot: Robot,
    target: pin.SE3,
    data: pin.Data | None = None,
    *,
    near: np.ndarray | None = None,
    n_starts: int = 64,
) -> list[np.ndarray]:
    """Every solution of ``target`` found within the joint limits, refined on ``robot``'s model to
    ``NEWTON_TOL``, each joint at the turn nearest ``near`` (default 0); distinct branches. The closed
    form where the arm has one, else the multi-start from ``n_starts`` starts."""
    data = robot.model.createData() if data is None else data
    ref = np.zeros(robot.n) if near is None else np.asarray(near, dtype=float)
    if spherical_wrist(robot) is None:
        solved = _multi_start(robot, data, target, n_starts)
    else:
        refined = (
            newton(robot, data, target, q, iters=20) for q in analytic_solutions(robot, target, data, ref)
        )
        solved = [q for q, err in refined if err <= ACCEPT_TOL]
    out: list[np.ndarray] = []
    for q in solved:
        q = nearest_turn(robot, q, ref)
        if within_limits(robot, q) and not any(float(np.abs(q - o).max()) < 1e-6 for o in out):
            out.append(q)
    return out


def _result(
    robot: Robot, data: pin.Data, target: pin.SE3, q: np.ndarray, status: SolveStatus, message: str = ""
) -> IkResult:
    """An `IkResult` with the pose error of ``q`` (forward kinematics run here unless solved: a solved
    ``q`` is where Newton left ``data``)."""
    m, fid = robot.model, robot.tcp_frame_id
    if status is not SolveStatus.SOLVED:
        pin.forwardKinematics(m, data, q)
    rel = pin.updateFramePlacement(m, data, fid).actInv(target)  # same norms as in the base frame
    pe, oe = math.hypot(*rel.translation.tolist()), math.hypot(*pin.log3(rel.rotation).tolist())
    return IkResult(q, status, pe, oe, message)


def solve_ik(
    robot: Robot,
    target: pin.SE3,
    data: pin.Data | None = None,
    *,
    seed: np.ndarray | None = None,
    near: np.ndarray | None = None,
    accept=None,
    n_starts: int = 64,
) -> IkResult:
    """The IK: joint angles within the limits putting the TCP at ``target`` (base frame), accepted by
    ``accept(data, q)`` (e.g. a branch selector's ``matches``; default: any).

    With ``seed`` (a neighbouring pose's solution): Newton from it (~8 µs a step); if it fails, or
    ends on another elbow or wrist branch than the seed's (near a singularity Newton can cross), the
    solution nearest the seed among ``ik_solutions`` (and Newton's). Without: the solution nearest
    ``near`` (default: the smallest |q|) among ``ik_solutions``. None found: INFEASIBLE where the
    closed form applies (it finds every solution), NOT_CONVERGED for the multi-start; ``q`` is then
    the seed (or ``near``) and the errors are its pose's."""
    data = scratch_data(robot) if data is None else data
    found: list[np.ndarray] = []
    if seed is not None:
        seed = np.asarray(seed, dtype=float)
        q, err = newton(robot, data, target, seed)
        if err <= ACCEPT_TOL and within_limits(robot, q) and (accept is None or accept(data, q)):
            if same_branch(robot, seed, q):
                return _result(robot, data, target, q, SolveStatus.SOLVED)
            found.append(q)  # crossed to another branch (near a singularity Newton can): a candidate
        near = seed
    ref = np.zeros(robot.n) if near is None else np.asarray(near, dtype=float)
    found += [
        s
        for s in ik_solutions(robot, target, data, near=ref, n_starts=n_starts)
        if accept is None or accept(data, s)
    ]
    if found:
        best = min(found, key=lambda s: float(np.sum((s - ref) ** 2)))
        newton(robot, data, target, best, iters=1)  # ``data`` at the solution
        return _result(robot, data, target, best, SolveStatus.SOLVED)
    closed = spherical_wrist(robot) is not None
    where = " on the selected branch" if accept is not None else ""
    how = "no closed-form solution" if closed else f"the {n_starts}-start Newton found no solution"
    return _result(
        robot,
        data,
        target,
        ref if seed is None else seed,
        SolveStatus.INFEASIBLE if closed else SolveStatus.NOT_CONVERGED,
        f"{how}{where} within the joint limits (unreachable, or every branch beyond a limit)",
    )
