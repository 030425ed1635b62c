"""Base and tool frames from the data in closed form, so no guess is needed; a guessed
tracker_to_base (cell or measurements file) is the reference only when it agrees with the data's."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.calibration.measurements import MeasurementSet
from rxcomm.calibration.residuals import log3
from rxcomm.errors import InputError
from rxcomm.model.geometric_errors import predict_poses
from rxcomm.model.robot import Robot


def _kabsch(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The rotation R minimising Σ‖v_k − R·u_k‖² (rows of u, v; no centring)."""
    a, _, bt = np.linalg.svd(u.T @ v)
    d = np.sign(np.linalg.det(bt.T @ a.T))
    return bt.T @ np.diag([1.0, 1.0, d]) @ a.T


def _project_so3(m: np.ndarray) -> np.ndarray:
    """The rotation nearest to `m` (Frobenius): the chordal mean of rotations summed into `m`."""
    a, _, bt = np.linalg.svd(m)
    return a @ np.diag([1.0, 1.0, np.sign(np.linalg.det(a @ bt))]) @ bt


@dataclass(frozen=True)
class DataFrames:
    """Base and tool frames estimated from the measurements alone: the measured pose
    X_i ≈ tracker_to_base · A(q_i) · tool with A the nominal TCP pose in the base frame (drives.yaml's
    TCP). `rotation_rms_rad`: what a rigid tool leaves of the measured orientations (None: positions)."""

    tracker_to_base: pin.SE3
    tool: pin.SE3  # the TCP correction: tcp' = tcp · tool
    rotation_rms_rad: float | None


def estimate_frames(robot: Robot, ms: MeasurementSet, point: np.ndarray | None = None) -> DataFrames:
    """tracker_to_base and the tool correction in closed form, no guess needed.

    Full pose: the base rotation R_Y from the relative rotations (log(R_Mi·R_Mjᵀ) = R_Y·log(R_Ai·R_Ajᵀ),
    a Kabsch fit of rotation vectors over pose pairs), the tool rotation R_D the chordal mean of
    R_Aiᵀ·R_Yᵀ·R_Mi, then base and tool translations by linear least squares (p_Mi − R_Y·a_i =
    R_Y·R_Ai·w + t_Y). Positions only: Kabsch registration of the nominal points alternated with the
    linear solve for the point offset w (converges in a few rounds from w = the nominal point).
    """
    if ms.n < 3:
        raise InputError("need at least 3 valid poses to locate the robot base in the tracker frame")
    a_p, a_r = predict_poses(robot, ms.q)
    pt = np.zeros(3) if point is None else np.asarray(point, dtype=float)
    p_m = ms.position_m
    if np.linalg.svd(p_m - p_m.mean(0), compute_uv=False)[1] < 1e-6:
        raise InputError("the measured positions are collinear: the base cannot be located", file=ms.source)

    def translations(r_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # [R_Y·R_Ai, I]·[w; t_Y] = p_Mi − R_Y·a_i, stacked over poses.
        a = np.concatenate([r_y @ a_r, np.broadcast_to(np.eye(3), a_r.shape)], axis=2).reshape(-1, 6)
        b = (p_m - a_p @ r_y.T).reshape(-1)
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
        return sol[:3], sol[3:]

    rms = None
    if ms.rotation is not None:
        i, j = np.triu_indices(ms.n, 1)
        u = log3(a_r[i] @ a_r[j].transpose(0, 2, 1))
        v = log3(ms.rotation[i] @ ms.rotation[j].transpose(0, 2, 1))
        nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
        ok = (nu > 0.05) & (nu < 2.8) & (nv < 2.8)  # log3 is ill-conditioned near π
        if ok.sum() < 2:
            raise InputError("the poses hardly rotate the tool: the base cannot be located", file=ms.source)
        r_y = _kabsch(u[ok], v[ok])
        r_d = _project_so3(np.sum(a_r.transpose(0, 2, 1) @ r_y.T @ ms.rotation, axis=0))
        w, t_y = translations(r_y)
        left = log3(ms.rotation @ (r_y @ a_r @ r_d).transpose(0, 2, 1))
        rms = float(np.sqrt(np.mean(np.sum(left**2, axis=1))))
    else:
        r_d, w, t_y = np.eye(3), pt, np.zeros(3)
        for _ in range(50):
            x = a_p + a_r @ w
            xc, mc = x.mean(0), p_m.mean(0)
            r_y = _kabsch(x - xc, p_m - mc)
            w_new, t_y = translations(r_y)
            done = np.linalg.norm(w_new - w) < 1e-9
            w = w_new
            if done:
                break
    return DataFrames(pin.SE3(r_y, t_y), pin.SE3(r_d, w - r_d @ pt), rms)


def register_base(robot: Robot, q: np.ndarray, positions_m: np.ndarray) -> pin.SE3:
    """tracker_to_base by rigid registration (Kabsch) of nominal TCP positions onto measured ones."""
    if q.shape[0] < 3:
        raise InputError("need at least 3 valid poses to register the robot base in the tracker frame")
    nominal, _ = predict_poses(robot, q)
    mc, nc = positions_m.mean(0), nominal.mean(0)
    r = _kabsch(nominal - nc, positions_m - mc)
    return pin.SE3(r, mc - r @ nc)


def placement_gap(robot: Robot, q: np.ndarray, a: pin.SE3, b: pin.SE3, point) -> float:
    """Median distance (m) between the nominal TCP positions placed by base frames a and b."""
    pa, _ = predict_poses(robot, q, None, a, point)
    pb, _ = predict_poses(robot, q, None, b, point)
    return float(np.median(np.linalg.norm(pa - pb, axis=1)))


# A guessed base farther than this from the data's (median TCP displacement) is replaced by the data's.
BASE_GUESS_TOLERANCE_M = 0.02


def reference_base(
    robot: Robot, ms: MeasurementSet, data: DataFrames, guess: pin.SE3 | None, source: str, point
) -> tuple[pin.SE3, str, str | None]:
    """(tracker_to_base, its source, a note or None): the guess (from `source`) when it places the
    robot within BASE_GUESS_TOLERANCE_M of where the data put it, else the data's frame with a note."""
    if guess is None:
        return data.tracker_to_base, "registration", None
    gap = placement_gap(robot, ms.q, guess, data.tracker_to_base, point)
    if gap <= BASE_GUESS_TOLERANCE_M:
        return guess, source, None
    dr = np.degrees(np.linalg.norm(pin.log3(guess.rotation.T @ data.tracker_to_base.rotation)))
    note = (
        f"tracker_to_base from the {source} places the robot {gap * 1e3:.0f} mm (median at the TCP; "
        f"{dr:.1f}° rotation) from where the measurements put it: the base from the data is used "
        f"(check the {source}'s tracker_to_base)"
    )
    return data.tracker_to_base, "registration", note
