"""What a generic controller's drives can follow without a torque feed-forward (issue 29).

The drives run a cascaded loop per axis (`rxcomm.cell.drives` simulates it; drives.yaml `servo` states
its tuning): position P (K_v = ω_v/γ) on a velocity PI (K_p = √((J_nom·ω_v)² + b_nom²), T_i = β/ω_v)
with a matched speed feed-forward, tuned on each axis' nominal inertia J_nom (`nominal_axis_inertia`)
and prior viscous friction b_nom (`velocity_gain`). Without a
torque feed-forward every torque the motion needs is built from the following error, and an axis
trips when that error leaves the window (0x8611). The catalogue limits (`rxcomm.model.catalogue`)
therefore bound the accelerations twice: by the peak torque, and so that the following error stays
within a stated fraction of the window. This module gives that second bound's terms:

- `peak_following_error`: the peak following error of the discrete loop (the cell's equations, drive
  cycle, speed feed-forward filter) on a rigid axis of its largest inertia with its friction
  (Coulomb stick–slip, viscous), for a move from rest at the generic controller's jerk ramp, with
  the velocity integrator at rest or holding the friction of a move the other way (a reversal);
- `tracking_bound`: per axis the largest acceleration whose peak error from rest stays within
  `TRACKING_FRACTION` (60 %) of the window and after a reversal within `REVERSAL_FRACTION` (90 %).
  The other axes' inertial coupling and the Coriolis torques are left to the rest: their worst case
  (every axis at its limit at the worst pose at once, as the torque bound takes it) would claim
  more than the window on the M900 sample, whose factory runs stay well within it. The reversal
  starts with the drive pushing −F_c and must swing to +F_c from the error before the axis breaks
  away: on a light wrist whose friction is large against its loop gain (MuJoCo Menagerie's ARX L5,
  J6: 0.005 kg·m², 0.3 N·m, K_p = 0.32 N·m·s/rad) that doubles the error, and the factory line,
  timed on the move from rest alone, tripped 0x8611 0.3 s after its approach.

On the RX130L sample the catalogue's torque bound leaves J6 a peak of 18 mrad (of 35); its drive
accelerations (scale 1.0) would give J6 40 mrad: the 0x8611 trip an RX160-class arm met (issue 29).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rxcomm.model.dynamics import RobotDynamics, prior_parameters
from rxcomm.model.robot import Robot
from rxcomm.schemas.drives import ServoLoops

VELOCITY_FILTER_S = 0.5e-3  # the velocity estimate's first-order filter (as the cell's drives)


def nominal_axis_inertia(robot: Robot, samples: int = 64, seed: int = 0) -> np.ndarray:
    """Mean diagonal of the prior mass matrix (links + reflected rotors) over random poses, kg·m²: the
    inertia the drives are tuned on (with the prior viscous friction: `velocity_gain`)."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.q_min, robot.q_max, (samples, robot.n))
    m = RobotDynamics(robot, prior_parameters(robot)).mass_matrix(q)
    return np.diagonal(m, axis1=1, axis2=2).mean(axis=0)


def velocity_gain(bandwidth_rad_s: float, j_nominal: np.ndarray, viscous_nominal: np.ndarray) -> np.ndarray:
    """K_p of the velocity PI tuned on the nominal axis 1/(J·s + b) for bandwidth ω_v: the P loop crosses
    over at ω_v, |K_p / (J·iω_v + b)| = 1, so K_p = √((J·ω_v)² + b²). It is J·ω_v where the viscous
    friction is small against J·ω_v (the samples: within 0.1 % on J1–J3); on an axis whose viscous
    friction dominates (a simulation model's stabilising damping on a light wrist without armature)
    J·ω_v alone leaves the loop a DC gain K_p/(K_p + b) of a few % and the axis trips 0x8611 on any move."""
    return np.hypot(np.asarray(j_nominal, float) * bandwidth_rad_s, np.asarray(viscous_nominal, float))


def peak_following_error(
    loops: ServoLoops,
    j_nominal: np.ndarray,
    j_plant: np.ndarray,
    cycle_s: float,
    accel: np.ndarray,
    v_max: np.ndarray,
    ramp_s: float,
    coulomb_nm: np.ndarray,
    viscous_nm_s: np.ndarray,
    disturbance_nm: np.ndarray,
    horizon_s: float = 0.8,
    viscous_nominal_nm_s: np.ndarray | None = None,
    integral_start_nm: np.ndarray | None = None,
) -> np.ndarray:
    """Peak |demand − actual| per axis (rad) of the drive loop (the cell's equations, rxcomm.cell.drives)
    without torque feed-forward, on a rigid axis of inertia `j_plant` with Coulomb (stick–slip) and
    viscous friction and a constant `disturbance_nm` opposing the motion (the other axes' coupling,
    Coriolis), for a demand from rest whose acceleration rises to `accel` in `ramp_s` (the generic
    controller's jerk) and holds until the speed reaches `v_max`; `integral_start_nm`: the velocity
    integrator's torque at the start (−coulomb_nm: a reversal). Every argument is per axis [n]."""
    w = loops.velocity_bandwidth_rad_s
    b_nom = np.zeros(len(j_nominal)) if viscous_nominal_nm_s is None else viscous_nominal_nm_s
    kv, kp = w / loops.position_gain_ratio, velocity_gain(w, j_nominal, b_nom)
    ki_dt = kp * cycle_s / (loops.integral_time_ratio / w)
    alpha = cycle_s / (VELOCITY_FILTER_S + cycle_s)
    n = len(j_nominal)
    q, v, enc, vel, d1, d2, vff, integ = (np.zeros(n) for _ in range(8))
    if integral_start_nm is not None:
        integ = np.array(integral_start_nm, dtype=float)
    dv, d, peak = np.zeros(n), np.zeros(n), np.zeros(n)
    for k in range(int(round(horizon_s / cycle_s))):
        vel = vel + alpha * ((q - enc) / cycle_s - vel)
        enc = q
        vff = vff + alpha * ((d1 - d2) / cycle_s - vff)
        ev = kv * (d1 - enc) + vff - vel
        u = kp * ev + integ
        integ = integ + ki_dt * ev
        a = np.where(dv < v_max, accel * min(k * cycle_s / ramp_s, 1.0) if ramp_s > 0 else accel, 0.0)
        dv = np.minimum(dv + a * cycle_s, v_max)
        d = d + dv * cycle_s
        d2, d1 = d1, d
        drive = u - disturbance_nm - viscous_nm_s * v
        moving = (v > 1e-9) | (drive > coulomb_nm)  # the demand moves forward: friction opposes it
        acc = np.where(moving, (drive - coulomb_nm) / j_plant, 0.0)
        v = np.where(moving, np.maximum(v + acc * cycle_s, 0.0), 0.0)
        q = q + v * cycle_s
        peak = np.maximum(peak, np.abs(d - q))
    return peak


TRACKING_FRACTION = 0.6  # of the following-error window an axis' own motion may use (the rest: coupling)
REVERSAL_FRACTION = 0.9  # the same after a reversal, the friction's worst start (the rest: coupling)


@dataclass(frozen=True)
class TrackingBound:
    """Per axis: the largest acceleration ≤ the given one whose own following error stays within
    `allowed_rad` from rest and `reversal_allowed_rad` after a reversal, the peak errors at it, and
    whether the bound cut the given acceleration."""

    a_max: np.ndarray
    peak_rad: np.ndarray
    allowed_rad: float
    binds: np.ndarray
    reversal_peak_rad: np.ndarray
    reversal_allowed_rad: float


def tracking_bound(
    robot: Robot,
    j_plant: np.ndarray,
    a_max: np.ndarray,
    v_max: np.ndarray,
    ramp_s: float,
    coulomb_nm: np.ndarray,
    viscous_nm_s: np.ndarray,
    fraction: float = TRACKING_FRACTION,
    iterations: int = 12,
    reversal_fraction: float = REVERSAL_FRACTION,
) -> TrackingBound:
    """The accelerations (≤ `a_max`) a generic controller's drives (drives.yaml `servo`, tuned on
    `nominal_axis_inertia`) follow without torque feed-forward with a peak following error ≤
    `fraction` of the window from rest and ≤ `reversal_fraction` after a reversal, on the axis'
    largest inertia `j_plant` with its friction (`peak_following_error`); bisection per axis where
    `a_max` itself exceeds either."""
    loops = robot.drives.servo
    window = loops.following_error_limit_rad
    allowed, reversal_allowed = fraction * window, reversal_fraction * window
    jn = nominal_axis_inertia(robot)
    a_max = np.asarray(a_max, float)
    zero = np.zeros(robot.n)
    coulomb = np.asarray(coulomb_nm, float)

    def peaks(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        args = (loops, jn, j_plant, robot.drives.cycle_s, a, v_max, ramp_s, coulomb, viscous_nm_s, zero)
        b_nom = np.asarray(robot.viscous_prior, float)
        rest = peak_following_error(*args, viscous_nominal_nm_s=b_nom)
        return rest, peak_following_error(*args, viscous_nominal_nm_s=b_nom, integral_start_nm=-coulomb)

    def within(a: np.ndarray) -> np.ndarray:
        rest, reversal = peaks(a)
        return (rest <= allowed) & (reversal <= reversal_allowed)

    binds = ~within(a_max)
    a = a_max
    if binds.any():
        lo, hi = np.zeros(robot.n), a_max.copy()
        for _ in range(iterations):
            mid = np.where(binds, (lo + hi) / 2, a_max)
            ok = within(mid)
            lo, hi = np.where(binds & ok, mid, lo), np.where(binds & ~ok, mid, hi)
        a = np.where(binds, lo, a_max)
    rest, reversal = peaks(a)
    return TrackingBound(a, rest, allowed, binds, reversal, reversal_allowed)
