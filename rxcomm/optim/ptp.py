"""Time/energy-optimal point-to-point motion (paper §5.4–5.5) as a scaled free-final-time OCP.

Formulation (DESIGN §7, "Planning facts"): the joints are a triple integrator driven by a jerk that is
constant on each of N intervals of a normalised time s ∈ [0, 1]; t = T·s with the final time T a
decision variable. The nodes carry (q, q̇, q̈); the torques come from the inverse dynamics at the nodes
(no forward dynamics, no numerical integrator: integrating a constant jerk is exact). This is what
makes it ~100× faster than the paper's forward-dynamics multiple shooting (`ptp_shooting`).

    minimise   ∫₀ᵀ (k1 + k2·τᵀτ) dt          (τᵀτ by the trapezoid rule over the nodes)
    subject to (q, q̇, q̈)_{k+1} = exact integration of the jerk u_k over h = T/N
               q(0) = q_start, q(T) = q_goal, q̇ = q̈ = 0 at both ends (rest to rest; q̈ = 0 keeps the
               torque continuous with the holding torque before and after the motion)
               q_min ≤ q ≤ q_max, |q̇| ≤ v_max, |τ| ≤ τ_max, |τ̇| ≤ τ̇_max,
               optionally |q̈| ≤ a_max and the TCP inside a box

Torque rate: the torque is differentiated exactly along the motion (forward-mode AD, CasADi
`jtimes`): τ̇ = ∂τ/∂q·q̇ + ∂τ/∂q̇·q̈ + ∂τ/∂q̈·u. The jerk jumps at the nodes, so τ̇ does too; it is
constrained on both sides of every node (with u_{k−1} and with u_k). Finite differences
(τ_{k+1} − τ_k)/h were measured to under-check by 15 % (N = 50) and 6 % (N = 100) between nodes, the
derivative by < 0.1 %. The rate limit applies to the torque *without Coulomb friction*: the smooth
sign tanh(q̇/ε) of the NLP model steps by 2·Fc within ~2ε/q̈ ≈ 1 ms at every velocity reversal, a
rate (≈ 4·10⁴ N·m/s on J2) set by ε, not by the drive; limiting it would make every reversal
crawl. The Coulomb step is what a drive's friction compensation delivers anyway.

Dense check with a margin: between nodes nothing is enforced, so the NLP uses every limit tightened to
(1 − margin) (default 1 %); the optimum is then sampled at the drive cycle by exact integration of the
piecewise-constant jerk, torques from the same inverse dynamics, and every limit is checked on those
samples (`rxcomm.limits`): the max ratio is the summary's `max_limit_ratio`.

Scaling: q in rad, q̇/v_max, q̈/a_ref, u/j_ref, T/T_ref with a_ref = τ_max/M_jj and j_ref = τ̇_max/M_jj
(M_jj the joint-space inertia diagonal at a reference posture), torque and rate rows divided by their
limits. IPOPT uses its L-BFGS Hessian approximation: the exact Hessian of the RNEA graph halves the
iterations but costs more than it saves.
"""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Literal

import casadi as ca
import numpy as np
import pinocchio as pin
from pydantic import BaseModel, ConfigDict, Field, model_validator

from rxcomm.dynamics import COULOMB_EPS_NLP_RAD_S, DynamicParameters, prior_parameters
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.limits import (
    AccelerationLimit,
    LimitReport,
    PositionLimit,
    TorqueLimit,
    TorqueRateLimit,
    VelocityLimit,
)
from rxcomm.optim.warm_start import KinematicProfile, feasible_profile, ruckig_profile
from rxcomm.robot import Robot
from rxcomm.symbolic import forward_kinematics_function, inverse_dynamics_function
from rxcomm.trajectory import Trajectory

Vec3 = tuple[float, float, float]


class PtpOptions(BaseModel):
    """Settings of the PtP OCP (units in the names)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_intervals: int = Field(50, ge=4, le=2000, description="N, jerk intervals of the normalised time")
    k1: float = Field(1.0, ge=0, description="weight of time in ∫(k1 + k2·τᵀτ)dt (dimensionless)")
    k2_per_nm2: float = Field(0.0, ge=0, description="weight of τᵀτ in ∫(k1 + k2·τᵀτ)dt, 1/(N·m)²")
    margin: float = Field(
        0.01,
        ge=0,
        lt=0.5,
        description="the NLP uses (1 − margin)·limit so the dense check passes between nodes",
    )
    acceleration_limits: bool = Field(
        False, description="also limit |q̈| ≤ a_max (the paper's PtP limits torque, not acceleration)"
    )
    tcp_box_m: tuple[Vec3, Vec3] | None = Field(
        None, description="(min, max) corners of a box in the base frame the TCP must stay in, m"
    )
    max_iter: int = Field(3000, ge=1, description="IPOPT iteration cap")
    max_wall_s: float | None = Field(None, gt=0, description="IPOPT wall-time cap, s")
    tol: float = Field(1e-6, gt=0, description="IPOPT relative tolerance")
    hessian: Literal["limited-memory", "exact"] = "limited-memory"
    torque_rate: Literal["derivative", "difference"] = Field(
        "derivative", description="τ̇ in the NLP: exact on both sides of each node, or (τ_{k+1} − τ_k)/h"
    )
    expand: bool = Field(True, description="expand the NLP to CasADi SX (slower to build, faster to solve)")

    @model_validator(mode="after")
    def _objective(self) -> PtpOptions:
        if self.k1 == 0 and self.k2_per_nm2 == 0:
            raise ValueError("k1 and k2_per_nm2 are both 0: nothing to minimise")
        if self.tcp_box_m is not None and not all(a < b for a, b in zip(*self.tcp_box_m, strict=True)):
            raise ValueError("tcp_box_m: every min must be below its max")
        return self


@dataclass(frozen=True, eq=False)
class PtpLimits:
    """The joint-space limits a PtP motion obeys (joint side, SI units)."""

    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    tau_max: np.ndarray
    tau_rate_max: np.ndarray
    a_max: np.ndarray | None = None

    @classmethod
    def from_robot(cls, robot: Robot, acceleration: bool = False) -> PtpLimits:
        return cls(
            robot.q_min, robot.q_max, robot.v_max, robot.tau_max, robot.tau_rate_max,
            robot.a_max if acceleration else None,
        )  # fmt: skip

    def dense_checks(self) -> list:
        """The limit objects of `rxcomm.limits` for the dense check (the same set the NLP obeys)."""
        lims = [PositionLimit(self.q_min, self.q_max), VelocityLimit(self.v_max)]
        if self.a_max is not None:
            lims.append(AccelerationLimit(self.a_max))
        return [*lims, TorqueLimit(self.tau_max), TorqueRateLimit(self.tau_rate_max)]

    def key(self) -> str:
        h = hashlib.sha256()
        for a in (self.q_min, self.q_max, self.v_max, self.tau_max, self.tau_rate_max, self.a_max):
            h.update(b"-" if a is None else np.ascontiguousarray(a, dtype=float).tobytes())
        return h.hexdigest()


@dataclass(frozen=True, eq=False)
class PtpDynamics:
    """What the OCP needs of the robot's dynamics, as CasADi Functions with named inputs.

    `inv_dyn` (q, qd, qdd) → tau: the joint torque the drives deliver (torque limit, objective, τ_ff).
    `coulomb` (qd) → tau: its Coulomb-friction part, left out of the torque-rate limit (module doc).
    `tcp_fk` (q) → (p, R): the TCP placement, needed only for a TCP box.
    """

    inv_dyn: ca.Function
    coulomb: ca.Function | None = None
    tcp_fk: ca.Function | None = None

    @classmethod
    def from_parameters(
        cls,
        robot: Robot,
        params: DynamicParameters | None = None,
        coulomb_eps_rad_s: float = COULOMB_EPS_NLP_RAD_S,
    ) -> PtpDynamics:
        """From `rxcomm.symbolic` with `params` (default: the robot's priors), smooth Coulomb friction."""
        params = prior_parameters(robot) if params is None else params
        inv_dyn = inverse_dynamics_function(robot, params, coulomb_eps_rad_s)
        qd = ca.SX.sym("qd", robot.n)
        coulomb = ca.Function(
            "coulomb", [qd], [ca.DM(params.coulomb_nm) * ca.tanh(qd / coulomb_eps_rad_s)], ["qd"], ["tau"]
        )
        return cls(inv_dyn, coulomb, forward_kinematics_function(robot))

    @property
    def dof(self) -> int:
        return int(self.inv_dyn.size1_in(0))

    def key(self) -> str:
        h = hashlib.sha256()
        for f in (self.inv_dyn, self.coulomb, self.tcp_fk):
            h.update(b"-" if f is None else f.serialize().encode())
        return h.hexdigest()

    def torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ [n, dof] at many samples (one mapped call)."""
        return np.asarray(self.inv_dyn.map(q.shape[0])(q.T, qd.T, qdd.T)).T.reshape(q.shape)

    def rate_torque(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The torque whose rate is limited: τ minus its Coulomb part."""
        if self.coulomb is None:
            return tau
        return tau - np.asarray(self.coulomb.map(q.shape[0])(qd.T)).T.reshape(q.shape)


@dataclass(frozen=True, eq=False)
class NodeGuess:
    """Values on the OCP grid: T, q/q̇/q̈ at the N + 1 nodes [N+1, dof], jerk on the N intervals [N, dof]."""

    duration_s: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    jerk: np.ndarray

    @classmethod
    def from_profile(cls, profile: KinematicProfile, n_intervals: int) -> NodeGuess:
        """Sample a kinematic profile at the nodes; the jerk makes q̈ match at every node."""
        T = max(profile.duration_s, 1e-3)
        t = np.linspace(0.0, T, n_intervals + 1)
        q, qd, qdd = profile.at(t)
        return cls(T, q, qd, qdd, np.diff(qdd, axis=0) / (T / n_intervals))


@dataclass(frozen=True, eq=False)
class PtpSolution:
    """The OCP's answer on its grid, and how IPOPT got there."""

    duration_s: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    jerk: np.ndarray
    tau: np.ndarray
    objective: float
    status: str
    success: bool
    iterations: int
    solve_seconds: float

    @property
    def n_intervals(self) -> int:
        return self.jerk.shape[0]

    @property
    def tau_squared_integral(self) -> float:
        """∫τᵀτ dt by the trapezoid rule over the nodes, (N·m)²·s."""
        s = np.sum(self.tau**2, axis=1)
        return float(self.duration_s / self.n_intervals * (s.sum() - 0.5 * (s[0] + s[-1])))


def _sx_function(f: ca.Function) -> ca.Function:
    return f.expand() if f.is_a("MXFunction") else f


def node_function(dyn: PtpDynamics, tcp: bool = False) -> ca.Function:
    """(q, q̇, q̈, u_left, u_right) → (τ, τ̇ with u_left, τ̇ with u_right[, p_tcp]), τ̇ exact by AD.

    τ̇ is the rate of τ minus its Coulomb part (module doc).
    """
    f = _sx_function(dyn.inv_dyn)
    n = dyn.dof
    q, qd, qdd = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("qdd", n)
    ul, ur = ca.SX.sym("u_left", n), ca.SX.sym("u_right", n)
    tau = f(q, qd, qdd)
    smooth = tau if dyn.coulomb is None else tau - _sx_function(dyn.coulomb)(qd)
    drift = ca.jtimes(smooth, ca.vertcat(q, qd), ca.vertcat(qd, qdd))
    outs = [tau, drift + ca.jtimes(smooth, qdd, ul), drift + ca.jtimes(smooth, qdd, ur)]
    names = ["tau", "tau_rate_left", "tau_rate_right"]
    if tcp:
        if dyn.tcp_fk is None:
            raise ValueError("a TCP box needs PtpDynamics.tcp_fk")
        outs.append(_sx_function(dyn.tcp_fk)(q)[0])
        names.append("p_tcp")
    return ca.Function("ptp_node", [q, qd, qdd, ul, ur], outs, ["q", "qd", "qdd", "u_left", "u_right"], names)


def inertia_diagonal(inv_dyn: ca.Function, q) -> np.ndarray:
    """diag M(q) from the inverse dynamics (τ is affine in q̈: M e_j = ID(q, 0, e_j) − ID(q, 0, 0))."""
    q = np.asarray(q, float)
    n = len(q)
    z = np.zeros(n)
    base = np.asarray(inv_dyn(q, z, z)).ravel()
    return np.array([float(np.asarray(inv_dyn(q, z, np.eye(n)[j])).ravel()[j] - base[j]) for j in range(n)])


class PtpOcp:
    """The NLP for one dynamics, limit set, option set and grid; `solve` may be called for many end points.

    Building it (CasADi expansion and sparse Jacobian) costs seconds; `cached_ocp` keeps a few.
    `q_ref` and `t_ref_s` set the variable scaling only (inertia at `q_ref`, default mid-range).
    """

    def __init__(
        self,
        dynamics: PtpDynamics,
        limits: PtpLimits,
        options: PtpOptions | None = None,
        *,
        q_ref=None,
        t_ref_s: float = 1.0,
    ):
        t_build = time.perf_counter()
        self.dynamics = dynamics
        self.limits = limits
        self.options = options = options or PtpOptions()
        n = self.dof = len(limits.q_min)
        N = self.N = options.n_intervals
        if dynamics.dof != n:
            raise ValueError(f"dynamics has {dynamics.dof} joints, limits {n}")
        q_ref = (limits.q_min + limits.q_max) / 2 if q_ref is None else np.asarray(q_ref, float)
        m_diag = np.maximum(inertia_diagonal(dynamics.inv_dyn, q_ref), 1e-6)
        self.t_ref = float(t_ref_s)
        self.v_ref = np.asarray(limits.v_max, float)
        self.a_ref = np.asarray(limits.tau_max, float) / m_diag
        self.j_ref = np.asarray(limits.tau_rate_max, float) / m_diag
        box = options.tcp_box_m is not None

        # decision vector w = [T/T_ref, Q (n×N+1), V = q̇/v_ref, A = q̈/a_ref, U = u/j_ref (n×N)]
        Tn = ca.MX.sym("T_scaled")
        Q, V, A = (ca.MX.sym(s, n, N + 1) for s in "QVA")
        U = ca.MX.sym("U", n, N)
        w = ca.vertcat(Tn, ca.vec(Q), ca.vec(V), ca.vec(A), ca.vec(U))
        self._sizes = (1, n * (N + 1), n * (N + 1), n * (N + 1), n * N)

        T = self.t_ref * Tn
        h = T / N
        vr, ar, jr = (ca.DM(x) for x in (self.v_ref, self.a_ref, self.j_ref))
        qd, qdd, u = ca.diag(vr) @ V, ca.diag(ar) @ A, ca.diag(jr) @ U
        q0, qd0, qdd0 = Q[:, :-1], qd[:, :-1], qdd[:, :-1]
        # exact integration of a constant jerk; defects scaled like the variables
        d_q = Q[:, 1:] - (q0 + h * qd0 + h**2 / 2 * qdd0 + h**3 / 6 * u)
        d_v = (qd[:, 1:] - (qd0 + h * qdd0 + h**2 / 2 * u)) / ca.repmat(vr, 1, N)
        d_a = (qdd[:, 1:] - (qdd0 + h * u)) / ca.repmat(ar, 1, N)

        tmax, rmax = ca.DM(limits.tau_max), ca.DM(limits.tau_rate_max)
        rows = [ca.vec(d_q), ca.vec(d_v), ca.vec(d_a)]
        if options.torque_rate == "derivative":
            zero = ca.MX.zeros(n, 1)
            u_ext = ca.horzcat(zero, u, zero)  # rest before and after the motion
            outs = node_function(dynamics, box).map(N + 1)(Q, qd, qdd, u_ext[:, :-1], u_ext[:, 1:])
            tau, rate_l, rate_r = outs[:3]
            rate_s = ca.horzcat(rate_l[:, 1:], rate_r[:, :-1]) / ca.repmat(rmax, 1, 2 * N)
        else:
            f = _sx_function(dynamics.inv_dyn)
            tau = f.map(N + 1)(Q, qd, qdd)
            smooth = tau if dynamics.coulomb is None else tau - _sx_function(dynamics.coulomb).map(N + 1)(qd)
            rate_s = (smooth[:, 1:] - smooth[:, :-1]) / h / ca.repmat(rmax, 1, N)
            outs = [tau]
            if box:
                outs.append(_sx_function(dynamics.tcp_fk).map(N + 1)(Q)[0])
        tau_rows = [tau]
        if dynamics.coulomb is not None:
            # The friction sign may flip anywhere between two nodes while the rest of the torque moves
            # little: bound each node's torque with its neighbours' friction too, else the optimum
            # hides up to 2·Fc of extra torque in the intervals where a joint reverses.
            c = _sx_function(dynamics.coulomb).map(N + 1)(qd)
            tau_rows += [tau[:, :-1] - c[:, :-1] + c[:, 1:], tau[:, 1:] - c[:, 1:] + c[:, :-1]]
        tau_s = ca.horzcat(*tau_rows)
        rows += [ca.vec(tau_s / ca.repmat(tmax, 1, tau_s.shape[1])), ca.vec(rate_s)]
        self._g_sizes = [3 * n * N, tau_s.numel(), rate_s.numel()]
        if box:
            lo, hi = (np.asarray(c, float) for c in options.tcp_box_m)
            centre, half = (lo + hi) / 2, (hi - lo) / 2
            p_s = (outs[-1][:, 1:-1] - ca.repmat(ca.DM(centre), 1, N - 1)) / ca.repmat(ca.DM(half), 1, N - 1)
            rows.append(ca.vec(p_s))
            self._g_sizes.append(3 * (N - 1))

        wts = np.ones(N + 1)
        wts[[0, -1]] = 0.5
        J = options.k1 * T + options.k2_per_nm2 * h * (ca.sum1(tau**2) @ ca.DM(wts))
        self._eval = ca.Function("ptp_outputs", [w], [T, tau, J])

        ipopt = {
            "max_iter": options.max_iter,
            "tol": options.tol,
            # the time converges to ~1e-5 long before IPOPT's default tolerances: stop there
            "acceptable_tol": 1e-4,
            "acceptable_iter": 5,
            "acceptable_obj_change_tol": 1e-6,
            "print_level": 0,
            "sb": "yes",
            "mu_strategy": "adaptive",
            "hessian_approximation": options.hessian,
        }
        if options.max_wall_s is not None:
            ipopt["max_wall_time"] = float(options.max_wall_s)
        self.solver = ca.nlpsol(
            "ptp",
            "ipopt",
            {"x": w, "f": J, "g": ca.vertcat(*rows)},
            {"ipopt": ipopt, "print_time": False, "expand": options.expand},
        )
        self.build_seconds = time.perf_counter() - t_build

    # --- bounds and guesses -------------------------------------------------------------------------
    def _bounds(self, q_start: np.ndarray, q_goal: np.ndarray):
        n, N, lim, s = self.dof, self.N, self.limits, 1.0 - self.options.margin
        half = (lim.q_max - lim.q_min) / 2
        lo = np.minimum(lim.q_min + (1 - s) * half, np.minimum(q_start, q_goal))
        hi = np.maximum(lim.q_max - (1 - s) * half, np.maximum(q_start, q_goal))
        q_lb, q_ub = np.tile(lo[:, None], N + 1), np.tile(hi[:, None], N + 1)
        q_lb[:, 0] = q_ub[:, 0] = q_start
        q_lb[:, -1] = q_ub[:, -1] = q_goal
        v_b = np.full((n, N + 1), s)
        v_b[:, [0, -1]] = 0.0
        a_lim = np.full(n, np.inf) if lim.a_max is None else s * lim.a_max / self.a_ref
        a_b = np.tile(a_lim[:, None], N + 1)
        a_b[:, [0, -1]] = 0.0
        u_b = np.full(n * N, np.inf)
        lbx = np.concatenate([[1e-3 / self.t_ref], q_lb.ravel("F"), -v_b.ravel("F"), -a_b.ravel("F"), -u_b])
        ubx = np.concatenate([[100.0 / self.t_ref], q_ub.ravel("F"), v_b.ravel("F"), a_b.ravel("F"), u_b])
        ng = sum(self._g_sizes)
        lbg, ubg = np.zeros(ng), np.zeros(ng)
        k = self._g_sizes[0]
        lbg[k:], ubg[k:] = -s, s
        return lbx, ubx, lbg, ubg

    def _pack(self, guess: NodeGuess) -> np.ndarray:
        N = self.N
        if guess.q.shape != (N + 1, self.dof) or guess.jerk.shape != (N, self.dof):
            raise ValueError(f"guess must be on the {N}-interval grid")
        return np.concatenate(
            [
                [guess.duration_s / self.t_ref],
                guess.q.ravel(),  # [N+1, n] row-major == [n, N+1] column-major
                (guess.qd / self.v_ref).ravel(),
                (guess.qdd / self.a_ref).ravel(),
                (guess.jerk / self.j_ref).ravel(),
            ]
        )

    def _unpack(self, w: np.ndarray) -> NodeGuess:
        n, N = self.dof, self.N
        o = np.cumsum((0, *self._sizes))
        blk = [w[o[i] : o[i + 1]] for i in range(5)]
        return NodeGuess(
            duration_s=float(blk[0][0] * self.t_ref),
            q=blk[1].reshape(N + 1, n),
            qd=blk[2].reshape(N + 1, n) * self.v_ref,
            qdd=blk[3].reshape(N + 1, n) * self.a_ref,
            jerk=blk[4].reshape(N, n) * self.j_ref,
        )

    def solve(self, q_start, q_goal, guess: NodeGuess) -> PtpSolution:
        """Solve from `guess` (on this grid). Never raises on non-convergence: see `.success`, `.status`."""
        q_start, q_goal = np.asarray(q_start, float), np.asarray(q_goal, float)
        lbx, ubx, lbg, ubg = self._bounds(q_start, q_goal)
        x0 = np.clip(self._pack(guess), lbx, ubx)
        t0 = time.perf_counter()
        res = self.solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        seconds = time.perf_counter() - t0
        stats = self.solver.stats()
        w = np.asarray(res["x"]).ravel()
        sol = self._unpack(w)
        T, tau, J = self._eval(w)
        return PtpSolution(
            duration_s=float(T),
            q=sol.q,
            qd=sol.qd,
            qdd=sol.qdd,
            jerk=sol.jerk,
            tau=np.asarray(tau).T,
            objective=float(J),
            status=str(stats.get("return_status", "unknown")),
            success=bool(stats.get("success", False)),
            iterations=int(stats.get("iter_count", -1)),
            solve_seconds=seconds,
        )


_OCP_CACHE: OrderedDict[tuple, PtpOcp] = OrderedDict()
_OCP_CACHE_SIZE = 4


def cached_ocp(dynamics: PtpDynamics, limits: PtpLimits, options: PtpOptions) -> PtpOcp:
    """A built `PtpOcp` for this dynamics, limits and options, reused within the process (LRU of 4)."""
    key = (dynamics.key(), limits.key(), options.model_dump_json())
    if key in _OCP_CACHE:
        _OCP_CACHE.move_to_end(key)
        return _OCP_CACHE[key]
    ocp = PtpOcp(dynamics, limits, options)
    _OCP_CACHE[key] = ocp
    while len(_OCP_CACHE) > _OCP_CACHE_SIZE:
        _OCP_CACHE.popitem(last=False)
    return ocp


# --- sampling at the drive cycle and the dense check ------------------------------------------------
def integrate_jerk(q0, qd0, qdd0, jerk, h: float, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact states at times `t` ∈ [0, N·h] of a triple integrator with jerk constant per interval h."""
    jerk = np.asarray(jerk, float)
    N, n = jerk.shape
    q, qd, qdd = (np.empty((N + 1, n)) for _ in range(3))
    q[0], qd[0], qdd[0] = q0, qd0, qdd0
    for k in range(N):  # node states by the same exact formulas the NLP uses
        u = jerk[k]
        q[k + 1] = q[k] + h * qd[k] + h**2 / 2 * qdd[k] + h**3 / 6 * u
        qd[k + 1] = qd[k] + h * qdd[k] + h**2 / 2 * u
        qdd[k + 1] = qdd[k] + h * u
    t = np.asarray(t, float)
    k = np.clip((t // h).astype(int), 0, N - 1)
    dt = (t - k * h)[:, None]
    u = jerk[k]
    return (
        q[k] + dt * qd[k] + dt**2 / 2 * qdd[k] + dt**3 / 6 * u,
        qd[k] + dt * qdd[k] + dt**2 / 2 * u,
        qdd[k] + dt * u,
    )


def sample_solution(sol: PtpSolution, dynamics: PtpDynamics, cycle_s: float, q_goal=None) -> Trajectory:
    """The optimum at the drive cycle: the jerk profile integrated exactly, torques from the dynamics.

    T is rounded up to a whole number of cycles by a uniform time stretch (q̇ × r, q̈ × r², jerk × r³
    with r = T/T' ≥ 0.9993 for T ≥ 0.5 s at 400 µs): only slower. The last sample is the goal at rest
    exactly (`q_goal` removes the NLP's ~1e-9 rad residual).
    """
    N, T = sol.n_intervals, sol.duration_s
    n_cycles = max(int(np.ceil(T / cycle_s - 1e-9)), 1)
    T2 = n_cycles * cycle_s
    r = T / T2
    t = np.arange(n_cycles + 1) * cycle_s
    q, qd, qdd = integrate_jerk(sol.q[0], sol.qd[0] * r, sol.qdd[0] * r**2, sol.jerk * r**3, T2 / N, t)
    q[-1] = sol.q[-1] if q_goal is None else q_goal
    qd[-1] = qdd[-1] = 0.0
    return Trajectory(t, q, qd, qdd, dynamics.torque(q, qd, qdd))


def sample_profile(profile: KinematicProfile, dynamics: PtpDynamics, cycle_s: float) -> Trajectory:
    """A kinematic profile at the drive cycle with its inverse-dynamics torques."""
    n_cycles = max(int(np.ceil(profile.duration_s / cycle_s - 1e-9)), 1)
    t = np.arange(n_cycles + 1) * cycle_s
    q, qd, qdd = profile.at(t)
    return Trajectory(t, q, qd, qdd, dynamics.torque(q, qd, qdd))


def dense_report(traj: Trajectory, dynamics: PtpDynamics, limits: PtpLimits, joint_names) -> LimitReport:
    """Every PtP limit on the drive-cycle samples; the torque rate of τ without its Coulomb part."""
    smooth = dynamics.rate_torque(traj.q, traj.qd, traj.tau_ff)
    ratios = {}
    for lim in limits.dense_checks():
        tau = smooth if isinstance(lim, TorqueRateLimit) else traj.tau_ff
        ratios[lim.name] = lim.ratios(traj.t, traj.q, traj.qd, traj.qdd, tau)
    return LimitReport(t=traj.t, ratios=ratios, joint_names=tuple(joint_names))


def tcp_box_ratio(robot: Robot, q: np.ndarray, box: tuple[Vec3, Vec3]) -> float:
    """max over samples and axes of |p − centre| / half-size for the TCP (≤ 1: inside the box)."""
    lo, hi = (np.asarray(c, float) for c in box)
    data = robot.create_data()
    p = np.empty((len(q), 3))
    for i, qi in enumerate(q):
        pin.framesForwardKinematics(robot.model, data, qi)
        p[i] = data.oMf[robot.tcp_frame_id].translation
    return float(np.max(np.abs(p - (lo + hi) / 2) / ((hi - lo) / 2)))


# --- the planner ------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PtpResult:
    """A solved PtP: the sampled trajectory, its dense limit report, the OCP solution and warm start."""

    trajectory: Trajectory
    report: LimitReport
    solution: PtpSolution
    warm_start: KinematicProfile
    build_seconds: float
    tcp_box_ratio: float | None = None

    @property
    def duration_s(self) -> float:
        return self.trajectory.duration_s

    @property
    def max_limit_ratio(self) -> float:
        r = self.report.max_ratio
        return r if self.tcp_box_ratio is None else max(r, self.tcp_box_ratio)

    @property
    def tau_squared_integral(self) -> float:
        """∫τᵀτ dt on the drive-cycle samples (trapezoid), (N·m)²·s."""
        tr = self.trajectory
        return float(np.trapezoid(np.sum(tr.tau_ff**2, axis=1), tr.t))


class PtpNotConverged(InfeasibleError):
    """IPOPT stopped without an optimum (exit 3); carries its status and the last iterate."""

    def __init__(self, status: str, solution: PtpSolution):
        self.status = status
        self.solution = solution
        super().__init__(
            f"plan-ptp: IPOPT did not converge: {status} after {solution.iterations} iterations "
            f"({solution.solve_seconds:.1f} s)"
        )


def check_boundary_state(dynamics: PtpDynamics, limits: PtpLimits, q, name: str, joint_names) -> np.ndarray:
    """Refuse an end point outside the position limits or whose holding torque exceeds the peak torque.

    Raises InputError with field `name[joint]` (exit 2).
    """
    q = np.asarray(q, float).ravel()
    n = len(limits.q_min)
    if q.shape != (n,) or not np.all(np.isfinite(q)):
        raise InputError(f"expected {n} finite joint angles, got {q.tolist()}", field=name)
    for j in range(n):
        if not limits.q_min[j] <= q[j] <= limits.q_max[j]:
            raise InputError(
                f"{q[j]:.6g} rad is outside the joint limits [{limits.q_min[j]:.6g}, {limits.q_max[j]:.6g}]",
                field=f"{name}[{joint_names[j]}]",
            )
    g = np.asarray(dynamics.inv_dyn(q, np.zeros(n), np.zeros(n))).ravel()
    for j in range(n):
        if abs(g[j]) > limits.tau_max[j]:
            raise InputError(
                f"holding torque {g[j]:.1f} N·m exceeds the peak torque {limits.tau_max[j]:.1f} N·m",
                field=f"{name}[{joint_names[j]}]",
            )
    return q


def default_kinematic_limits(robot: Robot, speed: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Velocity, acceleration and jerk limits of the ruckig warm start (a time scaling by `speed`).

    The drives' velocity and acceleration limits and a jerk reaching that acceleration in 50 ms:
    plausible for an arm, a starting point only (the OCP knows the torques).
    """
    v, a = np.asarray(robot.v_max, float), np.asarray(robot.a_max, float)
    return v * speed, a * speed**2, a / 0.05 * speed**3


def plan_ptp(
    robot: Robot,
    dynamics: PtpDynamics,
    q_start,
    q_goal,
    options: PtpOptions | None = None,
    *,
    warm_start: KinematicProfile | None = None,
    ocp: PtpOcp | None = None,
) -> PtpResult:
    """Plan the optimal rest-to-rest motion from `q_start` to `q_goal` (rad).

    Raises InputError (exit 2) for end points outside the limits, PtpNotConverged (exit 3) when IPOPT
    fails. `warm_start` overrides the ruckig profile; `ocp` a built NLP (default: `cached_ocp`).
    """
    options = options or PtpOptions()
    limits = PtpLimits.from_robot(robot, acceleration=options.acceleration_limits)
    q_start = check_boundary_state(dynamics, limits, q_start, "start", robot.joint_names)
    q_goal = check_boundary_state(dynamics, limits, q_goal, "goal", robot.joint_names)
    if np.max(np.abs(q_goal - q_start)) < 1e-9:
        raise InputError("the goal equals the start: nothing to plan", field="goal")
    if options.tcp_box_m is not None:
        for name, q in (("start", q_start), ("goal", q_goal)):
            if tcp_box_ratio(robot, q[None], options.tcp_box_m) > 1.0:
                raise InputError("the TCP is outside the TCP box", field=name)
    if warm_start is None:
        warm_start = ruckig_profile(q_start, q_goal, *default_kinematic_limits(robot))
    t0 = time.perf_counter()
    ocp = ocp or cached_ocp(dynamics, limits, options)
    build = time.perf_counter() - t0
    sol = ocp.solve(q_start, q_goal, NodeGuess.from_profile(warm_start, ocp.N))
    if not sol.success:
        raise PtpNotConverged(sol.status, sol)
    traj = sample_solution(sol, dynamics, robot.drives.cycle_s, q_goal=q_goal)
    report = dense_report(traj, dynamics, limits, robot.joint_names)
    box = None if options.tcp_box_m is None else tcp_box_ratio(robot, traj.q, options.tcp_box_m)
    return PtpResult(traj, report, sol, warm_start, build, box)


def kinematic_fallback(
    robot: Robot, dynamics: PtpDynamics, q_start, q_goal, options: PtpOptions | None = None
) -> tuple[Trajectory, LimitReport]:
    """The fastest time-scaled ruckig profile that passes the dense check of the PtP limits (≤ 1).

    For `--fallback` when the OCP does not converge. Raises InfeasibleError if none does.
    """
    options = options or PtpOptions()
    limits = PtpLimits.from_robot(robot, acceleration=options.acceleration_limits)
    cycle = robot.drives.cycle_s

    def check(p: KinematicProfile) -> tuple[Trajectory, LimitReport]:
        tr = sample_profile(p, dynamics, cycle)
        return tr, dense_report(tr, dynamics, limits, robot.joint_names)

    def ratio(p: KinematicProfile) -> float:
        tr, rep = check(p)
        r = rep.max_ratio
        if options.tcp_box_m is not None:
            r = max(r, tcp_box_ratio(robot, tr.q[:: max(len(tr.q) // 200, 1)], options.tcp_box_m))
        return r

    profile, _ = feasible_profile(q_start, q_goal, *default_kinematic_limits(robot), ratio)
    return check(profile)
