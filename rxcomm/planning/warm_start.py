"""Jerk-limited kinematic point-to-point profiles (ruckig): the PtP warm start and its fallback.

Ruckig computes a time-optimal profile under per-joint velocity, acceleration and jerk limits in
microseconds, all joints time-synchronised. It knows no dynamics: as a warm start the limits only need
to be plausible; as a fallback (`feasible_profile`) the profile is slowed down by time scaling until the
dense check of the real limits (torque, torque rate, ...) passes. architecture §7: such a profile is ≈ 25 %
slower than the dynamic optimum, a warm start and a fallback, not the answer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from rxcomm.errors import InfeasibleError, InputError


@dataclass(frozen=True, eq=False)
class KinematicProfile:
    """A rest-to-rest profile with piecewise-constant jerk; `at(t)` evaluates it anywhere in [0, T]."""

    duration_s: float
    trajectory: Trajectory
    dof: int

    def at(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, qd, qdd), each [len(t), dof], at the times `t` (clipped to [0, duration])."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration_s)
        out = np.empty((3, len(t), self.dof))
        for i, ti in enumerate(t):
            p, v, a = self.trajectory.at_time(float(ti))[:3]
            out[:, i] = p, v, a
        return out[0], out[1], out[2]


def ruckig_profile(
    q_start, q_goal, v_max, a_max, j_max, *, min_duration_s: float | None = None
) -> KinematicProfile:
    """The time-optimal jerk-limited rest-to-rest profile from `q_start` to `q_goal`, joints synchronised.

    Limits are per joint, positive (rad/s, rad/s², rad/s³). `min_duration_s` stretches it to at least
    that long (ruckig's `minimum_duration`), e.g. to build a different warm start.
    """
    q_start, q_goal = np.asarray(q_start, float), np.asarray(q_goal, float)
    n = len(q_start)
    for name, lim in (("v_max", v_max), ("a_max", a_max), ("j_max", j_max)):
        if not np.all(np.asarray(lim) > 0):
            raise InputError(f"must be positive per joint, got {np.asarray(lim).tolist()}", field=name)
    inp = InputParameter(n)
    inp.current_position = q_start.tolist()
    inp.current_velocity = [0.0] * n
    inp.current_acceleration = [0.0] * n
    inp.target_position = q_goal.tolist()
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = np.asarray(v_max, float).tolist()
    inp.max_acceleration = np.asarray(a_max, float).tolist()
    inp.max_jerk = np.asarray(j_max, float).tolist()
    if min_duration_s is not None:
        inp.minimum_duration = float(min_duration_s)
    traj = Trajectory(n)
    result = Ruckig(n).calculate(inp, traj)
    if result not in (Result.Working, Result.Finished):
        raise InfeasibleError(f"ruckig could not build a kinematic profile: {result.name}")
    duration = float(traj.duration)
    if duration <= 0.0:  # start == goal: a zero-length profile; keep it evaluable
        duration = 0.0
    return KinematicProfile(duration_s=duration, trajectory=traj, dof=n)


def scaled_profile(q_start, q_goal, v_max, a_max, j_max, speed: float) -> KinematicProfile:
    """The ruckig profile with limits scaled as a time scaling by `speed` ≤ 1 would scale them.

    Velocity × s, acceleration × s², jerk × s³: the same shape of motion, slower.
    """
    s = float(speed)
    return ruckig_profile(
        q_start, q_goal, np.asarray(v_max) * s, np.asarray(a_max) * s**2, np.asarray(j_max) * s**3
    )


def feasible_profile(
    q_start,
    q_goal,
    v_max,
    a_max,
    j_max,
    max_ratio: Callable[[KinematicProfile], float],
    *,
    target: float = 1.0,
    iterations: int = 40,
) -> tuple[KinematicProfile, float]:
    """The fastest time-scaled ruckig profile whose `max_ratio(profile)` (a dense limit check) is ≤ `target`.

    Bisects the speed factor s of `scaled_profile` (after doubling it while the profile still fits, so
    conservative kinematic limits do not make a slow fallback). Returns (profile, its ratio). Raises
    InfeasibleError if even a very slow profile fails (e.g. a holding torque above its limit).
    """

    def at(speed: float) -> tuple[KinematicProfile, float]:
        p = scaled_profile(q_start, q_goal, v_max, a_max, j_max, speed)
        return p, max_ratio(p)

    lo, hi = 1.0, 1.0
    best, best_r = at(1.0)
    if best_r <= target:
        while hi < 64.0:  # grow until infeasible
            hi *= 2.0
            p, r = at(hi)
            if r > target:
                break
            lo, best, best_r = hi, p, r
        else:
            return best, best_r
    else:
        lo = 1e-3
        best, best_r = at(lo)
        if best_r > target:
            raise InfeasibleError(
                f"no kinematic fallback: even at {lo:g}× speed the limit ratio is {best_r:.3f} > {target}"
            )
    for _ in range(iterations):
        if hi - lo < 1e-3 * hi:
            break
        mid = 0.5 * (lo + hi)
        p, r = at(mid)
        if r <= target:
            lo, best, best_r = mid, p, r
        else:
            hi = mid
    return best, best_r
