"""Energy figures of a motion from its joint torques: the paper's ∫τᵀτ dt and an electrical estimate.

The electrical estimate uses the drives: motor torques τ_m from τ = Rᵀ·τ_m (R = `joint_to_motor`),
motor speeds ω_m = R·q̇, currents I = τ_m / k_t (drives.yaml `torque_constant_nm_per_a`) and the
DC-equivalent winding resistance R_w (`winding_resistance_ohm`). Per axis the electrical power is
τ_m·ω_m + R_w·I²; the axes share one DC bus, so what the supply delivers is the positive part of their
sum: braking power beyond what the other axes draw is burnt in the brake resistor, not returned,
unless drives.yaml says `regenerative_supply: true` (then the net ∫P dt). Inverter and iron losses
are not modelled.

The planners' energy objective (`BusPowerModel`, issue 29) is the same power as a smooth function of
the joint torques and speeds: P = τᵀq̇ + τᵀQτ (mechanical power is invariant under the gear map,
τ_mᵀω_m = τᵀq̇; the copper losses Σ R_w·(τ_m/k_t)² are the quadratic form Q = R⁻¹·diag(R_w/k_t²)·R⁻ᵀ
of τ_m = R⁻ᵀτ), and without regeneration its positive part smoothed as ½(P + √(P² + δ²)), which
exceeds max(P, 0) by at most δ/2 (δ = `smoothing_w`): an NLP needs a derivative at P = 0.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

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
    """Energy the supply delivers (J): ∫ max(P, 0) dt of `electrical_power` (∫P dt with a regenerative
    supply); None when not measurable (no winding resistances in drives.yaml)."""
    t, qd, tau = _finite_rows(t, qd, tau)
    p = electrical_power(robot, qd, tau)
    if p is None:
        return None
    if len(t) < 2:
        return 0.0
    return float(np.trapezoid(p if robot.drives.regenerative_supply else np.maximum(p, 0.0), t))


def energy_split(robot: Robot, t, qd, tau) -> dict[str, float] | None:
    """Where the electrical energy goes (J): copper ∫τᵀQτ dt, mechanical ∫τᵀq̇ dt (net: friction work
    plus what gravity and the links store), and what the brake resistor burns (the supply's energy
    minus both: 0 with a regenerative supply). None without winding resistances."""
    model = BusPowerModel.of(robot)
    if model is None:
        return None
    t, qd, tau = _finite_rows(t, qd, tau)
    if len(t) < 2:
        return {"copper_j": 0.0, "mechanical_j": 0.0, "braking_j": 0.0}
    q = np.asarray(model.copper_w_per_nm2)
    copper = float(np.trapezoid(np.einsum("ki,ij,kj->k", tau, q, tau), t))
    mech = float(np.trapezoid(np.sum(tau * qd, axis=1), t))
    total = electrical_energy(robot, t, qd, tau)
    return {"copper_j": copper, "mechanical_j": mech, "braking_j": float(total) - copper - mech}


class BusPowerModel(BaseModel):
    """The bus power as the planners' objective: P = τᵀq̇ + τᵀQτ, its positive part smoothed unless the
    supply is regenerative (module doc). Numbers only, so an NLP built on it can be cached by it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    copper_w_per_nm2: tuple[tuple[float, ...], ...] = Field(
        description="Q, W/(N·m)²: copper losses τᵀQτ in joint torques"
    )
    regenerative: bool = Field(description="the supply takes braking power back (drives.yaml)")
    smoothing_w: float = Field(1.0, gt=0, description="δ of ½(P + √(P² + δ²)), W")

    @classmethod
    def of(cls, robot: Robot, smoothing_w: float = 1.0) -> BusPowerModel | None:
        """The model of `robot`'s drives; None when drives.yaml lacks a winding resistance."""
        resistance = [j.winding_resistance_ohm for j in robot.drives.joints]
        if any(r is None for r in resistance):
            return None
        r_inv = np.linalg.inv(robot.joint_to_motor)
        q = r_inv @ np.diag(np.asarray(resistance) / robot.torque_constant**2) @ r_inv.T
        q = (q + q.T) / 2
        return cls(
            copper_w_per_nm2=tuple(tuple(float(v) for v in row) for row in q),
            regenerative=robot.drives.regenerative_supply,
            smoothing_w=smoothing_w,
        )

    def power(self, qd, tau, mtimes=np.matmul, sqrt=np.sqrt):
        """Smoothed bus power of rows: q̇, τ [N, n] → [N] (numpy), or CasADi matrices with
        `mtimes=ca.mtimes, sqrt=ca.sqrt` (then [N, 1])."""
        q = np.asarray(self.copper_w_per_nm2)
        p = _row_sum(tau * qd) + _row_sum(mtimes(tau, q) * tau)
        if self.regenerative:
            return p
        return 0.5 * (p + sqrt(p * p + self.smoothing_w**2))

    def energy(self, t, qd, tau) -> float:
        """∫ of `power` by the trapezoid rule over samples t [N] (numpy): what the NLP minimises,
        measured on any sampling."""
        return float(np.trapezoid(self.power(np.asarray(qd, float), np.asarray(tau, float)), t))


def _row_sum(x):
    """Σ over the columns of each row, for numpy arrays and CasADi matrices alike."""
    if isinstance(x, np.ndarray):
        return x.sum(axis=1)
    import casadi as ca

    return ca.sum2(x)


def motion_energy(robot: Robot, t, q, tau) -> dict[str, float | None]:
    """The run summary's energy figures from sampled positions q [N, n] (speeds by central
    differences) and torques τ [N, n]."""
    t, q, tau = _finite_rows(t, q, tau)
    qd = np.gradient(q, t, axis=0) if len(t) >= 2 else np.zeros_like(q)
    return {
        "tau_squared_integral_nm2_s": torque_squared_integral(t, tau),
        "electrical_energy_j": electrical_energy(robot, t, qd, tau),
    }
