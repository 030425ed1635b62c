"""Geometric calibration from tracker measurements (paper §3.2; architecture §7 calibrate).

Model and parameters: `rxcomm.model.geometric_errors` (48 error twists; the identifiable subset by QR).
Problem: minimise Σᵢ ‖rᵢ‖² over the identifiable parameters p₁ (the others fixed at 0), with the
weighted residual of pose i

    rᵢ = [ (p_pred − p_meas) / σ_p ;  log3(R_pred·R_measᵀ) / σ_o ]     (tracker frame)

σ_p, σ_o the tracker's position and orientation noise (so rᵢ is ~N(0, I) when the model is right
and position and orientation are weighed by their precision). Levenberg–Marquardt
(`scipy.optimize.least_squares`, `method="lm"`; `trf` when a robust loss is asked) with the
analytic Jacobian of `geometric_errors` (orientation rows through the exact derivative of log3),
started at the closed-form base and tool frames, the joint errors at 0 (the paper starts at
p_e = 0). Standard deviations from the covariance s²·(JᵀJ)⁻¹ with s² the
residual variance per degree of freedom.

Around the fit (docs/calibrate-csv.md): the base and tool frames estimated from the data in closed
form (`estimate_frames`), so no guess is needed; a `tracker_to_base` from the measurements file or
the cell is the reference when it agrees with the data's, else replaced by it with a note; the
tracker noise given (settings, file) or estimated from the residuals (variance components,
`_Fitter.noise_from_residuals`); poses with a component beyond `outlier_sigma` robust σ after a first
fit are flagged (and dropped, by default, before the final fit); held-out poses (`validation` role,
or a seeded `holdout_fraction`) are never fitted; candidate models (base + tool frames; + joint
offsets; the full identifiable set; + joint compliance δq_j = c_j·τ_j with τ the prior model's
holding torque) compared by k-fold cross-validation over the fit poses, the simplest within one
standard error of the best chosen; the paper's Table 2 (`error_table`) before/after on fitted and
held-out poses, with the frames-only fit beside it; and, when the file has `baseline` poses (a naive
pose set measured for comparison), the chosen calibration fitted to those instead and judged on the
same held-out poses (`BaselineComparison`).

Input checks raise `InputError` (exit 2) with file and field: NaN rows, too few poses (says how
many are needed), a pose set that cannot identify some parameters (names them), positions that look
like millimetres, joint angles that look like degrees, orientations that do not fit a rigid tool
(angle convention), measurements that do not fit the robot even after the fit. A calibration worse
than the nominal model on the held-out poses raises `InfeasibleError` (exit 3).

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
from dataclasses import dataclass, replace
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
from rxcomm.model.dynamics import DynamicParameters, RobotDynamics, prior_parameters
from rxcomm.model.geometric_errors import (
    COMPONENTS,
    ErrorModel,
    IdentifiableSet,
    characteristic_length_m,
    identifiable_parameters,
    identification_jacobians,
    joint_motion_jacobians,
    joint_offset_names,
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
    angle_convention: str | None = None  # CSV only: how its orientation columns were read

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
            self.angle_convention,
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
    "x_m, y_m, z_m (or x_mm, y_mm, z_mm): TCP position in the tracker frame; optional TCP orientation "
    "in the tracker frame, the column names stating the convention: alpha_rad, beta_rad, gamma_rad "
    "(or _deg): Cardan angles x-y-z, R = Rx(alpha)·Ry(beta)·Rz(gamma); roll_rad, pitch_rad, yaw_rad "
    "(or _deg): R = Rz(yaw)·Ry(pitch)·Rx(roll) (URDF rpy); or qw, qx, qy, qz: a unit quaternion; "
    "optional valid (1/0) and role (fit/validation/baseline). See docs/calibrate-csv.md."
)

# Orientation columns: convention → (column stems, unit-suffixed or not).
ANGLE_CONVENTIONS = {
    "cardan_xyz": ("alpha", "beta", "gamma"),
    "rpy": ("roll", "pitch", "yaw"),
    "quaternion": ("qw", "qx", "qy", "qz"),
}


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
    conv, o_cols = None, []
    for name, stems in ANGLE_CONVENTIONS.items():
        if name == "quaternion":
            cols = [(col[st], 1.0) if st in col else None for st in stems]
        else:
            cols = [pick(a, ang, False) for a in stems]
        if any(c is not None for c in cols):
            if not all(c is not None for c in cols):
                raise InputError(f"give all of {', '.join(stems)} or none", file=path, field=stems[0])
            if conv is not None:
                raise InputError(
                    f"orientation given twice ({conv} and {name} columns): keep one convention",
                    file=path,
                    field=stems[0],
                )
            conv, o_cols = name, cols
    has_rot = conv is not None

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
    rot = None
    if o_arr is not None and conv == "quaternion":
        norms = np.linalg.norm(o_arr, axis=1)
        bad = np.flatnonzero(np.isfinite(norms) & (np.abs(norms - 1.0) > 1e-3))
        if bad.size:
            raise InputError(
                f"line {int(bad[0]) + 2}: quaternion norm {norms[bad[0]]:.6g}, not 1 (give w, x, y, z of a "
                "unit quaternion)",
                file=path,
                field="qw",
            )
        rot = np.array([rotation_from_wxyz(v / np.linalg.norm(v)) for v in o_arr])
    elif o_arr is not None:
        if np.nanmax(np.abs(o_arr)) > math.pi + 1e-6:
            first = header[o_cols[0][0]]
            raise InputError(
                f"orientation angles up to {np.nanmax(np.abs(o_arr)):.4g} rad exceed π: degrees given as "
                f"radians? (name the columns {first.rsplit('_', 1)[0]}_deg, …)",
                file=path,
                field=first,
            )
        if conv == "cardan_xyz":
            rot = cardan_xyz_matrix(o_arr)
        else:
            rot = np.array([pin.rpy.rpyToMatrix(v) for v in o_arr])
    return MeasurementSet(
        q=np.array(q, dtype=float),
        position_m=np.array(p, dtype=float),
        rotation=rot,
        valid=np.array(valid, dtype=bool),
        role=tuple(role),
        source=str(path),
        angle_convention=conv,
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


# ---------------------------------------------------------------------------------------------------
# Frames from the data (closed form)


def _kabsch(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The rotation R minimising Σ‖v_k − R·u_k‖² (rows of u, v; no centring)."""
    a, _, bt = np.linalg.svd(u.T @ v)
    d = np.sign(np.linalg.det(bt.T @ a.T))
    return bt.T @ np.diag([1.0, 1.0, d]) @ a.T


def _project_so3(m: np.ndarray) -> np.ndarray:
    """The rotation nearest to `m` (Frobenius): the chordal mean of rotations summed into `m`."""
    a, _, bt = np.linalg.svd(m)
    return a @ np.diag([1.0, 1.0, np.sign(np.linalg.det(a @ bt))]) @ bt


@dataclass(frozen=True)
class DataFrames:
    """Base and tool frames estimated from the measurements alone: the measured pose
    X_i ≈ tracker_to_base · A(q_i) · tool with A the nominal TCP pose in the base frame (drives.yaml's
    TCP). `rotation_rms_rad`: what a rigid tool leaves of the measured orientations (None: positions)."""

    tracker_to_base: pin.SE3
    tool: pin.SE3  # the TCP correction: tcp' = tcp · tool
    rotation_rms_rad: float | None


def estimate_frames(robot: Robot, ms: MeasurementSet, point: np.ndarray | None = None) -> DataFrames:
    """tracker_to_base and the tool correction in closed form, no guess needed.

    Full pose: the base rotation R_Y from the relative rotations (log(R_Mi·R_Mjᵀ) = R_Y·log(R_Ai·R_Ajᵀ),
    a Kabsch fit of rotation vectors over pose pairs), the tool rotation R_D the chordal mean of
    R_Aiᵀ·R_Yᵀ·R_Mi, then base and tool translations by linear least squares (p_Mi − R_Y·a_i =
    R_Y·R_Ai·w + t_Y). Positions only: Kabsch registration of the nominal points alternated with the
    linear solve for the point offset w (converges in a few rounds from w = the nominal point).
    """
    if ms.n < 3:
        raise InputError("need at least 3 valid poses to locate the robot base in the tracker frame")
    a_p, a_r = predict_poses(robot, ms.q)
    pt = np.zeros(3) if point is None else np.asarray(point, dtype=float)
    p_m = ms.position_m
    if np.linalg.svd(p_m - p_m.mean(0), compute_uv=False)[1] < 1e-6:
        raise InputError("the measured positions are collinear: the base cannot be located", file=ms.source)

    def translations(r_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # [R_Y·R_Ai, I]·[w; t_Y] = p_Mi − R_Y·a_i, stacked over poses.
        a = np.concatenate([r_y @ a_r, np.broadcast_to(np.eye(3), a_r.shape)], axis=2).reshape(-1, 6)
        b = (p_m - a_p @ r_y.T).reshape(-1)
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
        return sol[:3], sol[3:]

    rms = None
    if ms.rotation is not None:
        i, j = np.triu_indices(ms.n, 1)
        u = _log3(a_r[i] @ a_r[j].transpose(0, 2, 1))
        v = _log3(ms.rotation[i] @ ms.rotation[j].transpose(0, 2, 1))
        nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
        ok = (nu > 0.05) & (nu < 2.8) & (nv < 2.8)  # log3 is ill-conditioned near π
        if ok.sum() < 2:
            raise InputError("the poses hardly rotate the tool: the base cannot be located", file=ms.source)
        r_y = _kabsch(u[ok], v[ok])
        r_d = _project_so3(np.sum(a_r.transpose(0, 2, 1) @ r_y.T @ ms.rotation, axis=0))
        w, t_y = translations(r_y)
        left = _log3(ms.rotation @ (r_y @ a_r @ r_d).transpose(0, 2, 1))
        rms = float(np.sqrt(np.mean(np.sum(left**2, axis=1))))
    else:
        r_d, w, t_y = np.eye(3), pt, np.zeros(3)
        for _ in range(50):
            x = a_p + a_r @ w
            xc, mc = x.mean(0), p_m.mean(0)
            r_y = _kabsch(x - xc, p_m - mc)
            w_new, t_y = translations(r_y)
            done = np.linalg.norm(w_new - w) < 1e-9
            w = w_new
            if done:
                break
    return DataFrames(pin.SE3(r_y, t_y), pin.SE3(r_d, w - r_d @ pt), rms)


def register_base(robot: Robot, q: np.ndarray, positions_m: np.ndarray) -> pin.SE3:
    """tracker_to_base by rigid registration (Kabsch) of nominal TCP positions onto measured ones."""
    if q.shape[0] < 3:
        raise InputError("need at least 3 valid poses to register the robot base in the tracker frame")
    nominal, _ = predict_poses(robot, q)
    mc, nc = positions_m.mean(0), nominal.mean(0)
    r = _kabsch(nominal - nc, positions_m - mc)
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


# Compliance parameters are fitted as c·TAU_REF (rad per kN·m, ~1e-3 like the geometric ones).
TAU_REF_NM = 1000.0


def holding_torques(robot: Robot, q: np.ndarray, params: DynamicParameters | None = None) -> np.ndarray:
    """[N, n] static holding torque (gravity + balancer spring), N·m, of `params` (default the PRIOR
    dynamics model): what the joints' transmissions carry at standstill, so what bends them."""
    params = prior_parameters(robot) if params is None else params
    return RobotDynamics(robot, params).gravity_torque(np.atleast_2d(q))


@dataclass(frozen=True)
class _Problem:
    """The weighted residual of a fit: geometric parameters `idx` (into the 48) then, per compliant
    joint in `comp`, c_j·TAU_REF with the link at q − c·τ (τ the prior holding torque)."""

    robot: Robot
    q: np.ndarray
    p_meas: np.ndarray
    r_meas: np.ndarray | None
    t2b: pin.SE3
    sigma_p: float
    sigma_o: float
    idx: np.ndarray
    point: np.ndarray | None
    tau: np.ndarray | None = None  # [N, n] N·m, needed with `comp`
    comp: tuple[int, ...] = ()

    def errors(self, x: np.ndarray) -> ErrorModel:
        v = np.zeros(len(parameter_names(self.robot)))
        v[self.idx] = x[: len(self.idx)]
        return ErrorModel(parameter_names(self.robot), v)

    def q_link(self, x: np.ndarray) -> np.ndarray:
        if not self.comp:
            return self.q
        q = np.array(self.q)
        q[:, self.comp] -= self.tau[:, self.comp] * (x[len(self.idx) :] / TAU_REF_NM)
        return q

    def residual(self, x: np.ndarray) -> np.ndarray:
        p, r = predict_poses(self.robot, self.q_link(x), self.errors(x), self.t2b, self.point)
        res = [(p - self.p_meas) / self.sigma_p]
        if self.r_meas is not None:
            res.append(_log3(r @ self.r_meas.transpose(0, 2, 1)) / self.sigma_o)
        return np.concatenate(res, axis=1).ravel()

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        e, q = self.errors(x), self.q_link(x)
        po = self.r_meas is None
        jac = identification_jacobians(self.robot, q, e, self.t2b, po, self.point)[:, :, self.idx]
        if self.comp:
            jq = joint_motion_jacobians(self.robot, q, e, self.t2b, po, self.point)[:, :, list(self.comp)]
            jac = np.concatenate([jac, jq * (-self.tau[:, None, list(self.comp)] / TAU_REF_NM)], axis=2)
        k = jac.shape[2]
        jp = jac[:, :3] / self.sigma_p
        if po:
            return jp.reshape(-1, k)
        _, r = predict_poses(self.robot, q, e, self.t2b, self.point)
        err = r @ self.r_meas.transpose(0, 2, 1)
        jo = _jlog3(_log3(err)) @ err.transpose(0, 2, 1) @ jac[:, 3:] / self.sigma_o
        return np.concatenate([jp, jo], axis=1).reshape(-1, k)


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
        None, gt=0, description="tracker position noise (1σ, m); default the file's, else estimated"
    )
    orientation_sigma_rad: float | None = Field(
        None, gt=0, description="tracker orientation noise (1σ, rad); default the file's, else estimated"
    )
    point_in_tcp_m: tuple[float, float, float] | None = Field(
        None, description="measured point in the TCP frame (position-only probes); default the TCP origin"
    )
    max_iterations: int = Field(100, ge=1)
    cv_folds: int = Field(5, ge=2, description="folds of the cross-validation that chooses the model")
    model: Literal["auto", "frames", "offsets", "full", "full+compliance"] = Field(
        "auto", description="error model; auto: the simplest not significantly worse in cross-validation"
    )
    compliance: bool = Field(True, description="offer joint-compliance candidates to the model selection")
    undetermined_std_ratio: float = Field(
        5.0,
        gt=0,
        description="name a parameter whose σ at the TCP (m; rad × reach) exceeds this many position σ",
    )


@dataclass(frozen=True)
class FitResult:
    errors: ErrorModel
    std: np.ndarray  # [48], NaN for fixed parameters
    estimated: np.ndarray  # [48] bool
    residual_scale: float  # sqrt(χ²/dof) of the weighted residuals
    iterations: int
    cond: float  # of the scaled Jacobian at the solution
    compliance: np.ndarray | None = None  # [n] rad/(N·m), 0 for rigid joints; None: rigid model
    compliance_std: np.ndarray | None = None  # [n], NaN for joints not fitted
    x: np.ndarray | None = None  # the solution vector (warm starts)

    def link_angles(self, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The links' angles of this model at encoder angles q under holding torques τ."""
        return q if self.compliance is None else q - tau * self.compliance


@dataclass(frozen=True)
class Candidate:
    """One error model of the model selection and its k-fold cross-validation over the fit poses.

    `cv_misfit`: mean over poses of ‖r‖² (weighted residual) when the pose was held out; `cv_se` its
    standard error relative to the best candidate (paired); None when the folds cannot identify it."""

    name: str
    idx: tuple[int, ...]
    comp: tuple[int, ...]
    fit: FitResult | None
    cv_misfit: float | None
    cv_se: float | None
    cv_rms_position_m: float | None
    cv_rms_orientation_rad: float | None
    note: str | None = None

    @property
    def n_parameters(self) -> int:
        return len(self.idx) + len(self.comp)


@dataclass(frozen=True)
class TrackerNoise:
    position_sigma_m: float
    orientation_sigma_rad: float | None  # None: position-only measurements
    source: str  # "settings", "measurements" or "estimated"


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
    noise: TrackerNoise
    candidates: tuple[Candidate, ...]
    model: str  # the chosen candidate's name
    data_frames: DataFrames
    undetermined: tuple[str, ...] = ()  # parameters the data cannot determine (σ above the threshold)
    notes: tuple[str, ...] = ()  # what the user should know (frames far from the guess, tool offset…)


def _fit(
    robot: Robot,
    ms: MeasurementSet,
    t2b: pin.SE3,
    idx: np.ndarray,
    sigma_p: float,
    sigma_o: float,
    point: np.ndarray | None,
    settings: CalibrateSettings,
    x0: np.ndarray | None = None,
    tau: np.ndarray | None = None,
    comp: tuple[int, ...] = (),
) -> FitResult:
    idx = np.asarray(idx, dtype=int)
    prob = _Problem(robot, ms.q, ms.position_m, ms.rotation, t2b, sigma_p, sigma_o, idx, point, tau, comp)
    k = len(idx) + len(comp)
    x0 = np.zeros(k) if x0 is None else np.asarray(x0, dtype=float)
    m = prob.residual(x0).size
    if m <= k:
        raise InputError(f"{m} equations for {k} parameters: too few poses", file=ms.source)
    if settings.loss == "linear":
        sol = scipy.optimize.least_squares(
            prob.residual, x0, jac=prob.jacobian, method="lm", max_nfev=settings.max_iterations * (k + 1)
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
    dof = m - k
    s2 = float(res @ res) / dof
    sv = np.linalg.svd(jac * (1 / np.linalg.norm(jac, axis=0)), compute_uv=False)
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    names = parameter_names(robot)
    std = np.full(len(names), np.nan)
    std[idx] = sd[: len(idx)]
    est = np.zeros(len(names), dtype=bool)
    est[idx] = True
    compliance = compliance_std = None
    if comp:
        compliance, compliance_std = np.zeros(robot.n), np.full(robot.n, np.nan)
        compliance[list(comp)] = sol.x[len(idx) :] / TAU_REF_NM
        compliance_std[list(comp)] = sd[len(idx) :] / TAU_REF_NM
    return FitResult(
        prob.errors(sol.x),
        std,
        est,
        math.sqrt(s2),
        int(sol.nfev),
        float(sv[0] / sv[-1]),
        compliance,
        compliance_std,
        np.array(sol.x),
    )


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


def _independent(
    robot: Robot, ms: MeasurementSet, ordered: list[int], point: np.ndarray | None
) -> np.ndarray:
    """The parameters of `ordered` (preference order) that `ms` identifies: greedy Gram–Schmidt on the
    scaled Jacobian columns, keeping a column with more than 1e-6 of its norm outside the kept ones."""
    po = ms.position_only
    jac = identification_jacobians(robot, ms.q, None, None, po, point)
    row_w, col_s = measurement_scaling(robot, po)
    a = (jac * row_w[None, :, None]).reshape(-1, len(parameter_names(robot))) * col_s
    norms = np.linalg.norm(a, axis=0)
    basis = np.zeros((a.shape[0], 0))
    keep = []
    for i in ordered:
        if norms[i] <= 1e-9 * norms.max():
            continue
        c = a[:, i] / norms[i]
        for _ in range(2):
            c = c - basis @ (basis.T @ c)
        if np.linalg.norm(c) > 1e-6:
            keep.append(i)
            basis = np.column_stack([basis, c / np.linalg.norm(c)])
    return np.array(sorted(keep), dtype=int)


def _frames_only_indices(robot: Robot, ms: MeasurementSet, point: np.ndarray | None) -> np.ndarray:
    names = parameter_names(robot)
    return _independent(
        robot, ms, [i for i, n in enumerate(names) if n.startswith(("base.", "tool."))], point
    )


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
    """One weighted fit setting (model, base, noise, parameters) applied to pose subsets."""

    robot: Robot
    ms: MeasurementSet
    t2b: pin.SE3
    idx: np.ndarray  # geometric parameters (into the 48)
    sigma_p: float
    sigma_o: float
    point: np.ndarray | None
    settings: CalibrateSettings
    need: int  # the fewest poses the parameters need
    tau: np.ndarray  # [N, n] prior holding torques of all poses of `ms`
    comp: tuple[int, ...] = ()  # compliant joints
    x0: np.ndarray | None = None

    def problem(self, poses: np.ndarray) -> _Problem:
        sub = self.ms.subset(poses)
        return _Problem(
            self.robot,
            sub.q,
            sub.position_m,
            sub.rotation,
            self.t2b,
            self.sigma_p,
            self.sigma_o,
            np.asarray(self.idx),
            self.point,
            self.tau[poses],
            self.comp,
        )

    def fit(self, poses: np.ndarray, x0: np.ndarray | None = None) -> FitResult:
        return _fit(
            self.robot,
            self.ms.subset(poses),
            self.t2b,
            self.idx,
            self.sigma_p,
            self.sigma_o,
            self.point,
            self.settings,
            self.x0 if x0 is None else x0,
            self.tau[poses],
            self.comp,
        )

    def residuals(self, poses: np.ndarray, fit: FitResult) -> np.ndarray:
        """[n, rows]: the weighted residuals (position /σ_p, orientation /σ_o) of `fit` at `poses`."""
        return self.problem(poses).residual(fit.x).reshape(poses.size, -1)

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
            result = self.fit(poses, result.x)
        return result, poses, np.array(sorted(flagged), dtype=int)

    def noise_from_residuals(self, poses: np.ndarray, robust: bool, rounds: int = 6) -> _Fitter:
        """This fitter with σ_p, σ_o estimated from the fit's residuals (variance components):
        per group s² = Σ r_k² / Σ (1 − h_k) (Förstner), h the hat-matrix diagonal, so the redundancy
        the fit leaves each row is accounted for; `robust`: the scale 1.4826·median|r_k/√(1 − h_k)|
        instead, which a blunder does not inflate. Repeated until the weights settle."""
        f = self
        fit = None
        for _ in range(rounds):
            fit = f.fit(poses, None if fit is None else fit.x)
            prob = f.problem(poses)
            jac, res = prob.jacobian(fit.x), prob.residual(fit.x)
            qm, _ = np.linalg.qr(jac)
            red = np.maximum(1.0 - np.sum(qm**2, axis=1), 1e-6).reshape(poses.size, -1)
            z = np.abs(res.reshape(poses.size, -1)) / np.sqrt(red)
            if robust:
                k_p = 1.4826 * float(np.median(z[:, :3]))
                k_o = 1.4826 * float(np.median(z[:, 3:])) if z.shape[1] == 6 else 1.0
            else:
                k_p = math.sqrt(float(np.mean(z[:, :3] ** 2 * red[:, :3])) / float(np.mean(red[:, :3])))
                k_o = 1.0
                if z.shape[1] == 6:
                    k_o = math.sqrt(float(np.mean(z[:, 3:] ** 2 * red[:, 3:])) / float(np.mean(red[:, 3:])))
            f = replace(f, sigma_p=f.sigma_p * k_p, sigma_o=f.sigma_o * k_o)
            if abs(k_p - 1) < 0.01 and abs(k_o - 1) < 0.01:
                break
        return f

    def compare_baseline(self, poses: np.ndarray, heldout: np.ndarray, main: FitResult) -> BaselineComparison:
        """The same calibration from the baseline poses; a set that cannot identify the parameters
        is reported, not raised (it is a reference, not the user's calibration)."""
        none = np.array([], dtype=int)
        try:
            if poses.size < self.need:
                raise InputError(f"{poses.size} valid poses, the parameters need at least {self.need}")
            names = parameter_names(self.robot)
            sub = IdentifiableSet(tuple(self.idx), tuple(names[i] for i in self.idx), (), 0, 0.0, 0.0, 0.0)
            _rank_check(self.robot, self.ms.subset(poses), sub, self.point)
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

    def cross_validate(self, poses: np.ndarray, full: FitResult, folds: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per pose of `poses`: (weighted misfit, position error² m², orientation error² rad²) when its
        fold was held out; each fold's fit starts from `full` (the fit of all poses)."""
        mis = np.empty(poses.size)
        e_p = np.empty(poses.size)
        e_o = np.full(poses.size, np.nan)
        for k in np.unique(folds):
            test, train = poses[folds == k], poses[folds != k]
            fit = self.fit(train, full.x)
            r = self.residuals(test, fit)
            sel = folds == k
            mis[sel] = np.sum(r**2, axis=1)
            e_p[sel] = np.sum((r[:, :3] * self.sigma_p) ** 2, axis=1)
            if r.shape[1] == 6:
                e_o[sel] = np.sum((r[:, 3:] * self.sigma_o) ** 2, axis=1)
        return mis, e_p, e_o


def _candidates(robot: Robot, ms_fit: MeasurementSet, ident: IdentifiableSet, tau: np.ndarray, point, want):
    """(name, geometric indices, compliant joints) from the simplest to the richest model."""
    names = parameter_names(robot)
    frames = _frames_only_indices(robot, ms_fit, point)
    offsets = [names.index(n) for n in joint_offset_names(robot)]
    with_offsets = _independent(robot, ms_fit, [*frames, *[i for i in offsets if i in ident.indices]], point)
    full = np.array(ident.indices)
    out = [("frames", frames, ()), ("offsets", with_offsets, ()), ("full", full, ())]
    if want:
        # Joints whose holding torque matters (≥ 20 % of the largest) and varies over the poses.
        peak = np.max(np.abs(tau), axis=0)
        comp = tuple(int(j) for j in np.flatnonzero((peak >= 0.2 * peak.max()) & (np.ptp(tau, axis=0) > 1.0)))
        if comp:
            out.append(("full+compliance", full, comp))
    return out


def _choose(cands: list[Candidate]) -> Candidate:
    """The simplest candidate whose cross-validated misfit is within one paired standard error of
    the best's (the one-standard-error rule: a richer model must earn its parameters)."""
    scored = [c for c in cands if c.cv_misfit is not None]
    best = min(scored, key=lambda c: c.cv_misfit)
    for c in sorted(scored, key=lambda c: c.n_parameters):
        if c.cv_misfit - best.cv_misfit <= (c.cv_se or 0.0):
            return c
    return best


def _placement_gap(robot: Robot, q: np.ndarray, a: pin.SE3, b: pin.SE3, point) -> float:
    """Median distance (m) between the nominal TCP positions placed by base frames a and b."""
    pa, _ = predict_poses(robot, q, None, a, point)
    pb, _ = predict_poses(robot, q, None, b, point)
    return float(np.median(np.linalg.norm(pa - pb, axis=1)))


# A guessed base farther than this from the data's (median TCP displacement) is replaced by the data's.
BASE_GUESS_TOLERANCE_M = 0.02
# The tool correction beyond which drives.yaml's TCP is called wrong on the console.
TOOL_WARNING_M, TOOL_WARNING_RAD = 0.005, 0.02
# A rigid tool leaves at most this rms orientation after the closed-form frames (else: angle convention).
RIGID_TOOL_RAD = 0.05


def calibrate(
    robot: Robot,
    ms: MeasurementSet,
    settings: CalibrateSettings | None = None,
    tracker_to_base: pin.SE3 | None = None,
    dynamics: DynamicParameters | None = None,
) -> CalibrationResult:
    """Identify the geometric errors from `ms` (see the module docstring). `tracker_to_base` (e.g.
    from the cell) overrides the measurement file's as the guessed base; without either, or when the
    guess is far from the base the data give, the data's base (closed form) is the reference.
    `dynamics`: the model whose holding torques bend the joints (default the prior; an identified
    one makes the stiffness the true one rather than scaled by the prior's torque error)."""
    t0 = time.perf_counter()
    settings = settings or CalibrateSettings()
    point = None if settings.point_in_tcp_m is None else np.array(settings.point_in_tcp_m)
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
    notes: list[str] = []
    # The frames from the data; a guess is a reference when it agrees, never a refusal.
    data = estimate_frames(robot, ms_fit, point)
    if data.rotation_rms_rad is not None and data.rotation_rms_rad > RIGID_TOOL_RAD:
        conv = f" (read as {ms.angle_convention})" if ms.angle_convention else ""
        raise InputError(
            f"the measured orientations{conv} do not fit a rigid tool: with the best base and tool "
            f"rotations they are still {np.degrees(data.rotation_rms_rad):.1f}° rms off. Check the angle "
            "convention: alpha/beta/gamma columns are Cardan x-y-z (R = Rx·Ry·Rz), roll/pitch/yaw "
            "columns R = Rz·Ry·Rx, or give quaternion columns qw, qx, qy, qz (docs/calibrate-csv.md)",
            file=ms.source,
            field="orientation",
        )
    guess, source = (
        (tracker_to_base, "cell") if tracker_to_base is not None else (ms.tracker_to_base, "measurements")
    )
    if guess is None:
        t2b, source = data.tracker_to_base, "registration"
    else:
        gap = _placement_gap(robot, ms_fit.q, guess, data.tracker_to_base, point)
        if gap > BASE_GUESS_TOLERANCE_M:
            dr = np.degrees(np.linalg.norm(pin.log3(guess.rotation.T @ data.tracker_to_base.rotation)))
            notes.append(
                f"tracker_to_base from the {source} places the robot {gap * 1e3:.0f} mm (median at the TCP; "
                f"{dr:.1f}° rotation) from where the measurements put it: the base from the data is used "
                f"(check the {source}'s tracker_to_base)"
            )
            t2b, source = data.tracker_to_base, "registration"
        else:
            t2b = guess
    tool_twist = np.asarray(pin.log6(data.tool).vector)
    base_twist = np.asarray(pin.log6(t2b.inverse() * data.tracker_to_base).vector)
    names = parameter_names(robot)
    start = np.zeros(len(names))
    start[:6], start[-6:] = base_twist, tool_twist
    # Noise: given (settings, file) or estimated from the residuals.
    sp = settings.position_sigma_m or ms.position_sigma_m
    so = settings.orientation_sigma_rad or ms.orientation_sigma_rad
    noise_source = "settings" if settings.position_sigma_m else "measurements" if sp else "estimated"
    tau = holding_torques(robot, ms.q, dynamics)

    def fitter_for(idx: np.ndarray, comp: tuple[int, ...], base: _Fitter | None = None) -> _Fitter:
        x0 = np.concatenate([start[idx], np.zeros(len(comp))])
        if base is not None:
            return replace(base, idx=np.asarray(idx), comp=comp, x0=x0)
        return _Fitter(
            robot, ms, t2b, np.asarray(idx), sp or 1e-3, so or 1e-2, point, settings, need, tau, comp, x0
        )

    full_f = fitter_for(np.array(ident.indices), ())
    if noise_source == "estimated" or (not po and so is None):
        # Robust first (blunders), outliers out, then efficient on the clean poses, outliers again.
        full_f = full_f.noise_from_residuals(fit, robust=True)
        _, clean, _ = full_f.fit_dropping_outliers(fit)
        full_f = full_f.noise_from_residuals(clean, robust=False)
        if noise_source != "estimated":
            # Position noise given, orientation not: keep the given σ_p, the ratio from the residuals.
            full_f = replace(full_f, sigma_o=full_f.sigma_o * sp / full_f.sigma_p, sigma_p=sp)
    _, fit, flagged = full_f.fit_dropping_outliers(fit)
    ms_fit = ms.subset(fit)
    noise = TrackerNoise(full_f.sigma_p, None if po else full_f.sigma_o, noise_source)
    # The model chosen by the data: k-fold cross-validation over the fit poses.
    folds = np.random.default_rng(settings.seed + 1).permutation(fit.size) % min(settings.cv_folds, fit.size)
    cands: list[Candidate] = []
    per_pose: dict[str, np.ndarray] = {}
    for name, idx, comp in _candidates(robot, ms_fit, ident, tau[fit], point, settings.compliance):
        if settings.model != "auto" and name not in (settings.model, "frames"):
            continue
        f = fitter_for(idx, comp, full_f)
        idx_t = tuple(int(i) for i in idx)
        try:
            whole = f.fit(fit)
        except (InputError, InfeasibleError) as e:
            cands.append(Candidate(name, idx_t, comp, None, None, None, None, None, note=str(e)))
            continue
        try:
            mis, e_p, e_o = f.cross_validate(fit, whole, folds)
        except (InputError, InfeasibleError) as e:
            note = f"not cross-validated: {e}"
            cands.append(Candidate(name, idx_t, comp, whole, None, None, None, None, note=note))
            continue
        per_pose[name] = mis
        rms_o = None if po else float(np.sqrt(np.mean(e_o)))
        cands.append(
            Candidate(
                name, idx_t, comp, whole, float(np.mean(mis)), None, float(np.sqrt(np.mean(e_p))), rms_o
            )
        )
    if per_pose:
        best = min((c for c in cands if c.cv_misfit is not None), key=lambda c: c.cv_misfit)
        cands = [
            c
            if c.cv_misfit is None
            else replace(
                c, cv_se=float(np.std(per_pose[c.name] - per_pose[best.name], ddof=1) / math.sqrt(fit.size))
            )
            for c in cands
        ]
    if settings.model != "auto":
        chosen = next(c for c in cands if c.name == settings.model)
    elif per_pose:
        chosen = _choose(cands)
    else:
        # Too few poses to hold any out: the full rigid model, said so.
        chosen = next(c for c in cands if c.name == "full")
        notes.append(f"{fit.size} fit poses are too few to cross-validate the models: the full model is used")
    frames_c = next(c for c in cands if c.name == "frames")
    if chosen.fit is None:
        raise InputError(
            f"model {chosen.name!r} cannot be fitted: {chosen.note}", file=ms.source, field="model"
        )
    result, frames = chosen.fit, frames_c.fit
    if frames is None:
        raise InputError(f"the base + tool frames cannot be fitted: {frames_c.note}", file=ms.source)
    fitter = fitter_for(np.array(chosen.idx), chosen.comp, full_f)
    # Plausibility after the fit: what the frames and errors cannot explain is the wrong robot.
    ms_fit = ms.subset(fit)
    e_fit, _ = pose_errors(robot, _at_links(ms_fit, result, tau[fit]), result.errors, t2b, point)
    med = float(np.median(np.linalg.norm(e_fit, axis=1)))
    if med > 0.01:
        raise InputError(
            f"after fitting base, tool and joint errors the measured positions are still {med * 1e3:.0f} mm "
            "(median) from the robot's: wrong robot, joint order or signs, units, or joint angles that do "
            "not belong to the positions",
            file=ms.source,
            field="position_m",
        )
    tool = pin.exp6(result.errors.twist("tool"))
    if np.linalg.norm(tool.translation) > TOOL_WARNING_M or (
        not po and np.linalg.norm(pin.log3(tool.rotation)) > TOOL_WARNING_RAD
    ):
        notes.append(
            f"the tool (TCP) is {np.linalg.norm(tool.translation) * 1e3:.1f} mm"
            + ("" if po else f" / {np.degrees(np.linalg.norm(pin.log3(tool.rotation))):.2f}°")
            + " from drives.yaml's tcp: the calibration folds it in (update drives.yaml's tcp)"
        )
    if noise_source != "estimated" and result.residual_scale > 3:
        notes.append(
            f"residuals are {result.residual_scale:.1f}× the given tracker noise: the noise spec is "
            "optimistic or the model misses an effect"
        )
    if po:
        notes.append("position-only measurements: orientation is not measured, not scored, not calibrated")
    # Parameters the data cannot determine: σ at the TCP above the threshold (rotations × reach).
    length = characteristic_length_m(robot)
    lever = np.tile(np.array([1, 1, 1, length, length, length]), robot.n + 2)
    limit = settings.undetermined_std_ratio * noise.position_sigma_m
    undetermined = [names[i] for i in chosen.idx if result.std[i] * lever[i] > limit]
    for j in chosen.comp:
        c, sd = result.compliance[j], result.compliance_std[j]
        if not sd < 0.3 * abs(c):
            undetermined.append(f"{robot.joint_names[j]}.compliance")
    tables: dict[tuple[str, str], ErrorStats] = {}
    for set_name, sel in (("fit", fit), ("heldout", heldout)):
        if sel.size == 0:
            continue
        sub = ms.subset(sel)
        for model_name, fr in (("nominal", None), ("calibrated", result), ("frames_only", frames)):
            at = sub if fr is None else _at_links(sub, fr, tau[sel])
            tables[(set_name, model_name)] = error_table(
                robot, at, None if fr is None else fr.errors, t2b, point
            )
    # Sanity: the calibration must beat the nominal model on poses it never saw.
    if heldout.size:
        rigid_nominal = replace(fitter, idx=np.array([], dtype=int), comp=())
        nominal_mis = float(
            np.mean(rigid_nominal.problem(heldout).residual(np.zeros(0)).reshape(heldout.size, -1) ** 2)
            * rows
        )
        cal_mis = float(np.mean(fitter.weighted_misfit(heldout, result)))
        if cal_mis >= nominal_mis:
            nom, cal = tables[("heldout", "nominal")], tables[("heldout", "calibrated")]
            ori = ""
            if not po:
                ori = (
                    f", max orientation {np.degrees(nom.max_orientation_error_rad):.3f}° → "
                    f"{np.degrees(cal.max_orientation_error_rad):.3f}°"
                )
            raise InfeasibleError(
                f"the calibration is worse than the nominal model on the {heldout.size} held-out poses "
                f"(rms position {nom.rms_position_error_m * 1e3:.3f} → "
                f"{cal.rms_position_error_m * 1e3:.3f} mm"
                f"{ori}): the measurements do not describe this robot as modelled (angle convention, joint "
                "order, a moving tracker?); nothing written"
            )
    rigid = next((c for c in cands if c.name == "full"), None)
    if chosen.comp and rigid is not None and rigid.fit is not None and heldout.size:
        tables[("heldout", "rigid")] = error_table(robot, ms.subset(heldout), rigid.fit.errors, t2b, point)
    baseline_poses = valid[roles[valid] == "baseline"]
    comparison = None
    if baseline_poses.size:
        comparison = fitter.compare_baseline(baseline_poses, heldout, result)
        if comparison.fit is not None and heldout.size:
            sub = ms.subset(heldout)
            tables[("heldout", "baseline_poses")] = error_table(
                robot, _at_links(sub, comparison.fit, tau[heldout]), comparison.fit.errors, t2b, point
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
        noise=noise,
        candidates=tuple(cands),
        model=chosen.name,
        data_frames=data,
        undetermined=tuple(undetermined),
        notes=tuple(notes),
    )


def _at_links(ms: MeasurementSet, fit: FitResult, tau: np.ndarray) -> MeasurementSet:
    """`ms` with the joint angles the fit's model puts the links at (compliance deflection)."""
    return ms if fit.compliance is None else replace(ms, q=fit.link_angles(ms.q, tau))


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
