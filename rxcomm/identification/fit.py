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
rotor inertia, Coulomb (exact sign), viscous, offset, spring), reduced to the base parameters
(`BaseParameterSet`, the paper's κ regrouping, recorded in dynamics.yaml). Rows of joint j where
|q̇_j| < `min_speed_rad_s` are rejected: there the Coulomb term's sign is uncertain and the real
friction (stiction) is not Fc·sgn(q̇). So are the rows within `stick_guard_s` (default 1/cutoff) of
such a sample at the source rate: the low-pass spreads the stick phase's friction (anything within
±Fc) over that time, which parallel filtering of sgn(q̇) cannot reproduce; near reversals the
residual is 2–6× the noise, beyond 1/cutoff at the noise. Ordinary least squares, then weighted
least squares with each joint's rows divided by its noise standard deviation σ_j² = ‖r_j‖²/(m_j − p)
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
9283-like path) against its filtered measured torques: per joint RMS (N·m) and NRMSE = RMS error /
(max − min) of the measured torque (its range; stated in the summary). Without a validation log the
last `holdout_fraction` of the log is held out of the estimation and used instead.
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
from rxcomm.model.robot_csv import read_robot_csv
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
        0.2, gt=0, lt=0.9, description="last part of the log held out for validation without --validate"
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
    [M, n]: within the stick guard of a sample where the joint was slower than min_speed_rad_s."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    coulomb: np.ndarray
    near_stick: np.ndarray
    sample_hz: float
    source_hz: float

    def window(self, t0: float, t1: float) -> Processed:
        k = (self.t >= t0) & (self.t < t1)
        return Processed(
            self.t[k],
            self.q[k],
            self.qd[k],
            self.qdd[k],
            self.tau[k],
            self.coulomb[k],
            self.near_stick[k],
            self.sample_hz,
            self.source_hz,
        )


def preprocess(log: JointLog, settings: IdentifySettings) -> Processed:
    """Zero-phase low-pass, differentiation, trimming, decimation (module docstring)."""
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
    guard = 1.0 / fc if settings.stick_guard_s is None else settings.stick_guard_s
    near_stick = maximum_filter1d(
        np.abs(qd) < settings.min_speed_rad_s, size=2 * int(round(guard * fs)) + 1, axis=0
    )
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
        log.t[idx], q[idx], qd[idx], qdd[idx], tau[idx], coulomb[idx], near_stick[idx], fs / stride, fs
    )


def regressor(robot: Robot, data: Processed) -> np.ndarray:
    """Full regressor Y [M·n, P] (rows sample-major) of processed samples, with the parallel-filtered
    Coulomb columns: then filtered τ = Y·p holds as τ = Y·p does before filtering."""
    n = robot.n
    y = joint_torque_regressor(robot, data.q, data.qd, data.qdd)
    y3 = y.reshape(len(data.t), n, -1)
    idx = np.arange(n)
    y3[:, idx, 11 * n + idx] = data.coulomb
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
    prior = prior_parameters(robot) if prior is None else prior
    n = robot.n
    names = parameter_names(robot.joint_names, prior.has_spring)
    closest = parameters_from_base(robot, bset, est.p_b, prior)
    p_c = closest.vector()
    info = 0.5 * (est.info + est.info.T)
    if np.all(link_min_eigenvalues(closest) > 0) and not drive_violations(closest):
        return PhysicalFit(closest, bset.project(p_c), 0.0, True, "the closest full vector is consistent")
    scale = parameter_scale(names, prior.vector(), n)
    nonneg = [10 * n + k * n + i for k in (0, 1, 2) for i in range(n)]  # rotor, fc, fv
    if prior.has_spring:
        nonneg += [len(p_c) - 2, len(p_c) - 1]
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
    params = DynamicParameters.from_vector(robot.joint_names, p, prior.has_spring)
    return PhysicalFit(
        params, p_b, float(math.sqrt(max(d @ info @ d, 0.0))), bool(res.success), str(res.message)
    )


# ------------------------------------------------------------------------------------------------
# Validation


@dataclass(frozen=True, eq=False)
class Validation:
    """Measured (filtered) and predicted torques [M, n] at times `t`; per joint RMS error (N·m) and
    NRMSE (RMS error / (max − min) of the measured torque); `source` says on what;
    `standstill_fraction` per joint, where the prediction is the static-friction band."""

    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    rms_nm: np.ndarray
    nrmse: np.ndarray
    source: str
    standstill_fraction: np.ndarray


def validate(
    robot: Robot, params: DynamicParameters, data: Processed, source: str, min_speed_rad_s: float = 0.05
) -> Validation:
    """Predicted against measured torque of processed samples (both seen through the same filter).

    A joint slower than `min_speed_rad_s` sticks: its friction is static, anywhere within ±Fc, and
    the model predicts that band (the torque without Coulomb friction ± Fc); a measured torque inside
    it is no error. (An ISO 9283 path may hold a wrist joint still throughout.)"""
    params.check_robot(robot)
    y = regressor(robot, data)
    pred = (y @ params.vector()).reshape(data.tau.shape)
    still = np.abs(data.qd) < min_speed_rad_s
    if still.any():
        fc = np.abs(params.coulomb_nm)
        free = pred - data.coulomb * params.coulomb_nm
        pred = np.where(still, np.clip(data.tau, free - fc, free + fc), pred)
    err = data.tau - pred
    rms = np.sqrt(np.mean(err**2, axis=0))
    span = data.tau.max(axis=0) - data.tau.min(axis=0)
    nrmse = rms / np.maximum(span, 1e-12)
    return Validation(data.t, data.tau, pred, rms, nrmse, source, still.mean(axis=0))


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
    timings: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, object]:
        """The flat summary of dynamics.yaml (architecture §9 keys first)."""
        est, val = self.estimate, self.validation
        return {
            "n_base_params": self.bset.n_base,
            "validation_nrmse": val.nrmse.tolist(),
            "validation_rms_nm": val.rms_nm.tolist(),
            "seconds": self.seconds,
            "validation": val.source,
            "validation_nrmse_normalisation": "rms error / (max - min) of the measured torque",
            "validation_standstill_fraction": val.standstill_fraction.tolist(),
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
    prior = prior_parameters(robot) if prior is None else prior
    timings: dict[str, float] = {}
    bset = base_parameters(robot) if bset is None else bset
    timings["base_set"] = time.perf_counter() - t0
    tick = time.perf_counter()
    clean = check_log(log, robot, settings)
    data = preprocess(clean, settings)
    if validation_log is None:
        split = data.t[0] + (1.0 - settings.holdout_fraction) * (data.t[-1] - data.t[0])
        fit_data, val_data = data.window(-math.inf, split), data.window(split, math.inf)
        val_source = f"held out: last {100 * settings.holdout_fraction:.0f} % of the log (t >= {split:.3f} s)"
    else:
        fit_data = data
        val_data = preprocess(check_log(validation_log, robot, settings), settings)
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
        timings=timings,
    )
