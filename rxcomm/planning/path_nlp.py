"""The paper's path-domain optimal control problem (§5.2, eq. 38) as a CasADi NLP solved by IPOPT.

    minimise  ∫ (k1 + k2·τᵀτ + k3·P) dt = Σ_k Δt_k·(k1 + mean(k2·τᵀτ + k3·P at the interval ends))
    subject to joint velocity, acceleration, torque (and torque-rate, TCP acceleration) limits
               and optionally a fixed duration Σ_k Δt_k = T

P is the bus power of `rxcomm.model.energy.BusPowerModel` (copper losses τᵀQτ, mechanical power
τᵀq̇, its positive part smoothed unless the supply is regenerative): with k3 = 1 and the duration
fixed (k1 then adds a constant) the NLP minimises the electrical energy at that cycle time (issue 29).

over a fixed joint path q(σ). Variables per grid node: b_k = σ̇² and a_k = σ̈ (the convex choice of
Verscheure et al.: velocity and acceleration limits are linear in them, the time is convex). Between
nodes σ̈ is linear in σ, so σ̇² is quadratic and b_{k+1} − b_k = (a_k + a_{k+1})·Δσ_k holds exactly; the
first and last intervals are constant-jerk segments from and to rest with σ̈ = 0, where
b_1 = 1.5·a_1·Δσ_0 (mirrored at the end). σ̈ is therefore continuous, and so is the torque: the
torque-rate limit can hold on the sampled output, which a piecewise-constant σ̈ (toppra) cannot give.

Torque along the path (`PathDynamics`, s = √b):

    τ = m·a + c·b + v·s + Fc·tanh(q'·s/ε) + g,

with Coulomb friction smoothed exactly as the output feed-forward is (`rxcomm.model.dynamics`, ε =
`COULOMB_EPS_NLP_RAD_S`), so the torque and its rate here are the ones the sampled trajectory has:

    dτ/dt = (m'·a + m·a' + c'·b + 2c·a + g')·s + v'·b + v·a + Fc·(1 − tanh²)·(q''·b + q'·a)/ε,

a' = dσ̈/dσ of the interval, constrained at both ends of every interval (callers put nodes where a joint
reverses, where the friction term peaks); inside the end ramps the friction band's peak is bounded in
closed form. Joint accelerations are also constrained at interval midpoints: where a joint is at its
limit exactly where it reverses (q' = 0), σ̈ drops out of the node rows and would zig-zag. So is the
speed bound (joint velocities, TCP speed: σ̇² ≤ bound, a bound on b at the nodes): where it binds on
consecutive nodes the time depends on the nodes alone and σ̈ could alternate ±a between them, bulging
σ̇² by a·Δσ/2 in between; with the midpoint row σ̇² can exceed the bound inside an interval by at most
an eighth of its rise over that interval (the vertex of the quadratic between midpoint and node).

No symbolic robot model is needed: along a fixed path the dynamics are numbers at the nodes. The NLP is
an MX graph (builds in ~0.1 s; SX took 2.5 s) with all path data and per-node limits as parameters,
built once per (N, dof, options) and cached; re-solves are warm-started with the previous multipliers.
IPOPT runs to tol 1e-8: the time is nearly flat in the shape of the switches between limits, and a
looser tolerance stops with transitions that leave no limit active for several nodes.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rxcomm.errors import SolveOutcome
from rxcomm.model.energy import BusPowerModel
from rxcomm.planning.path_dynamics import PathDynamics
from rxcomm.planning.path_profile import PathProfile
from rxcomm.planning.topp import PlanLimits, velocity_bound_x

# IPOPT's time here is its linear algebra (6425 rows on 402 variables at N = 200; the functions are
# ~10 %), a third of it the adaptive barrier's safeguard: without it and without the residual checks of
# each step, 25 instead of 28 iterations and −35 % CPU on the RX130L line, the same durations and limit
# ratios on all nine sample paths of both robots (issue 32; `make bench` times the NLP without them too).
# Not for the energy objective: at a fixed duration the RX130L line-near-singularity then ran out of its
# 3000 iterations (tests/test_energy_objective.py), with the safeguard it converges.
SPEED_OPTIONS = {"adaptive_mu_globalization": "never-monotone-mode", "fast_step_computation": "yes"}
S_MIN = 1e-3  # m/s: interior nodes keep moving (Δt = 2Δσ/(s_k + s_{k+1}) stays finite)
SAG_FRACTION = 1 / 8  # energy objective: σ̇² at an interval's midpoint ≥ (1 − this) × the nodes' mean
_SIZES_PER_NODE_JOINT = (
    "qs",
    "qss",
    "m",
    "c",
    "v",
    "g",
    "dm",
    "dc",
    "dv",
    "dg",
    "a_max",
    "tau_max",
    "rate_max",
)


@dataclass(frozen=True, eq=False)
class NlpResult:
    ok: bool
    profile: PathProfile | None
    objective: float
    duration_s: float
    energy_nm2s: float  # ∫τᵀτ dt over the nodes (trapezoid)
    iterations: int
    status: str
    solve_seconds: float
    build_seconds: float
    duals: tuple[np.ndarray, np.ndarray] | None = None  # (λ_x, λ_g), to warm-start a re-solve
    bus_energy_j: float | None = None  # ∫P dt over the nodes (trapezoid) of the energy objective

    @property
    def outcome(self) -> SolveOutcome:
        """The solvers' one result convention, from IPOPT's status."""
        return SolveOutcome.from_ipopt(self.status, self.ok, self.iterations)


def _layout(n_nodes: int, dof: int) -> dict[str, tuple[int, int]]:
    """Layout of the parameter vector: name -> (offset, size)."""
    sizes = {"dsig": n_nodes - 1, "kappa": n_nodes, "acc_tcp": n_nodes, "scal": 8, "qmat": dof * dof}
    sizes |= {k: n_nodes * dof for k in _SIZES_PER_NODE_JOINT}
    sizes |= {k: (n_nodes - 1) * dof for k in ("qs_mid", "qss_mid", "a_max_mid")}
    sizes |= {"b_max_mid": n_nodes - 1}
    sizes |= {"fc": dof}
    out, off = {}, 0
    for k, sz in sizes.items():
        out[k] = (off, sz)
        off += sz
    return out


@dataclass(frozen=True, eq=False)
class _Solver:
    nlpsol: ca.Function
    layout: dict[str, tuple[int, int]]
    lbg: np.ndarray
    ubg: np.ndarray
    extras: ca.Function  # (x, p) -> (Δt per interval, τᵀτ per node, bus power per node)
    build_seconds: float
    duration_row: int  # the row Σ Δt − T of g


@functools.lru_cache(maxsize=16)
def _solver(
    n_nodes: int,
    dof: int,
    torque_rate: bool,
    tcp_acc: bool,
    max_iter: int,
    warm: bool = False,
    energy: bool = False,
) -> _Solver:
    """Build (once per process and shape) the IPOPT solver for n_nodes = N + 1 grid nodes."""
    t0 = time.perf_counter()
    lay = _layout(n_nodes, dof)
    p = ca.MX.sym("p", sum(sz for _, sz in lay.values()))

    def par(name: str, shape=None):
        off, sz = lay[name]
        v = p[off : off + sz]
        return ca.reshape(v, shape) if shape is not None else v

    N = n_nodes - 1
    shp = (n_nodes, dof)
    b = ca.MX.sym("b", n_nodes)
    a = ca.MX.sym("a", n_nodes)
    dsig = par("dsig")
    qs, qss, m, c, v, g, dm, dc, dv, dg, a_max, tau_max, rate_max = (
        par(k, shp) for k in _SIZES_PER_NODE_JOINT
    )
    fc = par("fc").T
    kappa, acc_tcp, scal = par("kappa"), par("acc_tcp"), par("scal")
    k1, k2, eps, k3, delta, regen = scal[0], scal[1], scal[3], scal[5], scal[6], scal[7]

    def rows(x):  # a node vector as a column per joint
        return ca.repmat(x, 1, dof)

    def lim(x, n):  # a per-joint row vector for n nodes
        return ca.repmat(x, n, 1)

    # σ̇ = √b; the end nodes rest (b = 0) where √b has no derivative: keep them out of the sqrt.
    s = ca.vertcat(0, ca.sqrt(b[1:N]), 0)
    s_r, a_r, b_r = rows(s), rows(a), rows(b)
    qdd = qss * b_r + qs * a_r
    th = ca.tanh(qs * s_r / eps)
    tau = m * a_r + c * b_r + v * s_r + lim(fc, n_nodes) * th + g
    cons, lbg, ubg = [], [], []

    def add(expr, lo, hi):
        expr = ca.vec(expr)
        cons.append(expr)
        lbg.append(np.full(expr.shape[0], lo))
        ubg.append(np.full(expr.shape[0], hi))

    add(
        ca.vertcat(
            b[1] - 1.5 * a[1] * dsig[0],
            b[2:N] - b[1 : N - 1] - (a[1 : N - 1] + a[2:N]) * dsig[1 : N - 1],
            b[N - 1] + 1.5 * a[N - 1] * dsig[N - 1],
        ),
        0.0,
        0.0,
    )
    add(qdd / a_max, -1.0, 1.0)
    # ... and at interval midpoints, where σ̇² = b_k + (3a_k + a_{k+1})·Δσ/4 exactly: without them a
    # joint at its limit where it reverses (q' = 0, so σ̈ drops out) lets σ̈ zig-zag and overshoot.
    qs_m, qss_m = par("qs_mid", (N, dof)), par("qss_mid", (N, dof))
    b_mid = b[:-1] + (3 * a[:-1] + a[1:]) * dsig / 4
    a_mid = (a[:-1] + a[1:]) / 2
    add((qss_m * rows(b_mid)[:N, :] + qs_m * rows(a_mid)[:N, :]) / par("a_max_mid", (N, dof)), -1.0, 1.0)
    # The speed bound (joint velocities, TCP speed) at the midpoints too: where it is active on
    # consecutive nodes (b_k = b_{k+1} = bound) the time depends on the nodes alone, σ̈ may alternate
    # ±a between them, and σ̇² bulges by a·Δσ/2 in between (1.7 % over a 0.4 m/s TCP cap).
    add(b_mid / par("b_max_mid"), -np.inf, 1.0)
    if energy:
        # Inside an interior interval σ̇² is quadratic in σ: the chord between the nodes less a sag
        # 4·x(1−x)·(a_{k+1} − a_k)·Δσ/4 (x: the fraction of the interval), which the Δt rows (exact for
        # a straight chord) do not see. A fixed-duration energy optimum used that: it zig-zagged σ̈ by
        # ±5 m/s² between nodes at the speed floor, σ̇² dipped below zero in between (a law that stops
        # and reverses, its time undefined) while Δt priced a short crawl (RX130L ISO line at 8 × T_opt).
        # The midpoint's sag is held to SAG_FRACTION of the chord: σ̇² stays positive throughout (for
        # any fraction ≤ ½) and the law's time within ≈ 4 % of Δt on such an interval. The time-optimal
        # problem has no use for time between the nodes and keeps its rows as they were.
        inner = slice(1, N - 1)
        sag_room = b_mid[inner] - (1 - SAG_FRACTION) * (b[1 : N - 1] + b[2:N]) / 2
        add(sag_room / par("b_max_mid")[inner], 0.0, np.inf)
    add(tau / tau_max, -1.0, 1.0)
    if tcp_acc:
        add((a * a + kappa * kappa * b * b) / (acc_tcp * acc_tcp), -np.inf, 1.0)
    if torque_rate:

        def rate(idx: slice, slope):
            """dτ/dt at nodes `idx` with σ̈ rising at `slope` (per m) on the interval beside them."""
            sj, aj, bj = rows(s[idx]), rows(a[idx]), rows(b[idx])
            body = (
                dm[idx, :] * aj + m[idx, :] * rows(slope) + dc[idx, :] * bj + 2 * c[idx, :] * aj + dg[idx, :]
            )
            fric = lim(fc, sj.shape[0]) * (1 - th[idx, :] ** 2) * (qss[idx, :] * bj + qs[idx, :] * aj) / eps
            return (body * sj + dv[idx, :] * bj + v[idx, :] * aj + fric) / rate_max[idx, :]

        slope = (a[2:N] - a[1 : N - 1]) / dsig[1 : N - 1]  # interior intervals 1..N-2
        j0 = a[1] * s[1] / (3 * dsig[0])  # constant jerk of the first and last intervals
        jn = -a[N - 1] * s[N - 1] / (3 * dsig[N - 1])
        add(rate(slice(1, N - 1), slope), -1.0, 1.0)  # left ends of the interior intervals
        add(rate(slice(2, N), slope), -1.0, 1.0)  # right ends
        add(rate(slice(1, 2), j0 / s[1]), -1.0, 1.0)
        add(rate(slice(N - 1, N), jn / s[N - 1]), -1.0, 1.0)
        # Inside the constant-jerk end intervals the inertial rate m·j is constant, and every moving
        # joint crosses the friction band |q̇| ≲ 2ε: Fc·tanh(q'·j·t²/2ε) changes at up to
        # 0.56·Fc·√(2|q'|·j/ε), growing in the direction of motion when starting and decaying when
        # stopping. Both the inertial rate alone and with the band's peak must hold.
        for node, jerk, direction in ((0, j0, 1.0), (N, jn, -1.0)):
            inertial = m[node, :] * jerk
            band = 0.56 * fc * ca.sqrt(2 * ca.fabs(qs[node, :]) * ca.fmax(jerk, 0) / eps + 1e-12)
            add(inertial / rate_max[node, :], -1.0, 1.0)
            add((inertial + direction * ca.sign(qs[node, :]) * band) / rate_max[node, :], -1.0, 1.0)

    tt = ca.sum2(tau * tau)
    dt = ca.vertcat(
        3 * dsig[0] / s[1],
        2 * dsig[1 : N - 1] / (s[1 : N - 1] + s[2:N]),
        3 * dsig[N - 1] / s[N - 1],
    )
    duration_row = sum(len(lo) for lo in lbg)
    add(ca.sum1(dt) - scal[2], 0.0, 0.0)  # the duration (its bounds opened when it is free)
    # bus power per node (BusPowerModel.power, with the regeneration switch a parameter)
    bus = ca.sum2(tau * qs * s_r) + ca.sum2(ca.mtimes(tau, par("qmat", (dof, dof))) * tau)
    bus = regen * bus + (1 - regen) * 0.5 * (bus + ca.sqrt(bus * bus + delta * delta))
    node_cost = k2 * tt + (k3 * bus if energy else 0)
    # A tiny penalty on σ̈ changes: where the binding limit does not involve σ̈ (a joint at its
    # acceleration limit exactly where it reverses, q' = 0), σ̈ is otherwise free to zig-zag between
    # nodes, and the sampled values between them overshoot.
    da = a[1:] - a[:-1]
    obj = ca.sum1(dt * (k1 + (node_cost[:-1] + node_cost[1:]) / 2)) + scal[4] * ca.sumsqr(da)
    x = ca.vertcat(b, a)
    opts = {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "print_time": False,
        "ipopt.max_iter": max_iter,
        "ipopt.tol": 1e-8,
        "ipopt.acceptable_tol": 1e-5,
        "ipopt.constr_viol_tol": 1e-8,
        "ipopt.mu_strategy": "adaptive",
    } | ({} if energy else {f"ipopt.{k}": v for k, v in SPEED_OPTIONS.items()})
    if warm:  # re-solves start from a solution and its multipliers: skip the barrier's first phase
        opts |= {
            "ipopt.mu_init": 1e-4,
            "ipopt.warm_start_init_point": "yes",
            "ipopt.warm_start_bound_push": 1e-6,
            "ipopt.warm_start_mult_bound_push": 1e-6,
        }
    solver = ca.nlpsol("path_nlp", "ipopt", {"x": x, "p": p, "f": obj, "g": ca.vertcat(*cons)}, opts)
    extras = ca.Function("path_nlp_extras", [x, p], [dt, tt, bus], ["x", "p"], ["dt", "tau_sq", "bus"])
    return _Solver(
        solver, lay, np.concatenate(lbg), np.concatenate(ubg), extras, time.perf_counter() - t0, duration_row
    )


def coulomb_levels(pd: PathDynamics) -> np.ndarray:
    """Fc per joint from the path dynamics' Coulomb term (±Fc where the joint moves)."""
    return np.abs(pd.f).max(axis=0)


def optimise_path(
    spline,
    grid: np.ndarray,
    pd: PathDynamics,
    dpd: dict[str, np.ndarray],
    limits: PlanLimits,
    warm: PathProfile | None,
    *,
    coulomb_eps_rad_s: float,
    k1: float = 1.0,
    k2: float = 0.0,
    curvature: np.ndarray | None = None,
    scale: dict[str, np.ndarray] | None = None,
    duals: tuple[np.ndarray, np.ndarray] | None = None,
    smoothing: float = 0.0,
    max_iter: int = 500,
    bus: BusPowerModel | None = None,
    k3: float = 0.0,
    duration_s: float | None = None,
) -> NlpResult:
    """Solve the path NLP on `grid` (N+1 nodes). `pd`/`dpd` are the path dynamics at the nodes and
    their σ-derivatives (keys m, c, v, g); `warm` a profile to start from (e.g. toppra's);
    `coulomb_eps_rad_s` the smoothing of the Coulomb sign used for the output torques too; `scale`
    local limit factors per node (`PlanLimits.at_nodes`); `duals` the multipliers of a previous solve
    of the same size (warm start); `smoothing` an optional weight on Σ(Δσ̈)²; `bus` and `k3` the
    electrical-energy term (weight 1/J); `duration_s` a fixed duration (None: free)."""
    grid = np.asarray(grid, dtype=float)
    n_nodes, dof = len(grid), pd.m.shape[1]
    if n_nodes < 4:
        raise ValueError("the path NLP needs at least 3 intervals")
    if not coulomb_eps_rad_s > 0:
        raise ValueError("coulomb_eps_rad_s must be positive")
    torque_rate = limits.tau_rate_max is not None
    tcp_acc = limits.tcp_acc_max is not None
    if tcp_acc and curvature is None:
        raise ValueError("a TCP acceleration limit needs the path curvature at the nodes")
    cached = _solver.cache_info().currsize
    if k3 > 0 and bus is None:
        raise ValueError("an energy weight k3 needs the bus power model")
    energy = bus is not None and k3 > 0
    sv = _solver(n_nodes, dof, torque_rate, tcp_acc, max_iter, duals is not None, energy)
    build = sv.build_seconds if _solver.cache_info().currsize > cached else 0.0
    qs, qss = spline(grid, 1), spline(grid, 2)
    mid = (grid[:-1] + grid[1:]) / 2
    qs_mid = spline(mid, 1)
    a_max = limits.at_nodes("a_max", n_nodes, scale)
    v_max, tcp_max = (limits.at_nodes(k, n_nodes, scale) for k in ("v_max", "tcp_speed_max"))
    b_hi = velocity_bound_x(qs, v_max, tcp_max)
    b_hi_mid = velocity_bound_x(
        qs_mid,
        np.minimum(v_max[:-1], v_max[1:]),
        None if tcp_max is None else np.minimum(tcp_max[:-1], tcp_max[1:]),
    )
    values = {
        "a_max": a_max,
        "a_max_mid": np.minimum(a_max[:-1], a_max[1:]),
        "tau_max": limits.at_nodes("tau_max", n_nodes, scale),
        "rate_max": limits.at_nodes("tau_rate_max", n_nodes, scale)
        if torque_rate
        else np.ones((n_nodes, dof)),
        "acc_tcp": limits.at_nodes("tcp_acc_max", n_nodes, scale) if tcp_acc else np.ones(n_nodes),
        "qs_mid": qs_mid,
        "b_max_mid": np.maximum(b_hi_mid, S_MIN**2),
        "qss_mid": spline(mid, 2),
        "dsig": np.diff(grid),
        "kappa": np.zeros(n_nodes) if curvature is None else curvature,
        "scal": np.array(
            [
                k1,
                k2,
                duration_s or 0.0,
                coulomb_eps_rad_s,
                smoothing,
                k3,
                bus.smoothing_w if bus else 1.0,
                float(bus.regenerative) if bus else 1.0,
            ]
        ),  # fmt: skip
        "qmat": np.zeros((dof, dof)) if bus is None else np.asarray(bus.copper_w_per_nm2),
        "qs": qs,
        "qss": qss,
        "m": pd.m,
        "c": pd.c,
        "v": pd.v,
        "g": pd.g,
        "dm": dpd["m"],
        "dc": dpd["c"],
        "dv": dpd["v"],
        "dg": dpd["g"],
        "fc": coulomb_levels(pd),
    }
    pvec = np.zeros(sum(sz for _, sz in sv.layout.values()))
    for k, (off, sz) in sv.layout.items():
        pvec[off : off + sz] = np.asarray(values[k], dtype=float).reshape(-1, order="F")
    lbx = np.concatenate([np.full(n_nodes, S_MIN**2), np.full(n_nodes, -np.inf)])
    ubx = np.concatenate([np.maximum(b_hi, S_MIN**2), np.full(n_nodes, np.inf)])
    for i in (0, n_nodes - 1):  # rest with zero acceleration at both ends
        lbx[i] = ubx[i] = lbx[n_nodes + i] = ubx[n_nodes + i] = 0.0
    b0 = np.interp(grid, warm.sigma, warm.sd**2) if warm is not None else 0.25 * np.minimum(b_hi, 1.0)
    lbg, ubg = sv.lbg.copy(), sv.ubg.copy()
    if duration_s is None:
        lbg[sv.duration_row], ubg[sv.duration_row] = -np.inf, np.inf
    b0 = np.clip(b0, S_MIN**2, ubx[:n_nodes])
    b0[[0, -1]] = 0.0
    a0 = np.gradient(b0, grid) / 2
    a0[[0, -1]] = 0.0
    t1 = time.perf_counter()
    args = {"x0": np.concatenate([b0, a0]), "p": pvec, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}
    if duals is not None:
        args |= {"lam_x0": duals[0], "lam_g0": duals[1]}
    sol = sv.nlpsol(**args)
    solve = time.perf_counter() - t1
    stats = sv.nlpsol.stats()
    x = np.array(sol["x"]).ravel()
    b_opt, a_opt = np.maximum(x[:n_nodes], 0.0), x[n_nodes:].copy()
    b_opt[[0, -1]] = a_opt[[0, -1]] = 0.0
    ok = bool(stats["success"]) or stats["return_status"] == "Solved_To_Acceptable_Level"
    dt, tt, pw = (np.array(v).ravel() for v in sv.extras(x, pvec))
    return NlpResult(
        ok=ok,
        profile=PathProfile(grid, np.sqrt(b_opt), a_opt, "linear") if ok else None,
        objective=float(sol["f"]),
        duration_s=float(dt.sum()),
        energy_nm2s=float(np.sum(dt * (tt[:-1] + tt[1:]) / 2)),
        iterations=int(stats["iter_count"]),
        status=str(stats["return_status"]),
        solve_seconds=solve,
        build_seconds=build,
        duals=(np.array(sol["lam_x"]).ravel(), np.array(sol["lam_g"]).ravel()),
        bus_energy_j=float(np.sum(dt * (pw[:-1] + pw[1:]) / 2)) if bus is not None else None,
    )
