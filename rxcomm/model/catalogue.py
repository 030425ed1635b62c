"""Catalogue limits: the joint speeds and accelerations a maker publishes for a generic controller.

A generic controller knows no dynamics, so its maker states kinematic limits that are safe at every
pose of the workspace with the rated payload. Here they are computed from the PRIOR model (URDF
inertias, drives.yaml rotor inertias, friction priors, spring, peak torques, `rated_payload`) as the
largest box |q̇_k| ≤ v_k, |q̈_k| ≤ a_k for which, at every sampled pose q and every joint j,

    |g_j(q) + τ_s,j(q)| + Σ_kl |H_j,kl(q)| v_k v_l + f_j(v) + Σ_k |M_jk(q)| a_k  ≤  τ_peak,j

(H_j the Coriolis/centrifugal quadratic form, f_j the worst friction at full speed, M with the
reflected rotor inertia). The left side bounds |τ_j| by the triangle inequality over every state in
the box: conservative, as a published figure must be.

The box's shape: velocity first, then acceleration, each a scale of the drive's own limits
(v = k_v·v_rated, the URDF's joint speeds; a = k_a·a_drive, drives.yaml's acceleration limits), the
way catalogues read (speeds near the motors' rated speeds, accelerations a generic controller
limits):

1. k_v the largest ≤ 1 for which the speed terms (Coriolis, friction) take at most
   1 − `ACCELERATION_RESERVE` of the headroom τ_peak,j − |g_j + τ_s,j| at every pose and joint: the
   bound at zero acceleration leaves that reserve of every pose's headroom for accelerating;
2. k_a the largest ≤ 1 for which the whole bound at v stays within τ_peak: acceleration fills the rest;
3. then each joint's acceleration cut, where needed, to what the drives follow without a torque
   feed-forward: its own following error (drives.yaml `servo` loops, its largest inertia, friction,
   the jerk ramp) peaking within 60 % of the following-error window (`rxcomm.model.servo`).
   `acceleration_binding` says per joint which bound binds: torque, following error or the drive.

Each by progressive filling: all joints' scale grows together until a torque row binds (tight: that
pose's bound equals its limit); the joints loading that row (through its speed terms in step 1,
through its inertia row in step 2) are fixed, the others grow on. A single time scale k (v = k·v,
a = k²·a, the shape slowing a motion down in time keeps) was the earlier rule: it gave the RX130L
speeds 31 % and accelerations 9 % of the drives' (a second to full speed), with which the ISO line
peaks at 0.64 m/s; the split with a 50 % reserve gives 20 % and 17 % and 0.76 m/s. No box at all
gives the line 1 m/s under this bound (`planning.catalogue_timing.catalogue_speed_bound`).

Poses are drawn uniformly within the joint limits (seeded); `CatalogueLimits` says how many, which
pose and which torque row bound each joint's speed and acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.errors import InfeasibleError
from rxcomm.model.dynamics import DynamicParameters, RobotDynamics, prior_parameters
from rxcomm.model.robot import Robot
from rxcomm.model.servo import tracking_bound

DEFAULT_POSES = 2000
JERK_RAMP_S = 0.05  # the generic controller's jerk: each joint reaches its acceleration in 50 ms
ACCELERATION_RESERVE = 0.5  # of every pose's torque headroom (peak − holding) kept for accelerating


@dataclass(frozen=True, eq=False)
class CatalogueLimits:
    """Per joint: v_max (rad/s) = k_v·v_rated, a_max (rad/s²) = k_a·a_drive, the scales
    (`velocity_scale`, `acceleration_scale`); what bound each (`velocity_bound_by[k]`,
    `acceleration_bound_by[k]`: the joint whose torque row binds it, or "drive" when the scale
    reaches 1, with the pose `…_worst_pose_rad[k]`, NaN for "drive"); the sample they were computed
    on and the reserve of step 1."""

    joint_names: tuple[str, ...]
    v_max: np.ndarray
    a_max: np.ndarray
    velocity_scale: np.ndarray
    acceleration_scale: np.ndarray
    velocity_bound_by: tuple[str, ...]
    acceleration_bound_by: tuple[str, ...]
    velocity_worst_pose_rad: np.ndarray
    acceleration_worst_pose_rad: np.ndarray
    acceleration_reserve: float
    payload_kg: float
    n_poses: int
    seed: int
    following_error_peak_rad: np.ndarray  # per joint, the own-axis peak following error at a_max
    following_error_allowed_rad: float  # the stated fraction of the drives' window
    following_error_reversal_peak_rad: np.ndarray  # the same after a reversal (servo.py)
    following_error_reversal_allowed_rad: float
    acceleration_binding: tuple[str, ...]  # per joint: "torque", "following error" or "drive"

    def binding_text(self) -> str:
        """Which bound binds each joint's acceleration, e.g. 'torque: joint_1, joint_2; following
        error: joint_6' (the plans' summaries state it)."""
        by: dict[str, list[str]] = {}
        for name, b in zip(self.joint_names, self.acceleration_binding, strict=True):
            by.setdefault(b, []).append(name)
        return "; ".join(f"{b}: {', '.join(names)}" for b, names in by.items())

    @property
    def bound_by(self) -> tuple[str, ...]:
        """Every joint whose torque row binds a limit (speed or acceleration)."""
        return self.velocity_bound_by + self.acceleration_bound_by

    def as_dict(self) -> dict[str, object]:
        """The artefact's statement of the limits and how they were computed (SI units)."""

        def pose(by: str, q: np.ndarray) -> list[float] | None:
            # none where no pose binds: the drive's own limit, or the following error (a servo bound)
            return None if by == "drive" or not np.all(np.isfinite(q)) else [float(x) for x in q]

        return {
            "method": "worst case over sampled poses of the prior model with the rated payload: "
            "|g + spring| + Σ|H| v v + friction(v) + Σ|M| a ≤ peak torque per joint (triangle "
            "inequality, all joints at their limits at once); velocity first: v = k_v·v_rated, k_v "
            "the largest with Σ|H| v v + friction(v) ≤ (1 − reserve)·(peak − |g + spring|) at every "
            "pose; then acceleration fills the rest: a = k_a·a_drive, k_a the largest with the whole "
            "bound ≤ peak (progressive filling of each scale over the joints)",
            "acceleration_reserve": self.acceleration_reserve,
            "n_poses": self.n_poses,
            "seed": self.seed,
            "payload_kg": self.payload_kg,
            "following_error": "and a = the largest whose own-axis following error, without torque "
            "feed-forward (drives.yaml servo loops on the axis' largest inertia, friction, the jerk "
            "ramp), peaks within the allowed fraction of the window from rest and within the "
            "reversal's after a reversal (the integrator holding −F_c; rxcomm.model.servo)",
            "following_error_allowed_rad": self.following_error_allowed_rad,
            "following_error_reversal_allowed_rad": self.following_error_reversal_allowed_rad,
            "joints": [
                {
                    "name": name,
                    "velocity_max_rad_s": float(self.v_max[k]),
                    "acceleration_max_rad_s2": float(self.a_max[k]),
                    "velocity_scale": float(self.velocity_scale[k]),
                    "acceleration_scale": float(self.acceleration_scale[k]),
                    "velocity_bound_by": self.velocity_bound_by[k],
                    "acceleration_bound_by": self.acceleration_bound_by[k],
                    "acceleration_binding": self.acceleration_binding[k],
                    "following_error_peak_rad": float(self.following_error_peak_rad[k]),
                    "following_error_reversal_peak_rad": float(self.following_error_reversal_peak_rad[k]),
                    "velocity_worst_pose_rad": pose(
                        self.velocity_bound_by[k], self.velocity_worst_pose_rad[k]
                    ),
                    "acceleration_worst_pose_rad": pose(
                        self.acceleration_bound_by[k], self.acceleration_worst_pose_rad[k]
                    ),
                }
                for k, name in enumerate(self.joint_names)
            ],
        }


def payload_parameters(robot: Robot, params: DynamicParameters | None = None) -> DynamicParameters:
    """`params` (default the prior) with drives.yaml's rated payload (a point mass at `com_m` in the
    TCP's parent frame) added to the last link's inertials; unchanged without a rated payload."""
    params = prior_parameters(robot) if params is None else params
    payload = robot.drives.rated_payload
    if payload is None:
        return params
    m = robot.model
    flange = m.frames[robot.flange_frame_id]
    if flange.parentJoint != m.njoints - 1:
        raise InfeasibleError(f"the TCP's parent frame {flange.name!r} is not on the last link")
    point = pin.Inertia(payload.mass_kg, np.array(payload.com_m, float), np.zeros((3, 3)))
    inertial = np.array(params.inertial)
    inertial[-1] += flange.placement.act(point).toDynamicParameters()
    from dataclasses import replace

    return replace(params, inertial=inertial)


@dataclass(frozen=True, eq=False)
class WorstCase:
    """The terms of the torque bound at poses q [N, n]: |g + τ_s| [N, n], |H| [N, n(row), n, n] (the
    Coriolis/centrifugal quadratic forms), |M| [N, n, n] (with rotor inertia), friction f(v) linear
    in the speed box (`friction_at`)."""

    hold: np.ndarray
    quadratic: np.ndarray
    mass: np.ndarray
    friction_0: np.ndarray
    friction_per_speed: np.ndarray

    def friction_at(self, v: np.ndarray) -> np.ndarray:
        return self.friction_0 + self.friction_per_speed @ v

    def bound(self, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Upper bound of |τ| [N, n] over |q̇| ≤ v, |q̈| ≤ a at each pose (triangle inequality)."""
        coriolis = np.einsum("ijkl,k,l->ij", self.quadratic, v, v)
        return self.hold + coriolis + self.friction_at(v)[None, :] + self.mass @ a


def worst_case_terms(robot: Robot, params: DynamicParameters, q: np.ndarray) -> WorstCase:
    """The bound's terms at poses q [N, n] (one CRBA, one gravity and n(n+1)/2 RNEA per pose)."""
    rd = RobotDynamics(robot, params)
    n = robot.n
    q = np.atleast_2d(np.asarray(q, float))
    free = pin.Model(rd.model)
    free.gravity.linear = np.zeros(3)
    data = free.createData()
    zero, eye = np.zeros(n), np.eye(n)
    quad = np.empty((len(q), n, n, n))
    for i, qi in enumerate(q):
        diag = [pin.rnea(free, data, qi, eye[k], zero) for k in range(n)]
        for k in range(n):
            quad[i, :, k, k] = diag[k]
            for m in range(k + 1, n):  # polarisation: H_km = (h(e_k + e_m) − h(e_k) − h(e_m)) / 2
                quad[i, :, k, m] = quad[i, :, m, k] = (
                    pin.rnea(free, data, qi, eye[k] + eye[m], zero) - diag[k] - diag[m]
                ) / 2
    f0, fv = np.array(params.coulomb_nm, float), np.diag(params.viscous_nm_s_per_rad)
    if params.has_motor_friction:
        r = np.abs(robot.joint_to_motor)
        f0 = f0 + r.T @ params.motor_coulomb_nm
        fv = fv + r.T @ np.diag(params.motor_viscous_nm_s_per_rad) @ r
    return WorstCase(np.abs(rd.gravity_torque(q)), np.abs(quad), np.abs(rd.mass_matrix(q)), f0, fv)


def _largest_scale(ok, tol: float = 1e-6) -> float:
    """The largest s in [0, 1] with ok(s) (ok monotone: true below some s*), by bisection."""
    if ok(1.0):
        return 1.0
    lo, hi = 0.0, 1.0
    while hi - lo > tol:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


@dataclass(frozen=True)
class _Filled:
    scale: np.ndarray
    bound_by: list[str]
    worst: np.ndarray  # per joint the index of the pose whose row bound it, −1 for "drive"


def _fill(n, box, ratio, load, names: tuple[str, ...], n_poses: int) -> _Filled:
    """Progressive filling of per-joint scales f ∈ [0, 1]: `box(f)` the (v, a) box, `ratio(v, a)`
    [N, n] the bound over its allowance (≤ 1 is safe), `load(i, j)` [n] how much each joint's scale
    loads row j at pose i (the joints fixed when that row binds)."""
    scale = np.zeros(n)
    free = np.ones(n, dtype=bool)
    bound_by = ["drive"] * n
    worst = np.full(n, -1)
    while free.any():

        def at(s: float, free=free) -> tuple[np.ndarray, np.ndarray]:
            return box(np.where(free, s, scale))

        s = _largest_scale(lambda s: bool(np.all(ratio(*at(s)) <= 1.0)))
        if s >= 1.0:
            scale[free] = 1.0
            break
        i, j = np.unravel_index(np.argmax(ratio(*at(s))), (n_poses, n))
        row = free & (load(i, j) > 1e-9 * max(float(load(i, j).max()), 1e-300))
        if not row.any():
            row = free.copy()
        scale[row] = s
        for k in np.flatnonzero(row):
            bound_by[k] = names[j]
            worst[k] = i
        free &= ~row
    return _Filled(scale, bound_by, worst)


def catalogue_limits(
    robot: Robot,
    n_poses: int = DEFAULT_POSES,
    seed: int = 0,
    params: DynamicParameters | None = None,
    acceleration_reserve: float = ACCELERATION_RESERVE,
) -> CatalogueLimits:
    """The catalogue limits of `robot` (module docstring) from `params` (default the prior with the
    rated payload), worst case over `n_poses` uniform poses, keeping `acceleration_reserve` of each
    pose's torque headroom for accelerating when the speeds are set. InfeasibleError when a joint
    cannot hold its load at rest somewhere (the rated payload is too heavy for the drives)."""
    if n_poses < 1:
        raise ValueError("n_poses must be positive")
    if not 0.0 < acceleration_reserve < 1.0:
        raise ValueError("acceleration_reserve must be in (0, 1)")
    params = payload_parameters(robot) if params is None else params
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.q_min, robot.q_max, (n_poses, robot.n))
    wc = worst_case_terms(robot, params, q)
    peak = np.asarray(robot.tau_max, float)
    n = robot.n
    zero = np.zeros(n)
    rest = wc.bound(zero, zero)
    if np.any(rest >= peak):
        i, j = np.unravel_index(np.argmax(rest / peak), rest.shape)
        raise InfeasibleError(
            f"catalogue limits: {robot.joint_names[j]} needs {rest[i, j]:.1f} N·m to hold the rated "
            f"payload at q = {np.round(q[i], 3).tolist()} rad, over its peak torque {peak[j]:.0f} N·m"
        )
    v_ref, a_ref = np.asarray(robot.v_max, float), np.asarray(robot.a_max, float)
    speed_allowance = (1.0 - acceleration_reserve) * (peak - wc.hold)  # [N, n], > 0 (checked above)
    vel = _fill(
        n,
        lambda f: (f * v_ref, zero),
        lambda v, a: (wc.bound(v, a) - wc.hold) / speed_allowance,
        lambda i, j: (wc.quadratic[i, j] + wc.quadratic[i, j].T) @ v_ref + wc.friction_per_speed[j],
        robot.joint_names,
        n_poses,
    )
    v_max = vel.scale * v_ref
    acc = _fill(
        n,
        lambda f: (v_max, f * a_ref),
        lambda v, a: wc.bound(v, a) / peak,
        lambda i, j: wc.mass[i, j] * a_ref,
        robot.joint_names,
        n_poses,
    )

    # what the drives follow without torque feed-forward: the own-axis following error (servo.py)
    a_torque = acc.scale * a_ref
    track = tracking_bound(
        robot,
        np.diagonal(wc.mass, axis1=1, axis2=2).max(axis=0),
        a_torque,
        v_max,
        JERK_RAMP_S,
        wc.friction_0,
        np.diag(wc.friction_per_speed),
    )
    binding = tuple(
        "following error" if track.binds[k] else ("drive" if acc.bound_by[k] == "drive" else "torque")
        for k in range(n)
    )
    bound_by = tuple(robot.joint_names[k] if track.binds[k] else acc.bound_by[k] for k in range(n))
    worst_acc = np.where(track.binds, -1, acc.worst)

    def poses(worst: np.ndarray) -> np.ndarray:
        return np.where((worst >= 0)[:, None], q[np.maximum(worst, 0)], np.nan)

    return CatalogueLimits(
        joint_names=robot.joint_names,
        v_max=v_max,
        a_max=track.a_max,
        velocity_scale=vel.scale,
        acceleration_scale=track.a_max / a_ref,
        velocity_bound_by=tuple(vel.bound_by),
        acceleration_bound_by=bound_by,
        velocity_worst_pose_rad=poses(vel.worst),
        acceleration_worst_pose_rad=poses(worst_acc),
        acceleration_reserve=acceleration_reserve,
        payload_kg=0.0 if robot.drives.rated_payload is None else robot.drives.rated_payload.mass_kg,
        n_poses=n_poses,
        seed=seed,
        following_error_peak_rad=track.peak_rad,
        following_error_allowed_rad=track.allowed_rad,
        following_error_reversal_peak_rad=track.reversal_peak_rad,
        following_error_reversal_allowed_rad=track.reversal_allowed_rad,
        acceleration_binding=binding,
    )
