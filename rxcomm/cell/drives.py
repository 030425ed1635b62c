"""The simulated cell's servo drives: per-axis cascaded loops, cyclic synchronous position (architecture §6).

Everything is joint side, one loop per axis. Timing convention (one drive cycle T, the
robot's `drives.yaml` cycle): the demand d_k the gateway hands over in cycle k is the position the
axis should have at the END of cycle k, and the feed-forward torque τ_ff,k is the torque for cycle k.
So a perfectly followed stream reports position actual = demand in the same cycle, and a master
compares trace record k with setpoint k. Per cycle k, with the encoder reading e_k at its start:

    velocity estimate  v̂   = first-order filter (T_f) of the encoder increments (e_k − e_{k−1})/T
    speed feed-forward v_ff = the same filter on the demand increments (d_{k−1} − d_{k−2})/T
    position P         v_ref = K_v·(d_{k−1} − e_k) + v_ff
    velocity PI        τ_fb  = K_p·(v_ref − v̂) + I,     I += K_p·T/T_i·(v_ref − v̂)
    0x60B2             τ     = sat(τ_fb + τ_ff, ±τ_peak)

The speed feed-forward is the demand differentiated and filtered like the measurement (a *matched*
feed-forward, as drives offer to avoid kicking the velocity loop): on a perfectly followed demand the
feedback torque is exactly zero, so the feed-forward torque alone moves the arm and the loops only
correct model errors — the paper's eq. (7) with K_p(q_d − q) + K_d(q̇_d − q̇) as the feedback.
Without a torque feed-forward the loops must build every torque (inertia, friction, Coriolis) from
errors: that is the lag of the paper's Fig. 2 "standard" case.

Tuning (like a drive commissioned on the nominal robot, not on the truth): velocity loop bandwidth
ω_v for every axis, K_p = √((J_i·ω_v)² + b_i²) with J_i the axis inertia of the PRIOR model (mean
diagonal of the mass matrix incl. reflected rotor inertia over seeded random poses) and b_i its prior
viscous friction (drives.yaml): the P loop on 1/(J_i·s + b_i) crosses over at ω_v, J_i·ω_v where b_i is
small against it (the samples' J1–J3 within 0.1 %; a simulation model's stabilising damping on a light
wrist is not, rxcomm.model.servo.velocity_gain), integral corner ω_v/β
(T_i = β/ω_v), position gain K_v = ω_v/γ. Anti-windup: the integrator stops while the output is
saturated in the error's direction and is clamped to ±τ_peak. The position demand is clamped to the
joint's software limits (the URDF's), as CiA 402 drives do (0x607D): a master pushing beyond them sees
the following error grow until the trip. A disabled axis keeps its integrator (the drive's
holding-torque memory) and preloads it when re-enabled, so releasing the brake does not let the arm
sag; at the first enable after power-on it is zero and the integrators build the holding torque
(a run without feed-forward on a cell it started hands them the model's static torque first,
`rxcomm.execution.handover`: a light wrist otherwise sags past the trip window).

Defaults and why: ω_v = 60 rad/s, K_v = 15 /s, T_i = 67 ms, T_f = 0.5 ms. Measured on the RX130L
sample: without feed-forward a J1–J3 move at 70 % of the velocity limits lags ≈ 1.4/1.9/1.8 mrad
(TCP ≈ 5 mm at ≈ 2.5 m/s), ≈ 2 mm at 1 m/s TCP — the millimetre lag of the paper's Fig. 2 standard
case; with the true model's feed-forward ≈ 5–12 µrad. Twice the bandwidth cuts the standard lag ≈ 4×
(it scales ≈ 1/ω_v²), which would hide what model-based feed-forward is for. The velocity loop's
phase margin at 2.5 kHz is large (T_f·ω_v = 0.03 rad). Friction sets the hold accuracy: a wrist axis
whose static torque exceeds its Coulomb friction slips, sticks and is freed by the integrator after
≈ 1–2 s (stick-slip, as on real arms). Following-error trip 35 mrad (≈ 20× the worst standard lag,
below what a stalled axis reaches in 0.1 s); quick stop at 1.5 × drives.yaml's acceleration limit
(5 mrad worst lag from full speed without feed-forward).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field

from rxcomm.model.robot import Robot
from rxcomm.model.servo import nominal_axis_inertia, velocity_gain
from rxcomm.schemas.drives import ServoLoops
from rxcomm.schemas.strict import Strict

_LOOPS = ServoLoops()  # the defaults a maker's data sheet (drives.yaml `servo`) states


class DriveTuning(Strict):
    """How the drives are tuned (all axes alike; per-axis gains follow from the prior inertias)."""

    velocity_bandwidth_rad_s: float = Field(
        _LOOPS.velocity_bandwidth_rad_s, gt=0, description="velocity loop bandwidth ω_v (K_p = J·ω_v), rad/s"
    )
    position_gain_ratio: float = Field(
        _LOOPS.position_gain_ratio, gt=1, description="γ: position gain K_v = ω_v/γ, 1/s"
    )
    integral_time_ratio: float = Field(
        _LOOPS.integral_time_ratio, gt=0, description="β: integral time T_i = β/ω_v"
    )
    velocity_filter_s: float = Field(0.5e-3, ge=0, description="T_f of the velocity estimate, s")
    following_error_limit_rad: float = Field(
        _LOOPS.following_error_limit_rad,
        gt=0,
        description="|demand − actual| above this trips the axis (0x8611), rad",
    )
    quick_stop_decel_ratio: float = Field(
        1.5, gt=0, description="quick-stop deceleration = this × drives.yaml acceleration_max"
    )
    inertia_samples: int = Field(64, ge=1, description="random poses averaged for the nominal inertia")
    inertia_seed: int = 0


@dataclass(frozen=True, eq=False)
class DriveGains:
    """Per-axis gains and limits (arrays of shape (n,)), joint side, SI."""

    cycle_s: float
    velocity_bandwidth_rad_s: float  # ω_v the velocity loops are tuned for (velocity_gain)
    nominal_inertia_kgm2: np.ndarray
    kv_per_s: np.ndarray  # position P
    kp_nm_s_per_rad: np.ndarray  # velocity P
    ti_s: np.ndarray  # velocity integral time
    velocity_filter_s: float
    peak_torque_nm: np.ndarray
    position_min_rad: np.ndarray  # software position limits (0x607D): the demand is clamped to them
    position_max_rad: np.ndarray
    following_error_limit_rad: np.ndarray
    quick_stop_decel_rad_s2: np.ndarray

    @property
    def n(self) -> int:
        return len(self.kv_per_s)


def drive_gains(robot: Robot, tuning: DriveTuning | None = None) -> DriveGains:
    """Gains of drives commissioned on the nominal `robot` (see the module docstring)."""
    t = tuning or DriveTuning()
    j = nominal_axis_inertia(robot, t.inertia_samples, t.inertia_seed)
    w = t.velocity_bandwidth_rad_s
    n = robot.n
    return DriveGains(
        cycle_s=robot.drives.cycle_s,
        velocity_bandwidth_rad_s=w,
        nominal_inertia_kgm2=j,
        kv_per_s=np.full(n, w / t.position_gain_ratio),
        kp_nm_s_per_rad=velocity_gain(w, j, np.asarray(robot.viscous_prior, float)),
        ti_s=np.full(n, t.integral_time_ratio / w),
        velocity_filter_s=t.velocity_filter_s,
        peak_torque_nm=np.array(robot.tau_max, dtype=float),
        position_min_rad=np.array(robot.q_min, dtype=float),
        position_max_rad=np.array(robot.q_max, dtype=float),
        following_error_limit_rad=np.full(n, t.following_error_limit_rad),
        quick_stop_decel_rad_s2=t.quick_stop_decel_ratio * np.array(robot.a_max, dtype=float),
    )


class CascadedDrives:
    """The loops of all axes. Call `measure` with each new encoder reading (after every plant step) and
    `control` once per cycle before the plant step; arrays are (n,).

    The per-cycle work is plain float arithmetic per axis (as a drive does it): for six axes that is
    several times cheaper than numpy's per-call overhead on 6-vectors.
    """

    def __init__(self, gains: DriveGains, encoder_rad: np.ndarray):
        self.gains = gains
        self.n = gains.n
        self._dt = gains.cycle_s
        self._alpha = gains.cycle_s / (gains.velocity_filter_s + gains.cycle_s)
        self._kv = gains.kv_per_s.tolist()
        self._kp = gains.kp_nm_s_per_rad.tolist()
        self._ki_dt = (gains.kp_nm_s_per_rad * gains.cycle_s / gains.ti_s).tolist()
        self._peak = gains.peak_torque_nm.tolist()
        self._qmin = gains.position_min_rad.tolist()
        self._qmax = gains.position_max_rad.tolist()
        e = [float(x) for x in encoder_rad]
        self._enc = e
        self._vel = [0.0] * self.n  # v̂, rad/s
        self._d1 = list(e)  # d_{k-1}
        self._d2 = list(e)  # d_{k-2}
        self._vff = [0.0] * self.n
        self._integral = [0.0] * self.n  # N·m, kept while disabled (holding-torque memory)
        self._enabled = [False] * self.n
        self._torque = [0.0] * self.n

    @property
    def encoder(self) -> np.ndarray:
        return np.array(self._enc)

    @property
    def velocity(self) -> np.ndarray:
        """The velocity estimate v̂ (rad/s)."""
        return np.array(self._vel)

    @property
    def integral(self) -> np.ndarray:
        return np.array(self._integral)

    @property
    def torque(self) -> np.ndarray:
        """The torque commanded in the last cycle (after saturation), N·m."""
        return np.array(self._torque)

    def measure(self, encoder_rad: np.ndarray) -> None:
        """A new encoder reading at the end of a cycle (start of the next): updates v̂."""
        e = encoder_rad.tolist()
        a, dt, vel, old = self._alpha, self._dt, self._vel, self._enc
        for i in range(self.n):
            vel[i] += a * ((e[i] - old[i]) / dt - vel[i])
        self._enc = e

    def control(self, demand_rad: np.ndarray, torque_ff_nm: np.ndarray, enabled: np.ndarray) -> np.ndarray:
        """Torque for this cycle (saturated; 0 on disabled axes) given demand d_k and τ_ff,k."""
        dem, ff, on = demand_rad.tolist(), torque_ff_nm.tolist(), np.asarray(enabled, dtype=bool).tolist()
        a, dt = self._alpha, self._dt
        enc, vel, d1, d2, vff, integ = self._enc, self._vel, self._d1, self._d2, self._vff, self._integral
        out = self._torque
        for i in range(self.n):
            if not on[i]:  # torque off, brake on: the demand history follows the actual position
                d1[i] = d2[i] = enc[i]
                vff[i] = out[i] = 0.0
                self._enabled[i] = False
                continue
            if not self._enabled[i]:  # enabling: no jump, the integrator keeps its holding torque
                d1[i] = d2[i] = enc[i]
                vff[i] = 0.0
                self._enabled[i] = True
            vff[i] += a * ((d1[i] - d2[i]) / dt - vff[i])
            ev = self._kv[i] * (d1[i] - enc[i]) + vff[i] - vel[i]
            u = self._kp[i] * ev + integ[i] + ff[i]
            peak = self._peak[i]
            # anti-windup: no integration while saturated in the direction the error pushes
            if u > peak:
                tau = peak
                if ev < 0.0:
                    integ[i] += self._ki_dt[i] * ev
            elif u < -peak:
                tau = -peak
                if ev > 0.0:
                    integ[i] += self._ki_dt[i] * ev
            else:
                tau = u
                integ[i] += self._ki_dt[i] * ev
            integ[i] = min(max(integ[i], -peak), peak)
            d2[i] = d1[i]
            d1[i] = min(max(dem[i], self._qmin[i]), self._qmax[i])  # never drives past its limits
            out[i] = tau
        return np.array(out)
