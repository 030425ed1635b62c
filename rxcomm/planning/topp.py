"""Time-optimal path parametrisation with toppra 0.6.10 (paper §5.2 with k2 = 0), as toppra is safe to use.

Settings that avoid toppra's measured pitfalls (architecture §7 "Planning facts"): the `seidel` solver
only; `DiscretizationType.Interpolation` for every second-order constraint (collocation under-checks
between grid points); the geometric path is our not-a-knot joint spline (clamped ends slow toppra
down 25×); the output is toppra's constant-acceleration parametrisation, which we sample ourselves
(`PathProfile`, kind `constant`) instead of its overshooting spline.

Constraints are small toppra `LinearConstraint` objects, each computing its canonical coefficients
from precomputed arrays (rows normalised by their limits, so F and g are constant):
- `PathTorqueConstraint`: |m·u + c·x + v·√x + θ·f + g| ≤ τmax for θ ∈ {0, 1} (x = σ̇², u = σ̈). The
  viscous term v·√x is not linear in x; it is bounded conservatively by the tangent of √x at a
  reference speed (above) and the chord through 0 and the velocity bound (below), so a second pass
  with the first pass's speeds as reference makes it tight where it matters.
- `JointAccelerationConstraint`, `SpeedBoundConstraint`: toppra's joint acceleration and velocity
  constraints with limits per gridpoint (re-solves tighten limits locally, where a sampled value
  exceeded one); the speed bound also carries the TCP speed limit (σ̇ ≤ v, σ being TCP arc length).
- `TcpAccelerationConstraint`: ‖p'·u + p''·x‖ ≤ a as a 32-gon inscribed in the circle (≤ 0.5 % inside).

Dynamics come in as a batched `inv_dyn(q, qd, qdd)`; nothing here imports a robot model. Failure is a
returned status with the σ where the path became uncontrollable, not an exception.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import toppra
import toppra.algorithm
import toppra.constraint as tc
from toppra.constraint.linear_constraint import LinearConstraint, canlinear_colloc_to_interpolate

from rxcomm.errors import SolveOutcome, SolveStatus
from rxcomm.planning.path_dynamics import InverseDynamics, PathDynamics, path_dynamics
from rxcomm.planning.path_profile import PathProfile

logging.getLogger("toppra").setLevel(logging.ERROR)  # toppra logs every solve at INFO/WARNING


@dataclass(frozen=True, eq=False)
class PlanLimits:
    """Limits a path plan honours (joint side, SI units); None switches a limit off."""

    v_max: np.ndarray
    a_max: np.ndarray
    tau_max: np.ndarray
    tau_rate_max: np.ndarray | None = None
    tcp_speed_max: float | None = None
    tcp_acc_max: float | None = None

    def __post_init__(self) -> None:
        for name in ("v_max", "a_max", "tau_max", "tau_rate_max"):
            a = getattr(self, name)
            if a is None:
                continue
            a = np.array(a, dtype=float)
            if a.ndim != 1 or not np.all(a > 0):
                raise ValueError(f"{name} must be a vector of positive limits, got {a}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        for name in ("tcp_speed_max", "tcp_acc_max"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ValueError(f"{name} must be positive, got {v}")

    def at_nodes(
        self, name: str, n_nodes: int, scale: dict[str, np.ndarray] | None = None
    ) -> np.ndarray | None:
        """Limit `name` per grid node: [n_nodes, dof] for joint limits, [n_nodes] for TCP limits,
        times the local factors `scale[name]` of the same shape (re-solves tighten limits locally)."""
        base = getattr(self, name)
        if base is None:
            return None
        out = np.broadcast_to(np.asarray(base, float), (n_nodes, *np.shape(base))).copy()
        if scale is not None and name in scale:
            out = out * scale[name]
        return out


class ToppraPath(toppra.interpolator.AbstractGeometricPath):
    """A joint path q(σ) for toppra from any callable `spline(s, order)` (scipy's CubicSpline)."""

    def __init__(self, spline, s_end: float, dof: int):
        self._spline, self._end, self._dof = spline, float(s_end), dof

    def __call__(self, path_positions, order: int = 0):
        return self._spline(path_positions, order)

    @property
    def dof(self) -> int:
        return self._dof

    @property
    def path_interval(self):
        return np.array([0.0, self._end])


class PathTorqueConstraint(LinearConstraint):
    """|τ| ≤ τmax (per node and joint) from precomputed path dynamics (see the module docstring).

    Rows are divided by their limit, so F and g are the same at every gridpoint."""

    def __init__(self, pd: PathDynamics, tau_max: np.ndarray, x_ref: np.ndarray, x_max: np.ndarray):
        super().__init__()
        n = pd.m.shape[1]
        tau_max = np.asarray(tau_max, dtype=float)
        if tau_max.shape != pd.m.shape or np.any(tau_max <= 0):
            raise ValueError("tau_max must hold one positive limit per gridpoint and joint")
        if np.shape(x_ref) != (len(pd.sigma),) or np.shape(x_max) != (len(pd.sigma),):
            raise ValueError("x_ref and x_max need one value per gridpoint")
        self.pd, self.tau_max, self.dof = pd, tau_max, n
        self.x_ref = np.maximum(np.asarray(x_ref, float), 1e-8)
        self.x_max = np.maximum(np.asarray(x_max, float), 1e-8)
        self.set_discretization_type(tc.DiscretizationType.Interpolation)
        self.identical = True

    def compute_constraint_params(self, path, gridpoints):
        pd, n = self.pd, self.dof
        if len(gridpoints) != len(pd.sigma) or not np.allclose(gridpoints, pd.sigma):
            raise ValueError("PathTorqueConstraint was built for other gridpoints")
        sr, sm = np.sqrt(self.x_ref)[:, None], np.sqrt(self.x_max)[:, None]
        # Upper rows bound v·√x from above, lower rows from below: tangent at x_ref or chord to x_max.
        tan_b, tan_c = pd.v / (2 * sr), pd.v * sr / 2
        chord_b = pd.v / sm
        pos = pd.v >= 0
        up_b, up_c = np.where(pos, tan_b, chord_b), np.where(pos, tan_c, 0.0)
        lo_b, lo_c = np.where(pos, chord_b, tan_b), np.where(pos, 0.0, tan_c)
        inv = 1.0 / self.tau_max
        a = np.hstack([pd.m, pd.m, pd.m, pd.m]) * np.tile(inv, 4)
        b = np.hstack([pd.c + up_b, pd.c + up_b, pd.c + lo_b, pd.c + lo_b]) * np.tile(inv, 4)
        c = np.hstack([pd.g + up_c, pd.g + pd.f + up_c, pd.g + lo_c, pd.g + pd.f + lo_c]) * np.tile(inv, 4)
        big_f = np.diag(np.concatenate([np.ones(2 * n), -np.ones(2 * n)]))
        g = np.ones(4 * n)
        return canlinear_colloc_to_interpolate(a, b, c, big_f, g, None, None, gridpoints, identical=True)


class JointAccelerationConstraint(LinearConstraint):
    """|q'·u + q''·x| ≤ a_max per gridpoint and joint (rows normalised by the limit)."""

    def __init__(self, a_max: np.ndarray):
        super().__init__()
        a_max = np.asarray(a_max, dtype=float)
        if a_max.ndim != 2 or np.any(a_max <= 0):
            raise ValueError("a_max must be [gridpoints, dof] positive limits")
        self.a_max, self.dof = a_max, a_max.shape[1]
        self.set_discretization_type(tc.DiscretizationType.Interpolation)
        self.identical = True

    def compute_constraint_params(self, path, gridpoints):
        if len(gridpoints) != len(self.a_max):
            raise ValueError("JointAccelerationConstraint was built for other gridpoints")
        a = path(gridpoints, 1) / self.a_max
        b = path(gridpoints, 2) / self.a_max
        n = self.dof
        big_f = np.vstack([np.eye(n), -np.eye(n)])
        return canlinear_colloc_to_interpolate(
            a, b, np.zeros_like(a), big_f, np.ones(2 * n), None, None, gridpoints, identical=True
        )


class SpeedBoundConstraint(LinearConstraint):
    """σ̇² ≤ x_max per gridpoint: joint velocity limits (|q'|·σ̇ ≤ v) and the TCP speed limit (σ̇ ≤ v,
    σ being the TCP arc length), combined beforehand by `velocity_bound_x`."""

    def __init__(self, x_max: np.ndarray):
        super().__init__()
        x_max = np.asarray(x_max, dtype=float)
        if x_max.ndim != 1 or np.any(x_max < 0):
            raise ValueError("x_max must be one non-negative bound per gridpoint")
        self.x_max, self.dof = x_max, None

    def get_dof(self):
        return None

    def compute_constraint_params(self, path, gridpoints):
        if len(gridpoints) != len(self.x_max):
            raise ValueError("SpeedBoundConstraint was built for other gridpoints")
        xbound = np.column_stack([np.zeros(len(self.x_max)), self.x_max])
        return None, None, None, None, None, None, xbound


class TcpAccelerationConstraint(LinearConstraint):
    """‖p'(σ)·σ̈ + p''(σ)·σ̇²‖ ≤ a_max, a polygon inside the circle in the (tangent, normal) plane."""

    SIDES = 32

    def __init__(self, curvature: np.ndarray, a_max: np.ndarray):
        super().__init__()
        a_max = np.asarray(a_max, dtype=float)
        if np.shape(curvature) != a_max.shape or a_max.ndim != 1 or np.any(a_max <= 0):
            raise ValueError("one curvature value and one positive limit per gridpoint")
        self.kappa, self.a_max = np.asarray(curvature, dtype=float), a_max
        self.set_discretization_type(tc.DiscretizationType.Interpolation)
        self.identical = True
        self.dof = None

    def get_dof(self):
        return None

    def compute_constraint_params(self, path, gridpoints):
        ang = 2 * np.pi * np.arange(self.SIDES) / self.SIDES
        # Arc-length parametrisation: p' ⟂ p'', |p'| = 1, |p''| = κ; w = (u, κ·x)/a_max.
        inv = 1.0 / self.a_max[:, None]
        a = np.cos(ang)[None, :] * inv
        b = np.sin(ang)[None, :] * (self.kappa[:, None] * inv)
        g = np.full(self.SIDES, np.cos(np.pi / self.SIDES))
        return canlinear_colloc_to_interpolate(
            a, b, np.zeros_like(a), np.eye(self.SIDES), g, None, None, gridpoints, identical=True
        )


@dataclass(frozen=True, eq=False)
class ToppResult:
    """toppra's outcome: `profile` when `ok`, else `uncontrollable_at_m` and a message."""

    ok: bool
    profile: PathProfile | None
    message: str = ""
    uncontrollable_at_m: float | None = None
    passes: int = 1

    @property
    def outcome(self) -> SolveOutcome:
        """The solvers' one result convention (an uncontrollable path has no profile: infeasible)."""
        return SolveOutcome(SolveStatus.SOLVED if self.ok else SolveStatus.INFEASIBLE, self.message)


def velocity_bound_x(
    qs: np.ndarray, v_max: np.ndarray, tcp_speed_max: np.ndarray | None = None
) -> np.ndarray:
    """Largest σ̇² allowed by joint (per node [N, dof]) and TCP (per node [N]) speed limits."""
    with np.errstate(divide="ignore"):
        x = np.min((v_max / np.abs(qs)) ** 2, axis=1)
    if tcp_speed_max is not None:
        x = np.minimum(x, tcp_speed_max**2)
    return np.minimum(x, 1e6)


def time_optimal(
    spline,
    length_m: float,
    gridpoints: np.ndarray,
    limits: PlanLimits,
    inv_dyn: InverseDynamics | None,
    curvature: np.ndarray | None = None,
    pd: PathDynamics | None = None,
    scale: dict[str, np.ndarray] | None = None,
) -> ToppResult:
    """Time-optimal σ̇(σ) on `gridpoints` for the joint path `spline(s, order)` under `limits`.

    `inv_dyn` (batched, exact Coulomb sign) gives the torque constraint (None: no torque limit);
    `pd` may pass precomputed path dynamics at the gridpoints. `curvature` [len(gridpoints)] is |p''|
    of the TCP path, needed for a TCP acceleration limit. `scale` holds local factors per limit name
    (`PlanLimits.at_nodes`). toppra ignores `tau_rate_max` (its σ̈ is piecewise constant).
    """
    grid = np.asarray(gridpoints, dtype=float)
    n_nodes = len(grid)
    qs, qss = spline(grid, 1), spline(grid, 2)
    path = ToppraPath(spline, length_m, qs.shape[1])
    x_max = velocity_bound_x(
        qs, limits.at_nodes("v_max", n_nodes, scale), limits.at_nodes("tcp_speed_max", n_nodes, scale)
    )
    base = [
        SpeedBoundConstraint(x_max),
        JointAccelerationConstraint(limits.at_nodes("a_max", n_nodes, scale)),
    ]
    if limits.tcp_acc_max is not None:
        if curvature is None:
            raise ValueError("a TCP acceleration limit needs the path curvature at the gridpoints")
        base.append(TcpAccelerationConstraint(curvature, limits.at_nodes("tcp_acc_max", n_nodes, scale)))
    if inv_dyn is not None and pd is None:
        pd = path_dynamics(inv_dyn, grid, spline(grid), qs, qss)
    tau_max = limits.at_nodes("tau_max", n_nodes, scale)
    x_ref = x_max
    viscous = 0.0 if pd is None else float(np.max(np.abs(pd.v) * np.sqrt(x_max)[:, None] / tau_max))
    if viscous > 0.5:
        # The tangent at the velocity bound claims v·√x_max/2 even at rest: where viscous friction
        # alone would need more than half the torque there (a model whose `damping` stabilises a
        # simulation, 200 N·m·s/rad on a 150 N·m joint), take the first tangent where it needs half.
        with np.errstate(divide="ignore"):
            x_half = np.min((0.5 * tau_max / np.abs(pd.v)) ** 2, axis=1)
        x_ref = np.minimum(x_max, x_half)
    passes = 2 if viscous > 0.005 else 1
    result = None
    for p in range(passes):
        cons = list(base)
        if pd is not None:
            cons.append(PathTorqueConstraint(pd, tau_max, x_ref, x_max))
        algo = toppra.algorithm.TOPPRA(
            cons, path, gridpoints=grid, solver_wrapper="seidel", parametrizer="ParametrizeConstAccel"
        )
        sdd, sd, _, k_sets = algo.compute_parameterization(0.0, 0.0, return_data=True)
        if sd is None:
            bad = np.flatnonzero(~np.isfinite(k_sets[:, 1]) | (k_sets[:, 1] < 0))
            where = float(grid[bad[-1]]) if len(bad) else None
            return ToppResult(
                False,
                None,
                "toppra: no feasible speed profile (uncontrollable"
                + (f" at σ = {where:.4f} m)" if where is not None else ")"),
                where,
                p + 1,
            )
        result = ToppResult(True, PathProfile(grid, sd, np.append(sdd, sdd[-1]), "constant"), passes=p + 1)
        if p + 1 < passes and not _torque_binds(pd, tau_max, sd, sdd, x_ref, x_max):
            break  # the conservative viscous bound is slack everywhere: tightening it changes nothing
        x_ref = np.maximum(sd**2, 0.01 * x_max)
    return result


def _torque_binds(pd, tau_max, sd, sdd, x_ref, x_max, tol: float = 0.99) -> bool:
    """Whether the linearised torque rows reach `tol` of their limit anywhere on the solution."""
    u = np.append(sdd, sdd[-1])[:, None]
    x = (sd**2)[:, None]
    sr, sm = np.sqrt(x_ref)[:, None], np.sqrt(x_max)[:, None]
    upper = np.where(pd.v >= 0, pd.v * (x + sr**2) / (2 * sr), pd.v * x / sm)
    lower = np.where(pd.v >= 0, pd.v * x / sm, pd.v * (x + sr**2) / (2 * sr))
    base = pd.m * u + pd.c * x + pd.g
    hi = np.maximum(base + upper, base + upper + pd.f)
    lo = np.minimum(base + lower, base + lower + pd.f)
    return bool(np.max(np.maximum(hi, -lo) / tau_max) >= tol)
