"""Joint logs for identification: reading and refusing (`rxcomm.identification.fit`).

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
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rxcomm.errors import InputError
from rxcomm.identification.settings import IdentifySettings
from rxcomm.io.run_log import read_run_log
from rxcomm.model.robot import Robot
from rxcomm.model.robot_csv import check_positions, read_robot_csv
from rxcomm.schemas.run_log import JOINTS_TOPIC


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

    def interpolation_warning(self) -> str:
        """What to tell a user of a log recorded with an interpolation ratio ('' for none)."""
        if self.cycles_per_sample <= 1:
            return ""
        return (
            f"{self.source} was recorded with --interpolation-ratio {self.cycles_per_sample}: each torque "
            f"sample is one drive cycle of {self.cycles_per_sample}, at one phase of the setpoint "
            "interpolation, which biases the inertias; record identification runs with "
            "--interpolation-ratio 1"
        )

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
