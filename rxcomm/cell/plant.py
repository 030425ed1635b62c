"""The simulated robot: the TRUE rigid-body dynamics with drives, integrated at the drive cycle.

    (M(q) + Rᵀ·J_m·R)·q̈ + h(q, q̇) + τ_0 + τ_s(q) + F_v·q̇ + f = τ,     |f_i| ≤ F_c,i

M, h from Pinocchio with the truth's link inertials, Rᵀ·J_m·R the reflected (coupled) rotor inertias,
τ_0 the torque offsets, τ_s the balancer spring (`rxcomm.spring`), F_v viscous and f the Coulomb
friction, which is set-valued at rest (stiction).

Integration (per sub-step h, torque held constant over the cycle): semi-implicit (symplectic) Euler
with implicit viscous friction, and Coulomb friction solved at the velocity level as in time-stepping
contact simulators (Moreau/Stewart–Trinkle):

    A = M + h·F_v,   v* = A⁻¹·(M·q̇ + h·(τ − h_nl − τ_0 − τ_s)),   q̇⁺ = v* − h·A⁻¹·f,   q⁺ = q + h·q̇⁺

with f the friction torque such that, per joint, q̇⁺_i = 0 while |f_i| < F_c,i (sticking) or
f_i = F_c,i·sgn(q̇⁺_i) (sliding). This is a box-constrained LCP with the SPD matrix h·A⁻¹, solved by
projected Gauss–Seidel (warm-started; a one-matvec fast path when every joint slides). A joint held
below break-away stays exactly still — no chattering, no creeping — and a joint reverses through zero
without the sign flipping back and forth. A braked (disabled) joint is the same constraint with the
brake's holding torque added to its friction capacity.
"""

from __future__ import annotations

import math
from operator import mul

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from rxcomm.dynamics import DynamicParameters, model_with_inertials
from rxcomm.errors import InputError
from rxcomm.robot import Robot

PGS_MAX_SWEEPS = 60
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
        params.check_robot(robot)
        if substeps < 1:
            raise ValueError("substeps must be >= 1")
        n = robot.n
        self.n = n
        self.model = model_with_inertials(robot.model, params.inertial)
        self.data = self.model.createData()
        r = robot.joint_to_motor
        self.rotor = r.T @ np.diag(params.rotor_inertia_kgm2) @ r
        self.fc = np.array(params.coulomb_nm, dtype=float)
        self.fv = np.array(params.viscous_nm_s_per_rad, dtype=float)
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
        self._hfv = np.diag(self.h * self.fv)
        self._rhs = np.zeros((n, n + 1))  # [right-hand side | h·I]: one LAPACK call gives v* and h·A⁻¹
        self._rhs[:, 1:] = self.h * np.eye(n)
        m = pin.crba(self.model, self.data, np.linspace(0.3, 0.8, n))
        self._crba_full = bool(np.allclose(m, m.T))

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
        a = m + self._hfv
        rhs = self._rhs
        rhs[:, 0] = m @ v + h * (tau - b)
        _, x, info = lapack.dposv(a, rhs)
        if info != 0:  # M is SPD for any physical parameter set; anything else is a broken truth file
            raise InputError(
                f"the true dynamics give a mass matrix that is not positive definite at q = "
                f"{np.round(q, 4).tolist()} (LAPACK info {info}): check the link inertials",
                field="dynamics.links",
            )
        vstar, g = x[:, 0], x[:, 1:]
        f, stuck = _coulomb(g, a, h, vstar, cap, self.friction)
        v_new = vstar - g @ f
        if stuck is not None:
            v_new[stuck] = 0.0  # exact: a solve leaves ~1e-16 rad/s, which would let a held joint creep
        self.friction = f
        self.v = v_new
        self.q = q + h * v_new


def _coulomb(
    g: np.ndarray, a: np.ndarray, h: float, vstar: np.ndarray, cap: np.ndarray, warm: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """Friction torques f with q̇⁺ = v* − g·f sticking (q̇⁺_i = 0, |f_i| ≤ cap_i) or sliding against f,
    and the mask of sticking joints (None: none); g = h·A⁻¹. Fast paths first (all sliding on, all
    sticking), then an active-set iteration over which joints stick, projected Gauss–Seidel last.

    Plain floats throughout: for six joints they cost a fraction of numpy's per-call overhead."""
    gl, vs, cl = g.tolist(), vstar.tolist(), cap.tolist()
    sign = [1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0) for v in vs]
    f = [c * s for c, s in zip(cl, sign, strict=True)]
    if all((v - sum(map(mul, row, f))) * s > 0.0 for v, row, s in zip(vs, gl, sign, strict=True)):
        return np.array(f), None  # every joint keeps sliding the way it went
    f = (a @ vstar / h).tolist()  # every joint stops
    if all(abs(fi) <= c for fi, c in zip(f, cl, strict=True)):
        return np.array(f), np.ones(len(f), dtype=bool)
    solved = _active_set(gl, vs, cl)
    if solved is None:
        return _pgs(g, vstar, cap, warm)
    return np.array(solved[0]), np.array(solved[1])


def _active_set(g: list[list[float]], vs: list[float], cap: list[float]) -> tuple[list, list] | None:
    """Which joints stick, by active-set iteration from the decoupled guess (friction alone stops the
    joint). A sticking joint has q̇⁺ = 0 and |f| ≤ cap, a sliding one f = cap·sgn(q̇⁺). None if it
    does not settle within 2n changes."""
    n = len(vs)
    rng = range(n)
    stuck = [abs(vs[i]) <= g[i][i] * cap[i] for i in rng]
    sign = [-1.0 if v < 0.0 else 1.0 for v in vs]
    for _ in range(2 * n):
        f = [0.0 if stuck[i] else cap[i] * sign[i] for i in rng]
        idx = [i for i in rng if stuck[i]]
        if idx:
            a = [[g[i][j] for j in idx] for i in idx]
            x = _solve_spd(a, [vs[i] - sum(map(mul, g[i], f)) for i in idx])
            if x is None:
                return None
            for k, i in enumerate(idx):
                f[i] = x[k]
        changed = False
        for i in rng:
            if stuck[i]:
                if abs(f[i]) > cap[i]:  # released: slides the way its friction was pushing
                    stuck[i] = False
                    sign[i] = 1.0 if f[i] > 0.0 else -1.0
                    changed = True
            elif (vs[i] - sum(map(mul, g[i], f))) * sign[i] <= 0.0:
                stuck[i] = True  # it would reverse within the step: it stops instead
                changed = True
        if not changed:
            return f, stuck
    return None


def _solve_spd(a: list[list[float]], b: list[float]) -> list[float] | None:
    """Gaussian elimination without pivoting (fine for SPD); a and b are overwritten."""
    k = len(b)
    for c in range(k):
        p = a[c][c]
        if p <= 0.0:
            return None
        for r in range(c + 1, k):
            m = a[r][c] / p
            if m != 0.0:
                row_r, row_c = a[r], a[c]
                for j in range(c, k):
                    row_r[j] -= m * row_c[j]
                b[r] -= m * b[c]
    x = [0.0] * k
    for r in range(k - 1, -1, -1):
        acc = b[r]
        row = a[r]
        for j in range(r + 1, k):
            acc -= row[j] * x[j]
        x[r] = acc / row[r]
    return x


def _pgs(
    g: np.ndarray, vstar: np.ndarray, cap: np.ndarray, warm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Projected Gauss–Seidel on the same box LCP (always converges: g is SPD)."""
    gl = g.tolist()
    vs = vstar.tolist()
    cl = cap.tolist()
    fl = np.clip(warm, -cap, cap).tolist()
    n = len(vs)
    for _ in range(PGS_MAX_SWEEPS):
        change = 0.0
        for i in range(n):
            row = gl[i]
            r = vs[i]
            for j in range(n):
                r -= row[j] * fl[j]
            fi = fl[i] + r / row[i]
            c = cl[i]
            fi = c if fi > c else (-c if fi < -c else fi)
            d = abs(fi - fl[i]) * row[i]
            if d > change:
                change = d
            fl[i] = fi
        if change < PGS_TOL_RAD_S:
            break
    f = np.array(fl)
    return f, np.abs(f) < cap * (1.0 - 1e-9)
