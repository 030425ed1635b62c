"""What a CP plan commands when the links are not where the encoders are (joint compliance, issue 17).

The planners time the link trajectory: q(t) on the IK of the (calibrated) kinematics. A calibration
that found joint compliance says the links sit at q_cmd − c·τ_hold(q_cmd) for encoder angles q_cmd;
the stage passes the inverse as a function `command` (link angles [N, n] → encoder angles [N, n],
`rxcomm.calibration.compensation.encoder_map`: the planning layer does not import the calibration).

`commanded_trajectory` maps the sampled link trajectory through it: q_cmd = E(q) exactly on every
sample, and by the chain rule q̇_cmd = q̇ + Dδ[q̇], q̈_cmd = q̈ + Dδ[q̈] + D²δ[q̇, q̇] with δ = E(q) − q,
its directional derivatives by central differences of step `STEP_RAD` along q̇ and q̈ (δ is ~1 mrad
and smooth: truncation and rounding ~1e-10 of q̇, q̈). At rest (q̇ = q̈ = 0) the commanded velocity and
acceleration are exactly zero.

`OnLink` evaluates a limit (the TCP's) on the link trajectory while the joint limits see the
commanded one, what `run` streams and checks.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Command = Callable[[np.ndarray], np.ndarray]  # link angles [N, n] → encoder angles [N, n]

STEP_RAD = 1e-3  # the directional-difference step (norm of the joint perturbation)


def commanded_trajectory(
    command: Command, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, step_rad: float = STEP_RAD
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q_cmd, q̇_cmd, q̈_cmd) [N, n] for the link trajectory (q, q̇, q̈) [N, n] (module docstring)."""
    q, qd, qdd = (np.asarray(a, float) for a in (q, qd, qdd))
    q_cmd = command(q)
    delta = q_cmd - q

    def along(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Dδ[v] and D²δ[v, v] per sample; zero where v is."""
        norm = np.linalg.norm(v, axis=1)
        moving = norm > 0
        eps = np.divide(step_rad, norm, out=np.zeros_like(norm), where=moving)[:, None]
        up, down = q + eps * v, q - eps * v
        d_up, d_down = command(up) - up, command(down) - down
        e = np.where(moving[:, None], eps, 1.0)
        first = np.where(moving[:, None], (d_up - d_down) / (2 * e), 0.0)
        second = np.where(moving[:, None], (d_up - 2 * delta + d_down) / e**2, 0.0)
        return first, second

    dv, dvv = along(qd)
    da, _ = along(qdd)
    return q_cmd, qd + dv, qdd + da + dvv


@dataclass(frozen=True, eq=False)
class OnLink:
    """`limit` (a `check_limits` object) evaluated on the link trajectory (q, q̇, q̈) given here,
    whatever trajectory the check passes."""

    limit: object
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray

    @property
    def name(self) -> str:
        return self.limit.name

    def ratios(self, t, q, qd, qdd, tau) -> np.ndarray:
        return self.limit.ratios(t, self.q, self.qd, self.qdd, tau)
