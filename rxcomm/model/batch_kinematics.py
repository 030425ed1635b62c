"""Forward kinematics of many joint vectors at once (numpy over the samples), for serial chains of
revolute joints: what the run-log writer needs per drive cycle (the TCP error and the planned TCP
speed of every sample), where Pinocchio's per-call overhead (~10 µs) made it the writer's largest cost.

The chain is read from the Pinocchio model (joint placements, joint axes, the TCP frame's placement in
its joint), so it is the same kinematics as ``rxcomm.model.kinematics``; tests/test_run_log_rows.py
compares both. A model with another joint type gets ``None`` from :func:`serial_chain` and the caller
uses Pinocchio.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.model.robot import Robot

_AXES = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}


@dataclass(frozen=True)
class SerialChain:
    """Revolute joints 1..n in order: placement in the parent joint (R [n,3,3], p [n,3]), unit axis
    [n,3] in the joint frame; the TCP's placement in joint n."""

    rotation: np.ndarray
    translation: np.ndarray
    axis: np.ndarray
    tcp_rotation: np.ndarray
    tcp_translation: np.ndarray


def serial_chain(robot: Robot) -> SerialChain | None:
    """The chain of ``robot`` up to its TCP; None unless it is n revolute joints, each the child of the
    one before, with the TCP on the last."""
    m = robot.model
    if m.nq != m.nv or m.njoints != m.nq + 1:
        return None
    axes = []
    for j in range(1, m.njoints):
        joint = m.joints[j]
        if m.parents[j] != j - 1:
            return None
        if joint.shortname() in _AXES:
            axes.append(_AXES[joint.shortname()])
        elif joint.shortname() == "JointModelRevoluteUnaligned":
            axes.append(tuple(np.asarray(joint.extract().axis, dtype=float)))
        else:
            return None
    frame = m.frames[robot.tcp_frame_id]
    if frame.parentJoint != m.njoints - 1:
        return None
    placements = [m.jointPlacements[j] for j in range(1, m.njoints)]
    return SerialChain(
        np.array([p.rotation for p in placements]),
        np.array([p.translation for p in placements]),
        np.array(axes, dtype=float),
        np.array(frame.placement.rotation),
        np.array(frame.placement.translation),
    )


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def _times(rot: np.ndarray, m: np.ndarray) -> np.ndarray:
    """rot [n, 3, 3] @ m [3, 3] (or [3]) as one matrix product over the stacked rows."""
    out = rot.reshape(-1, 3) @ m
    return out.reshape(rot.shape[0], 3, *m.shape[1:])


def tcp_positions(
    chain: SerialChain, q: np.ndarray, qd: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """TCP positions [n, 3] (m) of the rows of ``q`` [n, dof] and, with ``qd``, the TCP linear velocity
    [n, 3] (m/s, J_v(q)·qd: each joint's world axis × (p_tcp − p_joint)).

    Joint j turns by Rodrigues' formula, R_j(q) = A_j (I + sin q K + (1 − cos q) K²) with A_j its
    fixed placement and K the axis' cross-product matrix: three constant 3×3 factors per joint, so a
    step down the chain is three stacked matrix products and no per-sample work."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    pos = np.zeros((n, 3))
    axes, origins = [], []
    for j in range(q.shape[1]):
        a, k = chain.rotation[j], _skew(chain.axis[j])
        pos = pos + _times(rot, chain.translation[j])
        ra = _times(rot, a)
        axes.append(_times(ra, chain.axis[j]))
        origins.append(pos)
        s, c1 = np.sin(q[:, j])[:, None, None], (1.0 - np.cos(q[:, j]))[:, None, None]
        rot = ra + s * _times(rot, a @ k) + c1 * _times(rot, a @ k @ k)
    tcp = pos + _times(rot, chain.tcp_translation)
    if qd is None:
        return tcp, None
    qd = np.atleast_2d(np.asarray(qd, dtype=float))
    v = np.zeros((n, 3))
    for j, (a, o) in enumerate(zip(axes, origins, strict=True)):
        v += np.cross(a, tcp - o) * qd[:, j : j + 1]
    return tcp, v


def tcp_positions_pinocchio(robot: Robot, q: np.ndarray) -> np.ndarray:
    """The same positions through Pinocchio, one call per row (the reference for the tests)."""
    data = robot.create_data()
    out = np.zeros((len(q), 3))
    for i, qi in enumerate(np.atleast_2d(q)):
        pin.framesForwardKinematics(robot.model, data, qi)
        out[i] = data.oMf[robot.tcp_frame_id].translation
    return out
