"""The calibration's weighted residual and its Jacobian, and the paper's Table 2 statistics.

Residual of pose i (tracker frame): rᵢ = [ (p_pred − p_meas) / σ_p ; log3(R_pred·R_measᵀ) / σ_o ],
so rᵢ ~ N(0, I) when the model is right; orientation rows differentiate log3 exactly (`jlog3`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.calibration.compliance import TAU_REF_NM
from rxcomm.calibration.measurements import MeasurementSet
from rxcomm.model.geometric_errors import (
    ErrorModel,
    identification_jacobians,
    parameter_names,
    predict_poses,
)
from rxcomm.model.kinematics import cardan_xyz
from rxcomm.model.robot import Robot


def log3(r: np.ndarray) -> np.ndarray:
    """Batched log3 for rotations away from π ([N, 3, 3] → [N, 3])."""
    w = 0.5 * np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1)
    s = np.linalg.norm(w, axis=1)
    c = 0.5 * (np.trace(r, axis1=1, axis2=2) - 1.0)
    theta = np.arctan2(s, c)
    k = np.where(s > 1e-12, theta / np.maximum(s, 1e-300), 1.0 + s * s / 6.0)
    return w * k[:, None]


def skew(v: np.ndarray) -> np.ndarray:
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def jlog3(phi: np.ndarray) -> np.ndarray:
    """Batched inverse right Jacobian of SO(3) at log vectors [N, 3] (pin.Jlog3)."""
    th = np.linalg.norm(phi, axis=1)
    k = skew(phi)
    small = th < 1e-5
    ths = np.where(small, 1.0, th)
    coef = np.where(small, 1.0 / 12.0, 1.0 / ths**2 - (1 + np.cos(ths)) / (2 * ths * np.sin(ths)))
    return np.eye(3) + 0.5 * k + coef[:, None, None] * (k @ k)


@dataclass(frozen=True)
class Problem:
    """The weighted residual of a fit: geometric parameters `idx` (into the 48) then, per compliant
    joint in `comp`, c_j·TAU_REF with the link at q − c·τ (τ the prior holding torque)."""

    robot: Robot
    q: np.ndarray
    p_meas: np.ndarray
    r_meas: np.ndarray | None
    t2b: pin.SE3
    sigma_p: float
    sigma_o: float
    idx: np.ndarray
    point: np.ndarray | None
    tau: np.ndarray | None = None  # [N, n] N·m, needed with `comp`
    comp: tuple[int, ...] = ()

    def errors(self, x: np.ndarray) -> ErrorModel:
        v = np.zeros(len(parameter_names(self.robot)))
        v[self.idx] = x[: len(self.idx)]
        return ErrorModel(parameter_names(self.robot), v)

    def q_link(self, x: np.ndarray) -> np.ndarray:
        if not self.comp:
            return self.q
        q = np.array(self.q)
        q[:, self.comp] -= self.tau[:, self.comp] * (x[len(self.idx) :] / TAU_REF_NM)
        return q

    def residual(self, x: np.ndarray) -> np.ndarray:
        p, r = predict_poses(self.robot, self.q_link(x), self.errors(x), self.t2b, self.point)
        res = [(p - self.p_meas) / self.sigma_p]
        if self.r_meas is not None:
            res.append(log3(r @ self.r_meas.transpose(0, 2, 1)) / self.sigma_o)
        return np.concatenate(res, axis=1).ravel()

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        e, q = self.errors(x), self.q_link(x)
        po = self.r_meas is None
        full = identification_jacobians(self.robot, q, e, self.t2b, po, self.point, joints=bool(self.comp))
        jac = full[:, :, self.idx]
        if self.comp:  # the joint columns follow the 6·(n + 2) error parameters
            jq = full[:, :, [6 * (self.robot.n + 2) + j for j in self.comp]]
            jac = np.concatenate([jac, jq * (-self.tau[:, None, list(self.comp)] / TAU_REF_NM)], axis=2)
        k = jac.shape[2]
        jp = jac[:, :3] / self.sigma_p
        if po:
            return jp.reshape(-1, k)
        _, r = predict_poses(self.robot, q, e, self.t2b, self.point)
        err = r @ self.r_meas.transpose(0, 2, 1)
        jo = jlog3(log3(err)) @ err.transpose(0, 2, 1) @ jac[:, 3:] / self.sigma_o
        return np.concatenate([jp, jo], axis=1).reshape(-1, k)


def pose_errors(
    robot: Robot,
    ms: MeasurementSet,
    errors: ErrorModel | None,
    tracker_to_base: pin.SE3,
    point: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """(measured − predicted position [N, 3] m, Cardan x-y-z of R_meas·R_predᵀ [N, 3] rad or None)."""
    p, r = predict_poses(robot, ms.q, errors, tracker_to_base, point)
    e_pos = ms.position_m - p
    e_ori = None if ms.rotation is None else cardan_xyz(ms.rotation @ r.transpose(0, 2, 1))
    return e_pos, e_ori


@dataclass(frozen=True)
class ErrorStats:
    """The paper's Table 2 for one pose set and model."""

    n_poses: int
    max_abs: np.ndarray  # [6] x, y, z (m), α, β, γ (rad); NaN for orientation when position only
    peak_to_peak: np.ndarray
    rms: np.ndarray
    max_position_error_m: float
    max_orientation_error_rad: float | None
    rms_position_error_m: float  # sqrt(mean over poses of |e_xyz|²)


def error_table(
    robot: Robot, ms: MeasurementSet, errors: ErrorModel | None, tracker_to_base: pin.SE3, point=None
) -> ErrorStats:
    e_pos, e_ori = pose_errors(robot, ms, errors, tracker_to_base, point)
    e = np.concatenate([e_pos, np.full_like(e_pos, np.nan) if e_ori is None else e_ori], axis=1)
    max_ori = None
    if ms.rotation is not None:
        _, r = predict_poses(robot, ms.q, errors, tracker_to_base, point)
        max_ori = float(np.max(np.linalg.norm(log3(ms.rotation @ r.transpose(0, 2, 1)), axis=1)))
    return ErrorStats(
        n_poses=ms.n,
        max_abs=np.max(np.abs(e), axis=0),
        peak_to_peak=np.ptp(e, axis=0),
        rms=np.sqrt(np.mean(e**2, axis=0)),
        max_position_error_m=float(np.max(np.linalg.norm(e_pos, axis=1))),
        max_orientation_error_rad=max_ori,
        rms_position_error_m=float(np.sqrt(np.mean(np.sum(e_pos**2, axis=1)))),
    )
