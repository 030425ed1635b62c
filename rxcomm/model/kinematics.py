"""TCP kinematics: forward kinematics, Cardan angles, inverse kinematics, singularity measures.

Frames. Every pose here is in the robot's **base frame** (the URDF root, `universe` in Pinocchio)
unless a name says otherwise. With an error model (`rxcomm.model.geometric_errors.ErrorModel`) the base
frame stays the *nominal* one given by the cell layout; the model's `base.*` error moves the robot in
it (see `geometric_errors`). The tracker frame appears only in `geometric_errors.measured_pose`.

Orientation. Internally rotation matrices; for reports the paper's Cardan angles x-y-z (Bryant angles,
intrinsic): R = Rx(α)·Ry(β)·Rz(γ), β ∈ [−π/2, π/2] (`cardan_xyz`, `cardan_xyz_matrix`). Not to be
confused with URDF rpy, which is R = Rz(y)·Ry(p)·Rx(r).

Inverse kinematics. The one IK is `rxcomm.model.ik.solve_ik` (the closed form for spherical-wrist
arms, Newton on the given model, a multi-start only without a closed form); `inverse_kinematics`
(from a seed, optionally with an error model), `solve_branch_ik` (on a `Branch`), `solve_pose_ik`
(a Cardan pose, for the stages) and `pose_branches` (every branch of a pose, labelled) are its front
ends. Every one returns an `IkResult`: the solvers' convention, a `SolveStatus` and a message
(`result.outcome`); expected failure is a returned status (toppra style), not an exception — an
unreachable target gives `status=INFEASIBLE` with the seed's remaining error; callers that must
stop call `result.raise_if_failed()` (→ `InfeasibleError`, exit 3).

For many IK calls on a calibrated robot, apply the error model once (`errors.apply(robot)`) and pass
the calibrated `Robot` with `errors=None`: `errors=` here rebuilds the perturbed model on every call.
`ik_along` solves a sequence of poses (a sampled path) seeding each with the previous solution and
reports branch jumps; `tcp_sigma_min` and `wrist_singularity` measure the distance to singularities.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from rxcomm.errors import InfeasibleError, InputError
from rxcomm.model.ik import IkResult, ik_solutions, scratch_data, solve_ik
from rxcomm.model.robot import Robot
from rxcomm.schemas.path import Branch

ORIENTATION_LENGTH_M = 1.0  # weight of angular Jacobian rows in σ_min (1 rad ~ 1 m)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from rxcomm.model.geometric_errors import ErrorModel


def _robot_with(robot: Robot, errors: ErrorModel | None) -> Robot:
    return robot if errors is None else errors.apply(robot)


def frame_placement(robot: Robot, data: pin.Data, q: np.ndarray, frame_id: int) -> pin.SE3:
    """Placement of frame `frame_id` in the base frame at joint angles `q` (a copy; `data` is scratch)."""
    pin.forwardKinematics(robot.model, data, np.asarray(q, dtype=float))
    return pin.updateFramePlacement(robot.model, data, frame_id).copy()


def tcp_placement(robot: Robot, q: np.ndarray, errors: ErrorModel | None = None) -> pin.SE3:
    """TCP placement in the base frame (with `errors`: the perturbed robot's TCP, base error included)."""
    r = _robot_with(robot, errors)
    return frame_placement(r, r.create_data(), q, r.tcp_frame_id)


def tcp_pose(robot: Robot, q: np.ndarray, errors: ErrorModel | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(position [3] in m, rotation [3, 3]) of the TCP in the base frame."""
    m = tcp_placement(robot, q, errors)
    return m.translation.copy(), m.rotation.copy()


# ---------------------------------------------------------------------------------------------------
# Cardan angles x-y-z (paper §3.4, Table 2): R = Rx(α) Ry(β) Rz(γ).


def cardan_xyz(rotation: np.ndarray) -> np.ndarray:
    """Cardan angles (α, β, γ) in rad of R = Rx(α)·Ry(β)·Rz(γ); works on [..., 3, 3] stacks.

    At β = ±π/2 (gimbal lock) α + γ (or α − γ) is determined only; γ is then returned as 0.
    """
    r = np.asarray(rotation, dtype=float)
    beta = np.arcsin(np.clip(r[..., 0, 2], -1.0, 1.0))
    locked = np.abs(r[..., 0, 2]) > 1.0 - 1e-12
    alpha = np.where(locked, np.arctan2(r[..., 2, 1], r[..., 1, 1]), np.arctan2(-r[..., 1, 2], r[..., 2, 2]))
    gamma = np.where(locked, 0.0, np.arctan2(-r[..., 0, 1], r[..., 0, 0]))
    return np.stack([alpha, beta, gamma], axis=-1)


def cardan_xyz_matrix(angles: np.ndarray) -> np.ndarray:
    """Inverse of `cardan_xyz`: R = Rx(α)·Ry(β)·Rz(γ) from [..., 3] angles in rad."""
    a = np.asarray(angles, dtype=float)
    ca, sa = np.cos(a[..., 0]), np.sin(a[..., 0])
    cb, sb = np.cos(a[..., 1]), np.sin(a[..., 1])
    cg, sg = np.cos(a[..., 2]), np.sin(a[..., 2])
    r = np.empty(a.shape[:-1] + (3, 3))
    r[..., 0, 0] = cb * cg
    r[..., 0, 1] = -cb * sg
    r[..., 0, 2] = sb
    r[..., 1, 0] = ca * sg + sa * sb * cg
    r[..., 1, 1] = ca * cg - sa * sb * sg
    r[..., 1, 2] = -sa * cb
    r[..., 2, 0] = sa * sg - ca * sb * cg
    r[..., 2, 1] = sa * cg + ca * sb * sg
    r[..., 2, 2] = ca * cb
    return r


# ---------------------------------------------------------------------------------------------------
# Inverse kinematics


def quaternion_wxyz(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w ≥ 0, of a rotation matrix."""
    q = pin.Quaternion(np.asarray(rotation, dtype=float))
    q.normalize()
    out = np.array([q.w, q.x, q.y, q.z])
    return out if out[0] >= 0 else -out


def rotation_from_wxyz(qt: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z), normalised first."""
    w, x, y, z = (float(v) for v in qt)
    q = pin.Quaternion(w, x, y, z)
    q.normalize()
    return q.toRotationMatrix()


def _as_se3(target: pin.SE3 | tuple[np.ndarray, np.ndarray]) -> pin.SE3:
    if isinstance(target, pin.SE3):
        return target
    p, r = target
    return pin.SE3(np.asarray(r, dtype=float), np.asarray(p, dtype=float))


def inverse_kinematics(
    robot: Robot,
    target_pose: pin.SE3 | tuple[np.ndarray, np.ndarray],
    q_seed: np.ndarray,
    errors: ErrorModel | None = None,
) -> IkResult:
    """Joint angles putting the TCP at `target_pose` (base frame; `pin.SE3` or (position [3], rotation
    [3, 3])) within the joint limits, on the seed's branch when the seed is near one (`solve_ik`).
    `errors`: honour an error model (calibration). Failure is a status, not an exception."""
    r = _robot_with(robot, errors)
    return solve_ik(r, _as_se3(target_pose), scratch_data(r), seed=np.asarray(q_seed, dtype=float))


@dataclass(frozen=True)
class IkPathResult:
    """IK along a pose sequence. `q[k]` solves pose k; `converged[k]` per pose; `max_jump_rad` the largest
    joint change between consecutive solutions (a branch flip shows as a jump ≫ the path's step)."""

    q: np.ndarray
    converged: np.ndarray
    position_error_m: np.ndarray
    orientation_error_rad: np.ndarray
    max_jump_rad: float
    branch_jumps: tuple[int, ...]

    @property
    def ok(self) -> bool:
        return bool(np.all(self.converged)) and not self.branch_jumps

    def raise_if_failed(self, what: str = "path") -> IkPathResult:
        if not np.all(self.converged):
            k = int(np.argmin(self.converged))
            raise InfeasibleError(
                f"inverse kinematics failed along the {what} at pose {k} of {len(self.q)}: "
                f"{self.position_error_m[k] * 1e3:.3f} mm left (unreachable or at a joint limit)"
            )
        if self.branch_jumps:
            k = self.branch_jumps[0]
            raise InfeasibleError(
                f"the {what} changes IK branch between poses {k - 1} and {k} "
                f"(joint jump {self.max_jump_rad:.3f} rad): it crosses a singularity or a joint limit"
            )
        return self


def ik_along(
    robot: Robot,
    poses: Sequence[pin.SE3 | tuple[np.ndarray, np.ndarray]],
    q_seed: np.ndarray,
    errors: ErrorModel | None = None,
    *,
    max_jump_rad: float = 0.25,
) -> IkPathResult:
    """Solve IK for each pose in turn, seeding with the previous solution (linearly extrapolated).

    Keeps the seed's branch along the path as long as consecutive poses are close. A change of more
    than `max_jump_rad` (∞-norm) between consecutive solutions is reported in `branch_jumps` (the
    path passes a singularity, or a limit forced another branch).
    """
    r = _robot_with(robot, errors)
    n = len(poses)
    qs = np.zeros((n, r.n))
    conv = np.zeros(n, dtype=bool)
    pe = np.zeros(n)
    oe = np.zeros(n)
    prev = np.asarray(q_seed, dtype=float)
    prev2 = None
    jumps: list[int] = []
    max_jump = 0.0
    for k, pose in enumerate(poses):
        seed = prev if prev2 is None else np.clip(2 * prev - prev2, r.q_min, r.q_max)
        res = inverse_kinematics(r, pose, seed)
        if not res.converged and prev2 is not None:
            res = inverse_kinematics(r, pose, prev)
        qs[k], conv[k], pe[k], oe[k] = res.q, res.converged, res.position_error_m, res.orientation_error_rad
        if k > 0:
            jump = float(np.max(np.abs(res.q - prev)))
            max_jump = max(max_jump, jump)
            if jump > max_jump_rad:
                jumps.append(k)
        prev2 = prev if k > 0 else None
        prev = res.q
    return IkPathResult(qs, conv, pe, oe, max_jump, tuple(jumps))


# ---------------------------------------------------------------------------------------------------
# Singularity measures


def tcp_jacobian(robot: Robot, q: np.ndarray, data: pin.Data | None = None) -> np.ndarray:
    """6×n Jacobian of the TCP (linear m/s then angular rad/s, base-frame aligned, at the TCP point)."""
    data = robot.create_data() if data is None else data
    q = np.asarray(q, dtype=float)
    pin.computeJointJacobians(robot.model, data, q)
    pin.updateFramePlacements(robot.model, data)
    return pin.getFrameJacobian(robot.model, data, robot.tcp_frame_id, pin.LOCAL_WORLD_ALIGNED)


def tcp_sigma_min(
    robot: Robot,
    q: np.ndarray,
    data: pin.Data | None = None,
    orientation_length_m: float = ORIENTATION_LENGTH_M,
) -> float:
    """Smallest singular value of the TCP Jacobian (angular rows × `orientation_length_m`), m/rad.

    Zero at any singularity (wrist, elbow, shoulder); grows with distance from it.
    """
    jac = tcp_jacobian(robot, q, data).copy()
    jac[3:] *= orientation_length_m
    return float(np.linalg.svd(jac, compute_uv=False)[-1])


class BranchSelector:
    """Tests a configuration against a `Branch` and measures its distance to singularities.

    Shoulder/elbow/wrist are read geometrically so any 6R arm works, at the origins of the robot's
    `shoulder_joint_id`, `elbow_joint_id` and `wrist_joint_id` (the wrist's middle joint).
    """

    def __init__(self, robot: Robot, branch: Branch | None):
        self.robot = robot
        self.branch = branch or Branch(shoulder=None, elbow=None, wrist=None)
        self._forward = robot.forward_in_joint1

    def label_quantities(self, data: pin.Data, q: np.ndarray) -> dict[str, float]:
        """The signed quantity each label of q is the sign of, in radians (forward kinematics is run
        here): shoulder, the wrist centre's elevation from the plane across joint 1's forward
        direction; elbow, the elbow's from the shoulder–wrist line (vertical part); wrist, the wrist's
        middle joint angle. Its magnitude is the label's margin: how far a calibration may move the
        arm before the same configuration reads the other label."""
        pin.forwardKinematics(self.robot.model, data, q)
        r = self.robot
        j1, s, e, w = (data.oMi[i] for i in (1, r.shoulder_joint_id, r.elbow_joint_id, r.wrist_joint_id))
        reach = w.translation - j1.translation
        front = reach @ (j1.rotation @ self._forward) / max(float(np.linalg.norm(reach)), 1e-12)
        u = w.translation - s.translation
        u = u / max(np.linalg.norm(u), 1e-12)
        de = e.translation - s.translation
        up = (de - (de @ u) * u)[2] / max(float(np.linalg.norm(de)), 1e-12)
        return {"shoulder": float(front), "elbow": float(up), "wrist": float(q[r.wrist_joint_id - 1])}

    def labels(self, data: pin.Data, q: np.ndarray) -> dict[str, str]:
        """Shoulder/elbow/wrist labels of q (forward kinematics is run here)."""
        x = self.label_quantities(data, q)
        return {
            "shoulder": "front" if x["shoulder"] >= 0 else "back",
            "elbow": "up" if x["elbow"] >= 0 else "down",
            "wrist": "positive" if x["wrist"] >= 0 else "negative",
        }

    def matches(self, data: pin.Data, q: np.ndarray) -> bool:
        lab = self.labels(data, q)
        return all(getattr(self.branch, k) in (None, v) for k, v in lab.items())

    def jacobian(self, data: pin.Data, q: np.ndarray) -> np.ndarray:
        return tcp_jacobian(self.robot, q, data)

    def sigma_min(self, data: pin.Data, q: np.ndarray) -> float:
        return tcp_sigma_min(self.robot, q, data)


def solve_branch_ik(
    robot: Robot,
    data: pin.Data,
    target: pin.SE3,
    selector: BranchSelector,
    seed: np.ndarray | None = None,
    near: np.ndarray | None = None,
    n_starts: int = 64,
) -> IkResult:
    """The IK on the selector's branch (`rxcomm.model.ik.solve_ik`): a solution of `target` (TCP, base
    frame) within the joint limits. With `seed`: Newton from it, else the closed form's
    solution nearest it; without: the solution nearest `near` (default: smallest |q|). `n_starts`
    serves the numeric fallback of an arm without a closed form."""
    return solve_ik(robot, target, data, seed=seed, near=near, accept=selector.matches, n_starts=n_starts)


def pose_branches(
    robot: Robot, target: pin.SE3, data: pin.Data | None = None, near: np.ndarray | None = None
) -> list[tuple[Branch, np.ndarray]]:
    """Every solution of `target` within the joint limits with its `Branch` (shoulder, elbow, wrist),
    each joint at the turn nearest `near` (default 0): up to 8 for a spherical-wrist arm, distinct
    branches. Near a singularity two solutions can carry one label (the geometric labels meet there)."""
    data = scratch_data(robot) if data is None else data
    selector = BranchSelector(robot, None)
    return [(Branch(**selector.labels(data, q)), q) for q in ik_solutions(robot, target, data, near=near)]


def solve_pose_ik(
    robot: Robot,
    pose: np.ndarray,
    branch: Branch,
    field: str,
    near: np.ndarray | None = None,
    n_starts: int = 96,
) -> np.ndarray:
    """Joint angles putting the TCP at `pose` = (x, y, z, α, β, γ) (m; Cardan x-y-z rad, base frame) on
    `branch`, nearest `near` (default: the smallest |q|): `solve_branch_ik` (`n_starts`: the fallback's).
    An unreachable pose is an InputError naming `field` (exit 2)."""
    pose = np.asarray(pose, dtype=float)
    target = pin.SE3(cardan_xyz_matrix(pose[3:]), pose[:3])
    res = solve_branch_ik(
        robot, robot.create_data(), target, BranchSelector(robot, branch), near=near, n_starts=n_starts
    )
    if not res.ok:
        raise InputError(
            f"TCP pose {np.round(pose, 4).tolist()} is unreachable on branch "
            f"{branch.model_dump(exclude_none=True)} within the joint limits ({res.message})",
            field=field,
        )
    return res.q


def wrist_singularity(q: np.ndarray, wrist_joint: int = 4) -> np.ndarray:
    """|sin q5| (0 at the wrist singularity of a spherical wrist, where axes 4 and 6 align).

    `wrist_joint` is the 0-based index of the wrist's middle joint (J5). Works on [..., n] arrays.
    """
    return np.abs(np.sin(np.asarray(q, dtype=float)[..., wrist_joint]))
