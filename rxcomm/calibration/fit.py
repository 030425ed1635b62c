"""Geometric calibration from tracker measurements (paper §3.2; architecture §7 calibrate).

Model and parameters: `rxcomm.model.geometric_errors` (48 error twists; the identifiable subset by QR).
Problem: minimise Σᵢ ‖rᵢ‖² over the identifiable parameters p₁ (the others fixed at 0), with the
weighted residual of pose i

    rᵢ = [ (p_pred − p_meas) / σ_p ;  log3(R_pred·R_measᵀ) / σ_o ]     (tracker frame)

σ_p, σ_o the tracker's position and orientation noise (so rᵢ is ~N(0, I) when the model is right
and position and orientation are weighed by their precision). Levenberg–Marquardt
(`scipy.optimize.least_squares`, `method="lm"`; `trf` when a robust loss is asked) with the
analytic Jacobian of `geometric_errors` (orientation rows through the exact derivative of log3),
started at p_e = 0 as the paper. Standard deviations from the covariance s²·(JᵀJ)⁻¹ with s² the
residual variance per degree of freedom.

Around the fit: the nominal `tracker_to_base` (measurements file, cell, or — if neither is given —
a rigid registration of the nominal TCP positions onto the measured ones, Kabsch); poses with a
component beyond `outlier_sigma` robust σ after a first fit are flagged (and dropped, by default,
before the final fit); held-out poses (`validation` role, or a seeded `holdout_fraction`) are never
fitted; the paper's Table 2 (`error_table`) before/after on fitted and held-out poses; the honest
baseline "base + tool frames only" fitted the same way; and, when the file has `baseline` poses (a
naive pose set measured for comparison), the full calibration fitted to those instead and judged on
the same held-out poses (`BaselineComparison`).

Input checks raise `InputError` (exit 2) with file and field: NaN rows, too few poses (says how
many are needed), a pose set that cannot identify some parameters (names them), positions that look
like millimetres, joint angles that look like degrees, measurements that do not fit the robot.

Outputs: `write_calibrated_urdf` folds the errors into the URDF joint origins (base error into the
first joint's origin, so the URDF root stays the nominal base frame of the cell; tool error into
the fixed joint carrying the TCP's parent frame, so drives.yaml's TCP stays valid);
`load_calibration` gives (ErrorModel, tracker_to_base) back for IK and planners.
"""

from __future__ import annotations

import csv
import math
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pinocchio as pin
import scipy.linalg
import scipy.optimize
import scipy.stats
from pydantic import BaseModel, ConfigDict, Field

from rxcomm.errors import InfeasibleError, InputError
from rxcomm.io.files import atomic_write_text
from rxcomm.io.validate import check_kind, validate_model
from rxcomm.io.yaml_io import load_yaml, read_yaml_artefact
from rxcomm.model.geometric_errors import (
    COMPONENTS,
    ErrorModel,
    IdentifiableSet,
    identifiable_parameters,
    identification_jacobians,
    measurement_scaling,
    parameter_names,
    placement_to_se3,
    predict_poses,
    random_poses,
    se3_to_xyz_rpy,
)
from rxcomm.model.kinematics import cardan_xyz, cardan_xyz_matrix, rotation_from_wxyz
from rxcomm.model.robot import Robot
from rxcomm.schemas.calibration import Calibration
from rxcomm.schemas.measurements import Measurements

# ---------------------------------------------------------------------------------------------------
# Measurements


@dataclass(frozen=True)
class MeasurementSet:
    """Measurements as arrays. `rotation` None: position only. `role[i]` is 'fit', 'validation' or
    'baseline' (a reference pose set, fitted on its own for comparison: `calibrate`)."""

    q: np.ndarray  # [N, n] rad
    position_m: np.ndarray  # [N, 3] tracker frame
    rotation: np.ndarray | None  # [N, 3, 3] tracker frame
    valid: np.ndarray  # [N] bool
    role: tuple[str, ...]
    source: str | None = None
    tracker_to_base: pin.SE3 | None = None
    position_sigma_m: float | None = None
    orientation_sigma_rad: float | None = None

    @property
    def n(self) -> int:
        return self.q.shape[0]

    @property
    def position_only(self) -> bool:
        return self.rotation is None

    def subset(self, idx: np.ndarray) -> MeasurementSet:
        idx = np.asarray(idx, dtype=int)
        return MeasurementSet(
            self.q[idx],
            self.position_m[idx],
            None if self.rotation is None else self.rotation[idx],
            self.valid[idx],
            tuple(self.role[i] for i in idx),
            self.source,
            self.tracker_to_base,
            self.position_sigma_m,
            self.orientation_sigma_rad,
        )


def measurements_from_artefact(art: Measurements, file: str | None = None) -> MeasurementSet:
    """Arrays from a `rxcomm/Measurements` artefact (NaNs kept: `check_measurements` reports them)."""
    poses = art.poses
    if not poses:
        raise InputError("no poses", file=file, field="poses")
    n_q = {len(p.q_rad) for p in poses}
    if len(n_q) != 1:
        raise InputError(
            f"poses have different numbers of joint angles {sorted(n_q)}", file=file, field="poses"
        )
    has_rot = [p.quaternion_wxyz is not None for p in poses]
    if any(has_rot) and not all(has_rot):
        i = has_rot.index(False)
        raise InputError(
            "some poses have an orientation and some not", file=file, field=f"poses[{i}].quaternion_wxyz"
        )
    rot = None
    if all(has_rot):
        rot = np.array([rotation_from_wxyz(np.array(p.quaternion_wxyz, dtype=float)) for p in poses])
    t2b = None
    if art.tracker_to_base is not None:
        t2b = placement_to_se3(art.tracker_to_base.xyz_m, art.tracker_to_base.rpy_rad)
    return MeasurementSet(
        q=np.array([p.q_rad for p in poses], dtype=float),
        position_m=np.array([p.position_m for p in poses], dtype=float),
        rotation=rot,
        valid=np.array([p.valid for p in poses], dtype=bool),
        role=tuple(p.role for p in poses),
        source=file,
        tracker_to_base=t2b,
        position_sigma_m=art.position_sigma_m,
        orientation_sigma_rad=art.orientation_sigma_rad,
    )


ROLES = ("fit", "validation", "baseline")

CSV_HELP = (
    "tracker CSV: a header row, then one row per pose. Columns: q1_rad … q6_rad (or q1_deg …), "
    "x_m, y_m, z_m (or x_mm, y_mm, z_mm): TCP position in the tracker frame; optional alpha_rad, "
    "beta_rad, gamma_rad (or _deg): TCP orientation as Cardan angles x-y-z (R = Rx·Ry·Rz) in the "
    "tracker frame; optional valid (1/0) and role (fit/validation/baseline)."
)


def read_tracker_csv(path: str | Path, n_joints: int) -> MeasurementSet:
    """Measurements from a tracker CSV export (`CSV_HELP` documents the columns and units)."""
    path = Path(path)
    try:
        rows = list(csv.reader(path.read_text(encoding="utf-8").splitlines()))
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read: {e}", file=path) from e
    rows = [r for r in rows if r and not r[0].lstrip().startswith("#")]
    if len(rows) < 2:
        raise InputError("needs a header row and at least one pose row. " + CSV_HELP, file=path)
    header = [h.strip() for h in rows[0]]
    col = {h: i for i, h in enumerate(header)}

    def pick(stem: str, units: dict[str, float], required: bool) -> tuple[int, float] | None:
        for unit, scale in units.items():
            if f"{stem}_{unit}" in col:
                return col[f"{stem}_{unit}"], scale
        if required:
            raise InputError(f"missing column {stem}_{next(iter(units))}. " + CSV_HELP, file=path, field=stem)
        return None

    ang = {"rad": 1.0, "deg": math.pi / 180}
    length = {"m": 1.0, "mm": 1e-3}
    q_cols = [pick(f"q{j + 1}", ang, True) for j in range(n_joints)]
    p_cols = [pick(a, length, True) for a in ("x", "y", "z")]
    o_cols = [pick(a, ang, False) for a in ("alpha", "beta", "gamma")]
    if any(c is None for c in o_cols) and any(c is not None for c in o_cols):
        raise InputError("give all of alpha, beta, gamma or none", file=path, field="alpha")
    has_rot = all(c is not None for c in o_cols)

    def num(row: list[str], c: tuple[int, float], line: int, name: str) -> float:
        try:
            return float(row[c[0]]) * c[1]
        except (ValueError, IndexError) as e:
            raise InputError(
                f"line {line}: not a number: {row[c[0]] if c[0] < len(row) else ''!r}", file=path, field=name
            ) from e

    q, p, o, valid, role = [], [], [], [], []
    for k, row in enumerate(rows[1:], start=2):
        q.append([num(row, c, k, header[c[0]]) for c in q_cols])
        p.append([num(row, c, k, header[c[0]]) for c in p_cols])
        if has_rot:
            o.append([num(row, c, k, header[c[0]]) for c in o_cols])
        valid.append(row[col["valid"]].strip() not in ("0", "false", "False") if "valid" in col else True)
        r = row[col["role"]].strip() if "role" in col else "fit"
        if r not in ROLES:
            raise InputError(
                f"line {k}: role must be one of {', '.join(ROLES)}, got {r!r}", file=path, field="role"
            )
        role.append(r)
    o_arr = np.array(o, dtype=float) if has_rot else None
    if o_arr is not None and np.nanmax(np.abs(o_arr)) > math.pi + 1e-6:
        raise InputError(
            f"orientation angles up to {np.nanmax(np.abs(o_arr)):.4g} rad exceed π: degrees given as "
            "radians? (name the columns alpha_deg, beta_deg, gamma_deg)",
            file=path,
            field="alpha_rad",
        )
    return MeasurementSet(
        q=np.array(q, dtype=float),
        position_m=np.array(p, dtype=float),
        rotation=None if o_arr is None else cardan_xyz_matrix(o_arr),
        valid=np.array(valid, dtype=bool),
        role=tuple(role),
        source=str(path),
    )


def read_measurements(path: str | Path, robot: Robot) -> MeasurementSet:
    """A `rxcomm/Measurements` YAML artefact or a tracker CSV (by suffix), checked (`check_measurements`)."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        ms = read_tracker_csv(path, robot.n)
    else:
        data = load_yaml(path)
        check_kind(data, Measurements, file=path)
        art = validate_model(Measurements, data, file=path)
        if list(art.joint_names) != list(robot.joint_names):
            raise InputError(
                f"joint names {art.joint_names} are not this robot's {list(robot.joint_names)}",
                file=path,
                field="joint_names",
            )
        ms = measurements_from_artefact(art, str(path))
    check_measurements(ms, robot)
    return ms


def check_measurements(ms: MeasurementSet, robot: Robot) -> None:
    """Refuse NaN rows and implausible units (InputError naming file and pose)."""
    file = ms.source
    if ms.q.shape[1] != robot.n:
        raise InputError(
            f"{ms.q.shape[1]} joint angles per pose, the robot has {robot.n}", file=file, field="q"
        )
    # NaN/inf in a pose marked valid: name the rows.
    bad_q = ~np.all(np.isfinite(ms.q), axis=1)
    bad_p = ~np.all(np.isfinite(ms.position_m), axis=1)
    bad_o = np.zeros(ms.n, bool) if ms.rotation is None else ~np.all(np.isfinite(ms.rotation), axis=(1, 2))
    bad = (bad_q | ((bad_p | bad_o) & ms.valid)).nonzero()[0]
    if bad.size:
        what = "joint angles" if bad_q[bad[0]] else "position" if bad_p[bad[0]] else "orientation"
        raise InputError(
            f"NaN or infinite values in {bad.size} pose(s) marked valid, first in its {what}: poses "
            f"{bad[:10].tolist()} (mark unmeasured poses valid: false)",
            file=file,
            field=f"poses[{int(bad[0])}]",
        )
    # Joint angles: beyond the limits → maybe degrees.
    lim = np.maximum(np.abs(robot.q_min), np.abs(robot.q_max))
    over = np.abs(ms.q) > lim + 0.05
    if np.any(over):
        i, j = np.argwhere(over)[0]
        deg_ok = np.all(np.abs(np.radians(ms.q)) <= lim + 0.05)
        hint = " — they fit the limits if read as degrees: degrees given as radians?" if deg_ok else ""
        raise InputError(
            f"joint {robot.joint_names[j]} = {ms.q[i, j]:.4g} rad in pose {i} is beyond its limits "
            f"[{robot.q_min[j]:.3f}, {robot.q_max[j]:.3f}]{hint}",
            file=file,
            field=f"poses[{int(i)}].q_rad",
        )
    # Positions: the measured cloud cannot be larger than the arm's reach allows.
    p = ms.position_m[ms.valid]
    if p.shape[0] >= 2:
        spread = float(np.max(np.ptp(p, axis=0)))
        reach = robot.reach_m
        if spread > 2.5 * reach:
            hint = " (millimetres given as metres?)" if spread / 1000 < 2.5 * reach else ""
            raise InputError(
                f"measured TCP positions span {spread:.4g} m but the arm reaches only ≈{reach:.2f} m{hint}",
                file=file,
                field="position_m",
            )


def register_base(robot: Robot, q: np.ndarray, positions_m: np.ndarray) -> pin.SE3:
    """tracker_to_base by rigid registration (Kabsch) of nominal TCP positions onto measured ones."""
    if q.shape[0] < 3:
        raise InputError("need at least 3 valid poses to register the robot base in the tracker frame")
    nominal, _ = predict_poses(robot, q)
    mc, nc = positions_m.mean(0), nominal.mean(0)
    h = (nominal - nc).T @ (positions_m - mc)
    u, s, vt = np.linalg.svd(h)
    if s[1] < 1e-9 * max(s[0], 1e-300):
        raise InputError("the measured positions are collinear: the base cannot be registered")
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return pin.SE3(r, mc - r @ nc)


# ---------------------------------------------------------------------------------------------------
# Residuals and statistics


def _log3(r: np.ndarray) -> np.ndarray:
    """Batched log3 for rotations away from π ([N, 3, 3] → [N, 3])."""
    w = 0.5 * np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1)
    s = np.linalg.norm(w, axis=1)
    c = 0.5 * (np.trace(r, axis1=1, axis2=2) - 1.0)
    theta = np.arctan2(s, c)
    k = np.where(s > 1e-12, theta / np.maximum(s, 1e-300), 1.0 + s * s / 6.0)
    return w * k[:, None]


def _skew(v: np.ndarray) -> np.ndarray:
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def _jlog3(phi: np.ndarray) -> np.ndarray:
    """Batched inverse right Jacobian of SO(3) at log vectors [N, 3] (pin.Jlog3)."""
    th = np.linalg.norm(phi, axis=1)
    k = _skew(phi)
    small = th < 1e-5
    ths = np.where(small, 1.0, th)
    coef = np.where(small, 1.0 / 12.0, 1.0 / ths**2 - (1 + np.cos(ths)) / (2 * ths * np.sin(ths)))
    return np.eye(3) + 0.5 * k + coef[:, None, None] * (k @ k)


@dataclass(frozen=True)
class _Problem:
    robot: Robot
    q: np.ndarray
    p_meas: np.ndarray
    r_meas: np.ndarray | None
    t2b: pin.SE3
    sigma_p: float
    sigma_o: float
    idx: np.ndarray
    point: np.ndarray | None

    def errors(self, x: np.ndarray) -> ErrorModel:
        v = np.zeros(len(parameter_names(self.robot)))
        v[self.idx] = x
        return ErrorModel(parameter_names(self.robot), v)

    def residual(self, x: np.ndarray) -> np.ndarray:
        p, r = predict_poses(self.robot, self.q, self.errors(x), self.t2b, self.point)
        res = [(p - self.p_meas) / self.sigma_p]
        if self.r_meas is not None:
            res.append(_log3(r @ self.r_meas.transpose(0, 2, 1)) / self.sigma_o)
        return np.concatenate(res, axis=1).ravel()

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        e = self.errors(x)
        po = self.r_meas is None
        jac = identification_jacobians(self.robot, self.q, e, self.t2b, po, self.point)[:, :, self.idx]
        jp = jac[:, :3] / self.sigma_p
        if po:
            return jp.reshape(-1, len(self.idx))
        _, r = predict_poses(self.robot, self.q, e, self.t2b, self.point)
        err = r @ self.r_meas.transpose(0, 2, 1)
        jo = _jlog3(_log3(err)) @ err.transpose(0, 2, 1) @ jac[:, 3:] / self.sigma_o
        return np.concatenate([jp, jo], axis=1).reshape(-1, len(self.idx))


def pose_errors(
    robot: Robot,
    ms: MeasurementSet,
    errors: ErrorModel | None,
    tracker_to_base: pin.SE3,
    point: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """(measured − predicted position [N, 3] m, Cardan x-y-z of R_meas·R_predᵀ [N, 3] rad or None)."""
    p, r = predict_poses(robot, ms.q, errors, tracker_to_base, point)
    e_pos = ms.position_m - p
    e_ori = None if ms.rotation is None else cardan_xyz(ms.rotation @ r.transpose(0, 2, 1))
    return e_pos, e_ori


@dataclass(frozen=True)
class ErrorStats:
    """The paper's Table 2 for one pose set and model."""

    n_poses: int
    max_abs: np.ndarray  # [6] x, y, z (m), α, β, γ (rad); NaN for orientation when position only
    peak_to_peak: np.ndarray
    rms: np.ndarray
    max_position_error_m: float
    max_orientation_error_rad: float | None
    rms_position_error_m: float  # sqrt(mean over poses of |e_xyz|²)


def error_table(
    robot: Robot, ms: MeasurementSet, errors: ErrorModel | None, tracker_to_base: pin.SE3, point=None
) -> ErrorStats:
    e_pos, e_ori = pose_errors(robot, ms, errors, tracker_to_base, point)
    e = np.concatenate([e_pos, np.full_like(e_pos, np.nan) if e_ori is None else e_ori], axis=1)
    max_ori = None
    if ms.rotation is not None:
        _, r = predict_poses(robot, ms.q, errors, tracker_to_base, point)
        max_ori = float(np.max(np.linalg.norm(_log3(ms.rotation @ r.transpose(0, 2, 1)), axis=1)))
    return ErrorStats(
        n_poses=ms.n,
        max_abs=np.max(np.abs(e), axis=0),
        peak_to_peak=np.ptp(e, axis=0),
        rms=np.sqrt(np.mean(e**2, axis=0)),
        max_position_error_m=float(np.max(np.linalg.norm(e_pos, axis=1))),
        max_orientation_error_rad=max_ori,
        rms_position_error_m=float(np.sqrt(np.mean(np.sum(e_pos**2, axis=1)))),
    )


# ---------------------------------------------------------------------------------------------------
# The calibration


class CalibrateSettings(BaseModel):
    """Options of `calibrate` (the stage's settings, recorded in the artefact)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    holdout_fraction: float | None = Field(
        None,
        ge=0.0,
        lt=1.0,
        description="fraction of the fit-role poses held out (seeded); default 0 if the file has "
        "validation poses, else 0.25",
    )
    seed: int = 0
    loss: Literal["linear", "soft_l1", "huber", "cauchy"] = Field(
        "linear", description="robust loss on the weighted residuals (scale 3σ); linear = plain LM"
    )
    outlier_sigma: float = Field(
        5.0, gt=0, description="flag a pose with a residual beyond this many robust σ"
    )
    drop_outliers: bool = True
    position_sigma_m: float | None = Field(
        None, gt=0, description="tracker position noise; default file or 5e-5"
    )
    orientation_sigma_rad: float | None = Field(
        None, gt=0, description="tracker orientation noise; default 1e-4"
    )
    point_in_tcp_m: tuple[float, float, float] | None = Field(
        None, description="measured point in the TCP frame (position-only probes); default the TCP origin"
    )
    max_iterations: int = Field(100, ge=1)


@dataclass(frozen=True)
class FitResult:
    errors: ErrorModel
    std: np.ndarray  # [48], NaN for fixed parameters
    estimated: np.ndarray  # [48] bool
    residual_scale: float  # sqrt(χ²/dof) of the weighted residuals
    iterations: int
    cond: float  # of the scaled Jacobian at the solution


@dataclass(frozen=True)
class CalibrationResult:
    fit: FitResult
    frames_only: FitResult
    identifiable: IdentifiableSet
    tracker_to_base: pin.SE3
    tracker_to_base_source: str
    fit_idx: np.ndarray
    heldout_idx: np.ndarray
    outlier_idx: np.ndarray
    tables: dict[tuple[str, str], ErrorStats]  # (pose set, model) → stats
    baseline: BaselineComparison | None  # the same calibration from the 'baseline' poses, if measured
    measurement: str
    settings: CalibrateSettings
    seconds: float


def _fit(
    robot: Robot,
    ms: MeasurementSet,
    t2b: pin.SE3,
    idx: np.ndarray,
    sigma_p: float,
    sigma_o: float,
    point: np.ndarray | None,
    settings: CalibrateSettings,
) -> FitResult:
    prob = _Problem(robot, ms.q, ms.position_m, ms.rotation, t2b, sigma_p, sigma_o, np.asarray(idx), point)
    x0 = np.zeros(len(idx))
    m = prob.residual(x0).size
    if m <= len(idx):
        raise InputError(f"{m} equations for {len(idx)} parameters: too few poses", file=ms.source)
    if settings.loss == "linear":
        sol = scipy.optimize.least_squares(
            prob.residual,
            x0,
            jac=prob.jacobian,
            method="lm",
            max_nfev=settings.max_iterations * (len(idx) + 1),
        )
    else:
        sol = scipy.optimize.least_squares(
            prob.residual,
            x0,
            jac=prob.jacobian,
            method="trf",
            loss=settings.loss,
            f_scale=3.0,
            max_nfev=settings.max_iterations,
        )
    if not sol.success:
        raise InfeasibleError(f"calibration did not converge: {sol.message}")
    jac = prob.jacobian(sol.x)
    res = prob.residual(sol.x)
    dof = m - len(idx)
    s2 = float(res @ res) / dof
    sv = np.linalg.svd(jac * (1 / np.linalg.norm(jac, axis=0)), compute_uv=False)
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    names = parameter_names(robot)
    std = np.full(len(names), np.nan)
    std[idx] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    est = np.zeros(len(names), dtype=bool)
    est[idx] = True
    return FitResult(prob.errors(sol.x), std, est, math.sqrt(s2), int(sol.nfev), float(sv[0] / sv[-1]))


def _rank_check(robot: Robot, ms: MeasurementSet, ident: IdentifiableSet, point: np.ndarray | None) -> None:
    """Refuse a fit pose set that cannot identify the structurally identifiable parameters."""
    po = ms.position_only
    jac = identification_jacobians(robot, ms.q, None, None, po, point)
    row_w, col_s = measurement_scaling(robot, po)
    idx = list(ident.indices)
    a = (jac * row_w[None, :, None]).reshape(-1, len(parameter_names(robot)))[:, idx] * col_s[idx]
    a = a / np.maximum(np.linalg.norm(a, axis=0), 1e-300)
    _, r, piv = scipy.linalg.qr(a, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    weak = piv[diag < 1e-8 * diag[0]] if diag.size else []
    if len(weak):
        names = [ident.names[i] for i in weak]
        raise InputError(
            f"the {ms.n} fit poses cannot identify {len(names)} of the {len(idx)} identifiable parameters "
            f"(rank-deficient pose set; e.g. {names[:6]}): measure more varied poses (rxcomm select-configs)",
            file=ms.source,
            field="poses",
        )


def _frames_only_indices(robot: Robot, ms: MeasurementSet, point: np.ndarray | None) -> np.ndarray:
    names = parameter_names(robot)
    cand = [i for i, n in enumerate(names) if n.startswith(("base.", "tool."))]
    po = ms.position_only
    jac = identification_jacobians(robot, ms.q, None, None, po, point)
    row_w, col_s = measurement_scaling(robot, po)
    a = (jac * row_w[None, :, None]).reshape(-1, len(names))[:, cand] * col_s[cand]
    norms = np.linalg.norm(a, axis=0)
    live = norms > 1e-9 * norms.max()
    a = a[:, live] / norms[live]
    _, r, piv = scipy.linalg.qr(a, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    keep = np.array(cand)[live][piv[diag > 1e-8 * diag[0]]]
    return np.sort(keep)


@dataclass(frozen=True)
class BaselineComparison:
    """The full calibration fitted to the `baseline` poses instead (a reference set such as
    select-configs' linear scan), judged on the same held-out measurements as the main fit.

    `worse_p_value`: one-sided Wilcoxon signed-rank test that the baseline fit misses the held-out
    poses by more than the main fit, pose by pose, in the fit's own metric (the weighted residual:
    position /σ_p, orientation /σ_o); small means measurably worse. `fit` is None when the baseline
    poses cannot identify the parameters; `note` then says why."""

    n_poses: int
    fit: FitResult | None
    fit_idx: np.ndarray
    outlier_idx: np.ndarray
    worse_p_value: float | None
    note: str | None = None


@dataclass(frozen=True)
class _Fitter:
    """One weighted fit setting (model, base, noise, identifiable set) applied to pose subsets."""

    robot: Robot
    ms: MeasurementSet
    t2b: pin.SE3
    ident: IdentifiableSet
    sigma_p: float
    sigma_o: float
    point: np.ndarray | None
    settings: CalibrateSettings
    need: int  # the fewest poses the identifiable set needs

    @property
    def idx(self) -> np.ndarray:
        return np.array(self.ident.indices)

    def fit(self, poses: np.ndarray) -> FitResult:
        return _fit(
            self.robot,
            self.ms.subset(poses),
            self.t2b,
            self.idx,
            self.sigma_p,
            self.sigma_o,
            self.point,
            self.settings,
        )

    def residuals(self, poses: np.ndarray, fit: FitResult) -> np.ndarray:
        """[n, rows]: the weighted residuals (position /σ_p, orientation /σ_o) of `fit` at `poses`."""
        sub = self.ms.subset(poses)
        prob = _Problem(
            self.robot,
            sub.q,
            sub.position_m,
            sub.rotation,
            self.t2b,
            self.sigma_p,
            self.sigma_o,
            self.idx,
            self.point,
        )
        return prob.residual(fit.errors.values[self.idx]).reshape(poses.size, -1)

    def fit_dropping_outliers(self, poses: np.ndarray) -> tuple[FitResult, np.ndarray, np.ndarray]:
        """(fit, the poses it used, the flagged poses). A pose with a component beyond outlier_sigma
        robust σ (MAD of all weighted residual components) is flagged. One blunder smears into its
        neighbours' residuals through the fit, so when dropping, the worst pose only is removed and
        the rest refitted, until none is beyond (at most a quarter of the poses)."""
        result = self.fit(poses)
        flagged: list[int] = []
        while True:
            res = self.residuals(poses, result)
            scale = max(1.4826 * float(np.median(np.abs(res))), 1e-12)
            worst = np.max(np.abs(res), axis=1)
            beyond = worst > self.settings.outlier_sigma * scale
            if not np.any(beyond):
                break
            if not self.settings.drop_outliers:
                flagged += poses[beyond].tolist()
                break
            k = int(np.argmax(worst))
            flagged.append(int(poses[k]))
            poses = np.delete(poses, k)
            if poses.size < self.need or len(flagged) > max(1, poses.size // 4):
                raise InputError(
                    f"{len(flagged)} outlier poses ({flagged[:10]}) leave {poses.size} fit poses: the "
                    f"measurements do not fit the model (need {self.need} good poses)",
                    file=self.ms.source,
                    field="poses",
                )
            result = self.fit(poses)
        return result, poses, np.array(sorted(flagged), dtype=int)

    def compare_baseline(self, poses: np.ndarray, heldout: np.ndarray, main: FitResult) -> BaselineComparison:
        """The same calibration from the baseline poses; a set that cannot identify the parameters
        is reported, not raised (it is a reference, not the user's calibration)."""
        none = np.array([], dtype=int)
        try:
            if poses.size < self.need:
                raise InputError(f"{poses.size} valid poses, the parameters need at least {self.need}")
            _rank_check(self.robot, self.ms.subset(poses), self.ident, self.point)
            fit, used, flagged = self.fit_dropping_outliers(poses)
        except InputError as e:
            return BaselineComparison(int(poses.size), None, none, none, None, note=e.reason)
        except InfeasibleError as e:
            return BaselineComparison(int(poses.size), None, none, none, None, note=str(e))
        p_value = None
        if heldout.size:
            diff = self.weighted_misfit(heldout, fit) - self.weighted_misfit(heldout, main)
            if np.any(diff != 0):
                p_value = float(scipy.stats.wilcoxon(diff, alternative="greater").pvalue)
        return BaselineComparison(int(poses.size), fit, used, flagged, p_value)

    def weighted_misfit(self, poses: np.ndarray, fit: FitResult) -> np.ndarray:
        """Per pose, ‖r‖² of the weighted residual as the fit weighs it, of `fit`'s parameters."""
        return np.sum(self.residuals(poses, fit) ** 2, axis=1)


def calibrate(
    robot: Robot,
    ms: MeasurementSet,
    settings: CalibrateSettings | None = None,
    tracker_to_base: pin.SE3 | None = None,
) -> CalibrationResult:
    """Identify the geometric errors from `ms` (see the module docstring). `tracker_to_base` (e.g.
    from the cell) overrides the measurement file's; without either, the base is registered."""
    t0 = time.perf_counter()
    settings = settings or CalibrateSettings()
    point = None if settings.point_in_tcp_m is None else np.array(settings.point_in_tcp_m)
    sigma_p = settings.position_sigma_m or ms.position_sigma_m or 5e-5
    sigma_o = settings.orientation_sigma_rad or ms.orientation_sigma_rad or 1e-4
    po = ms.position_only
    rows = 3 if po else 6
    valid = np.flatnonzero(ms.valid)
    roles = np.array(ms.role)
    heldout = valid[roles[valid] == "validation"]
    fit = valid[roles[valid] == "fit"]
    frac = settings.holdout_fraction
    if frac is None:
        frac = 0.0 if heldout.size else 0.25
    if frac > 0 and fit.size:
        rng = np.random.default_rng(settings.seed)
        k = int(round(frac * fit.size))
        held = np.sort(rng.choice(fit, size=k, replace=False))
        heldout = np.union1d(heldout, held)
        fit = np.setdiff1d(fit, held)
    settings = settings.model_copy(update={"holdout_fraction": frac})
    ident = identifiable_parameters(robot, random_poses(robot, 60, np.random.default_rng(0)), po, point)
    p = len(ident)
    need = p // rows + 1
    if fit.size < need:
        raise InputError(
            f"{fit.size} valid fit poses give {fit.size * rows} equations for {p} identifiable parameters "
            f"({'position' if po else 'full pose'} measurement): need at least {need} fit poses "
            f"(≥ {2 * need} for a reliable fit; the paper uses 32)",
            file=ms.source,
            field="poses",
        )
    ms_fit = ms.subset(fit)
    _rank_check(robot, ms_fit, ident, point)
    # The nominal base in the tracker frame.
    if tracker_to_base is not None:
        t2b, source = tracker_to_base, "cell"
    elif ms.tracker_to_base is not None:
        t2b, source = ms.tracker_to_base, "measurements"
    else:
        t2b, source = register_base(robot, ms_fit.q, ms_fit.position_m), "registration"
    e_nom, _ = pose_errors(robot, ms_fit, None, t2b, point)
    med = float(np.median(np.linalg.norm(e_nom, axis=1)))
    if med > 0.05:
        raise InputError(
            f"the measured positions are {med * 1e3:.0f} mm (median) from the nominal robot's: wrong robot, "
            f"joint order, units, or tracker_to_base ({source})",
            file=ms.source,
            field="position_m",
        )
    fitter = _Fitter(robot, ms, t2b, ident, sigma_p, sigma_o, point, settings, need)
    result, fit, flagged = fitter.fit_dropping_outliers(fit)
    ms_fit = ms.subset(fit)
    frames_idx = _frames_only_indices(robot, ms_fit, point)
    frames = _fit(robot, ms_fit, t2b, frames_idx, sigma_p, sigma_o, point, settings)
    tables: dict[tuple[str, str], ErrorStats] = {}
    for set_name, sel in (("fit", fit), ("heldout", heldout)):
        if sel.size == 0:
            continue
        sub = ms.subset(sel)
        for model_name, errs in (
            ("nominal", None),
            ("calibrated", result.errors),
            ("frames_only", frames.errors),
        ):
            tables[(set_name, model_name)] = error_table(robot, sub, errs, t2b, point)
    baseline_poses = valid[roles[valid] == "baseline"]
    comparison = None
    if baseline_poses.size:
        comparison = fitter.compare_baseline(baseline_poses, heldout, result)
        if comparison.fit is not None and heldout.size:
            tables[("heldout", "baseline_poses")] = error_table(
                robot, ms.subset(heldout), comparison.fit.errors, t2b, point
            )
    return CalibrationResult(
        fit=result,
        frames_only=frames,
        identifiable=ident,
        tracker_to_base=t2b,
        tracker_to_base_source=source,
        fit_idx=fit,
        heldout_idx=heldout,
        outlier_idx=flagged,
        tables=tables,
        baseline=comparison,
        measurement="position" if po else "pose",
        settings=settings,
        seconds=time.perf_counter() - t0,
    )


# ---------------------------------------------------------------------------------------------------
# Calibrated URDF and loading a calibration


def _origin(joint: ET.Element) -> pin.SE3:
    o = joint.find("origin")
    xyz = [float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
    rpy = [float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
    return placement_to_se3(xyz, rpy)


def _set_origin(joint: ET.Element, m: pin.SE3) -> None:
    o = joint.find("origin")
    if o is None:
        o = ET.SubElement(joint, "origin")
    xyz, rpy = se3_to_xyz_rpy(m)
    o.set("xyz", " ".join(repr(v) for v in xyz))
    o.set("rpy", " ".join(repr(v) for v in rpy))


def calibrated_urdf_text(robot: Robot, errors: ErrorModel) -> str:
    """The robot's URDF with `errors` folded into the joint origins (see the module docstring)."""
    root = ET.parse(robot.urdf_path).getroot()
    joints = {j.get("name"): j for j in root.iter("joint")}
    model = robot.model
    for k, name in enumerate(robot.joint_names, start=1):
        el = joints[name]
        o = _origin(el)
        new = o * pin.exp6(errors.twist(name))
        if model.parents[k] == 0:
            # Pinocchio's placement = C·O (C: fixed joints above); exp(δb)·C·O = C·(C⁻¹·exp(δb)·C)·O.
            c = model.jointPlacements[k] * o.inverse()
            new = c.inverse() * pin.exp6(errors.twist("base")) * c * new
        _set_origin(el, new)
    tool = errors.twist("tool")
    if np.any(tool != 0):
        parent = robot.drives.tcp.parent_frame
        carrier = [
            j
            for j in root.iter("joint")
            if j.get("type") == "fixed" and j.find("child").get("link") == parent
        ]
        if not carrier:
            raise InputError(
                f"the tool error cannot be folded into the URDF: TCP parent frame {parent!r} is not the "
                "child of a fixed joint (add a fixed flange link)",
                file=robot.urdf_path,
                field="tcp.parent_frame",
            )
        f = placement_to_se3(robot.drives.tcp.xyz_m, robot.drives.tcp.rpy_rad)
        el = carrier[0]
        _set_origin(el, _origin(el) * f * pin.exp6(tool) * f.inverse())
    root.insert(0, ET.Comment(" calibrated by rxcomm: geometric errors folded into the joint origins "))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def write_calibrated_urdf(robot: Robot, errors: ErrorModel, path: str | Path) -> Path:
    """Write the calibrated URDF atomically. Load it with `load_robot(ROBOT_DIR, urdf=path)`."""
    return atomic_write_text(path, calibrated_urdf_text(robot, errors))


def load_calibration(path: str | Path) -> tuple[ErrorModel, pin.SE3]:
    """(ErrorModel, nominal tracker_to_base) from a `rxcomm/Calibration` artefact.

    `errors.apply(robot)` gives the calibrated robot (TCP in the cell's nominal base frame);
    `inverse_kinematics(robot, target, seed, errors=errors)` honours it.
    """
    art = read_yaml_artefact(path, Calibration)
    names = tuple(p.name for p in art.parameters)
    expected = {f"{g}.{c}" for g in ("base", "tool", *art.joint_names) for c in COMPONENTS}
    if set(names) != expected or len(names) != len(expected):
        raise InputError(
            "parameters must list the 48 error parameters exactly once", file=path, field="parameters"
        )
    order = parameter_names_from(art.joint_names)
    by_name = {p.name: p.value for p in art.parameters}
    t2b = placement_to_se3(art.tracker_to_base.xyz_m, art.tracker_to_base.rpy_rad)
    return ErrorModel(order, np.array([by_name[n] for n in order])), t2b


def parameter_names_from(joint_names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """`parameter_names` from joint names alone (no robot needed)."""
    return tuple(f"{g}.{c}" for g in ("base", *joint_names, "tool") for c in COMPONENTS)


def load_calibrated_robot(robot: Robot, path: str | Path) -> Robot:
    """`robot` with a calibration artefact's geometric errors applied: kinematics, IK and dynamics
    of the returned robot all honour the calibration (planners take it with `--calibration`)."""
    art = read_yaml_artefact(path, Calibration)
    if tuple(art.joint_names) != robot.joint_names:
        raise InputError(
            f"calibration is for joints {art.joint_names}, the robot has {list(robot.joint_names)}",
            file=path,
            field="joint_names",
        )
    errors = ErrorModel.from_mapping(robot, {p.name: p.value for p in art.parameters}, file=str(path))
    return errors.apply(robot)
