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


def _newton_before(robot: Robot, data: pin.Data, target: pin.SE3, q: np.ndarray, iters: int = 40):
    """The earlier `newton_pose`: framesForwardKinematics, then the frame Jacobian, np.linalg.solve."""
    m, fid = robot.model, robot.tcp_frame_id
    err = np.inf
    for _ in range(iters):
        pin.framesForwardKinematics(m, data, q)
        e = pin.log6(data.oMf[fid].actInv(target)).vector
        err = float(np.linalg.norm(e))
        if err < 1e-11:
            break
        jac = pin.computeFrameJacobian(m, data, q, fid, pin.LOCAL)
        try:
            dq = np.linalg.solve(jac, e)
        except np.linalg.LinAlgError:
            return q, np.inf
        step = np.max(np.abs(dq))
        if step > 0.5:
            dq *= 0.5 / step
        q = q + dq
    return q, err


def multi_start_before(robot: Robot, data: pin.Data, target: pin.SE3, n_starts: int = 96) -> list[np.ndarray]:
    """The earlier search for a pose's solutions (`solve_branch_ik` without a seed, no branch filter):
    Newton from ``n_starts`` deterministic starts, half facing the target; the converged ones."""
    rng = np.random.default_rng(0)
    lo, hi = robot.q_min, robot.q_max
    q1 = np.arctan2(target.translation[1], target.translation[0])
    found = []
    for k in range(n_starts):
        q0 = rng.uniform(np.maximum(lo, -np.pi), np.minimum(hi, np.pi))
        if k % 2 == 0:
            q0[0] = ((q1 if k % 4 == 0 else q1 + np.pi) + np.pi) % (2 * np.pi) - np.pi
        q, err = _newton_before(robot, data, target, q0)
        if err <= 1e-9 and np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9):
            found.append(q)
    return found
