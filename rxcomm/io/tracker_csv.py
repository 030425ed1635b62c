"""A tracker's time-stamped export during motion: the CSV a real laser tracker writes (docs/tracker-csv.md)
and the same samples from the simulated cell, as one `TrackerExport`.

Columns (a header row; ``#`` lines are comments): ``t_s`` (the tracker's own clock, s), ``x_m, y_m,
z_m`` (or ``x_mm`` …: TCP position in the tracker frame), optionally ``qw, qx, qy, qz`` (TCP
orientation in the tracker frame). A comment line ``# trigger_s: T`` gives the tracker-clock stamp of
the controller's stream-start trigger, when the tracker latched one.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_text

POSITION_UNITS = {"m": 1.0, "mm": 1e-3}


@dataclass(frozen=True)
class TrackerExport:
    """Tracker samples on the tracker's clock: ``t_s`` [k], ``position_m`` [k, 3] and
    ``quaternion_wxyz`` [k, 4] (NaN rows: orientation not measured) in the tracker frame."""

    t_s: np.ndarray
    position_m: np.ndarray
    quaternion_wxyz: np.ndarray
    trigger_s: float | None = None
    source: str = "csv"

    def __post_init__(self) -> None:
        k = len(self.t_s)
        if self.position_m.shape != (k, 3) or self.quaternion_wxyz.shape != (k, 4):
            raise ValueError("tracker export: t_s [k], position_m [k, 3], quaternion_wxyz [k, 4]")

    @property
    def n(self) -> int:
        return len(self.t_s)

    @property
    def rate_hz(self) -> float:
        """Median sample rate of the stamps (Hz); NaN with fewer than two samples."""
        if self.n < 2:
            return float("nan")
        return float(1.0 / np.median(np.diff(self.t_s)))


def read_tracker_csv(path: str | Path) -> TrackerExport:
    """Read a tracker export (docs/tracker-csv.md); InputError names file, field (column/row) and reason."""
    path = Path(path)
    trigger: float | None = None
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror}", file=path) from e
    rows = []
    for line in lines:
        s = line.strip()
        if s.startswith("#"):
            key, sep, value = s[1:].partition(":")
            if sep and key.strip() == "trigger_s":
                try:
                    trigger = float(value)
                except ValueError:
                    raise InputError(
                        f"not a number: {value.strip()!r}", file=path, field="trigger_s"
                    ) from None
            continue
        if s:
            rows.append(line)
    if not rows:
        raise InputError("no header row", file=path)
    reader = csv.reader(rows)
    header = [h.strip() for h in next(reader)]
    body = list(reader)
    col = {h: i for i, h in enumerate(header)}
    if "t_s" not in col:
        raise InputError(f"needs a t_s column (has {header})", file=path, field="t_s")
    unit = next((u for u in POSITION_UNITS if all(f"{a}_{u}" in col for a in "xyz")), None)
    if unit is None:
        raise InputError(f"needs x_m, y_m, z_m (or x_mm …) columns (has {header})", file=path, field="x_m")
    has_q = all(c in col for c in ("qw", "qx", "qy", "qz"))
    names = ["t_s", *(f"{a}_{unit}" for a in "xyz"), *(("qw", "qx", "qy", "qz") if has_q else ())]
    data = np.full((len(body), len(names)), np.nan)
    for r, cells in enumerate(body):
        for j, name in enumerate(names):
            try:
                data[r, j] = float(cells[col[name]])
            except (IndexError, ValueError):
                raise InputError(
                    f"row {r + 1}: not a number: {cells[col[name]] if col[name] < len(cells) else ''!r}",
                    file=path,
                    field=name,
                ) from None
    t = data[:, 0]
    if len(t) < 2 or not np.all(np.diff(t) > 0):
        raise InputError("t_s must increase strictly, with at least two rows", file=path, field="t_s")
    quat = data[:, 4:8] if has_q else np.full((len(t), 4), np.nan)
    if has_q:
        norm = np.linalg.norm(quat, axis=1)
        bad = np.flatnonzero(np.abs(norm - 1) > 1e-3)
        if bad.size:
            raise InputError(
                f"row {bad[0] + 1}: quaternion norm {norm[bad[0]]:.6f} ≠ 1", file=path, field="qw"
            )
    return TrackerExport(t, data[:, 1:4] * POSITION_UNITS[unit], quat, trigger, source="csv")


def write_tracker_csv(path: str | Path, export: TrackerExport) -> Path:
    """Write `export` in the documented format (metres, quaternion when measured), atomically."""
    out = ["# tracker export, rxcomm format (docs/tracker-csv.md)"]
    if export.trigger_s is not None:
        out.append(f"# trigger_s: {export.trigger_s!r}")
    has_q = bool(np.all(np.isfinite(export.quaternion_wxyz))) and export.n > 0
    out.append("t_s,x_m,y_m,z_m" + (",qw,qx,qy,qz" if has_q else ""))
    for i in range(export.n):
        vals = [export.t_s[i], *export.position_m[i], *(export.quaternion_wxyz[i] if has_q else ())]
        out.append(",".join(f"{v:.9g}" if j else f"{v:.7f}" for j, v in enumerate(vals)))
    return atomic_write_text(path, "\n".join(out) + "\n")
