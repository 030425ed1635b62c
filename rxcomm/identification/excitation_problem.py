"""The excitation NLP (`rxcomm.identification.excitation`): objective, constraint rows, SLSQP.

**Objective.** W = the base regressor (inertial + rotor + Coulomb + viscous + offset + spring
columns of `rxcomm.model.dynamics.joint_torque_regressor` kept by the `BaseParameterSet`) stacked over k
samples of one period, columns scaled to unit norm (paper: "the columns of Θ_f should also be
normalized"); minimise log cond(W) (or −log det(WᵀW)/p). cond is computed from the p × p Gram
matrix, and its gradient analytically: ∂ log cond/∂W_n = W_n·(v₁v₁ᵀ/λ₁ − v_pv_pᵀ/λ_p) (v, λ the
extreme eigenpairs of W_nᵀW_n), chained through the column scaling and, per sample, through a CasADi
reverse sweep of the symbolic regressor (`rxcomm.model.symbolic`) to q, q̇, q̈ and so to x. Coulomb's
sign is smoothed to tanh(q̇/ε) inside the NLP; reported figures use the exact sign and Pinocchio.

**Constraints** (paper eq. 30): the design limits of `rxcomm.identification.excitation_limits` (its
docstring says which, and how the exchange method and the dense check keep them between the grid
points); here they become the SLSQP's inequality rows with their Jacobians from CasADi.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pinocchio as pin
import scipy.linalg as sla
from scipy.optimize import minimize

from rxcomm import casadi_build
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.identification.excitation_limits import DesignLimits, reversal_ratios, robot_limit_ratios
from rxcomm.identification.excitation_trajectory import (
    FourierTrajectory,
    fourier_basis,
    snapped_omega,
)
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.base_parameters import BaseParameterSet, base_parameters
from rxcomm.model.dynamics import (
    COULOMB_EPS_NLP_RAD_S,
    DynamicParameters,
    joint_torque_regressor,
    n_parameters,
    prior_parameters,
)
from rxcomm.model.robot import Robot
from rxcomm.model.symbolic import frame_placement_expr, inverse_dynamics_expr
from rxcomm.schemas.cell import AllowedRegion
from rxcomm.schemas.excitation import ExcitationSettings

_TIGHTEN = 3e-4  # NLP limits are this fraction inside the design limits: room for dense-grid curvature

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
# The problem


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

        # Design limits as centre ± half-width (`DesignLimits`), named here as the NLP uses them.
        self.limits = lim = DesignLimits.from_settings(robot, region, s, self.prior)
        self.region = region
        self.q_centre, self.q_half = lim.q_centre, lim.q_half
        self.v_half, self.a_half, self.tau_half = lim.v_half, lim.a_half, lim.tau_half
        self.qdd_cross_max = lim.qdd_cross_max
        self.box_centre, self.box_half = lim.box_centre, lim.box_half
        self.nl_centre, self.nl_half = lim.nl_centre, lim.nl_half

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
        self._maps: dict[tuple[str, int], casadi_build.Mapped] = {}
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

    def _mapped(self, name: str, k: int) -> casadi_build.Mapped:
        key = (name, k)
        if key not in self._maps:
            f = {"yb": self._f_yb, "adj": self._f_adj, "h": self._f_h, "hj": self._f_hj}[name]
            self._maps[key] = casadi_build.Mapped(f, k)
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
        """`reversal_ratios` of the trajectory on the check grid: the torque-rate limit where a joint's
        velocity changes sign, (ratios [n, 2N], ∂ratio/∂x_full [n, 2N, n, 2N − 1])."""
        bv = self._basis(self.t_check)[1]
        return reversal_ratios(self.full(x), self.t_check, self.omega, self.n_h, self.qdd_cross_max, bv)

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
            is_max = np.empty(s.shape, dtype=bool)  # periodic neighbours, without np.roll's copies
            is_max[1:-1] = (s[1:-1] >= s[:-2]) & (s[1:-1] > s[2:])
            is_max[0] = (s[0] >= s[-1]) & (s[0] > s[1])
            is_max[-1] = (s[-1] >= s[-2]) & (s[-1] > s[0])
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

    def _speed_constraints(self):
        """(g, ∂g/∂x): g_j = mean q̇_j² / v_j² − 1 ≥ 0 over a period, v_j = min(min_rms_speed, ¼ of the
        joint's velocity limit). Exact on the objective grid (a trigonometric polynomial's mean square
        from ≥ 2N + 1 uniform samples); quadratic in the coefficients."""
        _, bv, _ = self._basis(self.t_obj)
        v_min = np.minimum(self.settings.min_rms_speed_rad_s, 0.25 * self.v_half)
        scale = 1.0 / np.maximum(v_min, 1e-12) ** 2
        k = len(self.t_obj)

        def fun(x: np.ndarray) -> np.ndarray:
            qd = bv @ self.full(x).T  # [k, n]
            return np.mean(qd**2, axis=0) * scale - 1.0

        def jac(x: np.ndarray) -> np.ndarray:
            qd = bv @ self.full(x).T
            d_full = (2.0 / k) * (bv.T @ qd).T * scale[:, None]  # [n, m]: row j is ∂g_j/∂x_j
            rows = np.zeros((self.n, self.n, self.m))
            rows[np.arange(self.n), np.arange(self.n)] = d_full
            return rows[:, self.free_mask]

        return fun, jac

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
        speed_fun, speed_jac = self._speed_constraints()
        x, iters = np.asarray(x0, dtype=float), 0
        # The best iterate within the constraints (the start if within them: after `tighten` grew, the
        # optimum it tightens is not, and returning it undid the tightening): if SLSQP ends outside.
        best = {"f": self.objective(x)[0] if fun(x).min() >= 0.0 else math.inf, "x": x}

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
                constraints=[
                    {"type": "ineq", "fun": fun, "jac": jac},
                    {"type": "ineq", "fun": speed_fun, "jac": speed_jac},
                ],
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
        """`robot_limit_ratios` of the samples against this problem's robot and region."""
        return robot_limit_ratios(self.robot, self.region, samples)

    def design_ratios(self, samples: Trajectory) -> np.ndarray:
        """`DesignLimits.ratios`: max |value − centre|/half of the design limits per sample."""
        return self.limits.ratios(self.robot, samples)
