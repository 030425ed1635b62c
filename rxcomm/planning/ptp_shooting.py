"""The paper's formulation of the PtP problem, as a benchmark peer: forward-dynamics multiple shooting.

MUSCOD-II (paper §5.5) integrates the equations of motion q̈ = M(q)⁻¹(τ − h(q, q̇)) on each shooting
interval and treats the torques as controls. Here the same, in CasADi + IPOPT: states (q, q̇) at N + 1
nodes, torques at the nodes interpolated linearly (so the torque rate (τ_{k+1} − τ_k)/h is exact and
bounded like in `ptp`), RK4 with `substeps` steps per interval, free final time, the same limits
(torque, torque rate, velocity, position, tightened by `margin`), the same objective ∫(k1 + k2·τᵀτ)dt
and rest-to-rest ends with the holding torque at both ends (q̈ = 0 there, as in `ptp`).

The forward dynamics come from the inverse dynamics alone: M(q) column by column
(M e_j = ID(q, 0, e_j) − ID(q, 0, 0)) and h(q, q̇) = ID(q, q̇, 0), then a symbolic 6×6 solve. Every RK4
stage costs n + 2 RNEAs and a solve, and the Jacobian of a shooting interval is dense in 2n + 2n
variables: this is why the formulation is slow (architecture §7 measured 31–156 s), and why `ptp` uses
inverse dynamics at the nodes instead. Give it a wall-time cap (`PtpOptions.max_wall_s`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rxcomm.planning.ptp_ocp import _sx_function
from rxcomm.planning.ptp_problem import (
    IpoptOutcome,
    PtpDynamics,
    PtpLimits,
    PtpOptions,
    ipopt_options,
    run_ipopt,
)
from rxcomm.planning.warm_start import KinematicProfile


@dataclass(frozen=True, eq=False)
class ShootingSolution(IpoptOutcome):
    """The shooting NLP's answer on its grid ([N+1, dof] arrays) and how IPOPT got there."""

    duration_s: float
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    build_seconds: float
    max_defect: float


def forward_dynamics_function(dynamics: PtpDynamics) -> ca.Function:
    """`forward_dynamics(q, qd, tau) -> qdd` from the inverse dynamics (M column by column, LU solve)."""
    f = _sx_function(dynamics.inv_dyn)
    n = dynamics.dof
    q, qd, tau = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("tau", n)
    zero = ca.SX.zeros(n)
    g = f(q, zero, zero)
    m = ca.horzcat(*[f(q, zero, ca.DM(np.eye(n)[:, j])) - g for j in range(n)])
    h = f(q, qd, zero)
    qdd = ca.solve(m, tau - h)
    return ca.Function("forward_dynamics", [q, qd, tau], [qdd], ["q", "qd", "tau"], ["qdd"])


def rk4_interval(fd: ca.Function, n: int, substeps: int) -> ca.Function:
    """(x0, tau0, tau1, h) → x1 for x = (q, q̇), torque linear from tau0 to tau1 over the interval."""
    x0, t0, t1, h = ca.SX.sym("x0", 2 * n), ca.SX.sym("tau0", n), ca.SX.sym("tau1", n), ca.SX.sym("h")

    def rhs(x, tau):
        return ca.vertcat(x[n:], fd(x[:n], x[n:], tau))

    x, dt = x0, h / substeps
    for i in range(substeps):
        a, b = i / substeps, (i + 0.5) / substeps
        ta, tb, tc = t0 + a * (t1 - t0), t0 + b * (t1 - t0), t0 + (i + 1) / substeps * (t1 - t0)
        k1 = rhs(x, ta)
        k2 = rhs(x + dt / 2 * k1, tb)
        k3 = rhs(x + dt / 2 * k2, tb)
        k4 = rhs(x + dt * k3, tc)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("rk4_interval", [x0, t0, t1, h], [x], ["x0", "tau0", "tau1", "h"], ["x1"])


class ShootingOcp:
    """Forward-dynamics multiple shooting for the PtP problem of `ptp.PtpOcp` (benchmark peer)."""

    def __init__(
        self,
        dynamics: PtpDynamics,
        limits: PtpLimits,
        options: PtpOptions | None = None,
        *,
        substeps: int = 1,
        t_ref_s: float = 1.0,
        expand: bool = False,
    ):
        t_build = time.perf_counter()
        self.dynamics, self.limits = dynamics, limits
        self.options = options = options or PtpOptions()
        n = self.dof = len(limits.q_min)
        N = self.N = options.n_intervals
        self.t_ref = float(t_ref_s)
        self.v_ref = np.asarray(limits.v_max, float)
        self.tau_ref = np.asarray(limits.tau_max, float)
        fd = forward_dynamics_function(dynamics)
        step = rk4_interval(fd, n, substeps).map(N)

        Tn = ca.MX.sym("T_scaled")
        Q, V, S = ca.MX.sym("Q", n, N + 1), ca.MX.sym("V", n, N + 1), ca.MX.sym("S", n, N + 1)
        w = ca.vertcat(Tn, ca.vec(Q), ca.vec(V), ca.vec(S))
        self._sizes = (1, n * (N + 1), n * (N + 1), n * (N + 1))
        T = self.t_ref * Tn
        h = T / N
        vr, tr = ca.DM(self.v_ref), ca.DM(self.tau_ref)
        qd, tau = ca.diag(vr) @ V, ca.diag(tr) @ S
        x = ca.vertcat(Q, qd)
        x1 = step(x[:, :-1], tau[:, :-1], tau[:, 1:], ca.repmat(h, 1, N))
        scale = ca.repmat(ca.vertcat(ca.DM.ones(n), vr), 1, N)
        defect = (x[:, 1:] - x1) / scale
        rate = (tau[:, 1:] - tau[:, :-1]) / h / ca.repmat(ca.DM(limits.tau_rate_max), 1, N)
        wts = np.ones(N + 1)
        wts[[0, -1]] = 0.5
        J = options.k1 * T + options.k2_per_nm2 * h * (ca.sum1(tau**2) @ ca.DM(wts))
        self._g_sizes = (2 * n * N, n * N)
        self._defect = ca.Function("defect", [w], [defect])
        self.solver = ca.nlpsol(
            "ptp_shooting",
            "ipopt",
            {"x": w, "f": J, "g": ca.vertcat(ca.vec(defect), ca.vec(rate))},
            {"ipopt": ipopt_options(options, "limited-memory"), "print_time": False, "expand": expand},
        )
        self._duration = ca.Function("duration", [w], [T])
        self.build_seconds = time.perf_counter() - t_build

    def _bounds(self, q_start, q_goal):
        n, N, lim, s = self.dof, self.N, self.limits, 1.0 - self.options.margin
        half = (lim.q_max - lim.q_min) / 2
        lo = np.minimum(lim.q_min + (1 - s) * half, np.minimum(q_start, q_goal))
        hi = np.maximum(lim.q_max - (1 - s) * half, np.maximum(q_start, q_goal))
        q_lb, q_ub = np.tile(lo[:, None], N + 1), np.tile(hi[:, None], N + 1)
        q_lb[:, 0] = q_ub[:, 0] = q_start
        q_lb[:, -1] = q_ub[:, -1] = q_goal
        v_b = np.full((n, N + 1), s)
        v_b[:, [0, -1]] = 0.0
        t_lb, t_ub = np.full((n, N + 1), -s), np.full((n, N + 1), s)
        z = np.zeros(n)
        for k, q in ((0, q_start), (-1, q_goal)):  # holding torque at rest: q̈ = 0 at both ends
            t_lb[:, k] = t_ub[:, k] = np.asarray(self.dynamics.inv_dyn(q, z, z)).ravel() / self.tau_ref
        lbx = np.concatenate([[1e-3 / self.t_ref], q_lb.ravel("F"), -v_b.ravel("F"), t_lb.ravel("F")])
        ubx = np.concatenate([[100.0 / self.t_ref], q_ub.ravel("F"), v_b.ravel("F"), t_ub.ravel("F")])
        ng = sum(self._g_sizes)
        lbg, ubg = np.zeros(ng), np.zeros(ng)
        lbg[self._g_sizes[0] :], ubg[self._g_sizes[0] :] = -s, s
        return lbx, ubx, lbg, ubg

    def guess_from_profile(self, profile: KinematicProfile) -> np.ndarray:
        N = self.N
        T = max(profile.duration_s, 1e-3)
        q, qd, qdd = profile.at(np.linspace(0.0, T, N + 1))
        tau = np.asarray(self.dynamics.inv_dyn.map(N + 1)(q.T, qd.T, qdd.T)).T
        return np.concatenate(
            [[T / self.t_ref], q.ravel(), (qd / self.v_ref).ravel(), (tau / self.tau_ref).ravel()]
        )

    def solve(self, q_start, q_goal, warm_start: KinematicProfile) -> ShootingSolution:
        q_start, q_goal = np.asarray(q_start, float), np.asarray(q_goal, float)
        lbx, ubx, lbg, ubg = self._bounds(q_start, q_goal)
        w, outcome = run_ipopt(self.solver, self.guess_from_profile(warm_start), lbx, ubx, lbg, ubg)
        n, N = self.dof, self.N
        o = np.cumsum((0, *self._sizes))
        return ShootingSolution(
            duration_s=float(self._duration(w)),
            q=w[o[1] : o[2]].reshape(N + 1, n),
            qd=w[o[2] : o[3]].reshape(N + 1, n) * self.v_ref,
            tau=w[o[3] : o[4]].reshape(N + 1, n) * self.tau_ref,
            **outcome,
            build_seconds=self.build_seconds,
            max_defect=float(np.max(np.abs(np.asarray(self._defect(w))))),
        )
