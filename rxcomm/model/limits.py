"""Dense limit checks on sampled trajectories, shared by every planner and by `run`.

Each limit is a small object with one method, `ratios(t, q, qd, qdd, tau) -> [n, dof]`, giving
value/limit per sample and joint (≤ 1 means inside). Planners check their outputs on a grid much
denser than their optimisation grid: between collocation points limits are violated by 1–2 %.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from rxcomm.model.robot import Robot

# How far a plan's value, sampled at the drive cycle, may exceed a limit: between a planner's grid
# nodes it can overshoot by a fraction of a per mille. One number for both sides, so that a plan a
# planner writes is a plan `run` accepts (the ISO line at 1.0016 × a torque-rate limit was not).
SAMPLED_LIMIT_TOLERANCE = 2e-3


class WorstLimit(NamedTuple):
    """The largest limit ratio of a trajectory: limit name, joint name, time (s), ratio (1 = at the bound)."""

    limit: str
    joint: str
    t_s: float
    ratio: float


@dataclass(frozen=True)
class PositionLimit:
    """|q − centre| / half-range: 1 at either joint limit."""

    q_min: np.ndarray
    q_max: np.ndarray
    name: str = "position"

    def ratios(self, t, q, qd, qdd, tau) -> np.ndarray:
        centre, half = (self.q_max + self.q_min) / 2, (self.q_max - self.q_min) / 2
        return np.abs(q - centre) / half


@dataclass(frozen=True)
class _MagnitudeLimit:
    """|x| / bound per sample and joint; x the sampled signal the subclass names (`SIGNAL`: the index
    into q, q̇, q̈, τ) in its unit (rad/s, rad/s², N·m)."""

    bound: np.ndarray
    SIGNAL: ClassVar[int]

    def ratios(self, t, q, qd, qdd, tau) -> np.ndarray:
        return np.abs((q, qd, qdd, tau)[self.SIGNAL]) / self.bound


@dataclass(frozen=True)
class VelocityLimit(_MagnitudeLimit):
    name: str = "velocity"
    SIGNAL = 1


@dataclass(frozen=True)
class AccelerationLimit(_MagnitudeLimit):
    name: str = "acceleration"
    SIGNAL = 2


@dataclass(frozen=True)
class TorqueLimit(_MagnitudeLimit):
    name: str = "torque"
    SIGNAL = 3


@dataclass(frozen=True)
class TorqueRateLimit:
    """Torque rate by finite differences of the sampled torque (one-sided at the ends)."""

    tau_rate_max: np.ndarray
    name: str = "torque_rate"

    def ratios(self, t, q, qd, qdd, tau) -> np.ndarray:
        if len(t) < 2:
            return np.zeros_like(tau)
        return np.abs(np.gradient(tau, t, axis=0)) / self.tau_rate_max


def robot_limits(robot: Robot, torque_rate: bool = True) -> list:
    """The joint-space limits of a robot: position, velocity, acceleration, torque (+ torque rate)."""
    limits = [
        PositionLimit(robot.q_min, robot.q_max),
        VelocityLimit(robot.v_max),
        AccelerationLimit(robot.a_max),
        TorqueLimit(robot.tau_max),
    ]
    if torque_rate:
        limits.append(TorqueRateLimit(robot.tau_rate_max))
    return limits


@dataclass(frozen=True)
class LimitReport:
    """Per limit: [n, dof] ratios; the worst value with where it occurs."""

    t: np.ndarray
    ratios: dict[str, np.ndarray]
    joint_names: tuple[str, ...]

    @property
    def max_ratio(self) -> float:
        return max(float(r.max()) for r in self.ratios.values())

    def max_by_limit(self) -> dict[str, float]:
        return {k: float(r.max()) for k, r in self.ratios.items()}

    def worst(self) -> WorstLimit:
        """Where the largest ratio is: which limit, which joint, when."""
        name = max(self.ratios, key=lambda k: self.ratios[k].max())
        i, j = np.unravel_index(np.argmax(self.ratios[name]), self.ratios[name].shape)
        return WorstLimit(name, self.joint_names[j], float(self.t[i]), float(self.ratios[name][i, j]))

    def active_fraction(self, threshold: float = 0.98, exclude: Sequence[str] = ("position",)) -> float:
        """Fraction of samples where at least one limit is at ≥ `threshold` of its bound.

        The paper's optimality check: a time-optimal trajectory has a constraint active everywhere.
        Position limits are excluded by default: they bound the path, not the timing.
        """
        active = np.zeros(len(self.t), dtype=bool)
        for k, r in self.ratios.items():
            if k not in exclude:
                active |= (r >= threshold).any(axis=1)
        return float(active.mean())


def check_limits(
    robot: Robot, t, q, qd, qdd, tau, limits: Sequence | None = None, joint_names: Sequence[str] | None = None
) -> LimitReport:
    """Evaluate every limit on the samples given (sample densely: at least the drive cycle)."""
    t, q, qd, qdd, tau = (np.asarray(a, dtype=float) for a in (t, q, qd, qdd, tau))
    limits = robot_limits(robot) if limits is None else limits
    return LimitReport(
        t=t,
        ratios={lim.name: lim.ratios(t, q, qd, qdd, tau) for lim in limits},
        joint_names=tuple(joint_names or robot.joint_names),
    )
