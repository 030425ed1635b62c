"""CSV exports for tools outside rxcomm: a trajectory for a controller, a run log for a spreadsheet.

Format (both): ``#`` comment lines first (what the file is, where it came from, the units), then one
header line of column names with the unit as their last word (``t_s``, ``q1_rad``, ``qd1_rad_s``,
``tau_ff1_Nm``), then one row per sample. Numbers are written with 17 significant digits, so a
float64 reads back exactly; a value not measured (NaN) is an empty cell. The readers here are the
round trip's other half (and what a test holds the files to).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_text
from rxcomm.io.run_log import read_run_log
from rxcomm.io.trajectory import Trajectory
from rxcomm.schemas.plain import sha256_file
from rxcomm.schemas.run_log import JOINT_FIELDS

# unit of a field's description (its first word) -> the column suffix
_UNIT_SUFFIX = {
    "rad": "rad",
    "rad/s": "rad_s",
    "rad/s²": "rad_s2",
    "N·m": "Nm",
    "m": "m",
    "m/s": "m_s",
    "s": "s",
}
TRAJECTORY_FIELDS = (("q", "rad"), ("qd", "rad_s"), ("qdd", "rad_s2"), ("tau_ff", "Nm"))


def _fmt(x: float) -> str:
    return "" if not np.isfinite(x) else f"{x:.17g}"


def _write_csv(path: Path, comments: Sequence[str], header: list[str], columns: list[np.ndarray]) -> Path:
    buf = io.StringIO()
    for line in comments:
        buf.write(f"# {line}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    table = np.column_stack([np.asarray(c, dtype=float) for c in columns]) if columns else np.zeros((0, 0))
    for row in table:
        w.writerow([_fmt(x) for x in row])
    atomic_write_text(path, buf.getvalue())
    return path


def read_csv_table(path: str | Path) -> tuple[list[str], dict[str, np.ndarray]]:
    """(comment lines, column name -> float64 values, empty cell -> NaN) of a CSV written here."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as e:
        raise InputError(f"cannot read: {e}", file=path) from e
    comments = [ln[1:].strip() for ln in lines if ln.startswith("#")]
    rows = list(csv.reader(ln for ln in lines if ln and not ln.startswith("#")))
    if not rows:
        raise InputError("no header line", file=path)
    header, body = rows[0], rows[1:]
    for i, r in enumerate(body):
        if len(r) != len(header):
            raise InputError(f"row {i + 1} has {len(r)} cells, the header {len(header)}", file=path)
    values = np.full((len(body), len(header)), np.nan)
    for i, r in enumerate(body):
        for j, x in enumerate(r):
            try:
                values[i, j] = float(x) if x else np.nan
            except ValueError:
                raise InputError(f"row {i + 1}: {x!r} is not a number", file=path, field=header[j]) from None
    values = values.reshape(len(body), len(header))
    return comments, {name: values[:, j] for j, name in enumerate(header)}


# ---------------------------------------------------------------- trajectory


def trajectory_header(joint_names: Sequence[str]) -> list[str]:
    """``t_s`` then ``q_<joint>_rad`` … ``tau_ff_<joint>_Nm``, the joints in the robot's order."""
    return ["t_s", *(f"{f}_{name}_{unit}" for f, unit in TRAJECTORY_FIELDS for name in joint_names)]


def _legacy_header(dof: int) -> list[str]:  # before joint names (q1_rad …): still read
    return ["t_s", *(f"{f}{j + 1}_{unit}" for f, unit in TRAJECTORY_FIELDS for j in range(dof))]


TRAJECTORY_UNITS = (
    "units: t s (from the plan's start); q rad; qd rad/s; qdd rad/s²; tau_ff N·m, the feed-forward "
    "torque on the joint (link) side of the gearbox; columns per joint in the robot's order"
)


def write_trajectory_csv(
    path: str | Path, traj: Trajectory, joint_names: Sequence[str], comments: Sequence[str] = ()
) -> Path:
    """t, q, q̇, q̈, τ_ff per joint (s, rad, rad/s, rad/s², N·m), one row per sample."""
    if len(joint_names) != traj.dof:
        raise InputError(f"{len(joint_names)} joint names for {traj.dof} joints", field="joint_names")
    cols = [traj.t, *(getattr(traj, f)[:, j] for f, _ in TRAJECTORY_FIELDS for j in range(traj.dof))]
    joints = "joints: " + ", ".join(joint_names)
    return _write_csv(Path(path), [*comments, TRAJECTORY_UNITS, joints], trajectory_header(joint_names), cols)


def csv_joint_names(header: Sequence[str]) -> list[str]:
    """The joint names of a trajectory CSV header: the ``q_<joint>_rad`` columns in order."""
    return [c[2:-4] for c in header if c.startswith("q_") and c.endswith("_rad") and len(c) > 6]


def read_trajectory_csv_named(path: str | Path) -> tuple[Trajectory, list[str] | None]:
    """(trajectory, joint names; None for the old ``q1_rad`` header) of a trajectory CSV
    (:func:`write_trajectory_csv`'s columns, in any order). InputError names the row or column that is
    wrong; rows count from 1 at the first data row."""
    path = Path(path)
    _, cols = read_csv_table(path)
    names = csv_joint_names(list(cols))
    if names:
        expected = trajectory_header(names)
    else:
        dof = sum(1 for k in cols if k.startswith("q") and k.endswith("_rad") and k[1:-4].isdigit())
        names, expected = [f"joint{j + 1}" for j in range(dof)], _legacy_header(dof)
    missing = [c for c in expected if c not in cols]
    if not names or missing or len(cols) != len(expected):
        extra = [c for c in cols if c not in expected]
        raise InputError(
            f"trajectory columns: missing {missing}, unknown {extra} (expected {expected})",
            file=path,
            field="header",
        )
    arrays = {
        f: np.column_stack([cols[expected[1 + k * len(names) + j]] for j in range(len(names))])
        for k, (f, _) in enumerate(TRAJECTORY_FIELDS)
    }
    for f, a in (("t", cols["t_s"][:, None]), *arrays.items()):
        bad = ~np.isfinite(a).all(axis=1)
        if bad.any():
            raise InputError(f"row {int(np.argmax(bad)) + 1}: {f} is empty or not finite", file=path, field=f)
    try:
        traj = Trajectory(cols["t_s"], arrays["q"], arrays["qd"], arrays["qdd"], arrays["tau_ff"])
    except ValueError as e:
        raise InputError(str(e).replace("sample", "row"), file=path) from e
    return traj, (None if expected == _legacy_header(len(names)) else names)


def read_trajectory_csv(path: str | Path) -> Trajectory:
    """The trajectory of :func:`read_trajectory_csv_named`."""
    return read_trajectory_csv_named(path)[0]


# ---------------------------------------------------------------- run log


def _suffix(name: str, description: str) -> str:
    unit = description.split(",")[0].strip()
    suffix = _UNIT_SUFFIX.get(unit, "")
    return "" if not suffix or name.endswith("_" + suffix) else "_" + suffix


def run_log_header(
    fields: Mapping[str, str], shapes: Mapping[str, tuple[int, ...]], joints: Sequence[str]
) -> list[str]:
    """``t_s`` then per field one column (scalar) or one per joint (``q_actual_joint_1_rad``)."""
    out = ["t_s"]
    for name, description in fields.items():
        suffix = _suffix(name, description)
        if len(shapes[name]) == 1:
            out.append(name + suffix)
        else:
            out += [f"{name}_{joints[j]}{suffix}" for j in range(shapes[name][1])]
    return out


def write_run_log_csv(
    path: str | Path,
    t: np.ndarray,
    columns: Mapping[str, np.ndarray],
    fields: Mapping[str, str],
    joints: Sequence[str],
    comments: Sequence[str] = (),
) -> Path:
    """One row per sample of ``t`` (s from the start); ``fields`` name -> "unit, meaning" in order."""
    shapes = {k: columns[k].shape for k in fields}
    cols: list[np.ndarray] = [t]
    for k in fields:
        c = columns[k]
        cols += [c] if c.ndim == 1 else [c[:, j] for j in range(c.shape[1])]
    units = "; ".join(f"{k}: {d}" for k, d in fields.items())
    return _write_csv(
        Path(path),
        [*comments, "t_s: s from the run's start", units],
        run_log_header(fields, shapes, joints),
        cols,
    )


def comment_lines(envelope: Mapping[str, Any], source: Path, sha256: str) -> list[str]:
    """What the exported file is and where it came from, for its ``#`` lines."""
    return [
        f"rxcomm export of {envelope.get('kind')} {source.name} (sha256 {sha256})",
        f"created {envelope.get('created')} by rxcomm {envelope.get('rxcomm_version')}",
    ]


# ---------------------------------------------------------------- artefact -> CSV


def export_run_log_csv(source: str | Path, out: str | Path) -> Path:
    """A run log's ``/run/joints`` (every field of the contract, per joint) as CSV."""
    source = Path(source)
    log = read_run_log(source)
    joints = log.joints
    names = joints.constants.get("joint_names") or [f"j{j + 1}" for j in range(joints.q_actual.shape[1])]
    fields = {k: d for k, d in JOINT_FIELDS.items() if k in joints.fields}
    comments = comment_lines(log.envelope, source, sha256_file(source))
    return write_run_log_csv(out, joints.t, joints.fields, fields, names, comments)


def read_run_log_csv(
    path: str | Path, joint_names: Sequence[str]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(t [n] s, field -> [n] or [n, joints]) of a CSV that :func:`export_run_log_csv` wrote."""
    path = Path(path)
    _, cols = read_csv_table(path)
    if "t_s" not in cols:
        raise InputError("no t_s column", file=path, field="header")
    out: dict[str, np.ndarray] = {}
    for name, description in JOINT_FIELDS.items():
        suffix = _suffix(name, description)
        per_joint = [f"{name}_{j}{suffix}" for j in joint_names]
        if all(c in cols for c in per_joint):
            out[name] = np.column_stack([cols[c] for c in per_joint])
        elif name + suffix in cols:
            out[name] = cols[name + suffix]
    return cols["t_s"], out
