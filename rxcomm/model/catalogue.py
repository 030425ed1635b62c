"""Catalogue limits: the joint speeds and accelerations a maker publishes for a generic controller.

A generic controller knows no dynamics, so its maker states kinematic limits that are safe at every
pose of the workspace with the rated payload. Here they are computed from the PRIOR model (URDF
inertias, drives.yaml rotor inertias, friction priors, spring, peak torques, `rated_payload`):

- per joint a time scale k ≤ 1 of the drive's own limits: v = k·v_rated (the URDF's joint speeds),
  a = k²·a_drive (drives.yaml's acceleration limits), as slowing a motion down in time by k scales
  its speeds by k and its accelerations (and so its dynamic torques) by k²;
- k the largest such that at every sampled pose q, every joint j and every state with |q̇_k| ≤ v_k,
  |q̈_k| ≤ a_k,

      |g_j(q) + τ_s,j(q)| + Σ_kl |H_j,kl(q)| v_k v_l + f_j(v) + Σ_k |M_jk(q)| a_k  ≤  τ_peak,j

  (H_j the Coriolis/centrifugal quadratic form, f_j the worst friction at full speed, M with the
  reflected rotor inertia). The left side bounds |τ_j| by the triangle inequality: conservative, as
  a published figure must be. Progressive filling: all joints' k grow together until a torque row
  binds (tight: that pose's bound equals its peak torque); the joints loading that row are fixed,
  the others grow on.

Poses are drawn uniformly within the joint limits (seeded); `CatalogueLimits` says how many, which
pose and which torque row bound each joint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.errors import InfeasibleError
from rxcomm.model.dynamics import DynamicParameters, RobotDynamics, prior_parameters
from rxcomm.model.robot import Robot

DEFAULT_POSES = 2000


@dataclass(frozen=True, eq=False)
class CatalogueLimits:
    """Per joint: v_max (rad/s), a_max (rad/s²), the time scale k of the drive limits; what bound it
    (`bound_by[k]`: the joint whose peak torque binds it, or "drive" when k reaches 1, with the pose
    `worst_pose_rad[k]`, NaN for "drive"); the sample they were computed on."""

    joint_names: tuple[str, ...]
    v_max: np.ndarray
    a_max: np.ndarray
    bound_by: tuple[str, ...]
    worst_pose_rad: np.ndarray
    time_scale: np.ndarray
    payload_kg: float
    n_poses: int
    seed: int

    def as_dict(self) -> dict[str, object]:
        """The artefact's statement of the limits and how they were computed (SI units)."""
        return {
            "method": "worst case over sampled poses of the prior model with the rated payload: "
            "|g + spring| + Σ|H| v v + friction(v) + Σ|M| a ≤ peak torque per joint, v = k·v_rated, "
            "a = k²·a_drive (progressive filling of k)",
            "n_poses": self.n_poses,
            "seed": self.seed,
            "payload_kg": self.payload_kg,
            "joints": [
                {
                    "name": name,
                    "velocity_max_rad_s": float(self.v_max[k]),
                    "acceleration_max_rad_s2": float(self.a_max[k]),
                    "time_scale": float(self.time_scale[k]),
                    "bound_by": self.bound_by[k],
                    "worst_pose_rad": None
                    if self.bound_by[k] == "drive"
                    else [float(x) for x in self.worst_pose_rad[k]],
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


def catalogue_limits(
    robot: Robot, n_poses: int = DEFAULT_POSES, seed: int = 0, params: DynamicParameters | None = None
) -> CatalogueLimits:
    """The catalogue limits of `robot` (module docstring) from `params` (default the prior with the
    rated payload), worst case over `n_poses` uniform poses. InfeasibleError when a joint cannot
    hold its load at rest somewhere (the rated payload is too heavy for the drives)."""
    if n_poses < 1:
        raise ValueError("n_poses must be positive")
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
    scale = np.zeros(n)
    free = np.ones(n, dtype=bool)
    bound_by = ["drive"] * n
    worst = np.full((n, n), np.nan)
    while free.any():

        def limits(s: float, free=free) -> tuple[np.ndarray, np.ndarray]:
            f = np.where(free, s, scale)
            return f * v_ref, f**2 * a_ref

        s = _largest_scale(lambda s: bool(np.all(wc.bound(*limits(s)) <= peak)))
        if s >= 1.0:
            scale[free] = 1.0
            break
        v, a = limits(s)
        i, j = np.unravel_index(np.argmax(wc.bound(v, a) / peak), rest.shape)
        # the free joints that load the binding row: through its inertia or its Coriolis terms
        load = (
            wc.mass[i, j] * a_ref
            + (wc.quadratic[i, j] + wc.quadratic[i, j].T) @ v_ref
            + wc.friction_per_speed[j]
        )
        row = free & (load > 1e-9 * load.max())
        if not row.any():
            row = free.copy()
        scale[row] = s
        for k in np.flatnonzero(row):
            bound_by[k] = robot.joint_names[j]
            worst[k] = q[i]
        free &= ~row
    return CatalogueLimits(
        joint_names=robot.joint_names,
        v_max=scale * v_ref,
        a_max=scale**2 * a_ref,
        bound_by=tuple(bound_by),
        worst_pose_rad=worst,
        time_scale=scale,
        payload_kg=0.0 if robot.drives.rated_payload is None else robot.drives.rated_payload.mass_kg,
        n_poses=n_poses,
        seed=seed,
    )
