"""Optimal exciting trajectories for dynamic identification (paper §4.2, architecture §7 excite).

**Trajectory.** Per joint a finite Fourier series with the common base frequency ω_f (paper eq. 29):
q̇_j(t) = Σ_l a_jl·cos(lω_f t) + b_jl·sin(lω_f t), q_j = q0_j + ∫q̇_j. It is periodic, so q(0) = q(T)
with T = 2π/ω_f. Rest-to-rest is exact by eliminating the first harmonic's coefficients:
a_j1 = −Σ_{l≥2} a_jl makes q̇(0) = q̇(T) = 0 and b_j1 = −Σ_{l≥2} l·b_jl makes q̈(0) = q̈(T) = 0. The
free variables per joint are the rest pose s_j = q_j(0) and a_jl, b_jl for l = 2..N (2N − 1 of them;
the paper's offset is q0_j = s_j + Σ_l b_jl/(lω_f)). Requiring in addition q(0) equal to the offset
q0 (the Fourier mean) would cost one degree of freedom per joint for nothing: the rest pose is a
variable already, or fixed by `start_rad`. q, q̇, q̈ are linear in the variables: sampled at times t
they are B_q(t)·x_j, B_v(t)·x_j, B_a(t)·x_j with the basis of `fourier_basis`.

**Objective.** W = the base regressor (inertial + rotor + Coulomb + viscous + offset + spring
columns of `rxcomm.model.dynamics.joint_torque_regressor` kept by the `BaseParameterSet`) stacked over k
samples of one period, columns scaled to unit norm (paper: "the columns of Θ_f should also be
normalized"); minimise log cond(W) (or −log det(WᵀW)/p). cond is computed from the p × p Gram
matrix, and its gradient analytically: ∂ log cond/∂W_n = W_n·(v₁v₁ᵀ/λ₁ − v_pv_pᵀ/λ_p) (v, λ the
extreme eigenpairs of W_nᵀW_n), chained through the column scaling and, per sample, through a CasADi
reverse sweep of the symbolic regressor (`rxcomm.model.symbolic`) to q, q̇, q̈ and so to x. Coulomb's
sign is smoothed to tanh(q̇/ε) inside the NLP; reported figures use the exact sign and Pinocchio.

**Constraints** (paper eq. 30): joint position (minus a margin), velocity, acceleration (fractions of
the limits), motor torque |τ| ≤ fraction·peak from the prior (URDF + drives.yaml) model, and the
tool (TCP), wrist centre (joint 5 origin) and elbow (joint 3 origin) inside the cell's allowed-region
boxes. Position, velocity and acceleration are linear in x; torque and positions come with their
Jacobians from CasADi. Constraints imposed at a finite grid are violated between its points (by 1–2 %
at the paper's k = 80), so each solve is followed by a dense check (`check_samples` per period) and
the worst violating times are added to the constraint grid (an exchange method for the
semi-infinite problem) until the dense check holds; the result is verified again at the drive cycle
with Pinocchio, independently of the CasADi model.

**Starts.** SLSQP from several random *feasible* trajectories (random rest pose inside the region,
random coefficients scaled down by bisection until every limit holds densely); the best feasible
result wins. The same random feasible trajectories give the baseline figure the summary reports.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import pinocchio as pin
import scipy.linalg as sla
from scipy.optimize import minimize

from rxcomm import casadi_build
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.base_parameters import BaseParameterSet, base_parameters
from rxcomm.model.dynamics import (
    COULOMB_EPS_NLP_RAD_S,
    DynamicParameters,
    RobotDynamics,
    joint_torque_regressor,
    n_parameters,
    prior_parameters,
)
from rxcomm.model.limits import TorqueRateLimit
from rxcomm.model.robot import Robot
from rxcomm.model.symbolic import frame_placement_expr, inverse_dynamics_expr
from rxcomm.schemas.cell import AllowedRegion, Box
from rxcomm.schemas.excitation import ExcitationSettings

REGION_POINTS = ("tool", "wrist_centre", "elbow")
_TIGHTEN = 3e-4  # NLP limits are this fraction inside the design limits: room for dense-grid curvature

Progress = Callable[[str, int, int], None]


class Mapped:
    """A CasADi function mapped over k samples and evaluated in place on numpy arrays (CasADi's
    buffer interface: no DM conversion, which costs more than the evaluation itself here).

    CasADi stores matrices column-major, so the mapped input of an (r × 1) argument, r × k, is a
    C-order [k, r] array (sample-major), and the mapped output of an (r × c) result is a C-order
    [k, c, r] array. Outputs must be dense (`ca.densify`). The returned arrays are reused by the
    next call: copy what you keep."""

    def __init__(self, f: ca.Function, k: int):
        self.k = k
        self._f = f.map(k)
        self._buf, self._eval = self._f.buffer()
        self._args = [np.zeros(self._f.nnz_in(i)) for i in range(self._f.n_in())]
        self._res = []
        for i in range(self._f.n_out()):
            if self._f.nnz_out(i) != self._f.numel_out(i):
                raise ValueError(f"output {i} of {f.name()} is sparse: densify it")
            self._res.append(np.zeros(self._f.nnz_out(i)))
        for i, arr in enumerate(self._args):
            self._buf.set_arg(i, memoryview(arr))
        for i, arr in enumerate(self._res):
            self._buf.set_res(i, memoryview(arr))
        self._shapes = [(k, f.size2_out(i), f.size1_out(i)) for i in range(f.n_out())]

    def __call__(self, *inputs: np.ndarray) -> list[np.ndarray]:
        for arr, x in zip(self._args, inputs, strict=True):
            arr[:] = np.ravel(x)
        self._eval()
        return [r.reshape(shape) for r, shape in zip(self._res, self._shapes, strict=True)]


# ------------------------------------------------------------------------------------------------
# The trajectory


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


# ------------------------------------------------------------------------------------------------
# Conditioning


def condition_numbers(w: np.ndarray) -> tuple[float, float]:
    """(cond of W with unit-norm columns, cond of W as is), 2-norm, via the small Gram matrix."""
    norms = np.linalg.norm(w, axis=0)
    if np.any(norms == 0):
        return math.inf, math.inf
    wn = w / norms
    lam = sla.eigvalsh(wn.T @ wn, driver="evr")
    if lam[0] <= lam[-1] * 1e-15:
        return math.inf, math.inf
    # The raw figure from the triangular factor of the well-conditioned normalised Gram matrix:
    # W = Q·R·D, so cond(W) = cond(R·D) without forming (or decomposing) the tall W again.
    r = np.linalg.cholesky(wn.T @ wn).T
    s = np.linalg.svd(r * norms[None, :], compute_uv=False)
    return float(math.sqrt(lam[-1] / lam[0])), float(s[0] / s[-1])


def base_regressor(robot: Robot, bset: BaseParameterSet, q, qd, qdd) -> np.ndarray:
    """Stacked base regressor (exact Coulomb sign), rows sample-major."""
    return bset.base_regressor(joint_torque_regressor(robot, q, qd, qdd))


# ------------------------------------------------------------------------------------------------
# Region points


def region_points(robot: Robot, q: np.ndarray) -> dict[str, np.ndarray]:
    """Tool (TCP), wrist centre and elbow (origins of `Robot.wrist_joint_id`, `elbow_joint_id`)
    positions [N, 3], base frame, by Pinocchio."""
    q = np.atleast_2d(q)
    model, data = robot.model, robot.create_data()
    out = {k: np.empty((len(q), 3)) for k in REGION_POINTS}
    for i, qi in enumerate(q):
        pin.forwardKinematics(model, data, qi)
        out["tool"][i] = pin.updateFramePlacement(model, data, robot.tcp_frame_id).translation
        out["wrist_centre"][i] = data.oMi[robot.wrist_joint_id].translation
        out["elbow"][i] = data.oMi[robot.elbow_joint_id].translation
    return out


def _box_centre_half(box: Box, margin: float) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.array(box.min_m), np.array(box.max_m)
    half = (hi - lo) / 2 - margin
    if np.any(half <= 0):
        raise InputError(f"the allowed-region margin {margin} m leaves an empty box", field="allowed_region")
    return (hi + lo) / 2, half


# ------------------------------------------------------------------------------------------------
# The problem


@dataclass
class StartResult:
    seed: int
    initial_cond: float
    cond: float
    feasible: bool
    iterations: int
    seconds: float
    trajectory: FourierTrajectory | None = field(default=None, repr=False)


@dataclass(frozen=True, eq=False)
class ExcitationDesign:
    """What `design_excitation` returns. `cond`/`cond_raw` at the k objective samples (exact sign);
    `cond_dense` over the drive-cycle samples of one period; `baseline_cond` the median over random
    feasible trajectories of the same form; `limit_ratios` max value/robot limit on the drive-cycle
    samples (`max_limit_ratio` their max)."""

    trajectory: FourierTrajectory
    samples: Trajectory
    bset: BaseParameterSet
    cond: float
    cond_raw: float
    cond_dense: float
    baseline_cond: float
    baseline_conds: tuple[float, ...]
    starts: tuple[StartResult, ...]
    limit_ratios: dict[str, float]
    worst_limit: tuple[str, str, float, float]
    seconds: float

    @property
    def max_limit_ratio(self) -> float:
        return max(self.limit_ratios.values())


class ExcitationProblem:
    """The excitation NLP for one robot, region and settings; see the module docstring.

    Variables: x = the free Fourier variables, joint-major ([n, 2N − 1] raveled), minus the rest pose
    when `settings.start_rad` fixes it.
    """

    def __init__(
        self,
        robot: Robot,
        region: AllowedRegion | None,
        settings: ExcitationSettings,
        bset: BaseParameterSet | None = None,
        prior: DynamicParameters | None = None,
    ):
        self.robot, self.settings = robot, settings
        self.bset = base_parameters(robot) if bset is None else bset
        self.prior = prior_parameters(robot) if prior is None else prior
        self.prior.check_robot(robot)
        s = settings
        self.n, self.n_h = robot.n, s.harmonics
        self.m = 2 * s.harmonics - 1
        self.omega = snapped_omega(s.omega_f_rad_s, robot.drives.cycle_s)
        self.period = 2.0 * math.pi / self.omega
        self.t_obj = np.arange(s.objective_samples) * self.period / s.objective_samples
        self.t_check = np.arange(s.check_samples) * self.period / s.check_samples

        # Design limits as centre ± half-width; joint quantities per joint, then the region boxes.
        q_lo, q_hi = robot.q_min + s.position_margin_rad, robot.q_max - s.position_margin_rad
        if np.any(q_hi <= q_lo):
            raise InputError("position_margin_rad leaves no joint range", field="position_margin_rad")
        self.q_centre, self.q_half = (q_hi + q_lo) / 2, (q_hi - q_lo) / 2
        self.v_half = s.velocity_fraction * robot.v_max
        self.a_half = s.acceleration_fraction * robot.a_max
        self.tau_half = s.torque_fraction * robot.tau_max
        # |q̈| allowed where q̇_j = 0: Fc·q̈/ε within the torque-rate budget (`crossings`)
        fc = self.prior.coulomb_nm
        with np.errstate(divide="ignore"):
            self.qdd_cross_max = np.where(
                fc > 0,
                (1.0 - s.torque_rate_reserve)
                * robot.tau_rate_max
                * COULOMB_EPS_NLP_RAD_S
                / np.maximum(fc, 1e-300),
                np.inf,
            )
        self.region = region
        if region is not None:
            boxes = [_box_centre_half(getattr(region, k), s.region_margin_m) for k in REGION_POINTS]
            self.box_centre = np.concatenate([c for c, _ in boxes])
            self.box_half = np.concatenate([h for _, h in boxes])
        else:
            self.box_centre, self.box_half = np.zeros(0), np.zeros(0)
        self.nl_centre = np.concatenate([np.zeros(self.n), self.box_centre])
        self.nl_half = np.concatenate([self.tau_half, self.box_half])

        # Fixed or free rest pose.
        self.free_mask = np.ones((self.n, self.m), dtype=bool)
        self.x_fixed = np.zeros((self.n, self.m))
        if s.start_rad is not None:
            start = np.asarray(s.start_rad, dtype=float)
            if start.shape != (self.n,):
                raise InputError(f"start_rad needs {self.n} values, got {start.shape[0]}", field="start_rad")
            ratio = np.abs(start - self.q_centre) / self.q_half
            if ratio.max() > 1:
                j = int(np.argmax(ratio))
                raise InputError(
                    f"start_rad puts {robot.joint_names[j]} outside its limits (minus the margin)",
                    field="start_rad",
                )
            self.free_mask[:, 0] = False
            self.x_fixed[:, 0] = start
        self.tighten = _TIGHTEN
        self._build_casadi()
        self._maps: dict[tuple[str, int], Mapped] = {}
        self._bases: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._last_objective: tuple[bytes, tuple[float, np.ndarray]] = (b"", (0.0, np.zeros(0)))

    # -- CasADi functions

    def _build_casadi(self) -> None:
        robot, n = self.robot, self.n
        q, qd, qdd = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("qdd", n)
        p = ca.SX.sym("p", n_parameters(robot))
        tau = inverse_dynamics_expr(robot, q, qd, qdd, p, self.settings.coulomb_eps_rad_s)
        y = ca.substitute(ca.jacobian(tau, p), p, ca.DM.zeros(p.shape[0]))  # τ is linear in p
        yb = y[:, [int(i) for i in self.bset.independent]]
        self._f_yb = ca.Function("base_regressor", [q, qd, qdd], [ca.densify(yb)], ["q", "qd", "qdd"], ["Yb"])
        adj = ca.SX.sym("adj", *yb.shape)
        s = ca.sum1(ca.sum2(adj * yb))
        self._f_adj = ca.Function(
            "base_regressor_vjp",
            [q, qd, qdd, adj],
            [ca.densify(ca.gradient(s, v)) for v in (q, qd, qdd)],
            ["q", "qd", "qdd", "adj_Yb"],
            ["adj_q", "adj_qd", "adj_qdd"],
        )
        tau_p = inverse_dynamics_expr(robot, q, qd, qdd, self.prior, COULOMB_EPS_NLP_RAD_S)
        outs = [tau_p]
        if self.region is not None:
            elbow = robot.model.getFrameId(robot.model.names[robot.elbow_joint_id], pin.FrameType.JOINT)
            wrist = robot.model.getFrameId(robot.model.names[robot.wrist_joint_id], pin.FrameType.JOINT)
            for fid in (robot.tcp_frame_id, wrist, elbow):
                outs.append(frame_placement_expr(robot, q, fid)[0])
        h = ca.vertcat(*outs)
        self._f_h = ca.Function("limits", [q, qd, qdd], [ca.densify(h)], ["q", "qd", "qdd"], ["h"])
        self._f_hj = ca.Function(
            "limits_jac",
            [q, qd, qdd],
            [ca.densify(e) for e in (h, ca.jacobian(h, q), ca.jacobian(h, qd), ca.jacobian(h, qdd))],
            ["q", "qd", "qdd"],
            ["h", "dh_dq", "dh_dqd", "dh_dqdd"],
        )
        self.n_nl = int(h.shape[0])
        self._f_yb, self._f_adj, self._f_h, self._f_hj = casadi_build.compiled(
            [self._f_yb, self._f_adj, self._f_h, self._f_hj]
        )

    def _mapped(self, name: str, k: int) -> Mapped:
        key = (name, k)
        if key not in self._maps:
            f = {"yb": self._f_yb, "adj": self._f_adj, "h": self._f_h, "hj": self._f_hj}[name]
            self._maps[key] = Mapped(f, k)
        return self._maps[key]

    # -- variables

    @property
    def n_free(self) -> int:
        return int(self.free_mask.sum())

    def full(self, x: np.ndarray) -> np.ndarray:
        """[n, 2N − 1] free Fourier variables from the optimisation vector."""
        xf = self.x_fixed.copy()
        xf[self.free_mask] = x
        return xf

    def _basis(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if t is self.t_obj or t is self.t_check:
            key = id(t)
            if key not in self._bases:
                self._bases[key] = fourier_basis(t, self.omega, self.n_h)
            return self._bases[key]
        return fourier_basis(t, self.omega, self.n_h)

    def trajectory(self, x: np.ndarray) -> FourierTrajectory:
        return FourierTrajectory.from_free(self.omega, self.n_h, self.full(x))

    def states(self, x: np.ndarray, t: np.ndarray):
        bq, bv, ba = self._basis(t)
        xf = self.full(x).T
        return bq @ xf, bv @ xf, ba @ xf

    # -- objective

    def objective(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """(f, ∂f/∂x): log cond(W_n) or −log det(W_nᵀW_n)/p at the k objective samples (smooth Coulomb)."""
        key = np.asarray(x, dtype=float).tobytes()
        if self._last_objective[0] != key:
            self._last_objective = (key, self._objective(np.asarray(x, dtype=float)))
        f, g = self._last_objective[1]
        return f, g.copy()

    def _objective(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        k, n = len(self.t_obj), self.n
        bq, bv, ba = self._basis(self.t_obj)
        xf = self.full(x).T
        qs, qds, qdds = bq @ xf, bv @ xf, ba @ xf  # [k, n]
        (y,) = self._mapped("yb", k)(qs, qds, qdds)  # [k, nb, n]: y[s, c, i] = Y_s[i, c]
        nb = self.bset.n_base
        w = y.transpose(0, 2, 1).reshape(k * n, nb)
        norms = np.maximum(np.linalg.norm(w, axis=0), 1e-300)
        wn = w / norms
        gram = wn.T @ wn
        lam, vec = sla.eigh(gram, driver="evr")
        lam = np.maximum(lam, 1e-300)
        if self.settings.objective == "cond":
            f = 0.5 * (math.log(lam[-1]) - math.log(lam[0]))
            v1, vp = vec[:, -1], vec[:, 0]
            g_n = wn @ (np.outer(v1, v1) / lam[-1] - np.outer(vp, vp) / lam[0])  # ∂f/∂W_n
        else:
            f = -float(np.sum(np.log(lam))) / nb
            g_n = -(2.0 / nb) * wn @ ((vec / lam) @ vec.T)
        # through the column scaling W_n = W / ‖W_col‖
        g_w = (g_n - wn * np.sum(wn * g_n, axis=0)) / norms
        adj = g_w.reshape(k, n, nb).transpose(0, 2, 1)
        aq, av, aa = (v[:, 0, :] for v in self._mapped("adj", k)(qs, qds, qdds, adj))  # [k, n]
        grad = bq.T @ aq + bv.T @ av + ba.T @ aa  # [m, n]
        return f, grad.T[self.free_mask]

    def cond(self, x: np.ndarray) -> tuple[float, float]:
        """(cond, cond_raw) at the k objective samples with the exact Coulomb sign (Pinocchio)."""
        q, qd, qdd = self.states(x, self.t_obj)
        return condition_numbers(base_regressor(self.robot, self.bset, q, qd, qdd))

    # -- constraints (ratios: value relative to the design limit, |r| ≤ 1 inside)

    def ratios(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Signed ratios (v − centre)/half [len(t), 3n + n_nl] on the CasADi model: position,
        velocity, acceleration, torque, region coordinates."""
        q, qd, qdd = self.states(x, t)
        h = self._mapped("h", len(t))(q, qd, qdd)[0][:, 0, :]
        return np.concatenate(
            [
                (q - self.q_centre) / self.q_half,
                qd / self.v_half,
                qdd / self.a_half,
                (h - self.nl_centre) / self.nl_half,
            ],
            axis=1,
        )

    def crossings(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The torque-rate limit where a joint's velocity changes sign: (ratios [n, 2N], ∂ratio/∂x_full
        [n, 2N, n, 2N − 1]); unused slots are 0 with zero gradient.

        `run` computes τ_ff with Coulomb friction smoothed to Fc·tanh(q̇/ε), whose rate through q̇ = 0
        is Fc·q̈/ε: a narrow spike (≈ 2ε/q̈, a few ms) that a check grid misses, so it is constrained
        where it happens. q̇_j, a trigonometric polynomial of degree N, has at most 2N zeros per
        period, found by sign changes on the check grid and refined by Newton steps; the ratio is
        |q̈_j(t*)|·Fc_j/ε / (budget·rate_max_j), its gradient ∂q̈/∂x + q⃛·∂t*/∂x with
        ∂t*/∂x = −(∂q̇/∂x)/q̈ (implicit function)."""
        n, m, k = self.n, self.m, 2 * self.n_h
        xf = self.full(x)
        _, bv, _ = self._basis(self.t_check)
        v = bv @ xf.T  # [len(t), n]
        ratios = np.zeros((n, k))
        jac = np.zeros((n, k, n, m))
        dt = self.t_check[1] - self.t_check[0]
        for j in np.flatnonzero(self.qdd_cross_max < np.inf):
            vj = v[:, j]
            nxt = np.roll(vj, -1)
            idx = np.flatnonzero(vj * nxt < 0)
            if not len(idx):
                continue
            ts = self.t_check[idx] + dt * vj[idx] / (vj[idx] - nxt[idx])
            for _ in range(2):  # Newton on q̇_j(t) = 0
                _, bvs, bas = fourier_basis(ts, self.omega, self.n_h)
                ts = ts - (bvs @ xf[j]) / (bas @ xf[j])
            _, bvs, bas = fourier_basis(ts, self.omega, self.n_h)
            bjs = fourier_jerk_basis(ts, self.omega, self.n_h)
            a, jerk = bas @ xf[j], bjs @ xf[j]
            order = np.argsort(-np.abs(a))[:k]  # at most 2N; keep the largest if rounding found more
            a, jerk, bvs, bas = a[order], jerk[order], bvs[order], bas[order]
            sgn = np.sign(a) / self.qdd_cross_max[j]
            ratios[j, : len(a)] = r = np.abs(a) / self.qdd_cross_max[j]
            # A near-tangent reversal (q̈ → 0) has a tiny ratio but an unbounded ∂t*/∂x: far from
            # its limit, the row is left without gradient rather than upset SLSQP's subproblem.
            live = r > 0.25
            jac[j, : len(a), j, :] = (sgn * live)[:, None] * (
                bas - (jerk / np.where(live, a, 1.0))[:, None] * bvs
            )
        return ratios, jac

    def _peak_constraints(self):
        """SLSQP inequality constraints (fun, jac) on the dense check grid: for every limited quantity
        (joint position, velocity, acceleration, torque, region coordinate) and sign, its largest
        local maxima r(t) must satisfy 1 − tighten − r ≥ 0.

        q, q̇, q̈ are trigonometric polynomials of degree N, which have at most N local maxima per
        period: constraining N peaks per sign constrains all of them, exactly as a max over t would,
        with a few hundred rows instead of the thousands of a fixed grid (SLSQP's cost grows with the
        rows). Torque and positions of the region points are not polynomials of degree N; they get
        2N. At a local maximum ∂r/∂t = 0, so the gradient of the peak value is
        ∂r/∂x at fixed t."""
        n, m = self.n, self.m
        t = self.t_check
        bq, bv, ba = self._basis(t)
        k_lin, k_nl = self.n_h, 2 * self.n_h
        n_lin = 3 * n
        n_pts = 2 * k_nl * self.n_nl
        hj = self._mapped("hj", n_pts)
        mask = self.free_mask.ravel()
        half_lin = np.concatenate([self.q_half, self.v_half, self.a_half])
        cache: dict = {}

        def select(s: np.ndarray, k: int) -> np.ndarray:
            """Indices [k, cols] of the k largest local maxima per column (periodic), padded with the
            largest remaining samples where a column has fewer maxima."""
            is_max = (s >= np.roll(s, 1, axis=0)) & (s > np.roll(s, -1, axis=0))
            key = np.where(is_max, s, s - 1e6)
            return np.argpartition(-key, k, axis=0)[:k]

        def peaks(r: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
            idx = np.concatenate([select(r, k), select(-r, k)])  # [2k, cols]
            sign = np.repeat([1.0, -1.0], k)[:, None] * np.ones((1, r.shape[1]))
            return idx, sign

        def evaluate(x):
            key = x.tobytes()
            if cache.get("key") == key:
                return cache
            xf = self.full(x)
            r = self.ratios(x, t)  # [len(t), n_lin + n_nl]
            # linear quantities: rows (peak, column)
            idx, sign = peaks(r[:, :n_lin], k_lin)
            cols = np.broadcast_to(np.arange(n_lin), idx.shape)
            g_lin = sign * r[idx, cols]
            j_lin = np.zeros((idx.size, n, m))
            rows = np.arange(idx.size).reshape(idx.shape)
            for kind, basis in enumerate((bq, bv, ba)):
                for j in range(n):
                    c = kind * n + j
                    j_lin[rows[:, c], j, :] = sign[:, c : c + 1] * basis[idx[:, c]] / half_lin[c]
            # nonlinear quantities: Jacobians of h at the selected times
            idx, sign = peaks(r[:, n_lin:], k_nl)
            cols = np.broadcast_to(np.arange(self.n_nl), idx.shape)
            g_nl = sign * r[idx, n_lin + cols]
            ti = idx.ravel()
            _, dq, dv, da = hj(*(b[ti] @ xf.T for b in (bq, bv, ba)))  # [n_pts, n, n_nl]
            o = cols.ravel()
            pts = np.arange(len(ti))
            d = [v[pts, :, o] for v in (dq, dv, da)]  # [n_pts, n]
            j_nl = (
                np.einsum("pj,pl->pjl", d[0], bq[ti])
                + np.einsum("pj,pl->pjl", d[1], bv[ti])
                + np.einsum("pj,pl->pjl", d[2], ba[ti])
            ) * (sign.ravel() / self.nl_half[o])[:, None, None]
            g_cr, j_cr = self.crossings(x)
            jac = np.concatenate([j_lin.reshape(-1, n * m), j_nl.reshape(-1, n * m), j_cr.reshape(-1, n * m)])
            cache.update(
                key=key,
                g=(1.0 - self.tighten) - np.concatenate([g_lin.ravel(), g_nl.ravel(), g_cr.ravel()]),
                j=-jac[:, mask],
            )
            return cache

        return (lambda x: evaluate(x)["g"]), (lambda x: evaluate(x)["j"])

    def bounds(self) -> list[tuple[float, float]]:
        lo = np.empty((self.n, self.m))
        hi = np.empty((self.n, self.m))
        lo[:, 0], hi[:, 0] = self.q_centre - self.q_half, self.q_centre + self.q_half
        amp = 2.0 * self.v_half[:, None]  # each coefficient is bounded by the velocity limit anyway
        lo[:, 1:], hi[:, 1:] = -amp, amp
        return list(zip(lo[self.free_mask], hi[self.free_mask], strict=True))

    def optimise(self, x0: np.ndarray) -> tuple[np.ndarray, int, bool]:
        """SLSQP from x0: (x, iterations, feasible on the dense check grid).

        SLSQP has no trust region: from a poor start its first steps can leap where the constraints'
        linearisation cannot bring it back, and it stalls infeasible ("positive directional derivative
        in line search"). One restart from where it stopped, with a fresh quasi-Newton model, recovers
        most; a start that stays infeasible is reported and left out (the best of several starts wins).
        (Scaling the objective down to shorten the first step was tried: it converges to far worse
        conditioning, cond 40–50 instead of 7–9, on a third of the RX130L starts.)"""
        s = self.settings
        fun, jac = self._peak_constraints()
        x, iters = np.asarray(x0, dtype=float), 0
        # The best iterate within the constraints (the start is one): returned if SLSQP ends outside.
        best = {"f": self.objective(x)[0] if self.max_ratio(x) <= 1.0 else math.inf, "x": x}

        def keep_best(xk: np.ndarray) -> None:
            if fun(xk).min() >= 0.0:
                f = self.objective(xk)[0]
                if f < best["f"]:
                    best.update(f=f, x=np.array(xk))

        for _ in range(2):
            res = minimize(
                self.objective,
                x,
                jac=True,
                method="SLSQP",
                bounds=self.bounds(),
                constraints=[{"type": "ineq", "fun": fun, "jac": jac}],
                options={"maxiter": s.max_iterations, "ftol": s.tolerance},
                callback=keep_best,
            )
            x, iters = np.asarray(res.x), iters + int(res.nit)
            self.last_message = str(res.message)
            if self.max_ratio(x) <= 1.0:
                keep_best(x)
                return (x if self.objective(x)[0] <= best["f"] else best["x"]), iters, True
        if math.isfinite(best["f"]):
            return best["x"], iters, self.max_ratio(best["x"]) <= 1.0
        return x, iters, False

    # -- random feasible trajectories

    def max_ratio(self, x: np.ndarray) -> float:
        """Largest design-limit ratio on the check grid, torque-rate spikes at velocity reversals included."""
        return float(max(np.abs(self.ratios(x, self.t_check)).max(), self.crossings(x)[0].max()))

    def _static_ok(self, start: np.ndarray) -> bool:
        z = np.zeros(self.n)
        h = np.asarray(self._f_h(start, z, z)).ravel()
        return bool(np.all(np.abs(h - self.nl_centre) <= self.nl_half * (1 - _TIGHTEN)))

    def random_feasible(self, rng: np.random.Generator, attempts: int = 200) -> np.ndarray:
        """A random trajectory of the problem's form within every design limit on the dense check grid.

        A random rest pose (inside the region, holding torque within limits) and random coefficients;
        each joint's coefficients are scaled to the largest amplitude its own position, velocity and
        acceleration limits allow (these are linear in them), then all together by bisection until
        the torque and region limits hold too. So every joint moves as much as a user scaling a random
        trajectory by hand would let it: the baseline is not made poor by joints that barely move."""
        lim = 1.0 - _TIGHTEN
        for _ in range(attempts):
            xf = np.zeros((self.n, self.m))
            if self.free_mask[:, 0].any():
                xf[:, 0] = self.q_centre + rng.uniform(-0.5, 0.5, self.n) * self.q_half
            else:
                xf[:, 0] = self.x_fixed[:, 0]
            if not self._static_ok(xf[:, 0]):
                continue
            direction = rng.standard_normal((self.n, self.m - 1))
            bq, bv, ba = self._basis(self.t_check)
            dq, dv, da = (b[:, 1:] @ direction.T for b in (bq, bv, ba))  # [len(t), n] at unit scale
            room_hi = self.q_centre + lim * self.q_half - xf[:, 0]
            room_lo = xf[:, 0] - (self.q_centre - lim * self.q_half)
            with np.errstate(divide="ignore"):
                a_pos = np.where(dq > 0, room_hi / dq, np.where(dq < 0, room_lo / -dq, np.inf)).min(axis=0)
            a_vel = lim * self.v_half / np.abs(dv).max(axis=0)
            a_acc = lim * self.a_half / np.abs(da).max(axis=0)
            direction *= np.minimum.reduce([a_pos, a_vel, a_acc])[:, None]

            def x_of(beta, xf=xf, direction=direction):
                y = xf.copy()
                y[:, 1:] = beta * direction
                return y[self.free_mask]

            def feasible(beta, x_of=x_of):
                return self.max_ratio(x_of(beta)) <= lim

            if feasible(1.0):
                return x_of(1.0)
            lo, hi = 0.0, 1.0
            for _ in range(25):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if feasible(mid) else (lo, mid)
            if lo > 0:
                return x_of(lo)
        raise InfeasibleError(
            f"no random feasible excitation found in {attempts} attempts: the rest poses tried violate the "
            "allowed region or the torque limits (check cell.yaml allowed_region and torque_fraction)"
        )

    # -- dense verification at the drive cycle (Pinocchio, robot limits)

    def limit_ratios(self, samples: Trajectory) -> tuple[dict[str, float], tuple[str, str, float, float]]:
        """Max value/limit per limit over the samples against the robot's limits (position, velocity,
        acceleration, torque, torque rate) and the allowed-region boxes (without margin)."""
        robot = self.robot
        centre, half = (robot.q_max + robot.q_min) / 2, (robot.q_max - robot.q_min) / 2
        per = {
            "position": np.abs(samples.q - centre) / half,
            "velocity": np.abs(samples.qd) / robot.v_max,
            "acceleration": np.abs(samples.qdd) / robot.a_max,
            "torque": np.abs(samples.tau_ff) / robot.tau_max,
            "torque_rate": TorqueRateLimit(robot.tau_rate_max).ratios(
                samples.t, samples.q, samples.qd, samples.qdd, samples.tau_ff
            ),
        }
        labels = {k: list(robot.joint_names) for k in per}
        if self.region is not None:
            pts = region_points(robot, samples.q)
            for name in REGION_POINTS:
                c, h = _box_centre_half(getattr(self.region, name), 0.0)
                per[f"region_{name}"] = np.abs(pts[name] - c) / h
                labels[f"region_{name}"] = ["x", "y", "z"]
        worst_key = max(per, key=lambda k: per[k].max())
        i, j = np.unravel_index(np.argmax(per[worst_key]), per[worst_key].shape)
        worst = (worst_key, labels[worst_key][j], float(samples.t[i]), float(per[worst_key][i, j]))
        return {k: float(v.max()) for k, v in per.items()}, worst

    def design_ratios(self, samples: Trajectory) -> np.ndarray:
        """|value − centre|/half of the design limits on the samples (Pinocchio), max per sample."""
        per = [
            np.abs(samples.q - self.q_centre) / self.q_half,
            np.abs(samples.qd) / self.v_half,
            np.abs(samples.qdd) / self.a_half,
            np.abs(samples.tau_ff) / self.tau_half,
            TorqueRateLimit(self.robot.tau_rate_max).ratios(
                samples.t, samples.q, samples.qd, samples.qdd, samples.tau_ff
            ),
        ]
        if self.region is not None:
            pts = region_points(self.robot, samples.q)
            c = self.box_centre.reshape(3, 3)
            h = self.box_half.reshape(3, 3)
            per += [np.abs(pts[name] - c[i]) / h[i] for i, name in enumerate(REGION_POINTS)]
        return np.max(np.concatenate(per, axis=1), axis=1)


# ------------------------------------------------------------------------------------------------
# The design


def design_excitation(
    robot: Robot,
    region: AllowedRegion | None,
    settings: ExcitationSettings | None = None,
    *,
    bset: BaseParameterSet | None = None,
    progress: Progress | None = None,
) -> ExcitationDesign:
    """Optimal exciting trajectory: the best of `settings.starts` seeded SLSQP runs, verified at the
    drive cycle. Raises InfeasibleError when no start gives a trajectory within every limit."""
    t0 = time.perf_counter()
    settings = settings or ExcitationSettings()
    prob = ExcitationProblem(robot, region, settings, bset)
    n_base = settings.baseline_trajectories
    baseline = []
    for i in range(n_base):
        x = prob.random_feasible(np.random.default_rng([settings.seed, 1_000_003, i]))
        baseline.append(prob.cond(x)[0])
        if progress:
            progress("baseline", i + 1, n_base)

    starts: list[StartResult] = []
    for i in range(settings.starts):
        ts = time.perf_counter()
        x0 = prob.random_feasible(np.random.default_rng([settings.seed, i]))
        c0 = prob.cond(x0)[0]
        x, iters, ok = prob.optimise(x0)
        starts.append(
            StartResult(
                seed=i,
                initial_cond=c0,
                cond=prob.cond(x)[0],
                feasible=ok,
                iterations=iters,
                seconds=time.perf_counter() - ts,
                trajectory=prob.trajectory(x),
            )
        )
        if progress:
            progress("starts", i + 1, settings.starts)
    feasible = [s for s in starts if s.feasible]
    if not feasible:
        raise InfeasibleError(
            f"none of {len(starts)} excitation starts satisfied every limit on the dense check "
            f"(best cond {min(s.cond for s in starts):.3g}); try more starts or looser fractions"
        )
    best = min(feasible, key=lambda s: s.cond)
    traj = best.trajectory
    x = traj.free()[prob.free_mask]

    # Drive-cycle verification (Pinocchio, independent of the CasADi model): should a limit be
    # exceeded between the check grid's samples, tighten the NLP by the excess and re-solve.
    samples = sample_trajectory(robot, traj, 1, prob.prior)
    for _ in range(3):
        excess = float(prob.design_ratios(samples).max()) - 1.0
        if excess <= 0:
            break
        prob.tighten += 2 * excess
        x, _, _ = prob.optimise(x)
        traj = prob.trajectory(x)
        samples = sample_trajectory(robot, traj, 1, prob.prior)
    else:
        worst = prob.design_ratios(samples).max()
        raise InfeasibleError(f"the excitation exceeds a design limit at the drive cycle by {worst:.4f}")
    cond, cond_raw = prob.cond(x)
    w_dense = base_regressor(robot, prob.bset, samples.q, samples.qd, samples.qdd)
    cond_dense = condition_numbers(w_dense)[0]
    if settings.periods > 1:
        samples = sample_trajectory(robot, traj, settings.periods, prob.prior)
    ratios, worst = prob.limit_ratios(samples)
    return ExcitationDesign(
        trajectory=traj,
        samples=samples,
        bset=prob.bset,
        cond=cond,
        cond_raw=cond_raw,
        cond_dense=cond_dense,
        baseline_cond=float(np.median(baseline)),
        baseline_conds=tuple(baseline),
        starts=tuple(starts),
        limit_ratios=ratios,
        worst_limit=worst,
        seconds=time.perf_counter() - t0,
    )
