"""Continuous-path planning (paper §5.1–5.3): Cartesian path → joint path → optimal timing → samples.

`plan_cp` chains the pieces, each usable alone:

1. IK along the path on one branch (`rxcomm.planning.path_ik.solve_path_ik`): q(σ) as a C² spline.
2. Statics first: |g(q(σ))| ≤ τmax (and + Coulomb friction, to move at all) on every knot, naming the
   joint and σ, because toppra reports infeasibility only as "uncontrollable".
3. toppra (`rxcomm.planning.topp.time_optimal`) on N intervals, half uniform in σ, half where the joint
   path bends (blends, the neighbourhood of a singularity): the time-optimal profile under joint
   velocity/acceleration/torque (+ TCP) limits with a piecewise-constant σ̈. `method="toppra"` stops
   here (fast; its torque steps at every node, so no torque-rate limit can hold).
4. By default the path NLP (`rxcomm.planning.path_nlp`: continuous σ̈, k2 > 0, torque-rate limits) on N
   intervals placed half by σ, half by toppra's time, denser at toppra's switch points, with
   constant-jerk end ramps as short as the torque rate allows (`jerk_step`) and nodes where a joint
   reverses; warm-started from toppra. If that solution leaves more than 3 % of the time without an
   active limit (the true optimum has one everywhere: the grid is too coarse there), a second pass on a
   grid refined on exactly those stretches, warm-started with the first pass's multipliers.
5. Sampling at the drive cycle, exactly (`PathProfile.sample`): q = q(σ), q̇ = q'σ̇, q̈ = q'σ̈ + q''σ̇²,
   τ_ff from the inverse dynamics with smoothed Coulomb friction (the same the NLP models).
6. Every limit checked on the samples (`rxcomm.model.limits.check_limits` + TCP limits). Between grid nodes
   sampled values can exceed a limit by a fraction of a percent (toppra's interpolation, the NLP's
   node-wise constraints); where a limit is above `target_ratio` (1.002) it is tightened locally, at the
   nodes of that interval, by its excess and the timing re-solved (at most `max_refinements` times).
   A plan still above 1.01 × a limit is refused (`InfeasibleError`).

Dynamics come in as functions (`PlanDynamics`): an exact-sign inverse dynamics for the path
coefficients and a smooth one for the output torques; `PlanDynamics.from_parameters` builds both from
`rxcomm.model.dynamics` parameters (the URDF prior or identified ones).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pinocchio as pin
from pydantic import BaseModel, ConfigDict, Field, model_validator

from rxcomm.errors import InfeasibleError
from rxcomm.model.limits import LimitReport, check_limits, robot_limits
from rxcomm.model.robot import Robot
from rxcomm.planning.path_dynamics import InverseDynamics, PathDynamics, path_dynamics
from rxcomm.planning.path_ik import JointPath, solve_path_ik
from rxcomm.planning.path_nlp import NlpResult, coulomb_levels, optimise_path
from rxcomm.planning.path_profile import PathProfile
from rxcomm.planning.paths import CartesianPath
from rxcomm.planning.topp import PlanLimits, ToppResult, time_optimal
from rxcomm.schemas.path import Branch

ACTIVE_THRESHOLD = 0.98  # a limit counts as active at ≥ 98 % of its bound (LimitReport.active_fraction)
MAX_RATIO = 1.01  # the sampled output may exceed no limit by more (architecture §9 summary, max_limit_ratio)


class CpSettings(BaseModel):
    """Options of a CP plan (recorded in the artefact's settings)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    k1: float = Field(1.0, ge=0, description="weight of time in ∫(k1 + k2·τᵀτ)dt")
    k2: float = Field(0.0, ge=0, description="weight of τᵀτ, 1/(N·m)²; > 0 needs the NLP")
    torque_rate: bool = Field(True, description="enforce the drives' torque-rate limits (needs the NLP)")
    method: Literal["nlp", "toppra"] = Field(
        "nlp",
        description="nlp: the path NLP warm-started by toppra; toppra: toppra alone (k2 = 0, no torque rate)",
    )
    intervals: int = Field(200, ge=10, le=5000, description="grid intervals along σ")
    tcp_speed_max_m_s: float | None = Field(None, gt=0)
    tcp_acceleration_max_m_s2: float | None = Field(None, gt=0)
    coulomb_eps_rad_s: float = Field(0.02, gt=0, description="Coulomb sign smoothing of the output torque")
    sigma_min_margin: float = Field(0.005, gt=0, description="smallest TCP-Jacobian singular value allowed")
    target_ratio: float = Field(
        1.002, ge=1.0, le=1.01, description="re-solve while a sampled limit exceeds this"
    )
    max_refinements: int = Field(4, ge=0, le=10)
    regrid_below: float = Field(
        0.97,
        ge=0,
        le=1,
        description="NLP: solve again on a grid refined where no limit is active if the first solution "
        "has one active less than this fraction of the time (0: never)",
    )

    @model_validator(mode="after")
    def _method_fits(self) -> CpSettings:
        if self.method == "toppra" and (self.k2 > 0 or self.torque_rate):
            raise ValueError(
                "method toppra cannot weigh torque (k2 > 0) or limit torque rate: use nlp or auto"
            )
        return self

    @property
    def uses_nlp(self) -> bool:
        return self.method == "nlp"


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

        params = prior_parameters(robot) if dynamics_path is None else load_dynamics(dynamics_path, robot)
        return cls.from_parameters(robot, params, eps)


# ---------------------------------------------------------------------------------------------------
# TCP limits as `rxcomm.model.limits` objects (ratios(t, q, qd, qdd, tau) -> [n, 1])


@dataclass(frozen=True, eq=False)
class TcpSpeedLimit:
    robot: Robot
    v_max: float
    name: str = "tcp_speed"

    def ratios(self, t, q, qd, qdd, tau) -> np.ndarray:
        m, d, fid = self.robot.model, self.robot.create_data(), self.robot.tcp_frame_id
        out = np.empty((len(q), 1))
        for i in range(len(q)):
            pin.forwardKinematics(m, d, q[i], qd[i])
            out[i, 0] = np.linalg.norm(pin.getFrameVelocity(m, d, fid, pin.LOCAL_WORLD_ALIGNED).linear)
        return out / self.v_max


@dataclass(frozen=True, eq=False)
class TcpAccelerationLimit:
    robot: Robot
    a_max: float
    name: str = "tcp_acceleration"

    def ratios(self, t, q, qd, qdd, tau) -> np.ndarray:
        m, d, fid = self.robot.model, self.robot.create_data(), self.robot.tcp_frame_id
        out = np.empty((len(q), 1))
        for i in range(len(q)):
            pin.forwardKinematics(m, d, q[i], qd[i], qdd[i])
            acc = pin.getFrameClassicalAcceleration(m, d, fid, pin.LOCAL_WORLD_ALIGNED).linear
            out[i, 0] = np.linalg.norm(acc)
        return out / self.a_max


# ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ActiveSegment:
    """A stretch of the trajectory where one limit is the binding one (ratio ≥ ACTIVE_THRESHOLD)."""

    limit: str
    joint: str
    t_start_s: float
    t_end_s: float
    sigma_start_m: float
    sigma_end_m: float


@dataclass(frozen=True, eq=False)
class CpPlan:
    """A planned CP trajectory, sampled at the drive cycle, with its checks and timings."""

    joint_path: JointPath
    profile: PathProfile
    method: str
    t: np.ndarray
    sigma: np.ndarray
    sigma_dot: np.ndarray
    sigma_ddot: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    report: LimitReport
    limit_scale: dict[str, float]  # smallest local factor applied per limit
    toppra: ToppResult
    nlp: NlpResult | None
    timings_s: dict[str, float]
    refinements: int
    settings: CpSettings
    active_segments: list[ActiveSegment] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def energy_nm2s(self) -> float:
        """∫τᵀτ dt over the samples (N²·m²·s)."""
        return float(np.trapezoid(np.sum(self.tau**2, axis=1), self.t))

    @property
    def tcp_speed(self) -> np.ndarray:
        """TCP speed (m/s): σ is the TCP arc length, so σ̇."""
        return self.sigma_dot

    @property
    def active_fraction(self) -> float:
        return self.report.active_fraction(ACTIVE_THRESHOLD, exclude=("position",))


def plan_limits(robot: Robot, settings: CpSettings) -> PlanLimits:
    return PlanLimits(
        v_max=robot.v_max,
        a_max=robot.a_max,
        tau_max=robot.tau_max,
        tau_rate_max=robot.tau_rate_max if settings.torque_rate else None,
        tcp_speed_max=settings.tcp_speed_max_m_s,
        tcp_acc_max=settings.tcp_acceleration_max_m_s2,
    )


def check_statics(robot: Robot, jp: JointPath, pd: PathDynamics) -> None:
    """Refuse a path whose holding torque (gravity + spring) alone, or with Coulomb friction added
    (needed to move at all), exceeds a joint's peak torque; name drives.yaml's peak torque, the joint
    and the σ stretch (InfeasibleError, exit 3, as plan-ptp's end points)."""
    from rxcomm.planning.path_ik import _fmt_ranges, _ranges

    tau_max = robot.tau_max
    fc = coulomb_levels(pd)
    for what, need in (
        ("gravity and spring alone need", np.abs(pd.g)),
        ("gravity, spring and Coulomb friction need", np.abs(pd.g) + fc),
    ):
        ratio = need / tau_max
        if ratio.max() > 1.0:
            j = int(np.argmax(ratio.max(axis=0)))
            i = int(np.argmax(ratio[:, j]))
            stretch = _fmt_ranges(_ranges(pd.sigma, ratio[:, j] > 1.0))
            raise InfeasibleError(
                f"path {jp.path.name!r}: {what} {need[i, j]:.0f} N·m on {robot.joint_names[j]} at "
                f"σ = {pd.sigma[i]:.4f} m (peak torque {tau_max[j]:.0f} N·m; over the limit at {stretch}): "
                "no timing can follow this path",
                file=robot.drives_path,
                field=f"joints[{j}].peak_torque_nm",
            )


def _coefficients(dyn: PlanDynamics, jp: JointPath, grid: np.ndarray) -> PathDynamics:
    return path_dynamics(dyn.exact, grid, jp(grid), jp(grid, 1), jp(grid, 2))


def _derivatives(
    dyn: PlanDynamics, jp: JointPath, grid: np.ndarray, h: float = 1e-5
) -> dict[str, np.ndarray]:
    """dm/dσ, dc/dσ, dv/dσ, dg/dσ by central differences (one-sided at the ends)."""
    up = np.minimum(grid + h, jp.length_m)
    lo = np.maximum(grid - h, 0.0)
    pu, pl = _coefficients(dyn, jp, up), _coefficients(dyn, jp, lo)
    return {k: (getattr(pu, k) - getattr(pl, k)) / (up - lo)[:, None] for k in ("m", "c", "v", "g")}


def reversal_points(jp: JointPath) -> np.ndarray:
    """σ where some joint's q' changes sign (the joint reverses; smooth Coulomb friction peaks there)."""
    s = np.linspace(0, jp.length_m, max(4 * len(jp.sigma), 400))
    qs = jp(s, 1)
    out = []
    for j in range(qs.shape[1]):
        if np.abs(qs[:, j]).max() < 1e-4:  # a joint that does not move has no reversal (only noise)
            continue
        idx = np.flatnonzero(np.sign(qs[:-1, j]) * np.sign(qs[1:, j]) < 0)
        for i in idx:
            a, b = qs[i, j], qs[i + 1, j]
            out.append(s[i] + (s[i + 1] - s[i]) * a / (a - b))
    return np.sort(np.array(out))


def switch_points(
    profile: PathProfile, jp: JointPath, limits: PlanLimits, pd: PathDynamics | None
) -> np.ndarray:
    """σ where the profile switches: σ̈ changes sign or another (limit, joint) becomes the binding one.

    Between such points a time-optimal profile rides one constraint; at them a continuous σ̈ needs
    a transition that only a fine grid keeps short."""
    g = profile.sigma
    sd, sdd = profile.sd, profile.sdd
    qs, qss = jp(g, 1), jp(g, 2)
    parts = [
        np.abs(qs) * sd[:, None] / limits.v_max,
        np.abs(qss * sd[:, None] ** 2 + qs * sdd[:, None]) / limits.a_max,
    ]
    if pd is not None:
        parts.append(np.abs(pd.torque(sdd, sd)) / limits.tau_max)
    binding = np.argmax(np.hstack(parts), axis=1)
    change = (binding[1:] != binding[:-1]) | (np.sign(sdd[1:]) * np.sign(sdd[:-1]) < 0)
    idx = np.flatnonzero(change[1:-1]) + 1  # not the rest-to-rest ends
    return (g[idx] + g[idx + 1]) / 2


def toppra_grid(jp: JointPath, intervals: int, a_max: np.ndarray) -> np.ndarray:
    """Grid for toppra: half the nodes uniform in σ, half where the joint path bends most
    (‖q''(σ)/a_max‖∞), so blends and the neighbourhood of singularities are resolved."""
    length = jp.length_m
    fine = np.linspace(0.0, length, 20 * intervals + 1)
    bend = np.max(np.abs(jp(fine, 2)) / a_max, axis=1)
    rho = 0.5 / length + 0.5 * bend / max(np.trapezoid(bend, fine), 1e-300)
    cum = np.concatenate([[0.0], np.cumsum((rho[1:] + rho[:-1]) / 2 * np.diff(fine))])
    grid = np.interp(np.linspace(0.0, cum[-1], intervals + 1), cum, fine)
    grid[0], grid[-1] = 0.0, length
    return grid


def jerk_step(
    pd: PathDynamics, node: int, qs: np.ndarray, accel: float, rate_max: np.ndarray | None, eps: float
) -> float:
    """Length (m) of the constant-jerk interval at a path end (`node` 0 or −1) that ramps |σ̈| from 0 to
    `accel` in the shortest time t the torque-rate limit allows. In the ramp the inertial rate m·j
    (j = a/t) is constant and every moving joint's Coulomb term crosses its band |q̇| ≲ 2ε, adding up
    to ±0.56·Fc·√(2|q'|·j/ε) — with the inertial rate when starting, against it when stopping (see
    `path_nlp`). σ at the end of the ramp is a·t²/6."""
    if rate_max is None or accel <= 0:
        return 0.0
    fc = coulomb_levels(pd)
    sign_f = np.sign(qs) * (1.0 if node == 0 else -1.0) * np.sign(pd.m[node])
    t = np.geomspace(1e-5, 1.0, 400)[:, None]
    inertial = np.abs(pd.m[node]) * accel / t
    band = 0.56 * fc * np.sqrt(2 * np.abs(qs) * accel / (t * eps))
    worst = np.maximum(inertial, np.abs(inertial + sign_f * band)) / rate_max
    ok = np.all(worst <= 1.0, axis=1)
    t_min = float(t[np.argmax(ok), 0]) if ok.any() else 1.0
    return accel * t_min**2 / 6


def nlp_grid(
    jp: JointPath,
    warm: PathProfile,
    intervals: int,
    focus: list[tuple[float, float]] | None = None,
    first_step_m: float = 0.0,
    last_step_m: float = 0.0,
) -> np.ndarray:
    """Grid for the NLP. Node density: half uniform in σ, half in the warm start's time, four times
    that on the `focus` stretches (σ ranges, each widened by one regular spacing) — where the binding
    limit switches, which a continuous σ̈ can only follow as fast as the grid allows. At both ends the
    steps double from `first_step_m` / `last_step_m` (the constant-jerk ramp from rest, `jerk_step`)
    up to the regular spacing. The interior node nearest each joint reversal is moved onto it."""
    length = jp.length_m
    fine = np.linspace(0.0, length, 20 * intervals + 1)
    t_fine = np.interp(fine, warm.sigma, warm.t_nodes)
    rho = 0.5 / length + 0.5 * np.gradient(t_fine, fine) / warm.duration_s
    if focus:
        width = length / intervals
        base = rho.copy()
        for a, b in focus:
            rho = rho + 3 * base * ((fine > a - width) & (fine < b + width))
    cum = np.concatenate([[0.0], np.cumsum((rho[1:] + rho[:-1]) / 2 * np.diff(fine))])

    def ramp(first: float, h: float) -> list[float]:
        steps, s = [], max(first, 1e-6 * length, h / 256)
        while s < h / 1.5 and len(steps) < 10:
            steps.append(s)
            s *= 2
        return steps

    h0 = cum[-1] / intervals / rho[0]
    h1 = cum[-1] / intervals / rho[-1]
    head, tail = ramp(first_step_m, h0), ramp(last_step_m, h1)
    z0, z1 = sum(head), length - sum(tail)
    n_mid = intervals - len(head) - len(tail)
    c0, c1 = np.interp([z0, z1], fine, cum)
    mid = np.interp(np.linspace(c0, c1, n_mid + 1), cum, fine)
    grid = np.concatenate([np.cumsum([0.0, *head])[:-1], mid, (length - np.cumsum([0.0, *tail]))[::-1][1:]])
    grid[0], grid[-1] = 0.0, length
    lo, hi = len(head) + 1, intervals - len(tail) - 1
    for sr in reversal_points(jp):
        i = int(np.argmin(np.abs(grid - sr)))
        if lo <= i <= hi and grid[i - 1] + 1e-6 < sr < grid[i + 1] - 1e-6:
            grid[i] = sr
    return grid


def active_segments(plan_t, sigma, report: LimitReport, min_fraction: float = 0.01) -> list[ActiveSegment]:
    """The binding limit over time: per sample the (limit, joint) with the largest ratio if ≥ the
    threshold; consecutive runs merged, runs shorter than `min_fraction` of the duration dropped."""
    names, cols, labels = [], [], []
    for k, r in report.ratios.items():
        if k == "position":
            continue
        for j in range(r.shape[1]):
            names.append(k)
            labels.append("TCP" if k.startswith("tcp") else report.joint_names[j])
            cols.append(r[:, j])
    mat = np.stack(cols, axis=1)
    best = np.argmax(mat, axis=1)
    best[mat[np.arange(len(best)), best] < ACTIVE_THRESHOLD] = -1
    segs: list[ActiveSegment] = []
    i, n, dur = 0, len(best), plan_t[-1] - plan_t[0]
    while i < n:
        j = i
        while j + 1 < n and best[j + 1] == best[i]:
            j += 1
        if best[i] >= 0 and (plan_t[j] - plan_t[i]) >= min_fraction * dur:
            k = best[i]
            if segs and segs[-1].limit == names[k] and segs[-1].joint == labels[k]:
                last = segs.pop()
                segs.append(
                    ActiveSegment(
                        names[k], labels[k], last.t_start_s, plan_t[j], last.sigma_start_m, sigma[j]
                    )
                )
            else:
                segs.append(ActiveSegment(names[k], labels[k], plan_t[i], plan_t[j], sigma[i], sigma[j]))
        i = j + 1
    return segs


def _limit_objects(robot: Robot, limits: PlanLimits) -> list:
    objs = robot_limits(robot, torque_rate=limits.tau_rate_max is not None)
    if limits.tcp_speed_max is not None:
        objs.append(TcpSpeedLimit(robot, limits.tcp_speed_max))
    if limits.tcp_acc_max is not None:
        objs.append(TcpAccelerationLimit(robot, limits.tcp_acc_max))
    return objs


_LIMIT_ATTR = {
    "velocity": "v_max",
    "acceleration": "a_max",
    "torque": "tau_max",
    "torque_rate": "tau_rate_max",
    "tcp_speed": "tcp_speed_max",
    "tcp_acceleration": "tcp_acc_max",
}


def _tighten(
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
class _NlpSetup:
    grid: np.ndarray
    pd: PathDynamics
    dpd: dict[str, np.ndarray]
    curvature: np.ndarray


def _nlp_setup(
    dynamics: PlanDynamics,
    jp: JointPath,
    path: CartesianPath,
    limits: PlanLimits,
    warm: PathProfile,
    intervals: int,
    focus: list[tuple[float, float]] | None = None,
) -> _NlpSetup:
    """The NLP grid fitted to a warm-start profile (its end accelerations; its switch points, or the
    `focus` stretches given) and the path dynamics on it."""
    g = warm.sigma
    pd_w = _coefficients(dynamics, jp, g)
    # End accelerations: toppra's first/last interval, or the NLP's first/last interior node.
    k0, k1 = (0, -2) if warm.kind == "constant" else (1, -2)
    steps = [
        jerk_step(pd_w, node, jp(g[node], 1), abs(warm.sdd[k]), limits.tau_rate_max, dynamics.eps)
        for node, k in ((0, k0), (-1, k1))
    ]
    if focus is None:
        focus = [(s, s) for s in switch_points(warm, jp, limits, pd_w)]
    grid = nlp_grid(jp, warm, intervals, focus, *steps)
    return _NlpSetup(
        grid,
        _coefficients(dynamics, jp, grid),
        _derivatives(dynamics, jp, grid),
        np.linalg.norm(path.position(grid, 2), axis=1),
    )


def _remap(fac: np.ndarray, old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """Local limit factors from one grid to another: each new node takes the smallest factor of the
    old nodes bounding its interval."""
    k = np.clip(np.searchsorted(old, new, side="right") - 1, 0, len(old) - 2)
    return np.minimum(fac[k], fac[k + 1])


def _inactive(report: LimitReport, sigma: np.ndarray, grid: np.ndarray) -> list[tuple[float, float]]:
    """σ stretches where no limit is active (the true optimum has one active everywhere: these show
    where the grid is too coarse), leaving out the constant-jerk ramps at both ends."""
    from rxcomm.planning.path_ik import _ranges

    mx = np.maximum.reduce([r.max(axis=1) for k, r in report.ratios.items() if k != "position"])
    keep = (sigma > grid[1]) & (sigma < grid[-2])
    return [(a, b) for a, b in _ranges(sigma, (mx < ACTIVE_THRESHOLD) & keep)]


def plan_cp(
    robot: Robot,
    path: CartesianPath,
    dynamics: PlanDynamics,
    settings: CpSettings | None = None,
    branch: Branch | None = None,
    q_near: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
) -> CpPlan:
    """Plan `path` on `robot` (pass a calibrated robot to honour a calibration). Raises
    InfeasibleError naming what fails (unreachable/singular σ, statics, uncontrollable, NLP)."""
    settings = settings or CpSettings()
    say = progress or (lambda _m: None)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if branch is None and q_near is None and path.spec is not None:
        branch = path.spec.branch
        q_near = None if path.spec.q_start_rad is None else np.asarray(path.spec.q_start_rad, float)
    say("inverse kinematics along the path")
    jp = solve_path_ik(robot, path, branch, q_near, sigma_min_margin=settings.sigma_min_margin)
    timings["ik_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    check_statics(robot, jp, _coefficients(dynamics, jp, jp.sigma))
    limits = plan_limits(robot, settings)
    grid = toppra_grid(jp, settings.intervals, robot.a_max)
    curvature = np.linalg.norm(path.position(grid, 2), axis=1)
    say("time-optimal timing (toppra)")
    topp = time_optimal(jp.spline, jp.length_m, grid, limits, dynamics.exact, curvature)
    timings["toppra_s"] = time.perf_counter() - t1
    if not topp.ok:
        raise InfeasibleError(f"path {path.name!r}: {topp.message} under {_limits_text(limits)}")

    use_nlp = settings.uses_nlp
    setup = _nlp_setup(dynamics, jp, path, limits, topp.profile, settings.intervals) if use_nlp else None
    sgrid = setup.grid if use_nlp else grid
    scale: dict[str, np.ndarray] = {}
    warm = topp.profile
    nlp: NlpResult | None = None
    timings["nlp_s"] = 0.0
    timings.setdefault("nlp_setup_s", 0.0)
    refinements = 0
    regridded = not use_nlp or settings.regrid_below <= 0.0
    while True:
        if use_nlp:
            say("optimal timing (path NLP)")
            t3 = time.perf_counter()
            nlp = optimise_path(
                jp.spline, setup.grid, setup.pd, setup.dpd, limits, warm,
                coulomb_eps_rad_s=dynamics.eps, k1=settings.k1, k2=settings.k2, curvature=setup.curvature,
                scale=scale, duals=None if nlp is None else nlp.duals,
            )  # fmt: skip
            timings["nlp_s"] += time.perf_counter() - t3
            if not nlp.ok:
                raise InfeasibleError(
                    f"path {path.name!r}: the path NLP did not converge ({nlp.status}, {nlp.iterations} "
                    f"iterations) under {_limits_text(limits)}"
                )
            profile = nlp.profile
        elif refinements == 0:
            profile = topp.profile
        else:
            t3 = time.perf_counter()
            res = time_optimal(jp.spline, jp.length_m, grid, limits, dynamics.exact, curvature, scale=scale)
            timings["toppra_s"] += time.perf_counter() - t3
            if not res.ok:
                raise InfeasibleError(f"path {path.name!r}: {res.message} under locally tightened limits")
            profile = res.profile
        t4 = time.perf_counter()
        t, s, sd, sdd = profile.sample(robot.drives.cycle_s)
        qs, qss = jp(s, 1), jp(s, 2)
        q = jp(s)
        qd = qs * sd[:, None]
        qdd = qs * sdd[:, None] + qss * (sd**2)[:, None]
        tau = dynamics.smooth(q, qd, qdd)
        report = check_limits(robot, t, q, qd, qdd, tau, limits=_limit_objects(robot, limits))
        timings["check_s"] = timings.get("check_s", 0.0) + time.perf_counter() - t4
        warm = profile
        if (
            not regridded
            and report.active_fraction(ACTIVE_THRESHOLD, exclude=("position",)) >= settings.regrid_below
        ):
            regridded = True  # good enough: keep this grid
        if not regridded:
            # Second pass on a grid fitted to this solution: dense where no limit is active.
            t2 = time.perf_counter()
            _tighten(report, s, sgrid, limits, scale, settings.target_ratio)
            new = _nlp_setup(
                dynamics, jp, path, limits, profile, settings.intervals, _inactive(report, s, sgrid)
            )
            scale = {k: _remap(v, sgrid, new.grid) for k, v in scale.items()}
            setup, sgrid, regridded = new, new.grid, True
            timings["nlp_setup_s"] += time.perf_counter() - t2
            continue
        if refinements >= settings.max_refinements or not _tighten(
            report, s, sgrid, limits, scale, settings.target_ratio
        ):
            break
        refinements += 1
    timings["total_s"] = time.perf_counter() - t0
    if report.max_ratio > MAX_RATIO:
        name, joint, t_w, ratio = report.worst()
        i = int(np.searchsorted(t, t_w))
        raise InfeasibleError(
            f"path {path.name!r}: {name} of {joint} reaches {ratio:.3f} × its limit at t = {t_w:.4f} s "
            f"(σ = {s[min(i, len(s) - 1)]:.4f} m) after {refinements} local re-tightenings; "
            "try more --path-intervals"
        )
    return CpPlan(
        joint_path=jp,
        profile=profile,
        method="nlp" if use_nlp else "toppra",
        t=t,
        sigma=s,
        sigma_dot=sd,
        sigma_ddot=sdd,
        q=q,
        qd=qd,
        qdd=qdd,
        tau=tau,
        report=report,
        limit_scale={k: float(v.min()) for k, v in scale.items()},
        toppra=topp,
        nlp=nlp,
        timings_s=timings,
        refinements=refinements,
        settings=settings,
        active_segments=active_segments(t, s, report),
    )


def _limits_text(limits: PlanLimits) -> str:
    parts = ["joint velocity", "acceleration", "torque"]
    if limits.tau_rate_max is not None:
        parts.append("torque-rate")
    if limits.tcp_speed_max is not None:
        parts.append(f"TCP speed {limits.tcp_speed_max:g} m/s")
    if limits.tcp_acc_max is not None:
        parts.append(f"TCP acceleration {limits.tcp_acc_max:g} m/s²")
    return ", ".join(parts) + " limits"


def path_deviation_m(robot: Robot, jp: JointPath, n: int = 400) -> float:
    """Largest TCP position error of the joint spline against the Cartesian path (between knots)."""
    s = np.linspace(0, jp.length_m, n)
    mid = (jp.sigma[:-1] + jp.sigma[1:]) / 2
    s = np.unique(np.concatenate([s, mid]))
    q = jp(s)
    p = jp.path.position(s)
    d = robot.create_data()
    err = 0.0
    for qi, pi in zip(q, p, strict=True):
        pin.framesForwardKinematics(robot.model, d, qi)
        err = max(err, float(np.linalg.norm(d.oMf[robot.tcp_frame_id].translation - pi)))
    return err
