"""Timing a fixed joint path behind one interface (paper §5.1–5.3; toppra's solver-interface idea).

A `TimingSolver` turns the path, its limits and local limit factors (`scale`: per limit, a factor at
every grid node) into a `PathProfile`. `ToppraTiming` is toppra's time-optimal profile (piecewise-constant
σ̈); `NlpTiming` the energy-weighted path NLP with torque-rate limits, warm-started by toppra, which may
once move its grid to where no limit is active. `plan_cp` runs one loop over either: solve, sample,
check, tighten locally where a sampled limit is exceeded, solve again.

`PlanDynamics` carries the inverse dynamics both need: exact-sign Coulomb friction for the path
coefficients, smoothed for the output torques.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from rxcomm.errors import InfeasibleError
from rxcomm.model.energy import BusPowerModel
from rxcomm.model.limits import LimitReport
from rxcomm.model.robot import Robot
from rxcomm.planning.cp_grid import jerk_step, nlp_grid, switch_points
from rxcomm.planning.path_dynamics import InverseDynamics, PathDynamics, path_dynamics
from rxcomm.planning.path_ik import JointPath
from rxcomm.planning.path_nlp import NlpResult, optimise_path
from rxcomm.planning.path_profile import PathProfile
from rxcomm.planning.paths import CartesianPath
from rxcomm.planning.topp import PlanLimits, ToppResult, time_optimal

ACTIVE_THRESHOLD = 0.98  # a limit counts as active at ≥ 98 % of its bound (LimitReport.active_fraction)
DURATION_AIMS, DURATION_REL_TOL = 4, 1e-4  # re-solves aiming a fixed-duration law at the duration asked


@dataclass(frozen=True, eq=False)
class PlanDynamics:
    """Batched inverse dynamics for planning: `exact` (sgn Coulomb) for path coefficients, `smooth`
    (tanh(q̇/ε) Coulomb) for the output torques; `eps` the ε of `smooth`."""

    exact: InverseDynamics
    smooth: InverseDynamics
    eps: float

    @classmethod
    def from_parameters(cls, robot: Robot, params, eps: float) -> PlanDynamics:
        from rxcomm.model.dynamics import RobotDynamics

        return cls(
            RobotDynamics(robot, params, None).inverse_dynamics,
            RobotDynamics(robot, params, eps).inverse_dynamics,
            eps,
        )

    @classmethod
    def load(cls, robot: Robot, dynamics_path: Path | None, eps: float) -> PlanDynamics:
        """From an identified `dynamics.yaml`, or from the robot's prior (URDF + drives) when None."""
        from rxcomm.model.base_parameters import load_dynamics
        from rxcomm.model.dynamics import prior_parameters

        if dynamics_path is None:
            return cls.from_parameters(robot, prior_parameters(robot), eps)
        params, fitted = load_dynamics(dynamics_path, robot)  # on the kinematics of the fit
        return cls.from_parameters(fitted, params, eps)


def path_coefficients(dyn: PlanDynamics, jp: JointPath, grid: np.ndarray) -> PathDynamics:
    return path_dynamics(dyn.exact, grid, jp(grid), jp(grid, 1), jp(grid, 2))


def path_coefficient_derivatives(
    dyn: PlanDynamics, jp: JointPath, grid: np.ndarray, h: float = 1e-5
) -> dict[str, np.ndarray]:
    """dm/dσ, dc/dσ, dv/dσ, dg/dσ by central differences (one-sided at the ends)."""
    up = np.minimum(grid + h, jp.length_m)
    lo = np.maximum(grid - h, 0.0)
    pu, pl = path_coefficients(dyn, jp, up), path_coefficients(dyn, jp, lo)
    return {k: (getattr(pu, k) - getattr(pl, k)) / (up - lo)[:, None] for k in ("m", "c", "v", "g")}


_LIMIT_ATTR = {
    "velocity": "v_max",
    "acceleration": "a_max",
    "torque": "tau_max",
    "torque_rate": "tau_rate_max",
    "tcp_speed": "tcp_speed_max",
    "tcp_acceleration": "tcp_acc_max",
}


def tighten_locally(
    report: LimitReport, sigma: np.ndarray, grid: np.ndarray, limits: PlanLimits, scale: dict, target: float
) -> bool:
    """Where a sampled value exceeds `target` × its limit, scale that limit down at the nodes of the
    grid interval around it (and its neighbours) by the excess; returns whether anything was tightened.
    Local, so the rest of the profile keeps its optimal timing."""
    n_nodes = len(grid)
    changed = False
    for name, ratios in report.ratios.items():
        attr = _LIMIT_ATTR.get(name)
        if attr is None or getattr(limits, attr) is None:
            continue
        bad = np.flatnonzero(ratios.max(axis=1) > target)
        if not len(bad):
            continue
        base = getattr(limits, attr)
        fac = scale.setdefault(attr, np.ones((n_nodes, *np.shape(base))))
        k = np.clip(np.searchsorted(grid, sigma[bad], side="right") - 1, 0, n_nodes - 2)
        need = np.ones_like(fac)  # per node the strongest reduction any sample asks for
        for i, kk in zip(bad, k, strict=True):
            r = ratios[i] if fac.ndim == 2 else ratios[i, 0]
            f = np.where(r > target, (target - 0.002) / r, 1.0)
            nodes = slice(max(kk - 1, 0), min(kk + 3, n_nodes))
            need[nodes] = np.minimum(need[nodes], f)
        fac *= need
        changed = True
    return changed


@dataclass(frozen=True, eq=False)
class NlpSetup:
    grid: np.ndarray
    pd: PathDynamics
    dpd: dict[str, np.ndarray]
    curvature: np.ndarray


@dataclass(frozen=True, eq=False)
class NlpProblem:
    """What the path NLP times: the joint path `jp` of `path` under `limits`, with `dynamics`, on
    grids of `intervals` intervals."""

    dynamics: PlanDynamics
    jp: JointPath
    path: CartesianPath
    limits: PlanLimits
    intervals: int

    def setup(self, warm: PathProfile, focus: list[tuple[float, float]] | None = None) -> NlpSetup:
        """The NLP grid fitted to a warm-start profile (its end accelerations; its switch points, or the
        `focus` stretches given) and the path dynamics on it."""
        dynamics, jp, path, limits = self.dynamics, self.jp, self.path, self.limits
        g = warm.sigma
        pd_w = path_coefficients(dynamics, jp, g)
        # End accelerations: toppra's first/last interval, or the NLP's first/last interior node.
        k0, k1 = (0, -2) if warm.kind == "constant" else (1, -2)
        steps = [
            jerk_step(pd_w, node, jp(g[node], 1), abs(warm.sdd[k]), limits.tau_rate_max, dynamics.eps)
            for node, k in ((0, k0), (-1, k1))
        ]
        if focus is None:
            focus = [(s, s) for s in switch_points(warm, jp, limits, pd_w)]
        grid = nlp_grid(jp, warm, self.intervals, focus, *steps)
        return NlpSetup(
            grid,
            path_coefficients(dynamics, jp, grid),
            path_coefficient_derivatives(dynamics, jp, grid),
            np.linalg.norm(path.position(grid, 2), axis=1),
        )


def remap_factors(fac: np.ndarray, old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """Local limit factors from one grid to another: each new node takes the smallest factor of the
    old nodes bounding its interval."""
    k = np.clip(np.searchsorted(old, new, side="right") - 1, 0, len(old) - 2)
    return np.minimum(fac[k], fac[k + 1])


def inactive_stretches(report: LimitReport, sigma: np.ndarray, grid: np.ndarray) -> list[tuple[float, float]]:
    """σ stretches where no limit is active (the true optimum has one active everywhere: these show
    where the grid is too coarse), leaving out the constant-jerk ramps at both ends."""
    from rxcomm.planning.path_ik import _ranges

    mx = np.maximum.reduce([r.max(axis=1) for k, r in report.ratios.items() if k != "position"])
    keep = (sigma > grid[1]) & (sigma < grid[-2])
    return [(a, b) for a, b in _ranges(sigma, (mx < ACTIVE_THRESHOLD) & keep)]


def limits_text(limits: PlanLimits) -> str:
    parts = ["joint velocity", "acceleration", "torque"]
    if limits.tau_rate_max is not None:
        parts.append("torque-rate")
    if limits.tcp_speed_max is not None:
        parts.append(f"TCP speed {limits.tcp_speed_max:g} m/s")
    if limits.tcp_acc_max is not None:
        parts.append(f"TCP acceleration {limits.tcp_acc_max:g} m/s²")
    return ", ".join(parts) + " limits"


# ---------------------------------------------------------------------------------------------------
# The solver interface and its two implementations


class TimingSolver(Protocol):
    """Times a fixed joint path. `grid` is where the local limit factors `scale` live (per limit
    attribute of `PlanLimits`, one factor per node); `timings_s` collects the solver's wall time."""

    method: str
    grid: np.ndarray

    def solve(self, scale: dict[str, np.ndarray]) -> PathProfile:
        """The profile under the limits scaled by `scale`; raises InfeasibleError if there is none."""
        ...

    def regrid(
        self, profile: PathProfile, report: LimitReport, sigma: np.ndarray, scale: dict[str, np.ndarray]
    ) -> dict[str, np.ndarray] | None:
        """A new grid fitted to `profile` (checked as `report` at the samples `sigma`) and `scale`
        carried onto it, or None to keep this grid."""
        ...


class ToppraTiming:
    """toppra's time-optimal profile (`topp.time_optimal`) on a fixed grid; never regrids."""

    method = "toppra"

    def __init__(
        self,
        jp: JointPath,
        path_name: str,
        grid: np.ndarray,
        limits: PlanLimits,
        dynamics: PlanDynamics,
        curvature: np.ndarray,
        first: ToppResult,
        timings_s: dict[str, float],
    ) -> None:
        self.jp, self.path_name, self.grid, self.limits = jp, path_name, grid, limits
        self.dynamics, self.curvature, self.first, self.timings_s = dynamics, curvature, first, timings_s

    def solve(self, scale: dict[str, np.ndarray]) -> PathProfile:
        if not scale:
            return self.first.profile
        t0 = time.perf_counter()
        jp = self.jp
        res = time_optimal(
            jp.spline, jp.length_m, self.grid, self.limits, self.dynamics.exact, self.curvature, scale=scale
        )
        self.timings_s["toppra_s"] = self.timings_s.get("toppra_s", 0.0) + time.perf_counter() - t0
        if not res.ok:
            raise InfeasibleError(f"path {self.path_name!r}: {res.message} under locally tightened limits")
        return res.profile

    def regrid(self, profile, report, sigma, scale) -> None:
        return None


class NlpTiming:
    """The path NLP (`path_nlp.optimise_path`: continuous σ̈, k2·τᵀτ, torque-rate limits) warm-started
    by `warm` and then by its own last solution and multipliers. If its first solution has a limit
    active less than `regrid_below` of the time, it moves its grid once to the inactive stretches."""

    method = "nlp"

    def __init__(
        self,
        problem: NlpProblem,
        warm: PathProfile,
        k1: float,
        k2: float,
        regrid_below: float,
        target_ratio: float,
        timings_s: dict[str, float],
        bus: BusPowerModel | None = None,
        duration_s: float | None = None,
    ) -> None:
        self.problem, self.k1, self.k2 = problem, k1, k2
        self.bus, self.duration_s = bus, duration_s  # the energy objective; a fixed duration
        self.regrid_below, self.target_ratio, self.timings_s = regrid_below, target_ratio, timings_s
        self.setup = problem.setup(warm)
        self.grid = self.setup.grid
        self.warm = warm
        self.result: NlpResult | None = None
        self.regridded = regrid_below <= 0.0
        timings_s.setdefault("nlp_s", 0.0)
        timings_s.setdefault("nlp_setup_s", 0.0)

    def solve(self, scale: dict[str, np.ndarray]) -> PathProfile:
        t0 = time.perf_counter()
        duals = None if self.result is None else self.result.duals
        res = self._optimise(scale, self.duration_s, self.warm, duals)
        # The Δt rows are exact where σ̇² is linear in σ; where the optimum lets it sag between the nodes
        # the law takes longer than they say (0.1–0.2 % at 8 × T_opt with path_nlp.SAG_FRACTION): the
        # duration row is aimed so that the law's own duration is the one asked for. Re-solves land on
        # neighbouring local optima (±0.05 % in the law's time), so the closest of the aims is kept.
        target, asked, best = self.duration_s, self.duration_s, res

        def miss(r: NlpResult) -> float:
            return abs(r.profile.duration_s / asked - 1) if r.ok else np.inf

        for _ in range(DURATION_AIMS):
            if asked is None or not res.ok or miss(res) < DURATION_REL_TOL:
                break
            target *= asked / res.profile.duration_s
            res = self._optimise(scale, target, res.profile, res.duals)
            best = res if miss(res) < miss(best) else best
        res = best if asked is not None else res
        self.timings_s["nlp_s"] += time.perf_counter() - t0
        pb = self.problem
        if not res.ok:
            raise InfeasibleError(
                f"path {pb.path.name!r}: the path NLP did not converge ({res.status}, {res.iterations} "
                f"iterations) under {limits_text(pb.limits)}"
            )
        self.result, self.warm = res, res.profile
        return res.profile

    def _optimise(
        self, scale: dict[str, np.ndarray], duration_s: float | None, warm: PathProfile, duals
    ) -> NlpResult:
        s, pb = self.setup, self.problem
        return optimise_path(
            pb.jp.spline, s.grid, s.pd, s.dpd, pb.limits, warm,
            coulomb_eps_rad_s=pb.dynamics.eps, k1=self.k1, k2=self.k2, curvature=s.curvature,
            scale=scale, duals=duals, bus=self.bus, k3=1.0 if self.bus is not None else 0.0,
            duration_s=duration_s,
            # near its time-optimal duration the fixed-time problem took 514 iterations (RX130L line at
            # 1.06 × T_opt, prior model); at the chain's durations ≈ 50
            max_iter=3000 if duration_s is not None else 500,
        )  # fmt: skip

    def regrid(self, profile, report, sigma, scale) -> dict[str, np.ndarray] | None:
        if self.regridded or report.active_fraction(ACTIVE_THRESHOLD, exclude=("position",)) >= (
            self.regrid_below
        ):
            self.regridded = True  # good enough: keep this grid
            return None
        t0 = time.perf_counter()
        # Second pass on a grid fitted to this solution: dense where no limit is active.
        tighten_locally(report, sigma, self.grid, self.problem.limits, scale, self.target_ratio)
        new = self.problem.setup(profile, inactive_stretches(report, sigma, self.grid))
        carried = {k: remap_factors(v, self.grid, new.grid) for k, v in scale.items()}
        self.setup, self.grid, self.regridded = new, new.grid, True
        self.timings_s["nlp_setup_s"] += time.perf_counter() - t0
        return carried
