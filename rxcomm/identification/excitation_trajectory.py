"""The exciting trajectory's parametrisation (`rxcomm.identification.excitation`).

**Trajectory.** Per joint a finite Fourier series with the common base frequency ω_f (paper eq. 29):
q̇_j(t) = Σ_l a_jl·cos(lω_f t) + b_jl·sin(lω_f t), q_j = q0_j + ∫q̇_j. It is periodic, so q(0) = q(T)
with T = 2π/ω_f. Rest-to-rest is exact by eliminating the first harmonic's coefficients:
a_j1 = −Σ_{l≥2} a_jl makes q̇(0) = q̇(T) = 0 and b_j1 = −Σ_{l≥2} l·b_jl makes q̈(0) = q̈(T) = 0. The
free variables per joint are the rest pose s_j = q_j(0) and a_jl, b_jl for l = 2..N (2N − 1 of them;
the paper's offset is q0_j = s_j + Σ_l b_jl/(lω_f)). Requiring in addition q(0) equal to the offset
q0 (the Fourier mean) would cost one degree of freedom per joint for nothing: the rest pose is a
variable already, or fixed by `start_rad`. q, q̇, q̈ are linear in the variables: sampled at times t
they are B_q(t)·x_j, B_v(t)·x_j, B_a(t)·x_j with the basis of `fourier_basis`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rxcomm.io.trajectory import Trajectory
from rxcomm.model.dynamics import (
    COULOMB_EPS_NLP_RAD_S,
    DynamicParameters,
    RobotDynamics,
    prior_parameters,
)
from rxcomm.model.robot import Robot

Progress = Callable[[str, int, int], None]


def fourier_basis(t: np.ndarray, omega: float, harmonics: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(B_q, B_v, B_a), each [len(t), 2N − 1]: q_j(t) = B_q·x_j etc. for the free variables of one
    joint x_j = (s, a_2..a_N, b_2..b_N), s = q_j(0), with a_1 and b_1 eliminated for rest-to-rest."""
    t = np.asarray(t, dtype=float)[:, None]
    n_h = harmonics
    ls = np.arange(2, n_h + 1, dtype=float)[None, :]
    w1, wl = omega * t, omega * ls * t
    bq = np.empty((t.shape[0], 2 * n_h - 1))
    bv, ba = np.zeros_like(bq), np.zeros_like(bq)
    bq[:, 0] = 1.0
    # a_l with a_1 = −Σ a_l
    bq[:, 1:n_h] = np.sin(wl) / (omega * ls) - np.sin(w1) / omega
    bv[:, 1:n_h] = np.cos(wl) - np.cos(w1)
    ba[:, 1:n_h] = -omega * ls * np.sin(wl) + omega * np.sin(w1)
    # b_l with b_1 = −Σ l·b_l (q measured from q(0))
    bq[:, n_h:] = -(np.cos(wl) - 1.0) / (omega * ls) + ls * (np.cos(w1) - 1.0) / omega
    bv[:, n_h:] = np.sin(wl) - ls * np.sin(w1)
    ba[:, n_h:] = omega * ls * (np.cos(wl) - np.cos(w1))
    return bq, bv, ba


def fourier_jerk_basis(t: np.ndarray, omega: float, harmonics: int) -> np.ndarray:
    """B_j [len(t), 2N − 1]: the jerk q⃛_j(t) = B_j·x_j (the time derivative of B_a)."""
    t = np.asarray(t, dtype=float)[:, None]
    n_h = harmonics
    ls = np.arange(2, n_h + 1, dtype=float)[None, :]
    w1, wl = omega * t, omega * ls * t
    bj = np.zeros((t.shape[0], 2 * n_h - 1))
    bj[:, 1:n_h] = -((omega * ls) ** 2) * np.cos(wl) + omega**2 * np.cos(w1)
    bj[:, n_h:] = -(omega**2) * ls**2 * np.sin(wl) + omega**2 * ls * np.sin(w1)
    return bj


@dataclass(frozen=True, eq=False)
class FourierTrajectory:
    """A rest-to-rest Fourier trajectory: `q_start` [n] (= q(0) = q(T)), `a`, `b` [n, N] (rad/s)."""

    omega_rad_s: float
    q_start: np.ndarray
    a: np.ndarray
    b: np.ndarray

    def __post_init__(self) -> None:
        for f in ("q_start", "a", "b"):
            arr = np.array(getattr(self, f), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, f, arr)
        if self.a.shape != self.b.shape or self.a.shape[0] != self.q_start.shape[0]:
            raise ValueError("a and b must be [n, N] with n = len(q_start)")
        ls = np.arange(1, self.harmonics + 1)
        scale = 1.0 + np.abs(self.a).sum() + np.abs(self.b * ls).sum()
        if np.abs(self.a.sum(axis=1)).max() > 1e-9 * scale or np.abs(self.b @ ls).max() > 1e-9 * scale:
            raise ValueError("not rest-to-rest: need Σ a_l = 0 and Σ l·b_l = 0 per joint")

    @property
    def n(self) -> int:
        return int(self.q_start.shape[0])

    @property
    def harmonics(self) -> int:
        return int(self.a.shape[1])

    @property
    def period_s(self) -> float:
        return 2.0 * math.pi / self.omega_rad_s

    @property
    def q0(self) -> np.ndarray:
        """The Fourier offset (mean position), paper eq. 29's q_i0."""
        ls = np.arange(1, self.harmonics + 1)
        return self.q_start + (self.b / (self.omega_rad_s * ls)).sum(axis=1)

    @classmethod
    def from_free(cls, omega: float, harmonics: int, x: np.ndarray) -> FourierTrajectory:
        """From the free variables [n, 2N − 1] (rows (s, a_2..a_N, b_2..b_N))."""
        x = np.asarray(x, dtype=float)
        n_h = harmonics
        a = np.concatenate([-x[:, 1:n_h].sum(axis=1, keepdims=True), x[:, 1:n_h]], axis=1)
        ls = np.arange(2, n_h + 1)
        b = np.concatenate([-(x[:, n_h:] @ ls)[:, None], x[:, n_h:]], axis=1)
        return cls(omega, x[:, 0], a, b)

    def free(self) -> np.ndarray:
        """The free variables [n, 2N − 1]."""
        return np.concatenate([self.q_start[:, None], self.a[:, 1:], self.b[:, 1:]], axis=1)

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, q̇, q̈), each [len(t), n], at times t (s); periodic in T."""
        bq, bv, ba = fourier_basis(np.atleast_1d(t), self.omega_rad_s, self.harmonics)
        x = self.free().T
        return bq @ x, bv @ x, ba @ x


def snapped_omega(omega_rad_s: float, cycle_s: float) -> float:
    """ω_f adjusted (by at most half a cycle per period) so that T = 2π/ω_f is whole drive cycles:
    the sampled trajectory then ends exactly at rest."""
    cycles = max(1, round(2.0 * math.pi / omega_rad_s / cycle_s))
    return 2.0 * math.pi / (cycles * cycle_s)


def sample_trajectory(
    robot: Robot, traj: FourierTrajectory, periods: int = 1, params: DynamicParameters | None = None
) -> Trajectory:
    """The trajectory at the drive cycle over `periods` periods, with τ_ff from `params` (default the
    prior) as `run` computes it: Coulomb friction smoothed to tanh(q̇/ε), ε = `COULOMB_EPS_NLP_RAD_S`."""
    dt = robot.drives.cycle_s
    steps = round(traj.period_s / dt)
    if abs(steps * dt - traj.period_s) > 1e-9 * traj.period_s:
        raise ValueError("the period is not a whole number of drive cycles (use snapped_omega)")
    t = np.arange(periods * steps + 1) * dt
    q, qd, qdd = traj.evaluate(t)
    # exact rest at the ends (evaluate gives ~1e-16 there)
    for arr in (qd, qdd):
        arr[0] = arr[-1] = 0.0
    q[-1] = q[0]
    dyn = RobotDynamics(robot, params or prior_parameters(robot), COULOMB_EPS_NLP_RAD_S)
    tau = dyn.inverse_dynamics(q, qd, qdd)
    return Trajectory(t, q, qd, qdd, tau)
