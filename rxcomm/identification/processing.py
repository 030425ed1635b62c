"""Joint logs → filtered, differentiated, decimated regressor rows (`rxcomm.identification.fit`).

**Processing** (`preprocess`). Resampling onto a uniform grid when the sampling jitters; zero-phase
Butterworth low-pass (`scipy.signal.sosfiltfilt`) of positions *and* torques with the same filter, so
both keep the same phase and gain below the cut-off; q̇, q̈ by central differences of the filtered
positions; the ends trimmed (filter transients); decimation to `decimate_hz` (2 × the cut-off: the
filtered noise's sample-to-sample correlation is then 0.1, at 2.5 × it is 0.32, enough to make the
standard deviations, which assume uncorrelated rows, 15–25 % optimistic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import maximum_filter1d
from scipy.signal import butter, sosfiltfilt

from rxcomm.errors import InputError
from rxcomm.identification.logs import JointLog
from rxcomm.identification.settings import IdentifySettings
from rxcomm.model.dynamics import joint_torque_regressor
from rxcomm.model.robot import Robot


@dataclass(frozen=True, eq=False)
class Processed:
    """Filtered, differentiated, decimated samples: `t` [M], `q`, `qd`, `qdd`, `tau` [M, n], and
    `coulomb` [M, n]: sgn(q̇) taken at the source rate and low-passed like the torque; `near_stick`
    [M, n]: within the stick guard of a sample where the joint was slower than min_speed_rad_s;
    `motor_coulomb` [M, n]: sgn(R·q̇) of the motors, filtered alike (None without a robot);
    `coulomb_predicted`, `motor_coulomb_predicted`: the same of `predicted_sign` — the prediction's
    friction shape: zero velocity at standstill, never the sign of the noise in q̇ (the fit's rows
    keep away from standstill, `near_stick`); `standing` [M, n]: where that sign is 0 (the joint
    stands, its friction anywhere in ±Fc)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    coulomb: np.ndarray
    near_stick: np.ndarray
    sample_hz: float
    source_hz: float
    motor_coulomb: np.ndarray | None = None
    coulomb_predicted: np.ndarray | None = None
    motor_coulomb_predicted: np.ndarray | None = None
    standing: np.ndarray | None = None

    def window(self, t0: float, t1: float) -> Processed:
        return self.select((self.t >= t0) & (self.t < t1))

    def select(self, k: np.ndarray) -> Processed:
        """The rows where the boolean mask `k` [M] is true."""
        return replace(
            self,
            t=self.t[k],
            q=self.q[k],
            qd=self.qd[k],
            qdd=self.qdd[k],
            tau=self.tau[k],
            coulomb=self.coulomb[k],
            near_stick=self.near_stick[k],
            motor_coulomb=None if self.motor_coulomb is None else self.motor_coulomb[k],
            coulomb_predicted=None if self.coulomb_predicted is None else self.coulomb_predicted[k],
            motor_coulomb_predicted=(
                None if self.motor_coulomb_predicted is None else self.motor_coulomb_predicted[k]
            ),
            standing=None if self.standing is None else self.standing[k],
        )


def predicted_sign(v: np.ndarray, v_min: float | np.ndarray) -> np.ndarray:
    """The Coulomb sign the prediction takes for velocities `v` [N, k]: sgn(v) where a column is at
    least `v_min` fast (per column), and inside each run slower than that the sign it had until v
    first reaches zero, the sign it leaves with from where v last left zero, and 0 between: a joint
    standing still has its friction anywhere in ±Fc and its q̇ is noise around zero, while one that
    only slows (a dip to 0.0035 rad/s), reverses (a smooth reversal at 0.16 rad/s² takes 60 ms to
    cross ±5 mrad/s) or creeps to a stop still slides, in the direction it moves."""
    v = np.asarray(v, dtype=float)
    lim = np.broadcast_to(np.asarray(v_min, dtype=float), v.shape[1:])
    out = np.where(np.abs(v) >= lim, np.sign(v), 0.0)
    for j in range(v.shape[1]):
        slow = np.concatenate([[False], np.abs(v[:, j]) < lim[j], [False]])
        edges = np.flatnonzero(np.diff(slow.astype(np.int8)))
        for a, b in zip(edges[::2], edges[1::2], strict=True):  # runs v[a:b] below the band
            sign = np.sign(v[a:b, j])
            if a > 0:
                other = np.flatnonzero(sign != out[a - 1, j])
                out[a : a + (other[0] if other.size else b - a), j] = out[a - 1, j]
            if b < len(v):
                other = np.flatnonzero(sign != out[b, j])
                out[a + (other[-1] + 1 if other.size else 0) : b, j] = out[b, j]
    return out


def preprocess(log: JointLog, settings: IdentifySettings, robot: Robot | None = None) -> Processed:
    """Zero-phase low-pass, differentiation, trimming, decimation (module docstring); with `robot`,
    the motors' filtered Coulomb shapes too (motor friction columns)."""
    step = float(np.median(np.diff(log.t)))
    fs = 1.0 / step
    fc = settings.cutoff
    if fc >= 0.45 * fs:
        raise InputError(
            f"cutoff_hz {fc} is not below the log's Nyquist frequency ({fs / 2:.1f} Hz)",
            file=log.source or None,
        )
    sos = butter(settings.filter_order, fc, fs=fs, output="sos")
    # Odd extension over 2/fc at the ends: the filter's start-up transient stays in the trimmed part.
    pad = min(len(log.t) - 1, int(2.0 * fs / fc))
    lag = log.torque_lag_s if settings.torque_lag_s is None else settings.torque_lag_s
    tau = log.tau
    if lag:  # the torque that acted at t (the ends, clamped, are trimmed below)
        tau = np.column_stack([np.interp(log.t + lag, log.t, c) for c in tau.T])
    q = sosfiltfilt(sos, log.q, axis=0, padlen=pad)
    tau = sosfiltfilt(sos, tau, axis=0, padlen=pad)
    qd = np.gradient(q, step, axis=0)
    qdd = np.gradient(qd, step, axis=0)
    # Parallel filtering of the one discontinuous column: the measured torque's Coulomb jumps are
    # smeared by the low-pass over ~1/cutoff, so the regressor's sgn(q̇) gets the same filter.
    coulomb = sosfiltfilt(sos, np.sign(qd), axis=0, padlen=pad)
    v_min = settings.standstill_speed_rad_s
    sign_predicted = predicted_sign(qd, v_min)
    coulomb_predicted = sosfiltfilt(sos, sign_predicted, axis=0, padlen=pad)
    motor = motor_predicted = None
    if robot is not None and robot.has_motor_friction:
        vm = qd @ robot.joint_to_motor.T
        motor = sosfiltfilt(sos, np.sign(vm), axis=0, padlen=pad)
        scale = np.abs(np.diag(robot.joint_to_motor))  # a motor's speed in its axis's joint units
        motor_predicted = sosfiltfilt(sos, predicted_sign(vm, v_min * scale), axis=0, padlen=pad)
    guard = 1.0 / fc if settings.stick_guard_s is None else settings.stick_guard_s
    slow = np.abs(qd) < settings.min_speed_rad_s
    if robot is not None and robot.has_motor_friction and robot.coupled_motors:
        # A coupled motor sticks when its own velocity R_i·q̇ passes zero, whatever its joints do:
        # then its friction is static too, on every joint it loads (speed in its axis's joint units).
        r = robot.joint_to_motor
        for i in robot.coupled_motors:
            motor_slow = np.abs(qd @ r[i]) < settings.min_speed_rad_s * abs(r[i, i])
            slow |= motor_slow[:, None] & (r[i] != 0)[None, :]
    near_stick = maximum_filter1d(slow, size=2 * int(round(guard * fs)) + 1, axis=0)
    trim = 2.0 / fc if settings.trim_s is None else settings.trim_s
    k0 = int(math.ceil(trim / step))
    stride = max(1, int(round(fs / settings.decimate)))
    idx = np.arange(k0, len(log.t) - k0, stride)
    if len(idx) < 10:
        raise InputError(
            f"the log is too short ({log.t[-1] - log.t[0]:.2f} s) for {trim:.2f} s of trimming at each end",
            file=log.source or None,
            field="t",
        )
    return Processed(
        log.t[idx],
        q[idx],
        qd[idx],
        qdd[idx],
        tau[idx],
        coulomb[idx],
        near_stick[idx],
        fs / stride,
        fs,
        None if motor is None else motor[idx],
        coulomb_predicted[idx],
        None if motor_predicted is None else motor_predicted[idx],
        sign_predicted[idx] == 0,
    )


def regressor(robot: Robot, data: Processed) -> np.ndarray:
    """Full regressor Y [M·n, P] (rows sample-major) of processed samples, with the parallel-filtered
    Coulomb columns: then filtered τ = Y·p holds as τ = Y·p does before filtering."""
    n = robot.n
    y = joint_torque_regressor(robot, data.q, data.qd, data.qdd)
    y3 = y.reshape(len(data.t), n, -1)
    idx = np.arange(n)
    if robot.friction_mode != "motor":
        y3[:, idx, 11 * n + idx] = data.coulomb
    if robot.has_motor_friction:
        if data.motor_coulomb is None:
            raise ValueError("motor friction columns need the data preprocessed with the robot")
        m0 = 14 * n + (2 if robot.drives.spring is not None else 0)
        y3[:, :, m0 : m0 + n] = robot.joint_to_motor.T[None, :, :] * data.motor_coulomb[:, None, :]
    return y
