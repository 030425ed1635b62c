"""Tracker measurements as arrays: a `rxcomm/Measurements` artefact or a tracker CSV, checked for
NaN rows and implausible units before any fit (paper §3.2; docs/calibrate-csv.md for the CSV)."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from rxcomm.errors import InputError
from rxcomm.io.validate import check_kind, validate_model
from rxcomm.io.yaml_io import load_yaml
from rxcomm.model.geometric_errors import placement_to_se3
from rxcomm.model.kinematics import cardan_xyz_matrix, rotation_from_wxyz
from rxcomm.model.robot import Robot
from rxcomm.schemas.measurements import Measurements


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

    def unread(self, role: str) -> tuple[int, int]:
        """(poses of `role` without a tracker reading, poses of `role`)."""
        mine = np.array(self.role) == role
        return int(np.sum(mine & ~self.valid)), int(np.sum(mine))

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
