"""Time/energy-optimal point-to-point motion (paper §5.4–5.5): solve the OCP, sample it, check it densely.

The OCP and its formulation are in `ptp_ocp`; its inputs in `ptp_problem`. Here: `plan_ptp` (warm start,
solve, dense check, re-solve), the sampling at the drive cycle, the result and the kinematic fallback.

Dense check with a margin: between nodes nothing is enforced, so the NLP uses every limit tightened to
(1 − margin) (default 1 %); the optimum is then sampled at the drive cycle by exact integration of the
piecewise-constant jerk, and every limit is checked on those samples as `run` checks them
(`rxcomm.model.limits`, torques from the output model: Coulomb friction smoothed with `run`'s
ε = 0.02 rad/s, the torque rate of the whole torque): the max ratio is the summary's
`max_limit_ratio`. A limit exceeded by more than `SAMPLED_LIMIT_TOLERANCE` (what `run` accepts) is
tightened and the NLP solved again from that solution (bounds only, at most `max_resolves` times);
a plan still beyond it is refused (InfeasibleError), never written for `run` to refuse.

The paper's problem (`PtpOptions.acceleration_limits` False: torque, torque rate, velocity, position)
is a benchmark `run` refuses anyway (its accelerations exceed the drives'): it keeps the paper's
statement, the torque rate of the NLP's torque without its Coulomb part, sampled torques from the
NLP's model, re-solves above `PAPER_TOLERANCE` and no refusal. With its unlimited accelerations every
reversal's friction step would be several times a limit, and bounding it costs ~15 % of the time.

Velocity reversals: the NLP's torque-rate rows leave Coulomb friction out (`ptp_ocp` module doc), but
the output torque steps by 2·Fc where a joint reverses, at a rate ≈ Fc·|q̈|/ε: on the RX130L's J3
(identified Fc ≈ 15 N·m) a reversal at its 8 rad/s² limit alone is 1.01 × its 6000 N·m/s. Energy-
weighted optima (k2 ≥ 1e-4) swing J3 out to its position limit and back at full deceleration, so the
plan failed `run`'s check (1.004 × at k2 = 1e-3). Where the excess is the friction step (the rate of
the torque without it is below the bound), |q̈| of that joint is capped at the nodes around the
reversal to what brings the step under the bound (`tighten_torque_rate`); a cap costs a few ms. Where the
rest of the torque is too fast between the nodes, the torque-rate margin grows by the excess.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from rxcomm.errors import InfeasibleError, InputError
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.energy import BusPowerModel
from rxcomm.model.limits import SAMPLED_LIMIT_TOLERANCE, LimitReport
from rxcomm.model.robot import Robot
from rxcomm.planning.ptp_ocp import PtpOcp, cached_ocp
from rxcomm.planning.ptp_problem import (
    NodeGuess,
    PtpDynamics,
    PtpLimits,
    PtpOptions,
    PtpSolution,
    Vec3,
    energy_quadrature,
)
from rxcomm.planning.warm_start import KinematicProfile, feasible_profile, ruckig_profile

PAPER_TOLERANCE = 0.01  # the paper's problem (no acceleration limits): re-solve above 1 % (module doc)


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


def sample_solution(
    sol: PtpSolution, dynamics: PtpDynamics, cycle_s: float, q_goal=None, output: bool = True
) -> Trajectory:
    """The optimum at the drive cycle: the jerk profile integrated exactly, torques from the dynamics.

    T is rounded up to a whole number of cycles by a uniform time stretch (q̇ × r, q̈ × r², jerk × r³
    with r = T/T' ≥ 0.9993 for T ≥ 0.5 s at 400 µs): only slower. The last sample is the goal at rest
    exactly (`q_goal` removes the NLP's ~1e-9 rad residual). Torques: the output model's (`run`'s
    friction smoothing), or with `output` False the NLP's.
    """
    N, T = sol.n_intervals, sol.duration_s
    n_cycles = max(int(np.ceil(T / cycle_s - 1e-9)), 1)
    T2 = n_cycles * cycle_s
    r = T / T2
    t = np.arange(n_cycles + 1) * cycle_s
    q, qd, qdd = integrate_jerk(sol.q[0], sol.qd[0] * r, sol.qdd[0] * r**2, sol.jerk * r**3, T2 / N, t)
    q[-1] = sol.q[-1] if q_goal is None else q_goal
    qd[-1] = qdd[-1] = 0.0
    tau = dynamics.output_torque(q, qd, qdd) if output else dynamics.torque(q, qd, qdd)
    return Trajectory(t, q, qd, qdd, tau)


def quadrature_energy(sol: PtpSolution, dynamics: PtpDynamics, bus: BusPowerModel) -> float:
    """The energy objective's own figure of a solution (J): `bus`'s smoothed power on the points and
    weights of `energy_quadrature` (states by exact integration of the jerk, the output model's torque),
    the value the NLP minimised; the plan is judged on `model.energy.electrical_energy` of its
    drive-cycle samples."""
    s, w = energy_quadrature(sol.n_intervals)
    T = sol.duration_s
    q, qd, qdd = integrate_jerk(sol.q[0], sol.qd[0], sol.qdd[0], sol.jerk, T / sol.n_intervals, s * T)
    return float(T * w @ bus.power(qd, dynamics.output_torque(q, qd, qdd)))


def sample_profile(profile: KinematicProfile, dynamics: PtpDynamics, cycle_s: float) -> Trajectory:
    """A kinematic profile at the drive cycle with its inverse-dynamics torques."""
    n_cycles = max(int(np.ceil(profile.duration_s / cycle_s - 1e-9)), 1)
    t = np.arange(n_cycles + 1) * cycle_s
    q, qd, qdd = profile.at(t)
    return Trajectory(t, q, qd, qdd, dynamics.output_torque(q, qd, qdd))


def dense_report(
    traj: Trajectory, limits: PtpLimits, joint_names, without_friction: PtpDynamics | None = None
) -> LimitReport:
    """Every PtP limit on the drive-cycle samples, as `run` checks them (the torque rate of the whole
    sampled torque, Coulomb friction included); with `without_friction` the torque rate of the NLP's
    torque without its Coulomb part (the paper's problem, module doc)."""
    ratios = {}
    for lim in limits.dense_checks():
        tau = traj.tau_ff
        if without_friction is not None and lim.name == "torque_rate":
            tau = without_friction.rate_torque(traj.q, traj.qd, tau)
        ratios[lim.name] = lim.ratios(traj.t, traj.q, traj.qd, traj.qdd, tau)
    return LimitReport(t=traj.t, ratios=ratios, joint_names=tuple(joint_names))


def tighten_torque_rate(
    traj: Trajectory,
    dynamics: PtpDynamics,
    limits: PtpLimits,
    rate: np.ndarray,
    caps: np.ndarray,
    rate_scale: np.ndarray,
    margin: float,
) -> None:
    """Tighten the NLP where the sampled torque rate exceeds its limit (module doc).

    `rate` [n, dof]: the torque-rate ratios of `traj`; `caps` [N+1, dof] (rad/s², the NLP's node grid,
    updated in place). At every sample above 1 + `SAMPLED_LIMIT_TOLERANCE` where the friction step's
    rate c (∝ |q̈|) is the larger part and the rest is below 1 − `margin`, c is scaled to the room left:
    |q̈| ≤ s·|q̈(t)| with s = (1 − margin − rate without friction)/c ∈ [0.2, 0.98] (|q̈| the largest of
    the sample and its neighbours), at the four nodes around it (the reversal moves a little when
    re-solved), at every node if that joint was capped in an earlier pass (its reversal moved out of
    the caps: the joint is not what sets the time there). At the other samples above the tolerance (a
    torque at its rate limit plus a little friction, e.g. where a joint starts) the NLP's torque-rate
    rows of that joint at the same nodes are scaled down by the excess (`rate_scale` [N+1, dof], in
    place, compounding over passes), as plan-cp tightens its limits locally.
    """
    t, N = traj.t, caps.shape[0] - 1
    friction = dynamics.output_coulomb_torque(traj.qd)
    c = np.abs(np.gradient(friction, t, axis=0)) / limits.tau_rate_max
    rest = np.abs(np.gradient(traj.tau_ff - friction, t, axis=0)) / limits.tau_rate_max
    h = traj.duration_s / N
    # |q̈| around each sample (the one-sided rate at the ends sees the next sample's)
    qdd = np.abs(traj.qdd)
    qdd_near = np.maximum(qdd, np.maximum(np.roll(qdd, 1, axis=0), np.roll(qdd, -1, axis=0)))
    capped_before = np.isfinite(caps).any(axis=0)
    factor = np.ones_like(rate_scale)  # this pass's scaling of the torque-rate rows (the worst sample's)
    for i, j in zip(*np.nonzero(rate > 1.0 + SAMPLED_LIMIT_TOLERANCE), strict=True):
        k = min(int(t[i] / h), N - 1)
        near = slice(max(k - 1, 0), min(k + 3, N + 1))
        if c[i, j] <= rest[i, j] or rest[i, j] >= 1.0 - margin:  # not a reversal's step
            factor[near, j] = np.minimum(factor[near, j], 1.0 - (rate[i, j] - 1.0) - margin)
            continue
        s = float(np.clip((1.0 - margin - rest[i, j]) / c[i, j], 0.2, 0.98))
        # a joint capped in an earlier pass whose reversal moved out of its caps is not what sets
        # the time there: cap it on the whole motion
        nodes = slice(1, N) if capped_before[j] else slice(max(k - 1, 1), min(k + 3, N))
        caps[nodes, j] = np.minimum(caps[nodes, j], s * qdd_near[i, j])
    # from the rows' bound as it stands: one that did not bind (the excess between the nodes, a start's
    # friction ramp) is lowered again on the next pass instead of set to the same value
    rate_scale *= factor


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
    margins: dict | None = None
    resolves: int = 0

    @property
    def duration_s(self) -> float:
        return self.trajectory.duration_s

    @property
    def max_limit_ratio(self) -> float:
        r = self.report.max_ratio
        return r if self.tcp_box_ratio is None else max(r, self.tcp_box_ratio)

    def active_fraction(self) -> float:
        """Fraction of the samples where some limit (not position) is active: within 1 % of the bound
        the NLP used (the limit tightened by its margin), the paper's time-optimality check."""
        used = [v for k, v in (self.margins or {}).items() if k != "position" and k in self.report.ratios]
        return self.report.active_fraction(threshold=1.0 - max(used, default=0.0) - 0.01)

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


def check_boundary_state(
    dynamics: PtpDynamics, limits: PtpLimits, q, name: str, joint_names, drives_file: Path | None = None
) -> np.ndarray:
    """Refuse an end point outside the position limits or whose holding torque exceeds the peak torque.

    Outside the limits: InputError with field `name[joint]` (exit 2). Holding torque above the peak:
    InfeasibleError naming `drives_file` and the joint's peak torque (exit 3, as plan-cp's statics).
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
            raise InfeasibleError(
                f"{name} [{joint_names[j]}]: holding torque {g[j]:.1f} N·m exceeds the peak torque "
                f"{limits.tau_max[j]:.1f} N·m: no motion can start or end there",
                file=drives_file,
                field=f"joints[{j}].peak_torque_nm",
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
    max_resolves: int = 4,
) -> PtpResult:
    """Plan the optimal rest-to-rest motion from `q_start` to `q_goal` (rad).

    Raises InputError (exit 2) for end points outside the limits, InfeasibleError (exit 3) for end
    points the drives cannot hold or a plan still beyond a limit after the re-solves, PtpNotConverged
    (exit 3) when IPOPT fails. `warm_start` overrides the ruckig profile; `ocp` a built NLP (default:
    `cached_ocp`).
    If the dense check finds a limit exceeded by more than `SAMPLED_LIMIT_TOLERANCE` between the nodes,
    the NLP is solved again from the solution with that limit tightened (at most `max_resolves` times):
    the friction step of a velocity reversal by local |q̈| caps (`tighten_torque_rate`), anything else by
    growing that limit's margin by the excess.
    """
    options = options or PtpOptions()
    limits = PtpLimits.from_robot(robot, acceleration=options.acceleration_limits)
    names, drives = robot.joint_names, robot.drives_path
    q_start = check_boundary_state(dynamics, limits, q_start, "start", names, drives)
    q_goal = check_boundary_state(dynamics, limits, q_goal, "goal", names, drives)
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
    margins = ocp.margins()
    # a plan for `run` (acceleration limits on) is checked as run checks it; the paper's problem as
    # the paper states it (module doc)
    for_run = options.acceleration_limits
    tolerance = SAMPLED_LIMIT_TOLERANCE if for_run else PAPER_TOLERANCE
    caps = np.full((ocp.N + 1, robot.n), np.inf)  # local |q̈| caps at velocity reversals, rad/s²
    rate_scale = np.ones((ocp.N + 1, robot.n))  # local torque-rate bounds (factors)
    guess = NodeGuess.from_profile(warm_start, ocp.N)
    if options.duration_s is not None:  # a fixed cycle time: start from the warm start stretched to it
        if options.duration_s < 0.5 * guess.duration_s:
            raise InfeasibleError(
                f"plan-ptp: {options.duration_s:.4g} s is far below the kinematic warm start's "
                f"{guess.duration_s:.4g} s"
            )
        guess = guess.stretched(options.duration_s)
    seconds, iterations = 0.0, 0
    for attempt in range(1 + max_resolves):
        sol = ocp.solve(q_start, q_goal, guess, margins, caps, rate_scale)
        seconds, iterations = seconds + sol.solve_seconds, iterations + sol.iterations
        sol = replace(sol, solve_seconds=seconds, iterations=iterations)
        if not sol.success:
            raise PtpNotConverged(sol.status, sol)
        traj = sample_solution(sol, dynamics, robot.drives.cycle_s, q_goal=q_goal, output=for_run)
        report = dense_report(traj, limits, robot.joint_names, None if for_run else dynamics)
        ratios = report.max_by_limit()
        if options.tcp_box_m is not None:
            ratios["tcp_box"] = tcp_box_ratio(robot, traj.q, options.tcp_box_m)
        over = {k: r for k, r in ratios.items() if r > 1.0 + tolerance}
        if not over:
            break
        if attempt == max_resolves:
            if for_run:
                raise _beyond_limits(report, ratios, attempt)
            break
        # between the nodes a limit was exceeded: tighten it and solve again from this solution
        # (only bounds change, the NLP is reused)
        if for_run and over.pop("torque_rate", None) is not None:
            tighten_torque_rate(
                traj, dynamics, limits, report.ratios["torque_rate"], caps, rate_scale, options.margin
            )
        for k, r in over.items():
            margins[k] += r - 1.0 + options.margin
        guess = NodeGuess(sol.duration_s, sol.q, sol.qd, sol.qdd, sol.jerk)
    return PtpResult(traj, report, sol, warm_start, build, ratios.get("tcp_box"), margins, attempt)


def _beyond_limits(report: LimitReport, ratios: dict[str, float], resolves: int) -> InfeasibleError:
    """The refusal of a plan `run` would refuse: its worst limit, where and when."""
    limit, joint, t_s, ratio = report.worst()
    if ratios.get("tcp_box", 0.0) > ratio:
        limit, joint, ratio, where = "tcp_box", "TCP", ratios["tcp_box"], ""
    else:
        where = f" of {joint} at t = {t_s:.4f} s"
    return InfeasibleError(
        f"plan-ptp: after {resolves} re-solves the sampled plan is {ratio:.4f} × the {limit} limit{where} "
        f"(run accepts ≤ {1.0 + SAMPLED_LIMIT_TOLERANCE:g}); try more --time-intervals or a wider "
        "--margin-fraction"
    )


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
        return tr, dense_report(tr, limits, robot.joint_names)

    def ratio(p: KinematicProfile) -> float:
        tr, rep = check(p)
        r = rep.max_ratio
        if options.tcp_box_m is not None:
            r = max(r, tcp_box_ratio(robot, tr.q[:: max(len(tr.q) // 200, 1)], options.tcp_box_m))
        return r

    profile, _ = feasible_profile(q_start, q_goal, *default_kinematic_limits(robot), ratio)
    return check(profile)
