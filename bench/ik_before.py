"""The IK as it was before the one IK (rxcomm before commit afcf7a6), kept here only to measure
against in the same run: a projected Levenberg–Marquardt from the seed on the world-aligned pose
error (`inverse_kinematics` then). Every branch of a pose was a 96-start Newton search, which is
still rxcomm's fallback for arms without a closed form (`rxcomm.model.ik._multi_start`)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from rxcomm.model.robot import Robot


def lm_from_seed(
    robot: Robot, target: pin.SE3, q_seed: np.ndarray, tol: float = 1e-11, max_step_rad: float = 0.2
) -> tuple[np.ndarray, bool]:
    """(q, converged): the earlier `inverse_kinematics` with its defaults (a fresh Data per call)."""
    model, data, fid = robot.model, robot.create_data(), robot.tcp_frame_id
    q = np.clip(np.asarray(q_seed, dtype=float).copy(), robot.q_min, robot.q_max)

    def evaluate(qv: np.ndarray) -> tuple[np.ndarray, float, float]:
        pin.forwardKinematics(model, data, qv)
        m = pin.updateFramePlacement(model, data, fid)
        ep = target.translation - m.translation
        eo = pin.log3(target.rotation @ m.rotation.T)
        return np.concatenate([ep, eo]), float(np.linalg.norm(ep)), float(np.linalg.norm(eo))

    e, pe, oe = evaluate(q)
    lam, stall = 1e-3, 0
    for _ in range(200):
        if pe <= tol and oe <= tol:
            break
        jac = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
        jtj, jte = jac.T @ jac, jac.T @ e
        cost = float(e @ e)
        improved = False
        for _ in range(12):
            dq = np.linalg.solve(jtj + lam * (np.eye(robot.n) + np.diag(np.diag(jtj))), jte)
            big = np.max(np.abs(dq))
            if big > max_step_rad:
                dq *= max_step_rad / big
            q_new = np.clip(q + dq, robot.q_min, robot.q_max)
            e_new, pe_new, oe_new = evaluate(q_new)
            if float(e_new @ e_new) < cost:
                q, e, pe, oe = q_new, e_new, pe_new, oe_new
                lam = max(lam / 5.0, 1e-12)
                improved = True
                break
            lam *= 8.0
        stall = stall + 1 if not improved or float(e @ e) >= 0.999 * cost else 0
        if stall >= 3 or lam > 1e8:
            break
    return q, bool(pe <= tol and oe <= tol)
