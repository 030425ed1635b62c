"""Dynamic parameter identification from joint logs (paper §4.1, §4.3; architecture §7 identify).

**Input.** A `JointLog` (t, q, τ at the joint side) from a run log MCAP (topic ``/run/joints``:
``q_actual`` rad, ``tau_actual`` N·m as the drives report it) or from a real robot's CSV
(`rxcomm.model.robot_csv`, docs/identify-csv.md). `check_log` refuses duplicated or non-monotonic time
stamps, gaps longer than `max_gap_s` (shorter ones, and lost records (NaN rows), are bridged
linearly), a joint count other than the robot's and torques at the drives' peak (saturated: the
measured torque is then not the one the model predicts).

**Alignment.** A run log's record pairs the position at the *end* of a drive cycle with the torque
commanded *during* it (docs/gateway.md §4.5): that torque accelerated the arm from the position one
cycle earlier, so it is paired with the position sampled `torque_lag_s` = one drive cycle before
its record (`JointLog.torque_lag_s`; 0 for a CSV unless `IdentifySettings.torque_lag_s` says
otherwise). Left unaligned, the 0.4 ms skew leaves h·dτ/dt in the residual (≈ 0.1 N·m rms on J2),
which the fit absorbs into friction.

**Processing** (`preprocess`). Resampling onto a uniform grid when the sampling jitters; zero-phase
Butterworth low-pass (`scipy.signal.sosfiltfilt`) of positions *and* torques with the same filter, so
both keep the same phase and gain below the cut-off; q̇, q̈ by central differences of the filtered
positions; the ends trimmed (filter transients); decimation to `decimate_hz` (2 × the cut-off: the
filtered noise's sample-to-sample correlation is then 0.1, at 2.5 × it is 0.32, enough to make the
standard deviations, which assume uncorrelated rows, 15–25 % optimistic).

**Estimation** (`estimate`). τ = Y(q, q̇, q̈)·p with `rxcomm.model.dynamics.joint_torque_regressor` (links,
rotor inertia, Coulomb (exact sign), viscous, offset, spring, and with drives.yaml `friction: motor|both`
the motors' Coulomb and viscous friction through Rᵀ), reduced to the base parameters
(`BaseParameterSet`, the paper's κ regrouping, recorded in dynamics.yaml). Rows of joint j where
|q̇_j| < `min_speed_rad_s` are rejected: there the Coulomb term's sign is uncertain and the real
friction (stiction) is not Fc·sgn(q̇). So are the rows within `stick_guard_s` (default 1/cutoff) of
such a sample at the source rate: the low-pass spreads the stick phase's friction (anything within
±Fc) over that time, which parallel filtering of sgn(q̇) cannot reproduce; near reversals the
residual is 2–6× the noise, beyond 1/cutoff at the noise. A coupled motor with friction sticks when
its own velocity R_i·q̇ passes zero, so its slow samples guard every joint it loads: without that
guard a simulated motor-6 stiction of 0.027 N·m came out 4σ low on the cell, with it 0.2σ.
Ordinary least squares, then weighted least squares with each joint's rows divided by its noise
standard deviation σ_j² = ‖r_j‖²/(m_j − p)
from the OLS residuals (Gautier's WLS); covariance (WᵀΣ⁻¹W)⁻¹ and relative standard deviations
σ_p/|p|. Normal equations on unit-norm columns (cond ≲ 10³ here) keep every decomposition p × p. A
regressor whose unit-column condition number exceeds `max_cond` is refused, naming the base
parameters the log does not excite.

**Physical consistency.** A base estimate is realisable by a physical robot if some full parameter
vector with K·p = p_b has every link's pseudo-inertia J = [[½tr(I)·1 − I, m·c], [(m·c)ᵀ, m]]
positive definite (Wensing et al. 2017) and non-negative rotor inertias, friction and spring. Always
reported: the minimum eigenvalue of each link's J for the full vector closest to the prior
(`parameters_from_base`), and the Mahalanobis distance √((p_b* − p̂)ᵀ·Λ·(p_b* − p̂)) (Λ the
information matrix WᵀΣ⁻¹W) from the unconstrained estimate p̂ to the nearest consistent p_b* —
in standard deviations: ≲ √p means "consistent within the noise". `physical_fit` finds p_b*: a
log-Cholesky parametrisation J = U·Uᵀ (U upper triangular, positive diagonal exp(·)) of each link and
bounds on the drive parameters, scipy least squares on ‖R·(K·p(θ) − p̂)‖ (Λ = RᵀR) with a small
pull towards the prior for the directions the data do not see, started from the prior. With
`physical=True` its full vector is the result.

**Validation** (`validate`). Torques predicted from the processed states of another log (an ISO
9283-like path) against its filtered measured torques, the plain prediction (nothing clipped): per
joint on the rows where it moves, RMS (N·m), NRMSE = RMS error / (max − min) of the measured torque
and R²; standstill rows apart (the share inside the stiction band). A joint that did not move is not
scored (NaN here, null in the summary), never 0. Clipping standstill predictions into the ±Fc band,
as this module once did, printed J4 of `make commission`'s ISO circle as 0 N·m where its plain
error is 1.9 N·m (static friction inside the band). Without a validation log the last
`holdout_fraction` of each of `holdout_blocks` blocks of the log is held out (`holdout_mask`); the
last part alone is often standstill on real recordings. `score` checks a model on a new log.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
import scipy.linalg as sla
from pydantic import BaseModel, ConfigDict, Field
from scipy.ndimage import maximum_filter1d
from scipy.optimize import least_squares
from scipy.signal import butter, sosfiltfilt

from rxcomm.errors import InputError
from rxcomm.io.run_log import read_run_log
from rxcomm.model.base_parameters import (
    BaseParameterSet,
    base_parameters,
    parameter_scale,
    parameters_from_base,
)
from rxcomm.model.dynamics import (
    DynamicParameters,
    joint_torque_regressor,
    parameter_names,
    prior_parameters,
)
from rxcomm.model.robot import Robot
from rxcomm.model.robot_csv import check_positions, read_robot_csv
from rxcomm.schemas.run_log import JOINTS_TOPIC

NRMSE_NORMALISATION = "range"  # RMS error / (max − min) of the measured torque, per joint


class IdentifySettings(BaseModel):
    """Options of `rxcomm identify` (units in the names)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    cutoff_hz: float = Field(10.0, gt=0, description="low-pass cut-off of positions and torques")
    filter_order: int = Field(4, ge=1, le=8, description="Butterworth order (doubled by the zero-phase pass)")
    decimate_hz: float = Field(
        20.0,
        gt=0,
        description="sample rate after filtering and differentiation (2 × cutoff: rows uncorrelated)",
    )
    min_speed_rad_s: float = Field(
        0.05, ge=0, description="rows of a joint slower than this are rejected (friction sign uncertain)"
    )
    method: Literal["wls", "ols"] = Field("wls", description="weighted (per-joint noise) or ordinary LS")
    physical: bool = Field(False, description="write the physically consistent estimate")
    holdout_fraction: float = Field(
        0.2, gt=0, lt=0.9, description="part of the log held out for validation without --validate"
    )
    holdout_blocks: int = Field(
        5,
        ge=1,
        description="without --validate the log is cut into this many blocks and the last holdout_fraction "
        "of each is held out (interleaved: a log that ends at standstill still validates on motion; "
        "1 = the last part of the log)",
    )
    friction: Literal["joint", "motor", "both"] | None = Field(
        None, description="friction model; None: drives.yaml's (`Robot.friction_mode`)"
    )
    min_rows_per_parameter: float = Field(
        10.0, gt=0, description="fewer fit rows per base parameter than this gets a warning and a suggestion"
    )
    max_cond: float = Field(
        1e4, gt=1, description="refuse a log whose unit-column base regressor is worse conditioned"
    )
    max_gap_s: float = Field(0.01, ge=0, description="longer gaps (or lost-record runs) are an error")
    torque_lag_s: float | None = Field(
        None,
        description="the torque paired with a position sample is logged this much later; "
        "None: the log's own (one drive cycle for a run log, 0 for a CSV)",
    )
    stick_guard_s: float | None = Field(
        None, ge=0, description="rows this close to a joint's slow sample are rejected; default 1/cutoff_hz"
    )
    saturation_fraction: float = Field(
        0.995, gt=0, le=1, description="|τ| at or above this fraction of peak torque counts as saturated"
    )
    trim_s: float | None = Field(None, ge=0, description="trimmed at each end; default 2/cutoff_hz")


# ------------------------------------------------------------------------------------------------
# Logs


@dataclass(frozen=True, eq=False)
class JointLog:
    """Joint-side samples: `t` [N] s, `q` [N, n] rad, `tau` [N, n] N·m; `source` the file.

    `torque_lag_s`: the torque that acted at a position sample's instant is logged this much later
    (one drive cycle in a run log, see the module docstring). `cycles_per_sample`: drive cycles per
    record (a run's interpolation ratio R): with R > 1 each torque is one cycle's of R, taken at one
    phase of the setpoint interpolation, which biases the inertias (≈ 0.3 % on J2 at R = 3)."""

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    source: str = ""
    torque_lag_s: float = 0.0
    cycles_per_sample: int = 1

    def __post_init__(self) -> None:
        for f in ("t", "q", "tau"):
            a = np.array(getattr(self, f), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, f, a)
        if (
            self.t.ndim != 1
            or self.q.ndim != 2
            or self.q.shape != self.tau.shape
            or len(self.t) != len(self.q)
        ):
            raise ValueError(
                f"t [N], q and tau [N, n] expected, got {self.t.shape}, {self.q.shape}, {self.tau.shape}"
            )

    @property
    def n(self) -> int:
        return int(self.q.shape[1])

    def window(self, t0: float, t1: float) -> JointLog:
        """Samples with t0 ≤ t < t1."""
        k = (self.t >= t0) & (self.t < t1)
        return replace(self, t=self.t[k], q=self.q[k], tau=self.tau[k])


def load_joint_log(path: str | Path, robot: Robot | None = None) -> JointLog:
    """A run log MCAP (kind rxcomm/RunLog, topic /run/joints: q_actual, tau_actual) or a real robot's
    CSV (needs `robot` for gear ratios, coupling, torque constants and signs)."""
    path = Path(path)
    if path.suffix == ".csv":
        if robot is None:
            raise ValueError("reading a robot CSV needs the robot (gear ratios, coupling, torque constants)")
        csv = read_robot_csv(path, robot)
        return JointLog(csv.t, csv.q, csv.tau, str(path))
    if not path.name.endswith((".mcap", ".mcap.part")):
        raise InputError("expected a run log (.mcap) or a robot CSV (.csv)", file=path)
    run_log = read_run_log(path, fields=("q_actual", "tau_actual"))
    td = run_log.joints
    for name in ("q_actual", "tau_actual"):
        if td[name].ndim != 2:
            raise InputError("expected a vector per message", file=path, field=f"{JOINTS_TOPIC}.{name}")
    if td["q_actual"].shape != td["tau_actual"].shape:
        raise InputError(
            f"q_actual has {td['q_actual'].shape[1]} joints, tau_actual {td['tau_actual'].shape[1]}",
            file=path,
            field=f"{JOINTS_TOPIC}.tau_actual",
        )
    summary = run_log.summary
    try:  # the drive cycle: records are R drive cycles apart
        ratio = int(summary["interpolation_ratio"])
        cycle_s = float(summary["sample_s"]) / ratio
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        if robot is None:
            raise InputError(
                "the run log's summary lacks sample_s / interpolation_ratio (the drive cycle)",
                file=path,
                field="summary",
            ) from None
        cycle_s, ratio = robot.drives.cycle_s, 1
    return JointLog(td.t, td["q_actual"], td["tau_actual"], str(path), cycle_s, max(ratio, 1))


def check_log(log: JointLog, robot: Robot, settings: IdentifySettings) -> JointLog:
    """Refuse what identification cannot use (see the module docstring); bridge short gaps and lost
    records; return the log on a clean time base."""
    file = log.source or None
    if log.n != robot.n:
        raise InputError(
            f"joint count mismatch: the log has {log.n} joints, the robot {robot.name!r} has {robot.n}",
            file=file,
            field="q",
        )
    t = log.t
    if len(t) < 10:
        raise InputError(f"only {len(t)} samples", file=file, field="t")
    dt = np.diff(t)
    if np.any(dt == 0):
        i = int(np.argmax(dt == 0))
        raise InputError(
            f"duplicated time stamp {t[i]:.6f} s (samples {i} and {i + 1})", file=file, field="t"
        )
    if np.any(dt < 0):
        i = int(np.argmax(dt < 0))
        raise InputError(
            f"time stamps not monotonic: {t[i + 1]:.6f} s after {t[i]:.6f} s (sample {i + 1})",
            file=file,
            field="t",
        )
    step = float(np.median(dt))
    if log.source.endswith((".mcap", ".mcap.part")):  # a CSV's columns are checked by its reader
        check_positions(log.q, robot, [f"q_actual[{j}]" for j in robot.joint_names], file)
    finite = np.isfinite(log.q).all(axis=1) & np.isfinite(log.tau).all(axis=1)
    if finite.sum() < 10:
        raise InputError("fewer than 10 samples with finite values", file=file, field="q")
    # Gaps: time steps or runs of lost records (NaN rows) longer than max_gap_s.
    tf = t[finite]
    gaps = np.diff(tf)
    worst = int(np.argmax(gaps))
    if gaps[worst] > max(settings.max_gap_s, 1.5 * step):
        raise InputError(
            f"gap of {gaps[worst]:.4f} s in the samples at {tf[worst]:.4f} s (longer than max_gap_s = "
            f"{settings.max_gap_s} s); split the log or record it again",
            file=file,
            field="t",
        )
    peak = settings.saturation_fraction * robot.tau_max
    sat = np.abs(log.tau[finite]) >= peak
    if sat.any():
        j = int(np.argmax(sat.sum(axis=0)))
        i = int(np.argmax(sat[:, j]))
        raise InputError(
            f"saturated torque: {robot.joint_names[j]} at {tf[i]:.4f} s reaches "
            f"{log.tau[finite][i, j]:.1f} N·m (peak {robot.tau_max[j]:.0f} N·m; "
            f"{int(sat[:, j].sum())} samples): the drive limited it, the model cannot explain it; "
            "reduce the excitation (torque_fraction) and record again",
            file=file,
            field="tau",
        )
    # Uniform time base (lost records and jitter bridged linearly; the low-pass follows).
    jitter = np.abs(dt - step).max() / step
    if finite.all() and jitter < 0.01:
        return log
    n_steps = int(round((tf[-1] - tf[0]) / step))
    tu = tf[0] + np.arange(n_steps + 1) * step
    q = np.column_stack([np.interp(tu, tf, c) for c in log.q[finite].T])
    tau = np.column_stack([np.interp(tu, tf, c) for c in log.tau[finite].T])
    return replace(log, t=tu, q=q, tau=tau)


# ------------------------------------------------------------------------------------------------
# Processing


@dataclass(frozen=True, eq=False)
class Processed:
    """Filtered, differentiated, decimated samples: `t` [M], `q`, `qd`, `qdd`, `tau` [M, n], and
    `coulomb` [M, n]: sgn(q̇) taken at the source rate and low-passed like the torque; `near_stick`
    [M, n]: within the stick guard of a sample where the joint was slower than min_speed_rad_s;
    `motor_coulomb` [M, n]: sgn(R·q̇) of the motors, filtered alike (None without a robot)."""

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
        )


def preprocess(log: JointLog, settings: IdentifySettings, robot: Robot | None = None) -> Processed:
    """Zero-phase low-pass, differentiation, trimming, decimation (module docstring); with `robot`,
    the motors' filtered Coulomb shapes too (motor friction columns)."""
    step = float(np.median(np.diff(log.t)))
    fs = 1.0 / step
    fc = settings.cutoff_hz
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
    motor = None
    if robot is not None and robot.has_motor_friction:
        motor = sosfiltfilt(sos, np.sign(qd @ robot.joint_to_motor.T), axis=0, padlen=pad)
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
    stride = max(1, int(round(fs / settings.decimate_hz)))
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


# ------------------------------------------------------------------------------------------------
# Estimation


@dataclass(frozen=True, eq=False)
class Estimate:
    """A base-parameter estimate: `p_b`, covariance `cov`, `relative_std` (σ/|p|), per-joint noise
    `sigma_joint_nm` (from the residuals of the method's weighting), `info` = WᵀΣ⁻¹W, the unit-column
    condition numbers, rows used/rejected, fit residual RMS per joint."""

    p_b: np.ndarray
    cov: np.ndarray
    relative_std: np.ndarray
    sigma_joint_nm: np.ndarray
    info: np.ndarray
    cond: float
    cond_raw: float
    n_rows: int
    n_rejected: int
    residual_rms_nm: np.ndarray
    p_ols: np.ndarray


def _solve_normal(w: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p, (WᵀW)⁻¹, WᵀW) by normal equations on unit-norm columns."""
    norms = np.linalg.norm(w, axis=0)
    wn = w / norms
    g = wn.T @ wn
    c = sla.cho_factor(g)
    p = sla.cho_solve(c, wn.T @ y) / norms
    g_inv = sla.cho_solve(c, np.eye(len(g))) / np.outer(norms, norms)
    return p, g_inv, (w.T @ w)


def excitation_report(
    w: np.ndarray, names: tuple[str, ...], max_cond: float
) -> tuple[float, float, list[str]]:
    """(cond, cond_raw, base parameters the data do not excite): those with the largest weights in
    the singular directions of the unit-column regressor whose singular value is below σ_max/max_cond."""
    norms = np.linalg.norm(w, axis=0)
    dead = [names[i] for i in np.flatnonzero(norms <= 1e-12 * max(norms.max(), 1e-300))]
    safe = np.where(norms > 0, norms, 1.0)
    wn = w / safe
    lam, vec = sla.eigh(wn.T @ wn)
    lam = np.maximum(lam, 0.0)
    cond = math.sqrt(lam[-1] / lam[0]) if lam[0] > 0 else math.inf
    if dead or not math.isfinite(cond):
        cond_raw = math.inf
    else:
        r = np.linalg.cholesky(wn.T @ wn).T
        s = np.linalg.svd(r * norms[None, :], compute_uv=False)
        cond_raw = float(s[0] / s[-1])
    weak = list(dead)
    for k in np.flatnonzero(lam < lam[-1] / max_cond**2):
        v = np.abs(vec[:, k])
        for i in np.flatnonzero(v >= 0.5 * v.max()):
            if names[i] not in weak:
                weak.append(names[i])
    return cond, cond_raw, weak


def estimate(
    robot: Robot,
    bset: BaseParameterSet,
    data: Processed,
    settings: IdentifySettings,
    *,
    source: str | None = None,
) -> Estimate:
    """OLS, then (method "wls") WLS on the processed samples; refuses poor excitation."""
    n, nb = robot.n, bset.n_base
    w = bset.base_regressor(regressor(robot, data))
    y = data.tau.ravel()
    joint = np.tile(np.arange(n), len(data.t))
    keep = ~data.near_stick.ravel()
    w, y, joint = w[keep], y[keep], joint[keep]
    cond, cond_raw, weak = excitation_report(w, bset.names, settings.max_cond)
    if cond > settings.max_cond or len(y) <= nb:
        still = [robot.joint_names[j] for j in range(n) if not np.any(joint == j)]
        parts = []
        if still:
            parts.append(
                f"{', '.join(still)} never moved faster than min_speed_rad_s = {settings.min_speed_rad_s} "
                "for longer than the stick guard (default 1/cutoff_hz)"
            )
        shown = [b for b in weak if b.split(".")[0] not in still]
        if shown:
            more = f" and {len(shown) - 12} more" if len(shown) > 12 else ""
            parts.append("not identifiable from this log: " + ", ".join(shown[:12]) + more)
        raise InputError(
            f"poor excitation: cond(W) = {cond:.3g} (unit-norm columns; limit max_cond = "
            f"{settings.max_cond:.3g}) over {len(y)} rows; {'; '.join(parts) or 'too few rows'}. "
            "Record an excitation trajectory (rxcomm excite) instead",
            file=source,
            field="q",
        )
    p_ols, g_inv, _ = _solve_normal(w, y)
    r = y - w @ p_ols
    m_j = np.bincount(joint, minlength=n)
    ss_j = np.bincount(joint, weights=r * r, minlength=n)
    dof = np.maximum(m_j - nb, 1)
    sigma = np.sqrt(ss_j / dof)
    if settings.method == "ols":
        s2 = float(r @ r) / max(len(y) - nb, 1)
        p, cov = p_ols, s2 * g_inv
        info = (w.T @ w) / s2
        sig = np.full(n, math.sqrt(s2))
    else:
        sig = np.maximum(sigma, 1e-9 * max(sigma.max(), 1e-12))
        wt = 1.0 / sig[joint]
        p, cov, info = _solve_normal(w * wt[:, None], y * wt)
        r = y - w @ p
    rms = np.sqrt(np.bincount(joint, weights=r * r, minlength=n) / np.maximum(m_j, 1))
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(np.abs(p) > 0, std / np.abs(p), np.inf)
    return Estimate(
        p_b=p,
        cov=cov,
        relative_std=rel,
        sigma_joint_nm=sig,
        info=info,
        cond=cond,
        cond_raw=cond_raw,
        n_rows=int(len(y)),
        n_rejected=int((~keep).sum()),
        residual_rms_nm=rms,
        p_ols=p_ols,
    )


# ------------------------------------------------------------------------------------------------
# Physical consistency


def pseudo_inertia(pi: np.ndarray) -> np.ndarray:
    """4 × 4 pseudo-inertia J = [[Σ, h], [hᵀ, m]] of the 10 parameters (m, h = m·c, Ixx Ixy Iyy Ixz Iyz
    Izz about the frame origin), Σ = ½tr(I)·1 − I. Positive definite ⇔ physically consistent."""
    m, h = pi[0], pi[1:4]
    i_o = np.array([[pi[4], pi[5], pi[7]], [pi[5], pi[6], pi[8]], [pi[7], pi[8], pi[9]]])
    j = np.empty((4, 4))
    j[:3, :3] = 0.5 * np.trace(i_o) * np.eye(3) - i_o
    j[:3, 3] = j[3, :3] = h
    j[3, 3] = m
    return j


def _from_pseudo_inertia(j: np.ndarray) -> np.ndarray:
    """Inverse of `pseudo_inertia` (linear): I = tr(Σ)·1 − Σ."""
    sigma = j[:3, :3]
    tr = sigma[0, 0] + sigma[1, 1] + sigma[2, 2]
    return np.array(
        [
            j[3, 3],
            j[0, 3],
            j[1, 3],
            j[2, 3],
            tr - sigma[0, 0],
            -sigma[0, 1],
            tr - sigma[1, 1],
            -sigma[0, 2],
            -sigma[1, 2],
            tr - sigma[2, 2],
        ]
    )


_TRIU = np.triu_indices(4, 1)


def _u_matrix(theta: np.ndarray) -> np.ndarray:
    u = np.zeros((4, 4))
    u[np.diag_indices(4)] = np.exp(np.clip(theta[:4], -50.0, 50.0))
    u[_TRIU] = theta[4:]
    return u


def _link_from_theta(theta: np.ndarray) -> np.ndarray:
    """Link parameters from the log-Cholesky variables (4 log-diagonal + 6 off-diagonal entries of the
    upper-triangular U with J = U·Uᵀ)."""
    u = _u_matrix(theta)
    return _from_pseudo_inertia(u @ u.T)


def _link_jacobian(theta: np.ndarray) -> np.ndarray:
    """∂(link parameters)/∂θ [10, 10]: dJ = dU·Uᵀ + U·dUᵀ, mapped linearly."""
    u = _u_matrix(theta)
    out = np.empty((10, 10))
    entries = [(i, i) for i in range(4)] + list(zip(*_TRIU, strict=True))
    for k, (a, b) in enumerate(entries):
        du = np.zeros((4, 4))
        du[a, b] = u[a, b] if k < 4 else 1.0
        dj = du @ u.T
        out[:, k] = _from_pseudo_inertia(dj + dj.T)
    return out


def _theta_from_link(pi: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """Inverse of `_link_from_theta`; a pseudo-inertia that is not positive definite is first projected
    (eigenvalues raised to `floor` > 0)."""
    j = pseudo_inertia(pi)
    lam, vec = np.linalg.eigh(j)
    if lam[0] <= floor:
        j = (vec * np.maximum(lam, floor)) @ vec.T
    flip = np.eye(4)[::-1]
    u = flip @ np.linalg.cholesky(flip @ j @ flip) @ flip
    return np.concatenate([np.log(np.diag(u)), u[_TRIU]])


def link_min_eigenvalues(params: DynamicParameters) -> np.ndarray:
    """Per link, the smallest eigenvalue of its pseudo-inertia (kg·m²; > 0 ⇔ consistent)."""
    return np.array([np.linalg.eigvalsh(pseudo_inertia(pi))[0] for pi in params.inertial])


def drive_violations(params: DynamicParameters) -> list[str]:
    """Names of drive parameters that must not be negative but are (rotor inertia, Coulomb, viscous,
    spring k and k·L0)."""
    out = []
    for i, j in enumerate(params.joint_names):
        for attr, name in (
            ("rotor_inertia_kgm2", "rotor_inertia"),
            ("coulomb_nm", "fc"),
            ("viscous_nm_s_per_rad", "fv"),
        ):
            if getattr(params, attr)[i] < 0:
                out.append(f"{j}.{name}")
    if params.spring is not None:
        out += [f"spring.{s}" for s, v in zip(("k", "kL0"), params.spring, strict=True) if v < 0]
    if params.has_motor_friction:
        for i, j in enumerate(params.joint_names):
            if params.motor_coulomb_nm[i] < 0:
                out.append(f"{j}.fc_motor")
            if params.motor_viscous_nm_s_per_rad[i] < 0:
                out.append(f"{j}.fv_motor")
    return out


@dataclass(frozen=True, eq=False)
class PhysicalFit:
    """The physically consistent estimate nearest (in the information metric) to the unconstrained one:
    `params` (full), `p_b` (= K·params), `mahalanobis` √((p_b − p̂)ᵀΛ(p_b − p̂)) in standard
    deviations (an upper bound of the least distance: `params` is consistent, maybe not the nearest),
    `success` (the solver converged within its evaluation cap), `message`."""

    params: DynamicParameters
    p_b: np.ndarray
    mahalanobis: float
    success: bool
    message: str


def physical_fit(
    robot: Robot,
    bset: BaseParameterSet,
    est: Estimate,
    prior: DynamicParameters | None = None,
    regularisation: float = 1e-3,
) -> PhysicalFit:
    """The physically consistent parameters nearest to the estimate (module docstring).

    Starts from the full vector closest to the prior that reproduces p̂ (`parameters_from_base`);
    if that is consistent already, it is the answer (distance 0). Otherwise its links are projected
    onto positive-definite pseudo-inertias (eigenvalues raised to 10⁻⁴ of the link's largest) and
    negative drive parameters set to 0, and a bounded least squares over log-Cholesky variables
    minimises ‖R·(K·p − p̂)‖² + regularisation²·‖(p − p_c)/scale‖², p_c that closest vector (the
    regularisation fixes the directions the data do not see)."""
    prior = prior_parameters(robot) if prior is None else prior.conform(robot)
    n = robot.n
    names = parameter_names(robot.joint_names, prior.has_spring, prior.has_motor_friction)
    closest = parameters_from_base(robot, bset, est.p_b, prior)
    p_c = closest.vector()
    info = 0.5 * (est.info + est.info.T)
    if np.all(link_min_eigenvalues(closest) > 0) and not drive_violations(closest):
        return PhysicalFit(closest, bset.project(p_c), 0.0, True, "the closest full vector is consistent")
    scale = parameter_scale(names, prior.vector(), n)
    nonneg = [10 * n + k * n + i for k in (0, 1, 2) for i in range(n)]  # rotor, fc, fv
    m0 = 14 * n + (2 if prior.has_spring else 0)
    if prior.has_spring:
        nonneg += [14 * n, 14 * n + 1]
    if prior.has_motor_friction:
        nonneg += list(range(m0, m0 + 2 * n))
    lo = np.full(len(p_c), -np.inf)
    lo[nonneg] = 0.0
    hi = np.full(len(p_c), np.inf)
    thetas = []
    for pi in closest.inertial:
        big = max(np.linalg.eigvalsh(pseudo_inertia(pi))[-1], 1e-12)
        thetas.append(_theta_from_link(pi, 1e-4 * big))
    theta0 = np.concatenate([*thetas, np.maximum(p_c[10 * n :], lo[10 * n :])])
    r_info = np.linalg.cholesky(info + 1e-12 * np.trace(info) / len(info) * np.eye(len(info))).T
    a_mat = r_info @ bset.K

    def full(theta: np.ndarray) -> np.ndarray:
        links = [_link_from_theta(theta[10 * i : 10 * i + 10]) for i in range(n)]
        return np.concatenate([*links, theta[10 * n :]])

    def residual(theta: np.ndarray) -> np.ndarray:
        p = full(theta)
        return np.concatenate([a_mat @ p - r_info @ est.p_b, regularisation * (p - p_c) / scale])

    def jacobian(theta: np.ndarray) -> np.ndarray:
        dp = np.zeros((len(p_c), len(theta)))
        for i in range(n):
            dp[10 * i : 10 * i + 10, 10 * i : 10 * i + 10] = _link_jacobian(theta[10 * i : 10 * i + 10])
        dp[10 * n :, 10 * n :] = np.eye(len(p_c) - 10 * n)
        return np.concatenate([a_mat @ dp, regularisation * dp / scale[:, None]])

    # The problem is ill-conditioned (directions the data do not see are held only by the small pull
    # towards p_c): trf creeps at the end (distance 0.55σ after 50 evaluations, 0.52σ after 200), so it
    # is capped. Every iterate is consistent, so the distance reported is an upper bound of the least.
    res = least_squares(residual, theta0, jac=jacobian, bounds=(lo, hi), method="trf", max_nfev=60)
    p = full(res.x)
    p_b = bset.K @ p
    d = p_b - est.p_b
    params = DynamicParameters.from_vector(robot.joint_names, p, prior.has_spring, prior.has_motor_friction)
    return PhysicalFit(
        params, p_b, float(math.sqrt(max(d @ info @ d, 0.0))), bool(res.success), str(res.message)
    )


# ------------------------------------------------------------------------------------------------
# Validation


MIN_SCORED_ROWS = 10  # a joint that moved on fewer validation rows than this is not scored


@dataclass(frozen=True, eq=False)
class Validation:
    """Measured (filtered) and predicted torques [M, n] at times `t`, the plain prediction (no
    clipping anywhere). Scored per joint on its *moving* rows (|q̇| ≥ min_speed_rad_s): `rms_nm`,
    `nrmse` (RMS error / (max − min) of the measured torque on those rows) and `r2`; NaN where the
    joint moved on fewer than `MIN_SCORED_ROWS` rows (not scored: nothing was measured, not 0).
    Standstill rows apart: `standstill_fraction`, `standstill_rms_nm` (NaN without any) and
    `standstill_in_band_fraction`, the share whose measured torque lies within the prediction
    without Coulomb friction ± the static friction (stiction: anything inside is no model error).
    `rms_all_nm`: the plain RMS error over every row. `source` says on what."""

    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    rms_nm: np.ndarray
    nrmse: np.ndarray
    r2: np.ndarray
    source: str
    standstill_fraction: np.ndarray
    standstill_rms_nm: np.ndarray
    standstill_in_band_fraction: np.ndarray
    rms_all_nm: np.ndarray
    moving: np.ndarray

    @property
    def scored(self) -> np.ndarray:
        return np.isfinite(self.rms_nm)


def _nan_list(a: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in a]


def friction_band_nm(robot: Robot, params: DynamicParameters) -> np.ndarray:
    """Per joint, the largest static friction torque (joint side): Fc + Σ_i |R_ij|·Fc_m,i."""
    band = np.abs(params.coulomb_nm)
    if params.has_motor_friction:
        band = band + np.abs(robot.joint_to_motor).T @ np.abs(params.motor_coulomb_nm)
    return band


def validate(
    robot: Robot, params: DynamicParameters, data: Processed, source: str, min_speed_rad_s: float = 0.05
) -> Validation:
    """Predicted against measured torque of processed samples (both seen through the same filter).

    The headline is the plain prediction error on the rows where the joint moves. A joint slower than
    `min_speed_rad_s` sticks: its friction is static, anywhere within ±Fc, so those rows are scored
    apart (module docstring); an ISO 9283 path may hold a wrist joint still throughout, which is then
    "not scored", never a perfect fit."""
    params = params.conform(robot)
    params.check_robot(robot)
    y = regressor(robot, data)
    pred = (y @ params.vector()).reshape(data.tau.shape)
    err = data.tau - pred
    moving = np.abs(data.qd) >= min_speed_rad_s
    n = robot.n
    rms, nrmse, r2 = (np.full(n, np.nan) for _ in range(3))
    still_rms, in_band = np.full(n, np.nan), np.full(n, np.nan)
    still = ~moving
    # the prediction without the Coulomb terms, for the stiction band
    free = pred - data.coulomb * params.coulomb_nm if robot.friction_mode != "motor" else pred.copy()
    if params.has_motor_friction:
        m_c = data.motor_coulomb * params.motor_coulomb_nm
        free = free - m_c @ robot.joint_to_motor
    band = friction_band_nm(robot, params)
    for j in range(n):
        k = moving[:, j]
        if k.sum() >= MIN_SCORED_ROWS:
            e, m = err[k, j], data.tau[k, j]
            rms[j] = math.sqrt(float(np.mean(e**2)))
            nrmse[j] = rms[j] / max(float(m.max() - m.min()), 1e-12)
            sst = float(np.sum((m - m.mean()) ** 2))
            r2[j] = 1.0 - float(np.sum(e**2)) / sst if sst > 0 else np.nan
        if still[:, j].any():
            s_ = still[:, j]
            still_rms[j] = math.sqrt(float(np.mean(err[s_, j] ** 2)))
            in_band[j] = float(np.mean(np.abs(data.tau[s_, j] - free[s_, j]) <= band[j]))
    return Validation(
        t=data.t,
        measured=data.tau,
        predicted=pred,
        rms_nm=rms,
        nrmse=nrmse,
        r2=r2,
        source=source,
        standstill_fraction=still.mean(axis=0),
        standstill_rms_nm=still_rms,
        standstill_in_band_fraction=in_band,
        rms_all_nm=np.sqrt(np.mean(err**2, axis=0)),
        moving=moving,
    )


def holdout_mask(t: np.ndarray, fraction: float, blocks: int) -> np.ndarray:
    """Rows held out for validation: the last `fraction` of each of `blocks` equal blocks of the time
    span (interleaved through the log, so a log that ends at standstill still validates on motion)."""
    t0, span = t[0], t[-1] - t[0]
    phase = ((t - t0) / span * blocks) % 1.0
    last = (t - t0) >= span * (1.0 - 1e-12)
    return (phase >= 1.0 - fraction - 1e-9) | last


# ------------------------------------------------------------------------------------------------
# The whole identification


@dataclass(frozen=True, eq=False)
class Identification:
    """What `identify` returns: the base set, the estimate, the parameters to write (`params`, with
    `p_b` = K·params; consistent when `physical`), the consistency figures, the validation."""

    bset: BaseParameterSet
    estimate: Estimate
    p_b: np.ndarray
    params: DynamicParameters
    physical: bool
    method: str
    physical_fit: PhysicalFit
    link_min_eig_kgm2: np.ndarray
    drive_violations: list[str]
    validation: Validation
    n_samples: int
    sample_hz: float
    source_hz: float
    seconds: float
    robot: Robot | None = None
    cutoff_hz: float = math.nan
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def friction_mode(self) -> str:
        return "joint" if self.robot is None else self.robot.friction_mode

    @property
    def rows_per_parameter(self) -> float:
        return self.estimate.n_rows / self.bset.n_base

    def inconsistent_links(self) -> list[str]:
        """Links whose pseudo-inertia (closest full vector to the prior) is not positive definite, with
        the smallest eigenvalue: no body has that mass distribution."""
        names = self.params.joint_names
        return [f"{names[i]} ({v:.3g} kg·m²)" for i, v in enumerate(self.link_min_eig_kgm2) if v <= 0]

    def warnings(self, settings: IdentifySettings | None = None) -> list[str]:
        """What a user should act on: too few rows per parameter, parameters the data barely see."""
        settings = settings or IdentifySettings()
        out = []
        rpp = self.rows_per_parameter
        if rpp < settings.min_rows_per_parameter:
            factor = settings.min_rows_per_parameter / rpp
            fc = min(self.cutoff_hz * factor, 0.4 * self.source_hz)
            out.append(
                f"{self.estimate.n_rows} fit rows for {self.bset.n_base} base parameters "
                f"({rpp:.1f} per parameter, fewer than {settings.min_rows_per_parameter:g}): the standard "
                f"deviations are large; a higher cut-off and sample rate keep more rows, e.g. --cutoff-hz "
                f"{fc:.0f} --decimate-hz {2 * fc:.0f}, or record a longer log"
            )
        big = [self.bset.names[i] for i in np.flatnonzero(self.estimate.relative_std > 1.0)]
        if big:
            more = f" and {len(big) - 5} more" if len(big) > 5 else ""
            out.append(
                f"{len(big)} base parameters have a relative standard deviation above 100 % "
                f"({', '.join(big[:5])}{more}): small, or the log hardly excites them"
            )
        return out

    def summary(self) -> dict[str, object]:
        """The flat summary of dynamics.yaml (architecture §9 keys first). Per-joint validation figures
        are null for a joint that did not move on the validation data (not scored)."""
        est, val = self.estimate, self.validation
        return {
            "n_base_params": self.bset.n_base,
            "validation_nrmse": _nan_list(val.nrmse),
            "validation_rms_nm": _nan_list(val.rms_nm),
            "seconds": self.seconds,
            "validation": val.source,
            "validation_r2": _nan_list(val.r2),
            "validation_scored_on": "rows where the joint moves (|qd| >= min_speed_rad_s); plain prediction",
            "validation_nrmse_normalisation": "rms error / (max - min) of the measured torque (moving rows)",
            "validation_joints_not_scored": ", ".join(
                j for j, ok in zip(self.params.joint_names, val.scored, strict=True) if not ok
            ),
            "validation_rms_all_rows_nm": val.rms_all_nm.tolist(),
            "validation_standstill_fraction": val.standstill_fraction.tolist(),
            "validation_standstill_rms_nm": _nan_list(val.standstill_rms_nm),
            "validation_standstill_in_band_fraction": _nan_list(val.standstill_in_band_fraction),
            "friction": self.friction_mode,
            "cutoff_hz": self.cutoff_hz,
            "rows_per_parameter": self.rows_per_parameter,
            "cond": est.cond,
            "cond_raw": est.cond_raw,
            "method": self.method + (" + physical consistency" if self.physical else ""),
            "n_samples": self.n_samples,
            "n_rows": est.n_rows,
            "n_rows_rejected": est.n_rejected,
            "sample_hz": self.sample_hz,
            "source_hz": self.source_hz,
            "fit_rms_nm": est.residual_rms_nm.tolist(),
            "noise_sigma_nm": est.sigma_joint_nm.tolist(),
            "max_relative_std": float(np.max(est.relative_std)),
            "median_relative_std": float(np.median(est.relative_std)),
            "link_pseudo_inertia_min_eig_kgm2": self.link_min_eig_kgm2.tolist(),
            "n_inconsistent_links": int(np.sum(self.link_min_eig_kgm2 <= 0)),
            "inconsistent_links": ", ".join(self.inconsistent_links()),
            "negative_drive_parameters": ", ".join(self.drive_violations),
            "consistency_distance_sigma": self.physical_fit.mahalanobis,
        }


def identify(
    robot: Robot,
    log: JointLog,
    settings: IdentifySettings | None = None,
    *,
    validation_log: JointLog | None = None,
    bset: BaseParameterSet | None = None,
    prior: DynamicParameters | None = None,
) -> Identification:
    """Identify the base parameters from `log` and validate them (module docstring)."""
    t0 = time.perf_counter()
    settings = settings or IdentifySettings()
    if settings.friction is not None and settings.friction != robot.friction_mode:
        robot = robot.with_friction(settings.friction)
    prior = prior_parameters(robot) if prior is None else prior.conform(robot)
    timings: dict[str, float] = {}
    bset = base_parameters(robot) if bset is None else bset
    if tuple(bset.full_names) != parameter_names(
        robot.joint_names, robot.drives.spring is not None, robot.has_motor_friction
    ):
        raise ValueError(f"the base set is not over robot {robot.name!r}'s parameters (friction model?)")
    timings["base_set"] = time.perf_counter() - t0
    tick = time.perf_counter()
    clean = check_log(log, robot, settings)
    data = preprocess(clean, settings, robot)
    if validation_log is None:
        held = holdout_mask(data.t, settings.holdout_fraction, settings.holdout_blocks)
        fit_data, val_data = data.select(~held), data.select(held)
        pct = 100 * settings.holdout_fraction
        if settings.holdout_blocks == 1:
            val_source = f"held out: last {pct:.0f} % of the log (t >= {val_data.t[0]:.3f} s)"
        else:
            val_source = (
                f"held out: last {pct:.0f} % of each of {settings.holdout_blocks} blocks of the log "
                "(interleaved)"
            )
    else:
        fit_data = data
        val_data = preprocess(check_log(validation_log, robot, settings), settings, robot)
        val_source = f"log: {Path(validation_log.source).name or 'given'}"
    timings["preprocess"] = time.perf_counter() - tick
    tick = time.perf_counter()
    est = estimate(robot, bset, fit_data, settings, source=log.source or None)
    timings["estimate"] = time.perf_counter() - tick
    tick = time.perf_counter()
    closest = parameters_from_base(robot, bset, est.p_b, prior)
    phys = physical_fit(robot, bset, est, prior)
    timings["physical"] = time.perf_counter() - tick
    if settings.physical:
        params, p_b = phys.params, phys.p_b
    else:
        params, p_b = closest, est.p_b
    tick = time.perf_counter()
    val = validate(robot, params, val_data, val_source, settings.min_speed_rad_s)
    timings["validate"] = time.perf_counter() - tick
    return Identification(
        bset=bset,
        estimate=est,
        p_b=p_b,
        params=params,
        physical=settings.physical,
        method=settings.method,
        physical_fit=phys,
        link_min_eig_kgm2=link_min_eigenvalues(closest),
        drive_violations=drive_violations(closest),
        validation=val,
        n_samples=len(fit_data.t),
        sample_hz=data.sample_hz,
        source_hz=data.source_hz,
        seconds=time.perf_counter() - t0,
        robot=robot,
        cutoff_hz=settings.cutoff_hz,
        timings=timings,
    )


def score(
    robot: Robot, params: DynamicParameters, log: JointLog, settings: IdentifySettings | None = None
) -> Validation:
    """An identified model checked on another log without refitting (e.g. last month's model against
    today's recording): the same processing and figures as `identify`'s validation."""
    settings = settings or IdentifySettings()
    if settings.friction is not None and settings.friction != robot.friction_mode:
        robot = robot.with_friction(settings.friction)
    data = preprocess(check_log(log, robot, settings), settings, robot)
    return validate(robot, params, data, f"log: {Path(log.source).name or 'given'}", settings.min_speed_rad_s)


def write_torques_csv(path: str | Path, joint_names: tuple[str, ...], val: Validation) -> Path:
    """The validation rows as CSV: time_s, then per joint the measured and predicted torque (N·m, both
    through the same low-pass) and whether the joint moved (scored) on that row."""
    path = Path(path)
    n = len(joint_names)
    header = ["time_s"]
    header += [f"tau{i + 1}_measured_nm" for i in range(n)] + [f"tau{i + 1}_predicted_nm" for i in range(n)]
    header += [f"moving{i + 1}" for i in range(n)]
    table = np.column_stack([val.t, val.measured, val.predicted, val.moving.astype(float)])
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"# {val.source}; joints {', '.join(joint_names)}\n" + ",".join(header) + "\n")
        np.savetxt(f, table, delimiter=",", fmt="%.10g")
    return path
