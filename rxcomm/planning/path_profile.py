"""A timing law along a path, σ(t), given at grid nodes, and its exact sampling at the drive cycle.

Two kinds, both exact between the nodes (no interpolation of the sampled signals):

- `constant`: σ̈ constant on each interval (toppra's `ParametrizeConstAccel`): σ̇² linear in σ, the time
  of an interval 2Δσ/(σ̇_k + σ̇_{k+1}); σ̈ jumps at the nodes, so torque does too.
- `linear`: σ̈ continuous and linear in σ on each interval (the path NLP): σ̇² is quadratic in σ and
  σ(t) solves σ̈ = α + β(σ − σ_k) in closed form (sinh/sin); an interval that starts or ends at rest with
  zero acceleration is a constant-jerk segment (σ ∝ t³), so torque starts and ends continuous.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

_SERIES = 1e-6


def _s_fun(z: np.ndarray) -> np.ndarray:
    """sinh(√z)/√z (z > 0), sin(√−z)/√−z (z < 0)."""
    z = np.asarray(z, dtype=float)
    out = 1 + z / 6 + z * z / 120
    pos, neg = z > _SERIES, z < -_SERIES
    out[pos] = np.sinh(np.sqrt(z[pos])) / np.sqrt(z[pos])
    out[neg] = np.sin(np.sqrt(-z[neg])) / np.sqrt(-z[neg])
    return out


def _c_fun(z: np.ndarray) -> np.ndarray:
    """(cosh(√z) − 1)/z, (1 − cos(√−z))/(−z) for z < 0."""
    z = np.asarray(z, dtype=float)
    out = 0.5 + z / 24 + z * z / 720
    pos, neg = z > _SERIES, z < -_SERIES
    out[pos] = (np.cosh(np.sqrt(z[pos])) - 1) / z[pos]
    out[neg] = (1 - np.cos(np.sqrt(-z[neg]))) / (-z[neg])
    return out


def _cosh_fun(z: np.ndarray) -> np.ndarray:
    z = np.asarray(z, dtype=float)
    out = 1 + z / 2 + z * z / 24
    pos, neg = z > _SERIES, z < -_SERIES
    out[pos] = np.cosh(np.sqrt(z[pos]))
    out[neg] = np.cos(np.sqrt(-z[neg]))
    return out


@dataclass(frozen=True, eq=False)
class PathProfile:
    """σ̇ and σ̈ at the nodes `sigma` [N+1] (m, m/s, m/s²). For kind `constant`, `sdd[k]` is the
    acceleration on interval k (the last entry repeats the previous one)."""

    sigma: np.ndarray
    sd: np.ndarray
    sdd: np.ndarray
    kind: Literal["constant", "linear"]
    t_nodes: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("sigma", "sd", "sdd"):
            a = np.array(getattr(self, name), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        sd = np.maximum(self.sd, 0.0)
        object.__setattr__(self, "sd", sd)
        if self.kind == "constant":
            dts = 2 * np.diff(self.sigma) / np.maximum(sd[:-1] + sd[1:], 1e-12)
        else:
            dts = np.array([self._interval_time(k) for k in range(len(self.sigma) - 1)])
        object.__setattr__(self, "t_nodes", np.concatenate([[0.0], np.cumsum(dts)]))

    @property
    def duration_s(self) -> float:
        return float(self.t_nodes[-1])

    def _jerk_start(self, k: int) -> bool:
        return self.kind == "linear" and self.sd[k] == 0 and self.sdd[k] == 0

    def _jerk_end(self, k: int) -> bool:
        return self.kind == "linear" and self.sd[k + 1] == 0 and self.sdd[k + 1] == 0

    def _interval_time(self, k: int) -> float:
        ds = self.sigma[k + 1] - self.sigma[k]
        s0, s1 = self.sd[k], self.sd[k + 1]
        if self.kind == "constant" or (s0 + s1) == 0:
            return 2 * ds / max(s0 + s1, 1e-12)
        if self._jerk_start(k):
            return 3 * ds / s1
        if self._jerk_end(k):
            return 3 * ds / s0
        alpha, beta = self.sdd[k], (self.sdd[k + 1] - self.sdd[k]) / ds
        tau = 2 * ds / (s0 + s1)
        for _ in range(30):  # Newton on x(τ) = Δσ; x' = σ̇ > 0 on the interval
            z = np.array([beta * tau * tau])
            x = s0 * tau * _s_fun(z)[0] + alpha * tau * tau * _c_fun(z)[0]
            xd = s0 * _cosh_fun(z)[0] + alpha * tau * _s_fun(z)[0]
            step = (x - ds) / max(xd, 1e-9)
            tau -= step
            if abs(step) < 1e-15 * max(tau, 1e-9):
                break
        return float(tau)

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(σ, σ̇, σ̈) at times t (s, within [0, duration])."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self.t_nodes, t, side="right") - 1, 0, len(self.sigma) - 2)
        tau = t - self.t_nodes[k]
        s0 = self.sd[k]
        ds = self.sigma[k + 1] - self.sigma[k]
        if self.kind == "constant":
            u = self.sdd[k]
            return self.sigma[k] + s0 * tau + 0.5 * u * tau**2, s0 + u * tau, u.copy()
        alpha = self.sdd[k]
        beta = (self.sdd[k + 1] - self.sdd[k]) / ds
        z = beta * tau**2
        x = s0 * tau * _s_fun(z) + alpha * tau**2 * _c_fun(z)
        xd = s0 * _cosh_fun(z) + alpha * tau * _s_fun(z)
        xdd = alpha + beta * x
        sig, sd, sdd = self.sigma[k] + x, xd, xdd
        dt = self.t_nodes[k + 1] - self.t_nodes[k]
        start = (self.sd[k] == 0) & (self.sdd[k] == 0)
        end = (self.sd[k + 1] == 0) & (self.sdd[k + 1] == 0)
        if np.any(start):  # σ = j·τ³/6 from rest, j = 6Δσ/Δt³
            j = 6 * ds[start] / dt[start] ** 3
            ts = tau[start]
            sig[start], sd[start], sdd[start] = self.sigma[k[start]] + j * ts**3 / 6, j * ts**2 / 2, j * ts
        if np.any(end):  # mirror image: rest at the end of the interval
            j = 6 * ds[end] / dt[end] ** 3
            tr = dt[end] - tau[end]
            sig[end], sd[end], sdd[end] = self.sigma[k[end] + 1] - j * tr**3 / 6, j * tr**2 / 2, -j * tr
        return sig, sd, sdd

    def sample(self, cycle_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(t, σ, σ̇, σ̈) at t = i·cycle_s, i = 0..M. The law is stretched by < one cycle so that the
        duration is a whole number of cycles and the last sample is the rest at the path end."""
        m = max(int(np.ceil(self.duration_s / cycle_s - 1e-9)), 1)
        t = np.arange(m + 1) * cycle_s
        k = self.duration_s / (m * cycle_s)  # ≤ 1: slower by less than one cycle
        s, sd, sdd = self.evaluate(t * k)
        return t, s, sd * k, sdd * k * k

    def time_at(self, sigma) -> np.ndarray:
        """t(σ) by interpolation between the nodes (for plots and reports)."""
        return np.interp(sigma, self.sigma, self.t_nodes)
