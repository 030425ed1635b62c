"""What gets streamed: a plan resampled on the drive-cycle grid, its feed-forward torque, its limit check.

Everything here is pure (no gateway): a plan is refused before any motion. A trajectory is checked
densely on the drive-cycle grid (400 µs) with the feed-forward torque the run will actually send, so
the torque limits are checked against the model in use; then it is subsampled to the stream's
setpoint period (R drive cycles) when the gateway interpolates.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from rxcomm.errors import InputError, SafetyStop
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.dynamics import COULOMB_EPS_NLP_RAD_S, DynamicParameters, RobotDynamics
from rxcomm.model.limits import SAMPLED_LIMIT_TOLERANCE, LimitReport, TorqueRateLimit, check_limits
from rxcomm.model.robot import Robot

REST_VELOCITY_RAD_S = 1e-3  # a plan must start and end at rest (|q̇| below this per joint)


@dataclass(frozen=True, eq=False)
class StreamPlan:
    """Setpoints on a uniform grid: ``q``, ``qd``, ``qdd``, ``tau_ff`` [n, dof] every ``sample_s``."""

    sample_s: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau_ff: np.ndarray
    report: LimitReport | None = None  # the dense check it passed (drive-cycle grid)
    # joints whose feed-forward keeps the smooth Coulomb sign: the held one would break their torque-rate
    # limit where the plan (made with the smooth sign) keeps it; with the ratio the held sign reached
    smooth_sign_joints: tuple[tuple[str, float], ...] = ()

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    @property
    def duration_s(self) -> float:
        return (self.n - 1) * self.sample_s

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.n) * self.sample_s

    def subsample(self, ratio: int) -> StreamPlan:
        """Every ``ratio``-th setpoint (the gateway interpolates linearly in between), last one kept."""
        if ratio == 1:
            return self
        idx = np.arange(0, self.n, ratio)
        if idx[-1] != self.n - 1:
            idx = np.append(idx, self.n - 1)  # overshoot the end by < R cycles: the plan holds there
        return StreamPlan(
            self.sample_s * ratio,
            self.q[idx],
            self.qd[idx],
            self.qdd[idx],
            self.tau_ff[idx],
            self.report,
            self.smooth_sign_joints,
        )


def resample(traj: Trajectory, sample_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, q̇, q̈) on the grid 0, sample_s, … covering the plan (times from its first sample).

    Already on the grid: copied. Otherwise q by cubic Hermite on (q, q̇), q̇ by cubic Hermite on (q̇, q̈),
    q̈ linear; grid points past the end hold the final state (a plan ends at rest).
    """
    t = traj.t - traj.t[0]
    n = int(np.ceil(t[-1] / sample_s - 1e-9)) + 1
    grid = np.arange(n) * sample_s
    if traj.n == n and np.allclose(t, grid, rtol=0, atol=1e-9):
        return np.array(traj.q), np.array(traj.qd), np.array(traj.qdd)
    if traj.n < 2:
        raise InputError("a plan needs at least two samples", field="t")
    tg = np.minimum(grid, t[-1])
    q = CubicHermiteSpline(t, traj.q, traj.qd, axis=0)(tg)
    qd = CubicHermiteSpline(t, traj.qd, traj.qdd, axis=0)(tg)
    qdd = np.stack([np.interp(tg, t, traj.qdd[:, j]) for j in range(traj.dof)], axis=1)
    return q, qd, qdd


# A joint whose planned speed reaches SLIDING_PEAK_FULL·ε somewhere in the plan slides (tanh(q̇/ε)
# reaches 76 % of Fc: the planners' model) and keeps the smooth sign's Coulomb term throughout. One
# that never exceeds SLIDING_PEAK_NONE·ε (< 46 %) creeps in stick-slip under its position loop: on its
# first direction of motion, the drive's integrator already holds the friction (the motion before the
# plan, which starts at rest), so it gets no Coulomb term there; from its first reversal on, the
# smooth sign helps the integrator swing through 2·Fc. A smoothstep in the plan's peak speed between.
SLIDING_PEAK_NONE = 0.5
SLIDING_PEAK_FULL = 1.0


def sliding_weight(qd: np.ndarray, eps_rad_s: float = COULOMB_EPS_NLP_RAD_S) -> np.ndarray:
    """Per axis of a plan's velocities ``qd`` [n, k], how much of the smooth Coulomb sign tanh(q̇/ε)
    its first direction of motion keeps, in [0, 1]: the smoothstep of the axis's peak |q̇| over the
    plan between SLIDING_PEAK_NONE·ε and SLIDING_PEAK_FULL·ε (nearly equal plans, nearly equal
    weights)."""
    peak = np.abs(np.atleast_2d(np.asarray(qd, dtype=float))).max(axis=0)
    x = np.clip((peak / eps_rad_s - SLIDING_PEAK_NONE) / (SLIDING_PEAK_FULL - SLIDING_PEAK_NONE), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def first_direction(qd: np.ndarray) -> np.ndarray:
    """Per sample and axis of ``qd`` [n, k]: True up to the axis's first reversal (a sign change of q̇,
    rests in between ignored), False from the first sample of the other sign on."""
    s = np.sign(np.asarray(qd, dtype=float))
    first = np.zeros(s.shape[1])
    for j in range(s.shape[1]):
        moving = np.flatnonzero(s[:, j])
        first[j] = s[moving[0], j] if moving.size else 0.0
    return ~np.maximum.accumulate(s == -first, axis=0)


def coulomb_weight(qd: np.ndarray, eps_rad_s: float = COULOMB_EPS_NLP_RAD_S) -> np.ndarray:
    """The weight [n, k] on tanh(q̇/ε) in the feed-forward: `sliding_weight` on each axis's first
    direction of motion, 1 after it. It changes only where q̇ changes sign, where tanh(q̇/ε) is about 0,
    so the weighted term is as continuous as the smooth sign and never steeper than it
    (|Δ(w·tanh)| ≤ |Δtanh| sample to sample)."""
    qd = np.atleast_2d(np.asarray(qd, dtype=float))
    return np.where(first_direction(qd), sliding_weight(qd, eps_rad_s), 1.0)


# The feed-forward's Coulomb sign through stops and reversals (`held_sign`, architecture §6.1). A joint
# that came to rest lets go of the sign it held through its stop over RELEASE_S (a smoothstep: at most
# 1.5·Fc/RELEASE_S, M900 J1 330 N·m/s against its 5000 N·m/s torque-rate limit); a shorter rest is a
# pause (the stretches of one direction either side are one stretch) or a reversal. A reversal on
# which the smooth sign takes longer than FLIP_S to swing (half its peak one way to half the other) is
# flipped over FLIP_S centred on it (at most 3·Fc/FLIP_S: M900 J1 1.6 kN·m/s); a faster one keeps the
# smooth sign, so a plan with neither rests nor slow reversals (the planners' CP and PtP plans) gets
# exactly the planners' friction model.
RELEASE_S = 0.05
FLIP_S = 0.02
MOVING_RAD_S = 1e-9  # |q̇| above this is motion; the planners' rests are exact zeros


def held_sign(
    qd: np.ndarray,
    sample_s: float,
    eps_rad_s: float = COULOMB_EPS_NLP_RAD_S,
    weight: np.ndarray | None = None,
) -> np.ndarray:
    """The Coulomb sign [n, k] the feed-forward uses along a plan sampled every ``sample_s``: the
    smooth sign tanh(q̇/ε), except per axis on a stretch of one sign of ``qd`` [n, k] that ends in a
    rest ≥ RELEASE_S or a slow reversal (two stretches of one sign with a pause < RELEASE_S between
    them count as one; its |tanh| is held at its running maximum through the pause, never dipping to
    0 there): from its peak |tanh| on held to its end; into the
    rest, let go over RELEASE_S while the joint rests; through a slow reversal, flipped over FLIP_S
    from the old stretch's peak to the new one's (held from the reversal on). A joint sliding to rest
    has its full friction until it stops, and one passing through rest has it the other way as soon as
    it moves: the smooth sign fades below ε, and its deficit stopped the M900's J1–J3 up to 0.75 mrad
    short of the ISO line's start, where their integrators wound up the full Fc against the line during
    the dwell, and held J2 back 1.5 mrad through its slow reversal on the line at 0.1 m/s. Friction at
    rest is set-valued, so a stuck joint holds whatever it is given within ±Fc and the release moves
    nothing. A plan that ends within a short rest keeps the smooth sign on its last stretch (nothing
    to release into). ``weight`` [n, k] (`coulomb_weight`, constant along a stretch) scales each
    stretch's sign before the flips blend them, so a creeping joint's weight changing at its first
    reversal steps nothing. Continuous: a sample-to-sample step is at most the (weighted) smooth
    sign's plus 3·sample_s/FLIP_S."""
    qd = np.atleast_2d(np.asarray(qd, dtype=float))
    w = np.ones_like(qd) if weight is None else np.asarray(weight, dtype=float)
    c = np.tanh(qd / eps_rad_s)
    n = qd.shape[0]
    n_release = int(np.ceil(RELEASE_S / sample_s - 1e-9))
    release = 1.0 - _smoothstep(np.arange(1, n_release + 1) / n_release)
    half_flip = max(1, int(np.ceil(FLIP_S / 2 / sample_s - 1e-9)))
    for j in range(qd.shape[1]):
        sg = np.sign(qd[:, j]) * (np.abs(qd[:, j]) > MOVING_RAD_S)
        cuts = np.r_[0, np.flatnonzero(sg[1:] != sg[:-1]) + 1, n]
        runs: list[tuple[int, int, float]] = []
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            if sg[a] == 0:
                continue
            if runs and runs[-1][2] == sg[a] and a - runs[-1][1] < n_release:  # a pause: one stretch
                a = runs.pop()[0]
            runs.append((int(a), int(b), sg[a]))
        mag = [np.abs(c[a:b, j]) for a, b, _ in runs]
        gaps = [(runs[i + 1][0] if i + 1 < len(runs) else n) - b for i, (_, b, _) in enumerate(runs)]
        slow = [
            i + 1 < len(runs)
            and runs[i + 1][2] == -s
            and gaps[i] < n_release
            and _swing(mag[i], mag[i + 1], b, runs[i + 1][0]) > 2 * half_flip
            for i, (_, b, s) in enumerate(runs)
        ]
        level, flips = c[:, j].copy(), []
        for i, (a, b, s) in enumerate(runs):
            m, k = mag[i].copy(), int(np.argmax(mag[i]))
            if slow[i] or gaps[i] >= n_release:
                m = np.maximum.accumulate(m)  # through a pause within it, held from its peak to its end
            if i > 0 and slow[i - 1]:
                m[:k] = m[k]  # the new direction's friction from the reversal on
            level[a:b] = s * m
            if gaps[i] >= n_release:
                level[b : b + n_release] = s * m[k] * release
            if slow[i]:
                mid = b + gaps[i] // 2
                flips.append((max(a, mid - half_flip), min(runs[i + 1][1], mid + half_flip)))
        level *= w[:, j]
        c[:, j] = level
        for lo, hi in flips:
            r = _smoothstep((np.arange(lo, hi) - lo + 0.5) / (hi - lo))
            c[lo:hi, j] = (1.0 - r) * level[max(lo - 1, 0)] + r * level[min(hi, n - 1)]
    return c


def _swing(before: np.ndarray, after: np.ndarray, end: int, start: int) -> int:
    """Samples the smooth sign takes through a reversal: from the last sample of the stretch ending at
    ``end`` at half its peak |tanh| to the first of the one starting at ``start`` at half its peak."""
    last = int(np.flatnonzero(before >= 0.5 * before.max())[-1]) - len(before)
    first = int(np.flatnonzero(after >= 0.5 * after.max())[0])
    return start + first - (end + last)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    return x * x * (3.0 - 2.0 * x)


def model_torque(
    robot: Robot,
    params: DynamicParameters,
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    sample_s: float | None = None,
) -> np.ndarray:
    """τ = M(q)q̈ + g(q, q̇) of the model (paper eq. 7) along a whole plan ([n, dof] samples in time
    order, from rest to rest): the feed-forward torque.

    Coulomb friction uses the planners' smooth sign (tanh, ε = 0.02 rad/s: an exact sign would step
    the feed-forward by 2·Fc through every velocity reversal), weighted by `coulomb_weight`, joint and
    motor friction alike: the smooth sign's fraction of Fc fed forward on top of the friction the
    integrator held pushed the M900's J4, creeping 2 mrad at ≤ 0.52·ε on its CP line, 2 mrad past its
    demand, where it stuck (architecture §6.1). Given the plan's ``sample_s``, the sign is held through
    each stop into a rest and let go at rest (`held_sign`); without it, the smooth sign throughout.
    """
    eps = COULOMB_EPS_NLP_RAD_S
    tau = RobotDynamics(robot, params, coulomb_eps_rad_s=eps).inverse_dynamics(q, qd, qdd)
    qd = np.asarray(qd, dtype=float)

    def weighted_sign(v: np.ndarray) -> np.ndarray:
        w = coulomb_weight(v, eps)
        return w * np.tanh(v / eps) if sample_s is None else held_sign(v, sample_s, eps, w)

    # the model's smooth-sign Coulomb term out, the weighted (held) one in
    tau += params.coulomb_nm * (weighted_sign(qd) - np.tanh(qd / eps))
    if params.has_motor_friction:
        r = robot.joint_to_motor
        vm = qd @ r.T / np.abs(np.diag(r))  # motor speeds on the joint scale, as RobotDynamics smooths them
        tau += (params.motor_coulomb_nm * (weighted_sign(vm) - np.tanh(vm / eps))) @ r
    return tau


def check_plan_shape(robot: Robot, traj: Trajectory, what: str = "plan") -> None:
    """InputError (exit 2) for a plan this robot cannot even interpret: wrong joint count, no duration,
    not at rest at either end."""
    if traj.dof != robot.n:
        raise InputError(f"{what} has {traj.dof} joints, the robot {robot.n}", field="q")
    if traj.n < 2 or traj.duration_s <= 0:
        raise InputError(f"{what} has no duration ({traj.n} samples)", field="t")
    for end, i in (("start", 0), ("end", -1)):
        v = np.abs(traj.qd[i])
        if np.any(v > REST_VELOCITY_RAD_S):
            j = int(np.argmax(v))
            raise InputError(
                f"{what} does not {end} at rest: |q̇| = {v[j]:.4g} rad/s on {robot.joint_names[j]} "
                f"(streaming starts from and ends in a held position)",
                field="qd",
            )


def prepare_plan(
    robot: Robot,
    traj: Trajectory,
    params: DynamicParameters,
    cycle_s: float,
    *,
    feedforward: bool = True,
    limit_tolerance: float = SAMPLED_LIMIT_TOLERANCE,
    what: str = "plan",
    sample_label: Callable[[int], str] | None = None,
) -> StreamPlan:
    """Resample ``traj`` at the drive cycle, compute the model torque, check every limit densely.

    ``params`` is the model: its torque is the feed-forward (zeros when ``feedforward`` is False) and
    is what the torque and torque-rate limits are checked on either way (without feed-forward the
    drives' loops must produce it). Raises InputError for a malformed plan and SafetyStop (exit 5)
    naming the limit, joint and time of the worst sample when a ratio exceeds 1 + ``limit_tolerance``;
    ``sample_label`` (index of the plan's own sample nearest that time -> e.g. "row 57") adds where it
    is in a plan file written elsewhere.
    """
    check_plan_shape(robot, traj, what)
    q, qd, qdd = resample(traj, cycle_s)
    t = np.arange(q.shape[0]) * cycle_s
    tau, smooth_sign = _held_within_torque_rate(robot, params, t, q, qd, qdd, 1.0 + limit_tolerance)
    report = check_limits(robot, t, q, qd, qdd, tau)
    if report.max_ratio > 1.0 + limit_tolerance:
        limit, joint, t_s, ratio = report.worst()
        where = ""
        if sample_label is not None:
            where = f" ({sample_label(int(np.argmin(np.abs(traj.t - traj.t[0] - t_s))))})"
        raise SafetyStop(
            f"{what} outside the robot's limits: {limit} of {joint} at t = {t_s:.4f} s{where} is "
            f"{ratio:.3f} × its limit (checked every {cycle_s * 1e3:g} ms)"
        )
    return StreamPlan(cycle_s, q, qd, qdd, tau if feedforward else np.zeros_like(tau), report, smooth_sign)


def _held_within_torque_rate(
    robot: Robot, params: DynamicParameters, t: np.ndarray, q, qd, qdd, max_ratio: float
) -> tuple[np.ndarray, tuple[tuple[str, float], ...]]:
    """The model torque with the held Coulomb sign, except on a joint where the held sign alone takes
    the torque rate above ``max_ratio`` of its limit and the smooth sign's ratio there is lower: the
    planners time a stop with the smooth sign, whose fading friction offsets the end of the
    deceleration; held to rest, the friction no longer does (RX130L J2 at the end of the ISO line at
    0.1 m/s, rated load: 1.105 × its limit). That joint keeps the smooth sign, named in the result."""
    tau = model_torque(robot, params, q, qd, qdd, t[1] - t[0])
    rate = TorqueRateLimit(robot.tau_rate_max)
    held = rate.ratios(t, q, qd, qdd, tau).max(axis=0)
    if not np.any(held > max_ratio):
        return tau, ()
    smooth_tau = model_torque(robot, params, q, qd, qdd)
    smooth = rate.ratios(t, q, qd, qdd, smooth_tau).max(axis=0)
    back = (held > max_ratio) & (smooth < held)
    tau[:, back] = smooth_tau[:, back]
    return tau, tuple((robot.joint_names[j], float(held[j])) for j in np.flatnonzero(back))


def distance_to_start(robot: Robot, q_now: np.ndarray, q_start: np.ndarray) -> dict[str, float]:
    """Per joint |q_now − q_start| (rad), keyed by joint name."""
    d = np.abs(np.asarray(q_now, dtype=float) - np.asarray(q_start, dtype=float))
    return {name: float(v) for name, v in zip(robot.joint_names, d, strict=True)}
