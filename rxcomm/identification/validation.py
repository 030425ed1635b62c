"""Scoring an identified model on processed samples (`rxcomm.identification.fit`).

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
from dataclasses import dataclass

import numpy as np

from rxcomm.identification.processing import Processed, regressor
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.robot import Robot

MIN_SCORED_ROWS = 10  # a joint that moved on fewer validation rows than this is not scored


@dataclass(frozen=True, eq=False)
class Validation:
    """Measured (filtered) and predicted torques [M, n] at times `t`, the plain prediction (no
    clipping anywhere). Scored per joint on its *moving* rows (|q̇| ≥ min_speed_rad_s): `rms_nm`,
    `nrmse` (RMS error / (max − min) of the measured torque on those rows) and `r2`; NaN where the
    joint moved on fewer than `MIN_SCORED_ROWS` rows (not scored: nothing was measured, not 0).
    Standstill rows apart: `standstill_fraction`, `standstill_rms_nm` (NaN without any) and
    `standstill_rows` (how many), the rows slower than that where the joint stands
    (`Processed.standing`: not those where it reverses, dips or creeps to a stop, which slide at ±Fc,
    the band's edge), and `standstill_in_band_fraction`, the share whose measured torque lies within
    the prediction without Coulomb friction ± the static friction (stiction: anything inside is no
    model error),
    NaN where the band (`stiction_band_nm`) is narrower than the joint's torque noise
    (`band_below_noise`: a row can then be neither inside nor outside it, as on a joint whose friction
    is all viscous). `rms_all_nm`: the plain RMS error over every row. `source` says on what."""

    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    rms_nm: np.ndarray
    nrmse: np.ndarray
    r2: np.ndarray
    source: str
    standstill_fraction: np.ndarray
    standstill_rows: np.ndarray
    standstill_rms_nm: np.ndarray
    standstill_in_band_fraction: np.ndarray
    rms_all_nm: np.ndarray
    moving: np.ndarray
    stiction_band_nm: np.ndarray
    band_below_noise: np.ndarray

    @property
    def scored(self) -> np.ndarray:
        return np.isfinite(self.rms_nm)

    @property
    def total_rms_moving_nm(self) -> float:
        """√(mean over the scored joints of rms_nm²): each joint weighs the same, however long it moved
        (NaN: none scored)."""
        ok = self.scored
        return math.sqrt(float(np.mean(self.rms_nm[ok] ** 2))) if ok.any() else math.nan

    @property
    def total_rms_every_row_nm(self) -> float:
        """√(mean over the same joints of rms_all_nm²): every row, standstill included."""
        ok = self.scored
        return math.sqrt(float(np.mean(self.rms_all_nm[ok] ** 2))) if ok.any() else math.nan


def nan_list(a: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in a]


def friction_band_nm(robot: Robot, params: DynamicParameters) -> np.ndarray:
    """Per joint, the largest static friction torque (joint side): Fc + Σ_i |R_ij|·Fc_m,i."""
    band = np.abs(params.coulomb_nm)
    if params.has_motor_friction:
        band = band + np.abs(robot.joint_to_motor).T @ np.abs(params.motor_coulomb_nm)
    return band


def joint_scores(
    measured: np.ndarray, predicted: np.ndarray, rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per joint on its scored rows (`rows` [M, n] boolean): (RMS error N·m, NRMSE = RMS / (max − min)
    of the measured torque, R²); NaN for a joint with fewer than `MIN_SCORED_ROWS` rows."""
    n = measured.shape[1]
    rms, nrmse, r2 = (np.full(n, np.nan) for _ in range(3))
    for j in range(n):
        k = rows[:, j]
        if k.sum() >= MIN_SCORED_ROWS:
            m = measured[k, j]
            e = m - predicted[k, j]
            rms[j] = math.sqrt(float(np.mean(e**2)))
            nrmse[j] = rms[j] / max(float(m.max() - m.min()), 1e-12)
            sst = float(np.sum((m - m.mean()) ** 2))
            r2[j] = 1.0 - float(np.sum(e**2)) / sst if sst > 0 else np.nan
    return rms, nrmse, r2


def validate(
    robot: Robot,
    params: DynamicParameters,
    data: Processed,
    source: str,
    min_speed_rad_s: float = 0.05,
    noise_nm: np.ndarray | None = None,
) -> Validation:
    """Predicted against measured torque of processed samples (both seen through the same filter);
    `noise_nm`: each joint's torque noise (the fit's), below which a stiction band is not scored.

    The headline is the plain prediction error on the rows where the joint moves. A joint slower than
    `min_speed_rad_s` that stands sticks: its friction is static, anywhere within ±Fc, so those rows
    are scored apart (module docstring); one slower than that which still slides (a reversal) counts
    in the every-row error only; an ISO 9283 path may hold a wrist joint still throughout, which is
    then "not scored", never a perfect fit."""
    params = params.conform(robot)
    params.check_robot(robot)
    y = regressor(robot, data)
    fitted = (y @ params.vector()).reshape(data.tau.shape)
    # the prediction without the Coulomb terms, for the stiction band; then with the Coulomb shape of
    # zero velocity at standstill (`Processed.coulomb_predicted`), never the sign of noise in q̇
    free, pred = fitted.copy(), np.zeros_like(fitted)
    if robot.friction_mode != "motor":
        free -= data.coulomb * params.coulomb_nm
        pred += data.coulomb_predicted * params.coulomb_nm
    if params.has_motor_friction:
        free -= (data.motor_coulomb * params.motor_coulomb_nm) @ robot.joint_to_motor
        pred += (data.motor_coulomb_predicted * params.motor_coulomb_nm) @ robot.joint_to_motor
    pred += free
    err = data.tau - pred
    moving = np.abs(data.qd) >= min_speed_rad_s
    n = robot.n
    still_rms, in_band = np.full(n, np.nan), np.full(n, np.nan)
    still = ~moving if data.standing is None else ~moving & data.standing
    band = friction_band_nm(robot, params)
    below = np.zeros(n, dtype=bool) if noise_nm is None else band < np.asarray(noise_nm, dtype=float)
    rms, nrmse, r2 = joint_scores(data.tau, pred, moving)
    for j in range(n):
        if still[:, j].any():
            s_ = still[:, j]
            still_rms[j] = math.sqrt(float(np.mean(err[s_, j] ** 2)))
            if not below[j]:
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
        standstill_rows=still.sum(axis=0),
        standstill_rms_nm=still_rms,
        standstill_in_band_fraction=in_band,
        rms_all_nm=np.sqrt(np.mean(err**2, axis=0)),
        moving=moving,
        stiction_band_nm=band,
        band_below_noise=below,
    )


def holdout_mask(t: np.ndarray, fraction: float, blocks: int) -> np.ndarray:
    """Rows held out for validation: the last `fraction` of each of `blocks` equal blocks of the time
    span (interleaved through the log, so a log that ends at standstill still validates on motion)."""
    t0, span = t[0], t[-1] - t[0]
    phase = ((t - t0) / span * blocks) % 1.0
    last = (t - t0) >= span * (1.0 - 1e-12)
    return (phase >= 1.0 - fraction - 1e-9) | last
