"""Jerk-limited moves between rest positions: the approach to a plan's start and a campaign's poses.

A ruckig profile (time-optimal under per-joint velocity, acceleration and jerk limits, joints
synchronised) at a fraction of the robot's velocity and acceleration limits, sampled at the drive
cycle. The result is an ordinary trajectory: it goes through the same dense limit check as any plan.
Given a model, the move is slowed until its torque fits: the fractions alone know nothing of gravity or
friction.
"""

from __future__ import annotations

import numpy as np

from rxcomm.errors import InputError
from rxcomm.execution.plan import model_torque
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.robot import Robot
from rxcomm.planning.warm_start import ruckig_profile

JERK_RAMP_S = 0.1  # acceleration builds up over this long: j_max = a_max / JERK_RAMP_S


def move_trajectory(
    robot: Robot,
    q_from: np.ndarray,
    q_to: np.ndarray,
    sample_s: float,
    speed_fraction: float = 0.2,
    hold_s: float = 0.0,
    *,
    paced_by: DynamicParameters | None = None,
    max_torque_ratio: float = 0.9,
) -> Trajectory:
    """Rest-to-rest jerk-limited move sampled every ``sample_s``, velocity and acceleration limits
    scaled by ``speed_fraction`` (0 < f ≤ 1), then ``hold_s`` at the goal (the drives settle on a
    streamed demand, so settling takes the same time on a real and a virtual-time cell). A move of
    zero length is two identical samples.

    ``paced_by`` a model: the fraction is lowered by 0.7× a step (at most 11) until that model's torque
    stays within ``max_torque_ratio`` of every peak. A joint whose viscous friction at 20 % of its speed
    limit already exceeds the peak (an imported model whose `damping` stabilises a simulation: the
    UR5e's 200 N·m·s/rad on a 150 N·m joint) moves slower instead of being refused; a pose whose
    holding torque alone is too high is still refused by the dense check (`prepare_plan`)."""
    if not 0.0 < speed_fraction <= 1.0:
        raise InputError(f"must be in (0, 1], got {speed_fraction}", field="speed_fraction")
    q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
    for name, q in (("q_from", q_from), ("q_to", q_to)):
        if q.shape != (robot.n,) or not np.all(np.isfinite(q)):
            raise InputError(f"expected {robot.n} finite joint angles, got {q.tolist()}", field=name)
    fraction = speed_fraction
    for _ in range(12 if paced_by is not None else 1):
        v = fraction * np.asarray(robot.v_max)
        a = fraction * np.asarray(robot.a_max)
        profile = ruckig_profile(q_from, q_to, v, a, a / JERK_RAMP_S)
        n = max(2, int(np.ceil(profile.duration_s / sample_s - 1e-9)) + 1)
        n_total = n + int(np.ceil(hold_s / sample_s - 1e-9))
        t = np.arange(n_total) * sample_s
        q, qd, qdd = profile.at(t)
        q[n - 1 :], qd[n - 1 :], qdd[n - 1 :] = q_to, 0.0, 0.0  # exactly at the goal, at rest
        if paced_by is None:
            break
        tau = model_torque(robot, paced_by, q, qd, qdd)
        if np.max(np.abs(tau) / np.asarray(robot.tau_max)) <= max_torque_ratio:
            break
        fraction *= 0.7
    return Trajectory(t, q, qd, qdd)
