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
6. With a `command` (the calibrated joint compliance, `rxcomm.planning.commanded`) the samples become
   what `run` streams: the encoder angles that put the links on the IK, q̇/q̈ by the chain rule, and
   τ_ff on them; the joint limits are checked on that, the TCP limits on the link trajectory.
7. Every limit checked on the samples (`rxcomm.model.limits.check_limits` + TCP limits). Between grid nodes
   sampled values can exceed a limit by a fraction of a percent (toppra's interpolation, the NLP's
   node- and midpoint-wise constraints); where a limit is above `target_ratio` (1 +
   `model.limits.SAMPLED_LIMIT_TOLERANCE` = 1.002, what `run` accepts) it is tightened locally, at the
   nodes of that interval, by its excess and the timing re-solved (at most `max_refinements` times).
   A plan still above 1.01 × a limit is refused (`InfeasibleError`).

Dynamics come in as functions (`PlanDynamics`): an exact-sign inverse dynamics for the path
coefficients and a smooth one for the output torques; `PlanDynamics.from_parameters` builds both from
`rxcomm.model.dynamics` parameters (the URDF prior or identified ones).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Literal

import numpy as np
import pinocchio as pin
from pydantic import BaseModel, ConfigDict, Field, model_validator

from rxcomm.errors import InfeasibleError
from rxcomm.model.energy import BusPowerModel
from rxcomm.model.limits import SAMPLED_LIMIT_TOLERANCE, LimitReport, check_limits, robot_limits
from rxcomm.model.robot import Robot
from rxcomm.planning.commanded import Command, OnLink, commanded_trajectory
from rxcomm.planning.cp_grid import toppra_grid
from rxcomm.planning.path_dynamics import PathDynamics
from rxcomm.planning.path_ik import SIGMA_MIN_MARGIN, JointPath, solve_path_ik
from rxcomm.planning.path_nlp import NlpResult, coulomb_levels
from rxcomm.planning.path_profile import PathProfile
from rxcomm.planning.paths import CartesianPath
from rxcomm.planning.timing import (
    ACTIVE_THRESHOLD,
    NlpProblem,
    NlpTiming,
    PlanDynamics,
    TimingSolver,
    ToppraTiming,
    limits_text,
    path_coefficients,
    tighten_locally,
)
from rxcomm.planning.topp import PlanLimits, ToppResult, time_optimal
from rxcomm.schemas.path import Branch

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
    sigma_min_margin: float = Field(
        SIGMA_MIN_MARGIN, gt=0, description="smallest TCP-Jacobian singular value allowed"
    )
    target_ratio: float = Field(
        1.0 + SAMPLED_LIMIT_TOLERANCE,
        ge=1.0,
        le=1.01,
        description="re-solve while a sampled limit exceeds this (what run accepts)",
    )
    max_refinements: int = Field(4, ge=0, le=10)
    objective: Literal["torque", "energy"] = Field(
        "torque",
        description="torque: ∫(k1 + k2·τᵀτ)dt; energy: the electrical energy drawn from the bus "
        "(copper, mechanical power, regeneration as drives.yaml says; model.energy.BusPowerModel) at a "
        "fixed duration_s",
    )
    duration_s: float | None = Field(
        None, gt=0, description="fix the duration (the NLP minimises the objective at it), s; none: free"
    )
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
        if self.method == "toppra" and (self.objective == "energy" or self.duration_s is not None):
            raise ValueError("method toppra is time-optimal: an energy objective or a duration needs nlp")
        if self.objective == "energy" and self.duration_s is None:
            raise ValueError("the energy objective needs a duration (the energy at that cycle time)")
        if self.duration_s is not None and self.objective != "energy":
            # ∫τᵀτ at a fixed time is mostly holding torque: its optimum crawls (σ̇ at the NLP's floor)
            # where gravity is low, so only the energy objective takes a duration
            raise ValueError("a fixed duration is for the energy objective")
        return self

    @property
    def uses_nlp(self) -> bool:
        return self.method == "nlp"


# ---------------------------------------------------------------------------------------------------
# TCP limits as `rxcomm.model.limits` objects (ratios(t, q, qd, qdd, tau) -> [n, 1])


@dataclass(frozen=True, eq=False)
class TcpLimit:
    """|a linear TCP quantity| against `bound`, per sample; subclasses name it and compute it from
    Pinocchio's data after forward kinematics to the order they need."""

    robot: Robot
    bound: float

    def ratios(self, t, q, qd, qdd, tau) -> np.ndarray:
        m, d, fid = self.robot.model, self.robot.create_data(), self.robot.tcp_frame_id
        out = np.empty((len(q), 1))
        for i in range(len(q)):
            out[i, 0] = np.linalg.norm(self.linear(m, d, fid, q[i], qd[i], qdd[i]))
        return out / self.bound


class TcpSpeedLimit(TcpLimit):
    name = "tcp_speed"

    @staticmethod
    def linear(m, d, fid, q, qd, qdd) -> np.ndarray:
        pin.forwardKinematics(m, d, q, qd)
        return pin.getFrameVelocity(m, d, fid, pin.LOCAL_WORLD_ALIGNED).linear


class TcpAccelerationLimit(TcpLimit):
    name = "tcp_acceleration"

    @staticmethod
    def linear(m, d, fid, q, qd, qdd) -> np.ndarray:
        pin.forwardKinematics(m, d, q, qd, qdd)
        return pin.getFrameClassicalAcceleration(m, d, fid, pin.LOCAL_WORLD_ALIGNED).linear


def tcp_limits(robot: Robot, speed_m_s: float | None, acceleration_m_s2: float | None) -> list[TcpLimit]:
    """The TCP limits set (None: off), as `check_limits` objects."""
    out: list[TcpLimit] = []
    if speed_m_s is not None:
        out.append(TcpSpeedLimit(robot, speed_m_s))
    if acceleration_m_s2 is not None:
        out.append(TcpAccelerationLimit(robot, acceleration_m_s2))
    return out


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
class PathSamples:
    """A timed path sampled: σ and its rates, the joint samples as commanded and their torques; `link`
    the links' (q, q̇, q̈) where q is commanded through a compliance (None: the same)."""

    t: np.ndarray
    sigma: np.ndarray
    sigma_dot: np.ndarray
    sigma_ddot: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    link: tuple | None


def joint_samples(jp: JointPath, s, sd, sdd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, q̇, q̈ along the path at σ, σ̇, σ̈ (chain rule: q̇ = q'σ̇, q̈ = q'σ̈ + q''σ̇²)."""
    qs, qss = jp(s, 1), jp(s, 2)
    return jp(s), qs * sd[:, None], qs * sdd[:, None] + qss * (sd**2)[:, None]


def commanded_path(t, s, sd, sdd, q, qd, qdd, command: Command | None, dynamics: PlanDynamics) -> PathSamples:
    """The samples `run` streams (through `command`'s compliance) with their smooth-friction torques."""
    q, qd, qdd, link = commanded_samples(command, q, qd, qdd)
    return PathSamples(t, s, sd, sdd, q, qd, qdd, dynamics.smooth(q, qd, qdd), link)


@dataclass(frozen=True, eq=False)
class CpPlan(PathSamples):
    """A planned CP trajectory, sampled at the drive cycle, with its checks and timings."""

    joint_path: JointPath
    profile: PathProfile
    method: str
    report: LimitReport
    limit_scale: dict[str, float]  # smallest local factor applied per limit
    toppra: ToppResult
    nlp: NlpResult | None
    timings_s: dict[str, float]
    refinements: int
    settings: CpSettings
    active_segments: list[ActiveSegment] = field(default_factory=list)

    @property
    def q_link(self) -> np.ndarray | None:
        """The links' angles where q is commanded through a compliance (None: q)."""
        return None if self.link is None else self.link[0]

    @property
    def link_angles(self) -> np.ndarray:
        """The link angles of the samples (the IK along the path): q unless compensated."""
        return self.q if self.q_link is None else self.q_link

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

    @classmethod
    def of(cls, x: PathSamples, report: LimitReport, **timing) -> CpPlan:
        """The plan of samples `x` checked in `report`; `timing`: how they were timed (joint_path,
        profile, method, limit_scale, toppra, nlp, timings_s, refinements, settings)."""
        samples = {f.name: getattr(x, f.name) for f in fields(PathSamples)}
        return cls(**samples, report=report, active_segments=active_segments(x.t, x.sigma, report), **timing)


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


def _limit_objects(robot: Robot, limits: PlanLimits, link: tuple | None = None) -> list:
    """The joint limits, and the TCP limits (on the `link` trajectory (q, q̇, q̈) when given)."""
    objs = robot_limits(robot, torque_rate=limits.tau_rate_max is not None)
    tcp = tcp_limits(robot, limits.tcp_speed_max, limits.tcp_acc_max)
    return objs + (tcp if link is None else [OnLink(lim, *link) for lim in tcp])


def commanded_samples(
    command: Command | None, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple | None]:
    """The sampled trajectory `run` streams and the link trajectory for the TCP limits (None: the
    same; without a `command` the samples pass unchanged)."""
    if command is None:
        return q, qd, qdd, None
    return (*commanded_trajectory(command, q, qd, qdd), (q, qd, qdd))


def plan_cp(
    robot: Robot,
    path: CartesianPath,
    dynamics: PlanDynamics,
    settings: CpSettings | None = None,
    branch: Branch | None = None,
    q_near: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
    command: Command | None = None,
) -> CpPlan:
    """Plan `path` on `robot` (pass a calibrated robot to honour a calibration, and its joint
    compliance as `command`: link → encoder angles). Raises InfeasibleError naming what fails
    (unreachable/singular σ, statics, uncontrollable, NLP)."""
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
    check_statics(robot, jp, path_coefficients(dynamics, jp, jp.sigma))
    limits = plan_limits(robot, settings)
    grid = toppra_grid(jp, settings.intervals, robot.a_max)
    curvature = np.linalg.norm(path.position(grid, 2), axis=1)
    say("time-optimal timing (toppra)")
    topp = time_optimal(jp.spline, jp.length_m, grid, limits, dynamics.exact, curvature)
    timings["toppra_s"] = time.perf_counter() - t1
    if not topp.ok:
        raise InfeasibleError(f"path {path.name!r}: {topp.message} under {limits_text(limits)}")

    timings.update(nlp_s=0.0, nlp_setup_s=0.0)
    solver: TimingSolver
    if settings.uses_nlp:
        warm, bus = topp.profile, None
        if settings.duration_s is not None:
            warm = _stretched(warm, settings.duration_s, path.name)
        if settings.objective == "energy":
            bus = BusPowerModel.of(robot)
            if bus is None:
                raise InfeasibleError(
                    "the energy objective needs every joint's winding_resistance_ohm",
                    file=robot.drives_path, field="joints[].winding_resistance_ohm",
                )  # fmt: skip
        solver = NlpTiming(
            NlpProblem(dynamics, jp, path, limits, settings.intervals), warm, settings.k1,
            settings.k2, 0.0 if settings.duration_s else settings.regrid_below, settings.target_ratio,
            timings, bus=bus, duration_s=settings.duration_s,
        )  # fmt: skip
    else:
        solver = ToppraTiming(jp, path.name, grid, limits, dynamics, curvature, topp, timings)
    scale: dict[str, np.ndarray] = {}
    refinements = 0
    while True:
        if solver.method == "nlp":
            say("optimal timing (path NLP)")
        profile = solver.solve(scale)
        t4 = time.perf_counter()
        t, s, sd, sdd = profile.sample(robot.drives.cycle_s)
        x = commanded_path(t, s, sd, sdd, *joint_samples(jp, s, sd, sdd), command, dynamics)
        checks = _limit_objects(robot, limits, x.link)
        report = check_limits(robot, t, x.q, x.qd, x.qdd, x.tau, limits=checks)
        timings["check_s"] = timings.get("check_s", 0.0) + time.perf_counter() - t4
        carried = solver.regrid(profile, report, s, scale)
        if carried is not None:
            scale = carried
            continue
        if refinements >= settings.max_refinements or not tighten_locally(
            report, s, solver.grid, limits, scale, settings.target_ratio
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
    return CpPlan.of(
        x, report, joint_path=jp, profile=profile, method=solver.method, toppra=topp,
        limit_scale={k: float(v.min()) for k, v in scale.items()},
        nlp=solver.result if isinstance(solver, NlpTiming) else None,
        timings_s=timings, refinements=refinements, settings=settings,
    )  # fmt: skip


def _stretched(profile: PathProfile, duration_s: float, name: str) -> PathProfile:
    """`profile` slowed uniformly to `duration_s` (σ̇ by T₀/T, σ̈ by its square): the warm start of a
    fixed-duration NLP. Refuses a duration below the time-optimal one (no timing reaches it)."""
    k = profile.duration_s / duration_s
    if k > 1.0 + 1e-9:
        raise InfeasibleError(
            f"path {name!r}: {duration_s:.4g} s is below its time-optimal duration {profile.duration_s:.4g} s"
        )
    return PathProfile(profile.sigma, profile.sd * k, profile.sdd * k * k, profile.kind)


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
