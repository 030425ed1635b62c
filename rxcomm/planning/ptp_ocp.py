"""The point-to-point OCP (paper §5.4–5.5): a scaled free-final-time transcription with exact derivatives.

Formulation (architecture §7, "Planning facts"): the joints are a triple integrator driven by a jerk that is
constant on each of N intervals of a normalised time s ∈ [0, 1]; t = T·s with the final time T a
decision variable. The nodes carry (q, q̇, q̈); the torques come from the inverse dynamics at the nodes
(no forward dynamics, no numerical integrator: integrating a constant jerk is exact). This is what
makes it much faster than the paper's forward-dynamics multiple shooting (`ptp_shooting`).

    minimise   ∫₀ᵀ (k1 + k2·τᵀτ) dt          (τᵀτ by the trapezoid rule over the nodes)
               or, `objective` energy, ∫₀ᵀ P dt at a fixed T: the bus power of
               `model.energy.BusPowerModel` (copper, mechanical, regeneration as drives.yaml says)
               by Simpson on the nodes and interval midpoints, with the torque `run` is judged on
               (`_window_energy`: a node trapezoid let the optimum swing q̇ between the nodes)
    subject to (q, q̇, q̈)_{k+1} = exact integration of the jerk u_k over h = T/N
               q(0) = q_start, q(T) = q_goal, q̇ = q̈ = 0 at both ends (rest to rest; q̈ = 0 keeps the
               torque continuous with the holding torque before and after the motion)
               q_min ≤ q ≤ q_max, |q̇| ≤ v_max (at the nodes and the interval midpoints: q̇ is
               quadratic in between), |τ| ≤ τ_max, |τ̇| ≤ τ̇_max, optionally |q̈| ≤ a_max and the
               TCP inside a box

Torque rate: the torque is differentiated exactly along the motion (forward-mode AD, CasADi
`jtimes`): τ̇ = ∂τ/∂q·q̇ + ∂τ/∂q̇·q̈ + ∂τ/∂q̈·u. The jerk jumps at the nodes, so τ̇ does too; it is
constrained on both sides of every node (with u_{k−1} and with u_k). Finite differences
(τ_{k+1} − τ_k)/h were measured to under-check by 15 % (N = 50) and 6 % (N = 100) between nodes, the
derivative by < 0.1 %. The rate limit applies to the torque *without Coulomb friction*: a smooth sign
tanh(q̇/ε) steps by 2·Fc within 2ε/|q̈| at every velocity reversal, a rate set by ε, not by the
drive (Fc·|q̈|/ε; with `run`'s ε = 0.02 rad/s ≈ 4·10⁴ N·m/s on J2 at the paper's unlimited
accelerations against 1.2·10⁴, 0.75 × at J2's 6 rad/s²); limiting it in the rows would make every
reversal crawl. The sampled plan is checked with the step (as `run` checks it):
`ptp` bounds it after the solve where it exceeds the limit, by local |q̈| caps (`solve(accel_caps=)`).

Friction smoothing: the PtP model uses ε = 0.1 rad/s (`PTP_COULOMB_EPS_RAD_S`; ≈ 6 °/s, 2–3 % of the
joints' top speeds), not the identification's 0.02. With 0.02 the friction step of a reversing joint
fits between two nodes, and the optimum hides it there: the torque checked only at the nodes was
1.036–1.049 × its limit between them (N = 50–100). With 0.1 the step spans about an interval and the
node constraints see it. Bounding each node's torque with its neighbours' friction instead also
works, but multiplied IPOPT's linear-algebra time by ~6.

Scaling: q in rad, q̇/v_max, q̈/a_ref, u/j_ref, T/T_ref with a_ref = τ_max/M_jj and j_ref = τ̇_max/M_jj
(M_jj the joint-space inertia diagonal at a reference posture), torque and rate rows divided by their
limits. Derivatives are assembled from per-node windows (`PtpOcp`), and IPOPT uses the exact Hessian
by default: measured on the RX130L line (N = 100) it converges in 25–35 iterations against 60–110 with
L-BFGS, whose low-rank updates also cost extra back-solves every iteration.
"""

from __future__ import annotations

import time
from collections import OrderedDict

import casadi as ca
import numpy as np

from rxcomm import casadi_build
from rxcomm.planning.ptp_problem import (
    NodeGuess,
    PtpDynamics,
    PtpLimits,
    PtpOptions,
    PtpSolution,
    energy_quadrature,
    ipopt_options,
    run_ipopt,
)

LIMIT_NAMES = ("position", "velocity", "acceleration", "torque", "torque_rate", "tcp_box")


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


def _csc(nrow: int, ncol: int, rows: np.ndarray, cols: np.ndarray) -> tuple[ca.Sparsity, np.ndarray]:
    """Sparsity of the (unique) entries (rows, cols) and the permutation putting them in CasADi's
    column-major nonzero order."""
    perm = np.lexsort((rows, cols))
    colind = np.searchsorted(cols[perm], np.arange(ncol + 1))
    return ca.Sparsity(nrow, ncol, colind.tolist(), rows[perm].tolist()), perm


def _nonzeros(m: ca.SX) -> ca.SX:
    """The structural nonzeros of `m` as a dense column, in CasADi's column-major order."""
    return ca.vertcat(*m.nonzeros()) if m.nnz() else ca.SX.zeros(0, 1)


def inertia_diagonal(inv_dyn: ca.Function, q) -> np.ndarray:
    """diag M(q) from the inverse dynamics (τ is affine in q̈: M e_j = ID(q, 0, e_j) − ID(q, 0, 0))."""
    q = np.asarray(q, float)
    n = len(q)
    z = np.zeros(n)
    base = np.asarray(inv_dyn(q, z, z)).ravel()
    return np.array([float(np.asarray(inv_dyn(q, z, np.eye(n)[j])).ravel()[j] - base[j]) for j in range(n)])


class PtpOcp:
    """The NLP for one dynamics, limit set, option set and grid; `solve` may be called for many end points.

    Structure: every node k owns a *window* of variables (T, the states of nodes k−1, k, k+1 and the
    jerks on both sides of k) and the constraint rows that depend only on them (the defects of
    interval k, τ_k, τ̇ on both sides of k, the friction-flip rows, q̇ at the midpoint of interval k,
    the TCP box). One SX function of a window gives the rows, its sparse Jacobian and the Hessian of
    its Lagrangian; they are mapped over the N + 1 windows and scattered into IPOPT's sparse matrices
    by index (custom `jac_g`, `grad_f`, `hess_lag`). This builds in a fraction of a second, where
    letting CasADi expand and differentiate the whole NLP took 5–15 s for N = 100. The Jacobian and
    Hessian maps run on two threads (CasADi's "thread" map), compiled to C by default (`_compiled`).
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
        self._sizes = (1, n * (N + 1), n * (N + 1), n * (N + 1), n * N)
        self.nx = sum(self._sizes)

        window, kinds, valid = self._window_function()
        var_index = self._window_variables()  # [N+1, m], −1 for padding
        m = window.size1_in(0)
        n_rows = len(kinds)
        # global rows: node-major, the valid rows of each window
        row_valid = np.array([[valid[i](k) for i in range(n_rows)] for k in range(N + 1)])  # [N+1, rows]
        row_index = np.full((N + 1, n_rows), -1)
        row_index[row_valid] = np.arange(int(row_valid.sum()))
        self.row_kinds = np.array([kinds[i] for k in range(N + 1) for i in range(n_rows) if row_valid[k, i]])
        # node and joint of every row (the per-joint blocks of a window are n rows long, in joint order)
        self.row_node, local = (a[row_valid] for a in np.indices((N + 1, n_rows)))
        self.row_joint = local % n
        ng = len(self.row_kinds)

        x = ca.MX.sym("x", self.nx)
        p = ca.MX.sym("p", 0)
        lam_g = ca.MX.sym("lam_g", ng)
        x_pad = ca.vertcat(x, 0)
        xi = ca.reshape(x_pad[np.where(var_index >= 0, var_index, self.nx).ravel().tolist()], m, N + 1)
        wts = ca.DM(self._window_weights())
        # the time's weight; a fixed duration makes it a constant, left out so the objective is the energy
        k1 = options.k1 if options.duration_s is None else 0.0

        rows, f_win = window.map(N + 1)(xi, wts)
        g = ca.vec(rows)[np.flatnonzero(row_valid.ravel()).tolist()]
        f = k1 * self.t_ref * x[0] + ca.sum2(f_win)

        # the window's Jacobian, gradient and Lagrangian Hessian, compiled together (options.compile,
        # `_compiled`); g and f stay SX so CasADi can still differentiate them (IPOPT's final
        # multiplier computation)
        xs, ws = window.sx_in()
        rows_s, f_s = window(xs, ws)
        jac_s = ca.jacobian(rows_s, xs)
        windows = [
            ca.Function("window_jac", [xs, ws], [_nonzeros(jac_s)]),
            ca.Function("window_grad", [xs, ws], [ca.densify(ca.gradient(f_s, xs))]),
        ]
        if options.hessian == "exact":
            lf, lr = ca.SX.sym("lam_f"), ca.SX.sym("lam_rows", rows_s.numel())
            hess_s = ca.triu(ca.hessian(lf * f_s + ca.dot(lr, rows_s), xs)[0])
            windows.append(ca.Function("window_hess", [xs, ws, lf, lr], [_nonzeros(hess_s)]))
        jw, gw, *hw = windows if options.compile is False else self._compiled(windows)

        # Jacobian: window Jacobians scattered by index (each global row lives in one window)
        sp_w = jac_s.sparsity()
        r_loc, c_loc = (np.array(a) for a in sp_w.get_triplet())
        nnz_w = sp_w.nnz()
        g_rows = row_index[:, r_loc]  # [N+1, nnz_w]
        g_cols = var_index[:, c_loc]
        keep = (g_rows >= 0) & (g_cols >= 0)
        src = (np.arange(N + 1)[:, None] * nnz_w + np.arange(nnz_w)[None, :])[keep]
        jac_sp, jac_perm = _csc(ng, self.nx, g_rows[keep], g_cols[keep])
        jac_nz = ca.vec(jw.map(N + 1, "thread", 2)(xi, wts))[src[jac_perm].tolist()]
        jac_g = ca.Function("jac_g", [x, p], [g, ca.MX(jac_sp, jac_nz)], ["x", "p"], ["g", "jac_g_x"])

        # gradient of f: window gradients summed into the variables they share
        cols = var_index.ravel()
        ok = cols >= 0
        assemble = ca.DM(
            ca.Sparsity.triplet(self.nx, cols.size, cols[ok].tolist(), np.flatnonzero(ok).tolist()), 1.0
        )
        grad = ca.mtimes(assemble, ca.vec(gw.map(N + 1)(xi, wts)))
        grad = grad + ca.DM([k1 * self.t_ref] + [0.0] * (self.nx - 1))
        grad_f = ca.Function("grad_f", [x, p], [f, grad], ["x", "p"], ["f", "grad_f_x"])

        nlp_opts: dict = {"print_time": False, "jac_g": jac_g, "grad_f": grad_f}
        if hw:
            nlp_opts["hess_lag"] = self._hessian(
                hw[0], hess_s.sparsity(), xi, wts, x, p, lam_g, var_index, row_index
            )

        nlp_opts["ipopt"] = ipopt_options(options, options.hessian)
        self.solver = ca.nlpsol("ptp", "ipopt", {"x": x, "f": f, "g": g}, nlp_opts)
        self._objective = ca.Function("objective", [x], [f])
        self.build_seconds = time.perf_counter() - t_build

    # --- the window -----------------------------------------------------------------------------------
    def _window_weights(self) -> np.ndarray:
        """[3, N+1] per window: the trapezoid weight of node k (∫τᵀτ dt, in units of h) and the energy
        quadrature's weights of node k and of the midpoint of interval k (fractions of T, 0 past the end)."""
        N = self.N
        trapezoid = np.ones(N + 1)
        trapezoid[[0, -1]] = 0.5
        _, w = energy_quadrature(N)
        return np.vstack([trapezoid, w[0::2], np.append(w[1::2], 0.0)])

    def _window_energy(self, T, state, u, tau, wt) -> ca.SX:
        """Window k's share of ∫₀ᵀ P dt (`BusPowerModel`): Simpson on the nodes and the interval
        midpoints (`energy_quadrature`), the midpoint's state by exact integration of u_k, and the torque
        `run` is judged on (`output_shift`: Coulomb friction smoothed with ε = 0.02, not the NLP's 0.1)."""
        dyn, bus, h = self.dynamics, self.options.bus, T / self.N
        q, qd, qdd = state
        qm = q + h / 2 * qd + h**2 / 8 * qdd + h**3 / 48 * u
        qdm, qddm = qd + h / 2 * qdd + h**2 / 8 * u, qdd + h / 2 * u
        tau_m = _sx_function(dyn.inv_dyn)(qm, qdm, qddm)
        if dyn.output_shift is not None:
            shift = _sx_function(dyn.output_shift)
            tau, tau_m = tau + shift(qd), tau_m + shift(qdm)

        def power(v, t):
            return bus.power(v.T, t.T, mtimes=ca.mtimes, sqrt=ca.sqrt)

        return T * (wt[1] * power(qd, tau) + wt[2] * power(qdm, tau_m))

    def _window_function(self):
        """SX function (xi, wt) → (rows, f_k), the row kinds and per-row validity predicates k → bool."""
        n, N, lim, opt, dyn = self.dof, self.N, self.limits, self.options, self.dynamics
        m = 1 + 11 * n
        xi, wt = ca.SX.sym("xi", m), ca.SX.sym("wt", 3)
        vr, ar, jr = (ca.DM(a) for a in (self.v_ref, self.a_ref, self.j_ref))
        tmax, rmax = ca.DM(lim.tau_max), ca.DM(lim.tau_rate_max)
        T = self.t_ref * xi[0]
        h = T / N

        def state(o):
            return xi[o : o + n], vr * xi[o + n : o + 2 * n], ar * xi[o + 2 * n : o + 3 * n]

        q, qd, qdd = state(1 + 3 * n)
        q_p, qd_p, qdd_p = state(1 + 6 * n)
        u_m, u = jr * xi[1 + 9 * n : 1 + 10 * n], jr * xi[1 + 10 * n :]
        tau, rate_l, rate_r = node_function(dyn)(q, qd, qdd, u_m, u)[:3]
        rows, kinds, valid = [], [], []

        def add(expr, kind, ok):
            rows.append(expr)
            kinds.extend([kind] * expr.numel())
            valid.extend([ok] * expr.numel())

        def interval(k):
            return k < N

        # exact integration of a constant jerk over interval k; defects scaled like the variables
        add(q_p - (q + h * qd + h**2 / 2 * qdd + h**3 / 6 * u), "defects", interval)
        add((qd_p - (qd + h * qdd + h**2 / 2 * u)) / vr, "defects", interval)
        add((qdd_p - (qdd + h * u)) / ar, "defects", interval)
        add(tau / tmax, "torque", lambda k: 0 < k < N)  # the end torques are the holding torques
        add(rate_l / rmax, "torque_rate", lambda k: k > 0)
        add(rate_r / rmax, "torque_rate", interval)
        # q̇ is quadratic between the nodes: bound it at the interval midpoints too (cheap rows)
        add((qd + h / 2 * qdd + h**2 / 8 * u) / vr, "velocity", interval)
        if opt.tcp_box_m is not None:
            if dyn.tcp_fk is None:
                raise ValueError("a TCP box needs PtpDynamics.tcp_fk")
            lo, hi = (np.asarray(c, float) for c in opt.tcp_box_m)
            p_tcp = _sx_function(dyn.tcp_fk)(q)[0]
            add((p_tcp - ca.DM((lo + hi) / 2)) / ca.DM((hi - lo) / 2), "tcp_box", lambda k: 0 < k < N)
        f_k = opt.k2_per_nm2 * h * wt[0] * ca.sumsqr(tau)
        if opt.objective == "energy":  # the bus power (BusPowerModel) on nodes and midpoints
            f_k += self._window_energy(T, (q, qd, qdd), u, tau, wt)
        fn = ca.Function("ptp_window", [xi, wt], [ca.vertcat(*rows), f_k], ["xi", "wt"], ["rows", "f"])
        return fn, kinds, valid

    def _window_variables(self) -> np.ndarray:
        """Global index of every window variable, −1 where the window reaches past the ends."""
        n, N = self.dof, self.N
        o_q, o_v, o_a, o_u = 1, 1 + n * (N + 1), 1 + 2 * n * (N + 1), 1 + 3 * n * (N + 1)
        idx = np.full((N + 1, 1 + 11 * n), -1)
        j = np.arange(n)
        for k in range(N + 1):
            idx[k, 0] = 0
            for s, node in enumerate((k - 1, k, k + 1)):
                if 0 <= node <= N:
                    base = 1 + 3 * n * s
                    idx[k, base : base + n] = o_q + node * n + j
                    idx[k, base + n : base + 2 * n] = o_v + node * n + j
                    idx[k, base + 2 * n : base + 3 * n] = o_a + node * n + j
            for s, iv in enumerate((k - 1, k)):
                if 0 <= iv < N:
                    idx[k, 1 + 9 * n + s * n : 1 + 10 * n + s * n] = o_u + iv * n + j
        return idx

    def _hessian(self, hw, sp_w, xi, wts, x, p, lam_g, var_index, row_index) -> ca.Function:
        """Exact Hessian of the Lagrangian, assembled from the window Hessians `hw` (upper triangle,
        sparsity `sp_w`)."""
        N = self.N
        lam_f = ca.MX.sym("lam_f")
        r_loc, c_loc = (np.array(a) for a in sp_w.get_triplet())
        nnz_w = sp_w.nnz()
        a, b = var_index[:, r_loc], var_index[:, c_loc]
        keep = (a >= 0) & (b >= 0)
        lo, hi = np.minimum(a, b)[keep], np.maximum(a, b)[keep]
        src = (np.arange(N + 1)[:, None] * nnz_w + np.arange(nnz_w)[None, :])[keep]
        # duplicates (variables shared by neighbouring windows) are summed by the assembly matrix
        key = hi * self.nx + lo
        uniq, inverse = np.unique(key, return_inverse=True)
        sp = ca.Sparsity.triplet(self.nx, self.nx, (uniq % self.nx).tolist(), (uniq // self.nx).tolist())
        # triplet() sorts column-major, as np.unique on hi * nx + lo already is
        assemble = ca.DM(ca.Sparsity.triplet(len(uniq), (N + 1) * nnz_w, inverse.tolist(), src.tolist()), 1.0)
        lam_pad = ca.vertcat(lam_g, 0)
        lam_w = ca.reshape(
            lam_pad[np.where(row_index >= 0, row_index, lam_g.numel()).ravel().tolist()], -1, N + 1
        )
        nz = ca.mtimes(assemble, ca.vec(hw.map(N + 1, "thread", 2)(xi, wts, lam_f, lam_w)))
        return ca.Function(
            "hess_lag",
            [x, p, lam_f, lam_g],
            [ca.MX(sp, nz)],
            ["x", "p", "lam_f", "lam_g"],
            ["triu_hess_gamma_x_x"],
        )

    def _compiled(self, fns: list[ca.Function]) -> list[ca.Function]:
        """`fns` as C compiled once per content (robot, limits, N, options) into the cache directory.

        By default unoptimised: gcc -O0 compiles the Hessian window (~1 MB of C) in ~1 s CPU and it
        runs in 4.2 ms per map of 101 windows against 23 ms in CasADi's virtual machine; -O1
        (`compile=True`) runs in 1.8 ms but takes ~1 min to compile (RX130L, N = 100, measured)."""
        flags = ("-O1",) if self.options.compile else ("-O0",)
        return casadi_build.compiled(fns, flags)

    # --- bounds and guesses -------------------------------------------------------------------------
    def margins(self, **override: float) -> dict[str, float]:
        """Per-limit margins: the options' margin for every limit, with `override`s."""
        m = dict.fromkeys(LIMIT_NAMES, self.options.margin)
        m.update(override)
        return m

    def _bounds(
        self,
        q_start: np.ndarray,
        q_goal: np.ndarray,
        margins: dict[str, float],
        accel_caps=None,
        rate_scale=None,
    ):
        n, N, lim = self.dof, self.N, self.limits
        half = (lim.q_max - lim.q_min) / 2
        mp = margins["position"]
        lo = np.minimum(lim.q_min + mp * half, np.minimum(q_start, q_goal))
        hi = np.maximum(lim.q_max - mp * half, np.maximum(q_start, q_goal))
        q_lb, q_ub = np.tile(lo[:, None], N + 1), np.tile(hi[:, None], N + 1)
        q_lb[:, 0] = q_ub[:, 0] = q_start
        q_lb[:, -1] = q_ub[:, -1] = q_goal
        v_b = np.full((n, N + 1), 1.0 - margins["velocity"])
        v_b[:, [0, -1]] = 0.0
        a_lim = (
            np.full(n, np.inf)
            if lim.a_max is None
            else (1.0 - margins["acceleration"]) * lim.a_max / self.a_ref
        )
        a_b = np.tile(a_lim[:, None], N + 1)
        if accel_caps is not None:  # local |q̈| caps per node [N+1, n], rad/s² (ptp: velocity reversals)
            a_b = np.minimum(a_b, np.asarray(accel_caps, float).T / self.a_ref[:, None])
        a_b[:, [0, -1]] = 0.0
        u_b = np.full(n * N, np.inf)
        t_lo, t_hi = (1e-3, 100.0) if self.options.duration_s is None else (self.options.duration_s,) * 2
        lbx = np.concatenate([[t_lo / self.t_ref], q_lb.ravel("F"), -v_b.ravel("F"), -a_b.ravel("F"), -u_b])
        ubx = np.concatenate([[t_hi / self.t_ref], q_ub.ravel("F"), v_b.ravel("F"), a_b.ravel("F"), u_b])
        bound = {k: 1.0 - v for k, v in margins.items()} | {"defects": 0.0}
        ubg = np.array([bound[k] for k in self.row_kinds])
        if rate_scale is not None:  # local torque-rate bounds per node [N+1, n], a factor ≤ 1
            rate = self.row_kinds == "torque_rate"
            ubg[rate] *= np.asarray(rate_scale, float)[self.row_node[rate], self.row_joint[rate]]
        return lbx, ubx, -ubg, ubg

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

    def solve(
        self,
        q_start,
        q_goal,
        guess: NodeGuess,
        margins: dict[str, float] | None = None,
        accel_caps: np.ndarray | None = None,
        rate_scale: np.ndarray | None = None,
    ) -> PtpSolution:
        """Solve from `guess` (on this grid) with limits tightened by `margins` (default: the options'),
        |q̈| at each node capped by `accel_caps` [N+1, dof] (rad/s², inf: no cap; default none) and the
        torque-rate rows of each node and joint scaled by `rate_scale` [N+1, dof] (≤ 1; default 1).

        Never raises on non-convergence: see `.success`, `.status`.
        """
        q_start, q_goal = np.asarray(q_start, float), np.asarray(q_goal, float)
        lbx, ubx, lbg, ubg = self._bounds(q_start, q_goal, margins or self.margins(), accel_caps, rate_scale)
        w, outcome = run_ipopt(self.solver, self._pack(guess), lbx, ubx, lbg, ubg)
        sol = self._unpack(w)
        return PtpSolution(
            duration_s=sol.duration_s,
            q=sol.q,
            qd=sol.qd,
            qdd=sol.qdd,
            jerk=sol.jerk,
            tau=self.dynamics.torque(sol.q, sol.qd, sol.qdd),
            **outcome,
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
