"""The factory's timing: a generic controller that knows only the catalogue limits (issue 17).

A robot as delivered knows no dynamics: its controller times a path or a point-to-point move from the
kinematic limits its maker publishes (`rxcomm.model.catalogue`), the same for every pose and payload.

- `plan_cp_catalogue`: IK along the path, then toppra's time-optimal σ̇(σ) under the catalogue joint
  speeds and accelerations and the path's TCP limits only (no torque constraint), sampled at the drive
  cycle and passed through the setpoint filter generic controllers use to limit jerk: a moving
  average over `JERK_RAMP_S` (it keeps every speed and acceleration within its bound, bounds the
  jerk by 2·a/T, makes the move T longer and rounds the joint path a little: part of the factory's
  path error). The torques τ of the result are the given model's, for the record: the factory
  streams none.
- `plan_ptp_catalogue`: ruckig's time-optimal jerk-limited rest-to-rest profile under the catalogue
  speeds and accelerations and a jerk reaching each acceleration in `JERK_RAMP_S` (50 ms).
- `pose_cycle_plan`: the ISO 9283 pose test (P1 → P5 → P4 → P3 → P2, `planning.iso9283`) with each
  move a cycloidal profile at the catalogue limits. Both states use it: the test measures the poses
  at rest, so only the kinematics the IK solved them on differ.

Both report every limit they honour on the drive-cycle samples; the torque against the drives' peak is
left out of that check (it is what the catalogue's worst case guarantees, not what the timing knows).

- `catalogue_speed_bound`: the highest TCP speed ANY catalogue box could give a path, whatever its
  shape (not only `model.catalogue`'s rule): a box must hold the catalogue's torque bound with its
  v_k, a_k ≥ every |q̇_k|, |q̈_k| of the motion, so at each path point the bound evaluated with that
  point's own |q̇(σ)|, |q̈(σ)| (at every sampled pose) is necessary. That per-point constraint
  admits an interval of σ̈ for each σ̇² (each pose's row is convex piecewise-linear in σ̈: exact
  roots at its breakpoints); forward integration from rest at full acceleration and backward from
  rest at full deceleration bound every feasible profile from above (phase-plane comparison), and
  their minimum, capped by a TCP speed, is the bound. On the RX130L's ISO line: 0.94 m/s at best,
  so no catalogue of this bound holds that line at 1 m/s.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rxcomm.errors import InfeasibleError
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.catalogue import (
    DEFAULT_POSES,
    JERK_RAMP_S,  # the generic controller's jerk: each joint reaches its acceleration in 50 ms
    CatalogueLimits,
    payload_parameters,
    worst_case_terms,
)
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.limits import AccelerationLimit, LimitReport, PositionLimit, VelocityLimit, check_limits
from rxcomm.model.robot import Robot
from rxcomm.planning.commanded import Command, OnLink
from rxcomm.planning.cp import CpPlan, CpSettings, commanded_path, joint_samples, tcp_limits
from rxcomm.planning.cp_grid import toppra_grid
from rxcomm.planning.iso9283 import (
    cube_from_rectangle,
    cycloidal_move,
    pose_cycle_joints,
    pose_cycle_trajectory,
)
from rxcomm.planning.path_ik import JointPath, solve_path_ik
from rxcomm.planning.paths import CartesianPath
from rxcomm.planning.ptp import sample_profile
from rxcomm.planning.ptp_problem import PtpDynamics
from rxcomm.planning.timing import PlanDynamics, limits_text
from rxcomm.planning.topp import PlanLimits, time_optimal
from rxcomm.planning.warm_start import ruckig_profile
from rxcomm.schemas.path import PathSpec

# JERK_RAMP_S: PtP uses ruckig's jerk limit a/T, CP a moving-average setpoint filter of length T


def moving_average(x: np.ndarray, n: int, rest_ends: bool) -> np.ndarray:
    """x [N, dof] filtered by a length-n moving average, N + n − 1 samples: padded with the end values
    (positions, `rest_ends` False) or zeros (speeds and accelerations of a rest-to-rest move)."""
    if n <= 1:
        return np.array(x, float)
    x = np.asarray(x, float)
    pad_lo = np.zeros((n - 1, x.shape[1])) if rest_ends else np.repeat(x[:1], n - 1, axis=0)
    pad_hi = np.zeros((n - 1, x.shape[1])) if rest_ends else np.repeat(x[-1:], n - 1, axis=0)
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), pad_lo, x, pad_hi]), axis=0)
    return (c[n:] - c[:-n]) / n


def _kinematic_checks(robot: Robot, catalogue: CatalogueLimits) -> list:
    return [
        PositionLimit(robot.q_min, robot.q_max),
        VelocityLimit(catalogue.v_max),
        AccelerationLimit(catalogue.a_max),
    ]


def plan_cp_catalogue(
    robot: Robot,
    path: CartesianPath,
    catalogue: CatalogueLimits,
    dynamics: PlanDynamics,
    settings: CpSettings | None = None,
    progress: Callable[[str], None] | None = None,
    command: Command | None = None,
) -> CpPlan:
    """Time `path` as a generic controller does (module docstring). `settings` give the grid
    intervals and TCP limits; `command` maps the filtered link trajectory to the encoders' (joint
    compliance, as `plan_cp`); InfeasibleError from the IK or when toppra finds no profile."""
    settings = settings or CpSettings(method="toppra", torque_rate=False)
    say = progress or (lambda _m: None)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    spec = path.spec
    branch = None if spec is None else spec.branch
    q_near = None if spec is None or spec.q_start_rad is None else np.asarray(spec.q_start_rad, float)
    say("inverse kinematics along the path")
    jp = solve_path_ik(robot, path, branch, q_near, sigma_min_margin=settings.sigma_min_margin)
    timings["ik_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    limits = PlanLimits(
        v_max=catalogue.v_max,
        a_max=catalogue.a_max,
        tau_max=robot.tau_max,  # unused: no inverse dynamics is given to toppra
        tcp_speed_max=settings.tcp_speed_max_m_s,
        tcp_acc_max=settings.tcp_acceleration_max_m_s2,
    )
    grid = toppra_grid(jp, settings.intervals, catalogue.a_max)
    curvature = np.linalg.norm(path.position(grid, 2), axis=1)
    say("catalogue timing (toppra, kinematic limits only)")
    topp = time_optimal(jp.spline, jp.length_m, grid, limits, None, curvature)
    timings["toppra_s"] = time.perf_counter() - t1
    if not topp.ok:
        raise InfeasibleError(f"path {path.name!r}: {topp.message} under catalogue {limits_text(limits)}")
    cycle = robot.drives.cycle_s
    _, s, sd, sdd = topp.profile.sample(cycle)
    q, qd, qdd = joint_samples(jp, s, sd, sdd)
    n_filter = max(int(round(JERK_RAMP_S / cycle)), 1)
    q, qd, qdd = (moving_average(x, n_filter, rest) for x, rest in ((q, False), (qd, True), (qdd, True)))
    s = moving_average(s[:, None], n_filter, False)[:, 0]
    sd, sdd = (moving_average(x[:, None], n_filter, True)[:, 0] for x in (sd, sdd))
    x = commanded_path(np.arange(len(q)) * cycle, s, sd, sdd, q, qd, qdd, command, dynamics)
    checks = _kinematic_checks(robot, catalogue)
    tcp = tcp_limits(robot, settings.tcp_speed_max_m_s, settings.tcp_acceleration_max_m_s2)
    checks += tcp if x.link is None else [OnLink(lim, *x.link) for lim in tcp]
    report = check_limits(robot, x.t, x.q, x.qd, x.qdd, x.tau, limits=checks)
    timings["total_s"] = time.perf_counter() - t0
    return CpPlan.of(
        x, report, joint_path=jp, profile=topp.profile, method="catalogue", limit_scale={}, toppra=topp,
        nlp=None, timings_s=timings, refinements=0, settings=settings,
    )  # fmt: skip


def filtered_path_deviation_m(robot: Robot, plan: CpPlan, path: CartesianPath, n: int = 600) -> float:
    """Largest distance of the TCP of the filtered setpoints (at `n` instants) from the Cartesian
    path (a polyline through it every 0.5 mm, distances to its segments): what the setpoint filter
    rounds off, nominal kinematics."""
    from rxcomm.model.kinematics import frame_placement

    pts = path.position(np.linspace(0.0, path.length_m, max(int(path.length_m / 5e-4), 2) + 1))
    a, ab = pts[:-1], np.diff(pts, axis=0)
    ab2 = np.maximum(np.sum(ab**2, axis=1), 1e-30)
    data = robot.create_data()
    worst = 0.0
    q = plan.link_angles
    for i in np.unique(np.linspace(0, len(q) - 1, n).astype(int)):
        p = frame_placement(robot, data, q[i], robot.tcp_frame_id).translation
        u = np.clip(np.sum((p - a) * ab, axis=1) / ab2, 0.0, 1.0)
        worst = max(worst, float(np.min(np.linalg.norm(a + u[:, None] * ab - p, axis=1))))
    return worst


def plan_ptp_catalogue(
    robot: Robot, dynamics: PtpDynamics, q_start, q_goal, catalogue: CatalogueLimits
) -> tuple[Trajectory, LimitReport]:
    """The generic controller's rest-to-rest move (module docstring) at the drive cycle, its torques
    from `dynamics` (for the record), and the check of the limits it honours."""
    profile = ruckig_profile(q_start, q_goal, catalogue.v_max, catalogue.a_max, catalogue.a_max / JERK_RAMP_S)
    traj = sample_profile(profile, dynamics, robot.drives.cycle_s)
    report = check_limits(
        robot, traj.t, traj.q, traj.qd, traj.qdd, traj.tau_ff, limits=_kinematic_checks(robot, catalogue)
    )
    return traj, report


def pose_cycle_plan(
    robot: Robot,
    rectangle: PathSpec,
    catalogue: CatalogueLimits,
    dynamics: PtpDynamics,
    n_cycles: int,
    dwell_s: float,
    sample_s: float,
    command: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[Trajectory, list[str], LimitReport]:
    """The pose-cycle plan through the test cube of `rectangle` (the iso9283-rectangle spec) on
    `robot` (a calibrated one to honour a calibration): the trajectory sampled every `sample_s` with
    its torques from `dynamics`, the poses in the order visited, the check of the catalogue limits.
    `command` maps each pose's IK solution to the joint angles commanded (a compliance
    compensation); default: as solved."""
    joints = pose_cycle_joints(robot, cube_from_rectangle(rectangle), rectangle.branch)
    if command is not None:
        joints = {k: command(q) for k, q in joints.items()}
    move = cycloidal_move(catalogue.v_max, catalogue.a_max, sample_s)
    traj, order = pose_cycle_trajectory(joints, n_cycles, dwell_s, move, sample_s)
    tau = dynamics.torque(traj.q, traj.qd, traj.qdd)
    traj = Trajectory(traj.t, traj.q, traj.qd, traj.qdd, tau)
    report = check_limits(
        robot, traj.t, traj.q, traj.qd, traj.qdd, tau, limits=_kinematic_checks(robot, catalogue)
    )
    return traj, order, report


@dataclass(frozen=True)
class SpeedBound:
    """`catalogue_speed_bound`'s result: the bound of σ̇ (m/s) at `sigma_m`, its peak and where."""

    sigma_m: np.ndarray
    speed_m_s: np.ndarray
    peak_m_s: float
    peak_at_m: float


def _sdd_interval(c, m, qs, qss, x, peak) -> tuple[float, float] | None:
    """The σ̈ with c + Σ_k m_k |q_s,k σ̈ + q_ss,k x| ≤ peak for every row (c, peak [N, n], m [N, n, n]):
    each row convex piecewise-linear in σ̈, so an interval found exactly from its breakpoints; None
    when some row has none (x above the limit curve)."""
    nz = np.abs(qs) > 1e-12
    p, r = qs[nz], qss[nz] * x
    m = m[:, :, nz]
    b = np.sort(-r / p)
    g = c[:, :, None] + np.einsum("ijk,kb->ijb", m, np.abs(p[:, None] * b[None, :] + r[:, None]))
    slope = np.maximum(m @ np.abs(p), 1e-12)  # |dg/dσ̈| beyond the outermost breakpoints
    ok = g <= peak[:, :, None]
    if not np.all(ok.any(axis=2)):
        return None
    nb = len(b)

    def at(idx):
        return np.take_along_axis(g, idx[..., None], 2)[..., 0], b[idx]

    hi_i = nb - 1 - np.argmax(ok[:, :, ::-1], axis=2)  # the last breakpoint within the row's limit
    (g_hi, b_hi), (g_up, b_up) = at(hi_i), at(np.minimum(hi_i + 1, nb - 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        upper = np.where(
            hi_i == nb - 1, b_hi + (peak - g_hi) / slope, b_hi + (peak - g_hi) * (b_up - b_hi) / (g_up - g_hi)
        )
        lo_i = np.argmax(ok, axis=2)
        (g_lo, b_lo), (g_dn, b_dn) = at(lo_i), at(np.maximum(lo_i - 1, 0))
        lower = np.where(
            lo_i == 0, b_lo - (peak - g_lo) / slope, b_lo - (peak - g_lo) * (b_lo - b_dn) / (g_dn - g_lo)
        )
    lo, hi = float(lower.max()), float(upper.min())
    return None if lo > hi else (lo, hi)


def catalogue_speed_bound(
    robot: Robot,
    joint_path: JointPath,
    speed_cap_m_s: float,
    params: DynamicParameters | None = None,
    n_poses: int = DEFAULT_POSES,
    seed: int = 0,
    n_points: int = 1001,
) -> SpeedBound:
    """The upper bound of the TCP speed along `joint_path` under any catalogue box (module
    docstring), capped at `speed_cap_m_s`: the catalogue's torque bound at the same `n_poses`
    sampled poses (`seed`) of `params` (default: the prior with the rated payload)."""
    params = payload_parameters(robot) if params is None else params
    q = np.random.default_rng(seed).uniform(robot.q_min, robot.q_max, (n_poses, robot.n))
    wc = worst_case_terms(robot, params, q)
    peak = np.broadcast_to(np.asarray(robot.tau_max, float), wc.hold.shape)
    sig = np.linspace(0.0, joint_path.length_m, n_points)
    ds = float(sig[1] - sig[0])
    qs, qss = joint_path(sig, 1), joint_path(sig, 2)
    coriolis = np.einsum("ijkl,sk,sl->sij", wc.quadratic, np.abs(qs), np.abs(qs))  # × σ̇² per point

    def interval(k: int, x: float) -> tuple[float, float] | None:
        speed = np.abs(qs[k]) * np.sqrt(x)
        c = wc.hold + x * coriolis[k] + wc.friction_at(speed)[None, :]
        return _sdd_interval(c, wc.mass, qs[k], qss[k], x, peak)

    def limit_curve(k: int, x_hi: float) -> float:
        lo, hi = 0.0, x_hi
        for _ in range(40):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if interval(k, mid) is not None else (lo, mid)
        return lo

    cap = speed_cap_m_s**2

    def sweep(order: range, side: int) -> np.ndarray:
        out = np.zeros(n_points)
        x = 0.0
        for k in order:
            iv = interval(k, x)
            if iv is None:
                x = limit_curve(k, x)
                iv = interval(k, x) or (0.0, 0.0)
            out[k] = x
            x = min(max(x + 2.0 * ds * (iv[1] if side > 0 else -iv[0]), 0.0), cap)
        return out

    forward = sweep(range(n_points), 1)
    backward = sweep(range(n_points - 1, -1, -1), -1)
    speed = np.sqrt(np.minimum(forward, backward))
    k = int(np.argmax(speed))
    return SpeedBound(sig, speed, float(speed[k]), float(sig[k]))
