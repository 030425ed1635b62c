"""Energy figures of a motion from its joint torques: the paper's ∫τᵀτ dt and an electrical estimate.

The electrical estimate uses the drives: motor torques τ_m from τ = Rᵀ·τ_m (R = `joint_to_motor`),
motor speeds ω_m = R·q̇, currents I = τ_m / k_t (drives.yaml `torque_constant_nm_per_a`) and the
DC-equivalent winding resistance R_w (`winding_resistance_ohm`). Per axis the electrical power is
τ_m·ω_m + R_w·I²; the axes share one DC bus, so what the supply delivers is the positive part of their
sum: braking power beyond what the other axes draw is burnt in the brake resistor, not returned
(no regenerative supply). Inverter and iron losses are not modelled.
"""

from __future__ import annotations

import numpy as np

from rxcomm.model.robot import Robot


def _finite_rows(t: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    t = np.asarray(t, float)
    arrs = [np.asarray(a, float) for a in arrays]
    keep = np.isfinite(t) & np.all([np.all(np.isfinite(a), axis=1) for a in arrs], axis=0)
    return (t[keep], *(a[keep] for a in arrs))


def torque_squared_integral(t, tau) -> float:
    """∫τᵀτ dt (N²·m²·s) by the trapezoidal rule over samples t [N] (s), τ [N, n] (N·m); rows with a
    NaN (lost records) are left out."""
    t, tau = _finite_rows(t, tau)
    if len(t) < 2:
        return 0.0
    return float(np.trapezoid(np.sum(tau**2, axis=1), t))


def electrical_power(robot: Robot, qd, tau) -> np.ndarray | None:
    """Bus power drawn per sample (W, may be negative when braking) for joint speeds q̇ [N, n] (rad/s)
    and joint torques τ [N, n] (N·m); None when drives.yaml lacks a winding resistance."""
    resistance = [j.winding_resistance_ohm for j in robot.drives.joints]
    if any(r is None for r in resistance):
        return None
    r = robot.joint_to_motor
    tau_m = np.linalg.solve(r.T, np.asarray(tau, float).T).T
    omega_m = np.asarray(qd, float) @ r.T
    current = tau_m / robot.torque_constant
    return np.sum(tau_m * omega_m + np.asarray(resistance) * current**2, axis=1)


def electrical_energy(robot: Robot, t, qd, tau) -> float | None:
    """Energy the supply delivers (J): ∫ max(P, 0) dt of `electrical_power`; None when not measurable
    (no winding resistances in drives.yaml)."""
    t, qd, tau = _finite_rows(t, qd, tau)
    p = electrical_power(robot, qd, tau)
    if p is None:
        return None
    if len(t) < 2:
        return 0.0
    return float(np.trapezoid(np.maximum(p, 0.0), t))


def motion_energy(robot: Robot, t, q, tau) -> dict[str, float | None]:
    """The run summary's energy figures from sampled positions q [N, n] (speeds by central
    differences) and torques τ [N, n]."""
    t, q, tau = _finite_rows(t, q, tau)
    qd = np.gradient(q, t, axis=0) if len(t) >= 2 else np.zeros_like(q)
    return {
        "tau_squared_integral_nm2_s": torque_squared_integral(t, tau),
        "electrical_energy_j": electrical_energy(robot, t, qd, tau),
    }
