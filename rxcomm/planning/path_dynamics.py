"""Joint torque along a fixed joint path as a function of path speed and acceleration (paper eq. 35).

On a path q(σ) the joint velocity and acceleration are q̇ = q'·σ̇ and q̈ = q'·σ̈ + q''·σ̇², so any
inverse dynamics made of rigid-body terms, rotor inertia, viscous and Coulomb friction, a spring and
a constant offset becomes

    τ(σ) = m(σ)·σ̈ + c(σ)·σ̇² + v(σ)·σ̇ + θ·f(σ) + g(σ),      θ ∈ [0, 1],

m, c, g as in the classic path dynamics, v the viscous term, f the full Coulomb torque sgn(q')·Fc (θ
is the share a smooth Coulomb model tanh(q̇/ε) delivers, 1 at speed). Limits imposed for θ = 0 and
θ = 1 hold for every θ in between (the set is convex), so planners enforce both ends and any smoothing
of the sign is covered.

The coefficients come from five evaluations of a batched inverse dynamics `inv_dyn(q, qd, qdd)`
(shapes [N, n]), toppra style — the robot's dynamics are a function passed in, never imported here:
g = τ(q, 0, 0); m = τ(q, 0, q') − g; and from h(λ) = τ(q, λq', λ²q'') − g = λ²c + λv + f at λ = 1, 2, 3.
This is exact when `inv_dyn` uses the exact sign for Coulomb friction (`coulomb_eps_rad_s=None` in
`rxcomm.model.dynamics.RobotDynamics`); pass that one here and the smooth one for the output torques.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

InverseDynamics = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class PathDynamics:
    """Coefficients [N, n] of τ = m·σ̈ + c·σ̇² + v·σ̇ + θ·f + g at the path points `sigma` [N]."""

    sigma: np.ndarray
    m: np.ndarray
    c: np.ndarray
    v: np.ndarray
    f: np.ndarray
    g: np.ndarray

    def torque(self, sdd, sd, theta: float = 1.0) -> np.ndarray:
        """τ [N, n] for path acceleration `sdd` and speed `sd` ([N] each)."""
        sdd, sd = np.asarray(sdd, float)[:, None], np.asarray(sd, float)[:, None]
        return self.m * sdd + self.c * sd**2 + self.v * sd + theta * self.f + self.g


def path_dynamics(inv_dyn: InverseDynamics, sigma, q, qs, qss) -> PathDynamics:
    """Decompose `inv_dyn` along the path points (q, q' = dq/dσ, q'' = d²q/dσ²), each [N, n]."""
    q, qs, qss = (np.asarray(a, dtype=float) for a in (q, qs, qss))
    zero = np.zeros_like(q)
    g = np.asarray(inv_dyn(q, zero, zero))
    m = np.asarray(inv_dyn(q, zero, qs)) - g
    h1, h2, h3 = (np.asarray(inv_dyn(q, lam * qs, lam * lam * qss)) - g for lam in (1.0, 2.0, 3.0))
    c = (h3 - 2 * h2 + h1) / 2
    v = h2 - h1 - 3 * c
    f = h1 - c - v
    return PathDynamics(np.asarray(sigma, dtype=float), m, c, v, f, g)
