"""The simulated robot: the TRUE rigid-body dynamics with drives, integrated at the drive cycle.

    (M(q) + Rᵀ·J_m·R)·q̈ + h(q, q̇) + τ_0 + τ_s(q) + F_v·q̇ + f = τ,     |f_i| ≤ F_c,i

M, h from Pinocchio with the truth's link inertials, Rᵀ·J_m·R the reflected (coupled) rotor inertias,
τ_0 the torque offsets, τ_s the balancer spring (`rxcomm.model.spring`), F_v viscous and f the Coulomb
friction, which is set-valued at rest (stiction).

Integration (per sub-step h, torque held constant over the cycle): semi-implicit (symplectic) Euler
with implicit viscous friction, and Coulomb friction solved at the velocity level as in time-stepping
contact simulators (Moreau/Stewart–Trinkle):

    A·q̇⁺ = r − h·f,   A = M + h·F_v,   r = M·q̇ + h·(τ − h_nl − τ_0 − τ_s),   q⁺ = q + h·q̇⁺

with f the friction torque such that, per joint, q̇⁺_i = 0 while |f_i| ≤ F_c,i (sticking) or
f_i = F_c,i·sgn(q̇⁺_i) (sliding): a box-constrained LCP. It is solved by an active set over which joints
stick, started from the joints at rest: with the sticking set S and the sliding set F known,
A_FF·q̇⁺_F = r_F − h·f_F gives the sliding velocities and h·f_S = r_S − A_SF·q̇⁺_F the holding torques;
a sticking joint whose holding torque exceeds F_c breaks away, a sliding one whose velocity would
change sign stops; repeat (one small solve when nothing changes, the usual case). Projected
Gauss–Seidel on the equivalent LCP in h·A⁻¹ is the fallback should the set cycle. A joint held below
break-away stays exactly still — no chattering, no creeping — and a joint reverses through rest
without the sign flipping back and forth. A braked (disabled) joint is the same constraint with the
brake's holding torque added to its friction capacity.

Motor-side friction (truth `motor_*_friction_nm`): a motor's viscous friction adds Fv_m·R_iᵀR_i to
F_v (implicit); its Coulomb friction acts on the motor velocity R_i·q̇, which no joint's box in the
LCP can express, and is applied explicitly, regularised: Rᵀ·Fc_m·tanh(R·q̇ / (N·ε)), ε =
`MOTOR_COULOMB_EPS_RAD_S` in the axis's joint units (stable: h·Fc_m·R_ii/ε is well below the axis
inertia). A motor's Coulomb friction therefore has no stiction of its own; the joints' hold the arm.
(Putting joint 6's Coulomb friction on motor 6 instead, as stiction, left joint 6's joint-side drive
loop without friction: 31 mrad lag on the excitation, near the 35 mrad trip.) The plant needs
positive-definite link inertias (M must be SPD): a massless link or a point mass is fine for
identification priors, not here.
"""

from __future__ import annotations

import math
from operator import mul

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from rxcomm.errors import InputError
from rxcomm.model.dynamics import DynamicParameters, model_with_inertials
from rxcomm.model.robot import Robot

PGS_MAX_SWEEPS = 60
MOTOR_COULOMB_EPS_RAD_S = 0.01  # regularisation of motor-side Coulomb friction (joint units)
PGS_TOL_RAD_S = 1e-12


class Plant:
    """State (q, q̇) of the true robot; `step(τ, braked)` advances one drive cycle."""

    def __init__(
        self,
        robot: Robot,
        params: DynamicParameters,
        q0_rad: np.ndarray,
        *,
        cycle_s: float | None = None,
        substeps: int = 1,
        brake_torque_nm: np.ndarray | None = None,
    ):
        params.check_robot(robot, friction=False)
        if substeps < 1:
            raise ValueError("substeps must be >= 1")
        n = robot.n
        self.n = n
        for name, pi in zip(robot.joint_names, params.inertial, strict=True):
            # Identification accepts a massless link or a point mass as a prior; integrating needs
            # M(q) positive definite, i.e. every link a body with mass.
            if not pi[0] > 0:
                raise InputError(
                    f"the simulated plant needs a positive mass for every link; {name} has {pi[0]:g} kg",
                    field="dynamics.links",
                )
        self.model = model_with_inertials(robot.model, params.inertial)
        self.data = self.model.createData()
        r = robot.joint_to_motor
        self.rotor = r.T @ np.diag(params.rotor_inertia_kgm2) @ r
        self.fc = np.array(params.coulomb_nm, dtype=float)
        fv = np.diag(np.array(params.viscous_nm_s_per_rad, dtype=float))
        self._motor_coulomb: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        if params.has_motor_friction:
            fv = fv + r.T @ np.diag(params.motor_viscous_nm_s_per_rad) @ r
            mfc = np.array(params.motor_coulomb_nm, dtype=float)
            if np.any(mfc):
                scale = 1.0 / (np.abs(np.diag(r)) * MOTOR_COULOMB_EPS_RAD_S)
                self._motor_coulomb = (r, mfc, scale)
        self.fv_matrix = fv
        self.offset = np.array(params.offset_nm, dtype=float)
        self.h = (robot.drives.cycle_s if cycle_s is None else cycle_s) / substeps
        self.substeps = substeps
        self.brake = 2.0 * np.array(robot.tau_max) if brake_torque_nm is None else np.asarray(brake_torque_nm)
        spring = robot.drives.spring
        self._spring = None
        if spring is not None and params.spring is not None:
            self._spring = (
                robot.spring_joint_index,
                spring.fixed_pivot_m * spring.moving_pivot_m,
                spring.fixed_pivot_m**2 + spring.moving_pivot_m**2,
                spring.angle_offset_rad,
                float(params.spring[0]),
                float(params.spring[1]),
            )
        self.q = np.array(q0_rad, dtype=float)
        if self.q.shape != (n,):
            raise ValueError(f"q0 must have shape ({n},)")
        self.v = np.zeros(n)
        self.friction = np.zeros(n)  # last friction torque f (N·m), warm start of the next solve
        self._static_q: np.ndarray | None = None  # static torque at q, valid while the arm rests
        self._hfv = self.h * self.fv_matrix
        m = pin.crba(self.model, self.data, np.linspace(0.3, 0.8, n))
        self._crba_full = bool(np.allclose(m, m.T))

    @property
    def tracker_state(self) -> np.ndarray:
        """What the tracker needs of the plant to see the TCP: the joint angles (rigid links)."""
        return self.q

    def spring_torque(self, q: np.ndarray) -> np.ndarray:
        out = np.zeros(self.n)
        if self._spring is not None:
            k, ab, a2b2, off, kk, kl0 = self._spring
            th = q[k] + off
            s = ab * math.sin(th)
            out[k] = kk * s - kl0 * s / math.sqrt(a2b2 - 2.0 * ab * math.cos(th))
        return out

    def static_torque(self, q: np.ndarray) -> np.ndarray:
        """Gravity + spring + offset at rest (what the motors hold, friction aside), N·m."""
        return pin.computeGeneralizedGravity(self.model, self.data, q) + self.spring_torque(q) + self.offset

    def step(self, tau_nm: np.ndarray, braked: np.ndarray) -> None:
        """Advance one drive cycle with joint torques `tau_nm` held; `braked` joints are held by brakes."""
        cap = self.fc + self.brake * braked
        for _ in range(self.substeps):
            if not self.v.any():
                # At rest the all-sticking solution of the friction problem is f = τ − static(q)
                # (no velocity terms, q unchanged): if it fits the friction caps nothing moves, exactly
                # what the full step would give, for the cost of one comparison.
                if self._static_q is None:
                    self._static_q = self.static_torque(self.q)
                f = tau_nm - self._static_q
                if (np.abs(f) <= cap).all():
                    self.friction = f
                    return
            self._substep(tau_nm, cap)
            self._static_q = None

    def _substep(self, tau: np.ndarray, cap: np.ndarray) -> None:
        h, q, v = self.h, self.q, self.v
        m = pin.crba(self.model, self.data, q)
        if not self._crba_full:  # older Pinocchio fills the upper triangle only
            m = np.triu(m) + np.triu(m, 1).T
        m = m + self.rotor
        b = pin.nonLinearEffects(self.model, self.data, q, v) + self.offset + self.spring_torque(q)
        if self._motor_coulomb is not None:  # explicit, regularised (module docstring)
            rm, mfc, scale = self._motor_coulomb
            b = b + rm.T @ (mfc * np.tanh((rm @ v) * scale))
        a = m + self._hfv
        r = m @ v + h * (tau - b)
        v_new, f = friction_step(a, r, h, cap, v)
        self.friction = f
        self.v = v_new
        self.q = q + h * v_new


def friction_step(
    a: np.ndarray, r: np.ndarray, h: float, cap: np.ndarray, v: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(q̇⁺, f) solving A·q̇⁺ = r − h·f with Coulomb friction f (|f_i| ≤ cap_i, sticking joints exactly at
    rest); `v` (the current velocity) seeds which joints slide and which way. See the module docstring."""
    n = len(r)
    free = v != 0.0
    sign = np.sign(v)
    for _ in range(2 * n + 2):
        f = cap * sign  # sliding joints' friction; sticking joints' entries are replaced below
        rf = r - h * f
        if free.all():  # every joint moving: one solve, only reversals to check
            vn = _spd_solve(a, rf)
            if ((vn * sign) > 0.0).all():
                return vn, f
            hold = np.zeros(n)
        else:
            vn = np.zeros(n)
            if free.any():
                idx = np.flatnonzero(free)
                vn[idx] = _spd_solve(a[idx[:, None], idx], rf[idx])
            hold = (r - a @ vn) / h  # the friction that keeps each joint where it is (sticking ones)
        # a sticking joint whose holding torque exceeds the cap breaks away (the way it pushed);
        # a sliding one whose velocity would change sign within the step stops instead
        bad = np.where(free, vn * sign <= 0.0, np.abs(hold) > cap)
        if not bad.any():
            return vn, np.where(free, f, hold)
        sign = np.where(bad & ~free, np.sign(hold), sign)
        free = free ^ bad
    return _pgs(a, r, h, cap)


def _spd_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    _, x, info = lapack.dposv(a, b)
    if info != 0:  # M is SPD for any physical parameter set; anything else is a broken truth file
        raise InputError(
            f"the true dynamics give a mass matrix that is not positive definite (LAPACK info {info}): "
            "check the link inertials",
            field="dynamics.links",
        )
    return x


def _pgs(a: np.ndarray, r: np.ndarray, h: float, cap: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projected Gauss–Seidel on the LCP in g = h·A⁻¹ (q̇⁺ = v* − g·f, v* = A⁻¹·r): always converges
    (g is SPD), slowly when joints are strongly coupled. The fallback of `friction_step`."""
    n = len(r)
    x = _spd_solve(a, np.column_stack([r, h * np.eye(n)]))
    vstar, g = x[:, 0], x[:, 1:]
    gl, vs, cl = g.tolist(), vstar.tolist(), cap.tolist()
    fl = [0.0] * n
    for _ in range(PGS_MAX_SWEEPS):
        change = 0.0
        for i in range(n):
            row = gl[i]
            ri = vs[i] - sum(map(mul, row, fl))
            fi = fl[i] + ri / row[i]
            c = cl[i]
            fi = c if fi > c else (-c if fi < -c else fi)
            change = max(change, abs(fi - fl[i]) * row[i])
            fl[i] = fi
        if change < PGS_TOL_RAD_S:
            break
    f = np.array(fl)
    vn = vstar - g @ f
    vn[np.abs(f) < cap * (1.0 - 1e-9)] = 0.0  # sticking joints exactly at rest
    return vn, f
