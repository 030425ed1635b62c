"""The axis-2 gravity balancer (architecture §4, `schemas.drives.BalancerSpring`).

A spring stretched between a pivot on the parent link (distance a from the joint axis) and one on the
child link (distance b). With θ = q + offset its length and lever are

    L(θ) = sqrt(a² + b² − 2ab·cos θ),      dL/dq = ab·sin θ / L.

Its potential ½k(L − L0)² makes the joint need the holding torque

    τ_s = k·(L − L0)·dL/dq = [ab·sin θ, −ab·sin θ / L] · [k, k·L0],

linear in (k, k·L0). The first column has the shape sin(q + offset), the same as a link's gravity
torque about a horizontal axis, so `spring.k` regroups with that link's first moment; the second
column (∝ sin θ / L) does not, so k·L0 stays identifiable. The sign convention is the one of inverse
dynamics: τ_s is added to the torque the motor must deliver; a balancer that helps holds the arm
with τ_s of sign opposite to gravity's.
"""

from __future__ import annotations

import numpy as np

from rxcomm.schemas.drives import BalancerSpring

SPRING_PARAMETERS = ("k", "kL0")


def spring_length(spring: BalancerSpring, q: np.ndarray) -> np.ndarray:
    """Spring length L (m) at joint angle(s) q (rad) of the spring joint."""
    a, b = spring.fixed_pivot_m, spring.moving_pivot_m
    return np.sqrt(a * a + b * b - 2.0 * a * b * np.cos(np.asarray(q, dtype=float) + spring.angle_offset_rad))


def spring_regressor(spring: BalancerSpring, q: np.ndarray) -> np.ndarray:
    """Columns of τ_s in (k, k·L0): shape (..., 2) for spring-joint angles q of shape (...)."""
    q = np.asarray(q, dtype=float)
    ab_sin = spring.fixed_pivot_m * spring.moving_pivot_m * np.sin(q + spring.angle_offset_rad)
    return np.stack([ab_sin, -ab_sin / spring_length(spring, q)], axis=-1)


def spring_torque(spring: BalancerSpring, q: np.ndarray, k_n_per_m: float, k_l0_n: float) -> np.ndarray:
    """Holding torque τ_s (N·m) of the spring at spring-joint angles q."""
    return spring_regressor(spring, q) @ np.array([k_n_per_m, k_l0_n])


def spring_prior(spring: BalancerSpring) -> np.ndarray:
    """(k, k·L0) from drives.yaml's stiffness and free length."""
    return np.array([spring.stiffness_n_per_m, spring.stiffness_n_per_m * spring.free_length_m])
