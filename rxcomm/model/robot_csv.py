"""Joint logs recorded on a real robot, as CSV (format: docs/identify-csv.md).

One header line names the columns, then one row per sample; lines starting with ``#`` are comments.
Columns (i = 1..n, the axis number in drives.yaml order; other columns are ignored):

- ``time_s``: time, s (strictly increasing);
- positions, one kind: ``q{i}_rad`` joint side, or ``motor{i}_rad`` motor shaft angle;
- torques, one kind: ``tau{i}_nm`` joint side, ``motor_tau{i}_nm`` motor side, or ``current{i}_a``
  motor current (A, torque-producing component).

Motor-side values are as the drives report them: θ_raw,i = s_i·θ_m,i + o_i and τ_raw,i = s_i·τ_m,i with
the motor signs s_i and encoder offsets o_i (`encoder_offset_rad`, the reading at the joint's
calibrated zero) of drives.yaml, and currents I_i = τ_raw,i / k_t,i (torque constants). With
R = `robot.joint_to_motor` = diag(gear ratio)·C (C the coupling, e.g. the RX130L's J5→J6 wrist),
θ_m = R·q and τ_joint = Rᵀ·τ_m (power balance τ_mᵀθ̇_m = τᵀq̇), so q = R⁻¹·θ_m.

Unit sanity (`check_positions`): joint positions far outside the URDF limits are refused, naming the
column and the unit they look like (degrees, ×1000) or the offsets that put them there.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rxcomm.errors import InputError
from rxcomm.model.robot import Robot

TIME_COLUMNS = ("time_s",)
POSITION_KINDS = {"joint": "q{i}_rad", "motor": "motor{i}_rad"}
TORQUE_KINDS = {"joint": "tau{i}_nm", "motor": "motor_tau{i}_nm", "current": "current{i}_a"}


@dataclass(frozen=True, eq=False)
class RobotCsv:
    """A CSV log converted to the joint side: `t` [N] s, `q` [N, n] rad, `tau` [N, n] N·m, and which
    kinds of columns it had (`positions`: joint|motor, `torques`: joint|motor|current)."""

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    positions: str
    torques: str


LIMIT_MARGIN_RAD = 0.2  # beyond the URDF limits by more than this is not a measurement error


def check_positions(
    q: np.ndarray,
    robot: Robot,
    columns: list[str] | tuple[str, ...],
    file: Path | str | None,
    hint: str = "",
) -> None:
    """InputError (exit 2) when a joint's positions lie far outside its limits: names the column and
    the unit the values look like (degrees; ×1000 such as mrad), else `hint` (e.g. the offsets)."""
    lo, hi = robot.q_min - LIMIT_MARGIN_RAD, robot.q_max + LIMIT_MARGIN_RAD
    for j in range(robot.n):
        c = q[:, j]
        c = c[np.isfinite(c)]
        if len(c) == 0 or (c.min() >= lo[j] and c.max() <= hi[j]):
            continue
        unit = ""
        for name, scale in (("degrees", math.pi / 180.0), ("×1000 (mrad?)", 1e-3)):
            if (c * scale).min() >= lo[j] and (c * scale).max() <= hi[j]:
                unit = f"; the values fit the limits if they are in {name}: give radians"
                break
        raise InputError(
            f"{robot.joint_names[j]} ranges over [{c.min():.4g}, {c.max():.4g}] rad, outside its limits "
            f"[{robot.q_min[j]:.3f}, {robot.q_max[j]:.3f}] rad{unit or hint}",
            file=file,
            field=columns[j],
        )


def _header(path: Path) -> tuple[list[str], int]:
    try:
        with open(path, encoding="utf-8") as f:
            for number, line in enumerate(f):
                text = line.strip()
                if text and not text.startswith("#"):
                    return [c.strip() for c in text.split(",")], number
    except FileNotFoundError as e:
        raise InputError("file not found", file=path) from e
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read: {e}", file=path) from e
    raise InputError("no header line (expected e.g. time_s,q1_rad,…,tau1_nm,…)", file=path)


def _indexed(columns: list[str], pattern: str) -> dict[int, int]:
    """{axis number: column index} for the columns matching pattern (with {i})."""
    rx = re.compile("^" + re.escape(pattern).replace(r"\{i\}", r"(\d+)") + "$")
    out = {}
    for k, c in enumerate(columns):
        if m := rx.match(c):
            out[int(m.group(1))] = k
    return out


def _pick(columns: list[str], kinds: dict[str, str], what: str, n: int, path: Path) -> tuple[str, list[int]]:
    found = {kind: _indexed(columns, pattern) for kind, pattern in kinds.items()}
    present = [kind for kind, cols in found.items() if cols]
    if not present:
        names = " or ".join(p.format(i=1) + "…" for p in kinds.values())
        raise InputError(f"no {what} columns (expected {names})", file=path, field="header")
    if len(present) > 1:
        raise InputError(
            f"{what} columns of several kinds ({', '.join(present)}): give one kind",
            file=path,
            field="header",
        )
    kind = present[0]
    cols = found[kind]
    if sorted(cols) != list(range(1, len(cols) + 1)):
        raise InputError(
            f"{what} columns must be numbered 1..n, got {sorted(cols)}",
            file=path,
            field=kinds[kind].format(i="i"),
        )
    if len(cols) != n:
        raise InputError(
            f"joint count mismatch: {len(cols)} {what} columns, the robot has {n} joints",
            file=path,
            field=kinds[kind].format(i="i"),
        )
    return kind, [cols[i] for i in range(1, n + 1)]


def read_robot_csv(path: str | Path, robot: Robot) -> RobotCsv:
    """Read a real robot's CSV log and convert it to joint-side positions and torques."""
    path = Path(path)
    columns, header_line = _header(path)
    if len(set(columns)) != len(columns):
        dup = sorted({c for c in columns if columns.count(c) > 1})
        raise InputError(f"duplicate columns {dup}", file=path, field="header")
    time_col = next((columns.index(c) for c in TIME_COLUMNS if c in columns), None)
    if time_col is None:
        raise InputError("no time_s column", file=path, field="header")
    pos_kind, pos_cols = _pick(columns, POSITION_KINDS, "position", robot.n, path)
    tau_kind, tau_cols = _pick(columns, TORQUE_KINDS, "torque", robot.n, path)
    try:
        data = np.loadtxt(path, delimiter=",", comments="#", skiprows=header_line + 1, ndmin=2)
    except ValueError as e:
        raise InputError(f"not a numeric table: {e}", file=path) from e
    if data.shape[0] == 0:
        raise InputError("no data rows", file=path)
    if data.shape[1] != len(columns):
        raise InputError(f"{data.shape[1]} values per row, header has {len(columns)}", file=path)
    for k in (time_col, *pos_cols, *tau_cols):
        bad = ~np.isfinite(data[:, k])
        if bad.any():
            raise InputError(
                f"non-finite value in data row {int(np.argmax(bad)) + 1}", file=path, field=columns[k]
            )
    t = data[:, time_col]
    pos = data[:, pos_cols]
    raw = data[:, tau_cols]
    r = robot.joint_to_motor
    sign = robot.motor_sign
    offsets = robot.encoder_offset
    q = np.linalg.solve(r, ((pos - offsets) * sign).T).T if pos_kind == "motor" else pos
    hint = ""
    if pos_kind == "motor" and np.any(offsets):
        hint = f"; check encoder_offset_rad in drives.yaml ({np.round(offsets, 4).tolist()} rad, motor side)"
    check_positions(q, robot, [columns[k] for k in pos_cols], path, hint)
    if tau_kind == "joint":
        tau = raw
    else:
        tau_m = raw * sign * (robot.torque_constant if tau_kind == "current" else 1.0)
        tau = tau_m @ r
    return RobotCsv(t=t, q=q, tau=tau, positions=pos_kind, torques=tau_kind)


def write_robot_csv(
    path: str | Path,
    robot: Robot,
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray,
    *,
    positions: str = "motor",
    torques: str = "current",
    comment: str = "",
) -> Path:
    """Write joint-side data in the CSV format, converting to motor side as a drive would report it
    (the inverse of `read_robot_csv`; for tests and for exporting logs to other tools)."""
    if positions not in POSITION_KINDS or torques not in TORQUE_KINDS:
        raise ValueError(f"positions in {list(POSITION_KINDS)}, torques in {list(TORQUE_KINDS)}")
    r, sign = robot.joint_to_motor, robot.motor_sign
    pos = q @ r.T * sign + robot.encoder_offset if positions == "motor" else q
    if torques == "joint":
        tq = tau
    else:
        tau_m = np.linalg.solve(r.T, np.asarray(tau).T).T
        tq = tau_m * sign / (robot.torque_constant if torques == "current" else 1.0)
    n = robot.n
    header = ["time_s"]
    header += [POSITION_KINDS[positions].format(i=i + 1) for i in range(n)]
    header += [TORQUE_KINDS[torques].format(i=i + 1) for i in range(n)]
    table = np.column_stack([t, pos, tq])
    path = Path(path)
    lines = [f"# {line}" for line in comment.splitlines()] + [",".join(header)]
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
        np.savetxt(f, table, delimiter=",", fmt="%.10g")
    return path
