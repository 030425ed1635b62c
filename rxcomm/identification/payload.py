"""A payload on the flange identified with the robot's identified dynamics held fixed (architecture §7).

The arm carrying a load is the same arm with the load's 10 inertial parameters δp added to the last
link's (`rxcomm.model.payload`), so on a log recorded with the load on

    τ_measured − Y(q, q̇, q̈)·p  =  Y_last(q, q̇, q̈)·δp  + noise

with p the identified robot (dynamics.yaml, fixed) and Y_last the last link's 10 columns of the same
regressor identification uses (`rxcomm.identification.processing.regressor`: same low-pass, same
differentiation, the Coulomb columns filtered alike). Rows of a joint near stiction are left out (its
friction is static there, anywhere within ±Fc, as in `identify`). The fit is weighted least squares,
per-joint weights from a first ordinary fit's residual; the covariance is the residual's. Mass, centre
of mass and inertia about it (flange frame) follow from δp, their σ by first-order propagation.
Validation: the identified model alone and with the payload, predicted against measured torque on
another motion (`rxcomm.identification.validation.validate`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from rxcomm.errors import InputError
from rxcomm.identification.logs import JointLog, check_log
from rxcomm.identification.processing import preprocess, regressor
from rxcomm.identification.settings import IdentifySettings
from rxcomm.identification.validation import Validation, validate
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.payload import FlangeInertia, flange_inertia, last_link_columns
from rxcomm.model.robot import Robot

MIN_ROWS = 200  # regressor rows for 10 parameters at the least
MAX_COND = 1e5  # a worse conditioned (unit-column) last-link regressor: the motion does not excite the load


@dataclass(frozen=True, eq=False)
class PayloadResult:
    """δp (last joint's frame) with its covariance, the load in flange terms ± σ, the fit and the
    validation (the model alone, then with the payload) on another log, if one was given."""

    inertial: np.ndarray
    cov: np.ndarray
    load: FlangeInertia
    mass_std_kg: float
    com_std_m: np.ndarray
    inertia_std_kgm2: np.ndarray  # Pinocchio order Ixx Ixy Iyy Ixz Iyz Izz
    rows: int
    cond: float
    residual_rms_nm: np.ndarray
    noise_weights_nm: np.ndarray
    without: Validation | None
    with_payload: Validation | None
    seconds: float


def _flange_vector(robot: Robot, p: np.ndarray) -> np.ndarray:
    """δp → (m, c (3), I_c in Pinocchio order (6)) in the flange frame."""
    load = flange_inertia(robot, p)
    return np.array([load.mass_kg, *load.com_m, *load.inertia6])


def _propagate(robot: Robot, p: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """σ of (m, c, I_c) by first-order propagation (central differences of the map from δp)."""
    jac = np.empty((10, 10))
    steps = np.maximum(1e-6, 1e-4 * np.abs(p))
    for k in range(10):
        e = np.zeros(10)
        e[k] = steps[k]
        jac[:, k] = (_flange_vector(robot, p + e) - _flange_vector(robot, p - e)) / (2 * steps[k])
    return np.sqrt(np.maximum(np.diag(jac @ cov @ jac.T), 0.0))


def _residual_rows(robot: Robot, params: DynamicParameters, log: JointLog, settings: IdentifySettings):
    """(Y_last, residual, joint of each row, the processed data) of a log; rows near stiction left out."""
    data = preprocess(check_log(log, robot, settings), settings, robot)
    y = regressor(robot, data)
    r = data.tau.ravel() - y @ params.vector()
    keep = ~data.near_stick.ravel()
    joint = np.tile(np.arange(robot.n), len(data.t))
    return y[keep, last_link_columns(robot)], r[keep], joint[keep], data


def identify_payload(
    robot: Robot,
    params: DynamicParameters,
    log: JointLog,
    settings: IdentifySettings,
    validation_log: JointLog | None = None,
) -> PayloadResult:
    """The payload on `log` (recorded with it mounted) with the robot's `params` held fixed; validated on
    `validation_log` (recorded with the same payload, another motion) when given."""
    t0 = time.perf_counter()
    params = params.conform(robot)
    params.check_robot(robot)
    y, r, joint, _ = _residual_rows(robot, params, log, settings)
    if len(r) < MIN_ROWS:
        raise InputError(
            f"only {len(r)} regressor rows away from stiction (at least {MIN_ROWS}): record a longer motion",
            file=log.source or None,
        )
    norms = np.linalg.norm(y, axis=0)
    sv = np.linalg.svd(y / np.where(norms > 0, norms, 1.0), compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    if not cond <= MAX_COND:
        raise InputError(
            f"the motion does not excite the last link's 10 parameters (cond {cond:.3g} > {MAX_COND:g}): "
            "move every joint, the wrist through several orientations",
            file=log.source or None,
        )
    # ordinary fit, then weighted by each joint's residual σ
    p0 = np.linalg.lstsq(y, r, rcond=None)[0]
    e0 = r - y @ p0
    sigma = np.array(
        [
            math.sqrt(float(np.mean(e0[joint == j] ** 2))) if (joint == j).any() else 1.0
            for j in range(robot.n)
        ]
    )
    sigma = np.maximum(sigma, 1e-9)
    w = 1.0 / sigma[joint]
    yw, rw = y * w[:, None], r * w
    p, *_ = np.linalg.lstsq(yw, rw, rcond=None)
    ew = rw - yw @ p
    s2 = float(ew @ ew) / max(1, len(rw) - 10)
    cov = s2 * np.linalg.inv(yw.T @ yw)
    e = r - y @ p
    rms = np.array(
        [
            math.sqrt(float(np.mean(e[joint == j] ** 2))) if (joint == j).any() else math.nan
            for j in range(robot.n)
        ]
    )
    load = flange_inertia(robot, p)
    std = _propagate(robot, p, cov)
    without = with_load = None
    if validation_log is not None:
        data_v = preprocess(check_log(validation_log, robot, settings), settings, robot)
        inertial = np.array(params.inertial)
        inertial[-1] += p
        source = f"log: {validation_log.source.rsplit('/', 1)[-1] or 'given'}"
        without = validate(robot, params, data_v, source, settings.min_speed_rad_s)
        with_load = validate(
            robot, replace(params, inertial=inertial), data_v, source, settings.min_speed_rad_s
        )
    return PayloadResult(
        inertial=p,
        cov=cov,
        load=load,
        mass_std_kg=float(std[0]),
        com_std_m=std[1:4],
        inertia_std_kgm2=std[4:],
        rows=len(r),
        cond=cond,
        residual_rms_nm=rms,
        noise_weights_nm=sigma,
        without=without,
        with_payload=with_load,
        seconds=time.perf_counter() - t0,
    )
