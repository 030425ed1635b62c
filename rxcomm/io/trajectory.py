"""Sampled joint trajectory (t, q, q̇, q̈, τ_ff) and its MCAP file form.

Units: s, rad, rad/s, rad/s², N·m. The file is ``NAME.mcap`` (topic ``/trajectory``, one message per
sample, vectors as arrays so Foxglove plots ``/trajectory.q[0]``, the robot's ``joint_names`` in each;
stamped in epoch time from the plan's creation) with ``NAME.yaml`` beside it
(:class:`rxcomm.schemas.trajectory.TrajectorySummary`: the envelope, the summary and the MCAP's hash).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from rxcomm.errors import InputError
from rxcomm.io.mcap_io import McapWriter, field_for, read_mcap
from rxcomm.io.validate import check_kind, validate_model
from rxcomm.io.yaml_io import check_mcap_summary, mcap_summary, summary_yaml_path, write_mcap_summary
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.trajectory import TrajectorySummary

TOPIC = "/trajectory"
SCHEMA_TITLE = "rxcomm.Trajectory"
CORE_FIELDS = ("q", "qd", "qdd", "tau_ff")


class InvalidTrajectory(ValueError):
    """A trajectory array with the wrong shape or values; ``field`` names it."""

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}")


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)  # own copy, so freezing it cannot affect the caller's array
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)  # arrays: no meaningful == or hash
class Trajectory:
    """Immutable sampled trajectory: ``t`` [n] strictly increasing; ``q``, ``qd``, ``qdd``, ``tau_ff``
    [n, dof]; ``extra`` named [n] or [n, k] arrays (e.g. path parameter ``sigma``, ``sigma_dot``).

    ``tau_ff=None`` means zeros. Arrays are copied to read-only float64. Raises InvalidTrajectory.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau_ff: np.ndarray | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _frozen(self.t)
        if t.ndim != 1 or t.shape[0] < 1:
            raise InvalidTrajectory("t", f"expected shape [n >= 1], got {t.shape}")
        n = t.shape[0]
        q = _frozen(self.q)
        if q.ndim != 2 or q.shape[0] != n or q.shape[1] < 1:
            raise InvalidTrajectory("q", f"expected shape [{n}, dof], got {q.shape}")
        shape = q.shape
        tau = np.zeros(shape) if self.tau_ff is None else self.tau_ff
        arrays = {"t": t, "q": q, "qd": _frozen(self.qd), "qdd": _frozen(self.qdd), "tau_ff": _frozen(tau)}
        for name in CORE_FIELDS[1:]:
            if arrays[name].shape != shape:
                raise InvalidTrajectory(name, f"expected shape {list(shape)}, got {arrays[name].shape}")
        extra = {}
        for name, a in self.extra.items():
            if name in (*arrays, "timestamp"):
                raise InvalidTrajectory(name, "extra name collides with a core field")
            a = _frozen(a)
            if a.ndim not in (1, 2) or a.shape[0] != n:
                raise InvalidTrajectory(name, f"expected shape [{n}] or [{n}, k], got {a.shape}")
            extra[name] = a
        for name, a in (*arrays.items(), *extra.items()):
            finite = np.isfinite(a).reshape(n, -1).all(axis=1)
            if not finite.all():
                raise InvalidTrajectory(name, f"non-finite value at sample {int(np.argmin(finite))}")
        if n > 1 and not np.all(np.diff(t) > 0):
            raise InvalidTrajectory(
                "t", f"not strictly increasing at sample {int(np.argmin(np.diff(t) > 0)) + 1}"
            )
        for name, a in arrays.items():
            object.__setattr__(self, name, a)
        object.__setattr__(self, "extra", MappingProxyType(extra))

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    @property
    def dof(self) -> int:
        return int(self.q.shape[1])

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])


def save_trajectory_mcap(
    path: str | Path,
    traj: Trajectory,
    envelope: Mapping[str, Any] | Artefact,
    joint_names: Sequence[str] | None = None,
    views: Callable[[McapWriter, Trajectory], None] | None = None,
) -> TrajectorySummary:
    """Write ``traj`` to ``NAME.mcap`` and its summary to ``NAME.yaml``; return the summary.
    ``joint_names`` go into every message (a channel constant) so Foxglove shows which joint is which;
    ``views`` (e.g. `rxcomm.execution.plan_views.plan_views`) writes Foxglove's 3D channels beside.

    ``envelope`` comes from ``TrajectorySummary.envelope(inputs, settings, summary)`` and must carry
    the summary keys architecture §9 requires. Order: finished ``NAME.mcap.part`` -> hash -> ``NAME.yaml``
    -> rename, so a visible ``NAME.mcap`` always has its YAML beside it.
    """
    path = Path(path)
    summary_yaml_path(path)  # refuses a name not ending in .mcap before anything is written
    env = envelope.envelope_dict() if isinstance(envelope, Artefact) else dict(envelope)
    check_kind(env, TrajectorySummary, file=path, prefix="envelope")
    fields = [*CORE_FIELDS, *traj.extra]
    columns = {"q": traj.q, "qd": traj.qd, "qdd": traj.qdd, "tau_ff": traj.tau_ff, **traj.extra}
    data = {**env, "topic": TOPIC, "n_samples": traj.n, "fields": fields}
    mcap_summary(TrajectorySummary, data, path)  # fail on a bad envelope/summary before writing anything
    summary: list[TrajectorySummary] = []

    def write_yaml(part: Path) -> None:
        summary.append(write_mcap_summary(TrajectorySummary, data, path, part))

    with McapWriter(path, env) as w:
        if joint_names is not None:
            if len(joint_names) != traj.dof:
                raise InvalidTrajectory("joint_names", f"{len(joint_names)} names for {traj.dof} joints")
            fields = {k: field_for(c) for k, c in columns.items()}
            w.add_channel(TOPIC, SCHEMA_TITLE, fields, constants={"joint_names": list(joint_names)})
        w.write_arrays(TOPIC, traj.t, columns, schema_title=SCHEMA_TITLE)
        if views is not None:
            views(w, traj)
        w.finish(before_rename=write_yaml)
    return summary[0]


def load_trajectory_mcap(path: str | Path) -> tuple[Trajectory, dict[str, Any]]:
    """Read a trajectory MCAP; returns the trajectory and its envelope (dict, JSON values).

    Raises InputError naming the file and field if it is not an rxcomm trajectory.
    """
    traj, env, _ = load_trajectory_named(path)
    return traj, env


def load_trajectory_named(path: str | Path) -> tuple[Trajectory, dict[str, Any], list[str] | None]:
    """:func:`load_trajectory_mcap` and the joint names the file carries (None: a file without)."""
    path = Path(path)
    check_mcap_summary(path)
    contents = read_mcap(path, topics=[TOPIC])  # the samples, not a plan's 3D view channels
    env = contents.envelope
    check_kind(env, TrajectorySummary, file=path, prefix="envelope")
    validate_model(Artefact, env, file=path, prefix="envelope")
    if TOPIC not in contents.topics:
        raise InputError(f"no {TOPIC} topic (has {sorted(contents.topics)})", file=path, field=TOPIC)
    td = contents.topics[TOPIC]
    for name in CORE_FIELDS:
        if name not in td.fields:
            raise InputError("field missing", file=path, field=f"{TOPIC}.{name}")
    extra = {k: v for k, v in td.fields.items() if k not in CORE_FIELDS}
    if td.backwards_at_s is not None:
        raise InputError(
            f"log time goes backwards at t = {td.backwards_at_s:.6f} s: the samples are out of order",
            file=path,
            field=f"{TOPIC}.log_time",
        )
    check_sample_period(td.t, path)
    try:
        traj = Trajectory(td.t, td["q"], td["qd"], td["qdd"], td["tau_ff"], extra)
    except InvalidTrajectory as e:
        raise InputError(e.reason, file=path, field=f"{TOPIC}.{e.field}") from e
    names = td.constants.get("joint_names")
    return traj, env, (list(names) if isinstance(names, list) else None)


def check_sample_period(t: np.ndarray, path: Path) -> None:
    """Every planner samples its trajectory at one period (the drive cycle): refuse a hole or a
    repeated sample (InputError naming the time) instead of interpolating across it."""
    if t.size < 3:
        return
    dt = np.diff(t)
    period = float(np.median(dt))
    bad = np.flatnonzero(np.abs(dt - period) > max(1e-6, 1e-3 * period))
    if bad.size:
        k = int(bad[0])
        raise InputError(
            f"log time steps from {t[k]:.6f} s to {t[k + 1]:.6f} s ({dt[k]:.6g} s) where the trajectory "
            f"is sampled every {period:.6g} s: a hole or a repeated sample",
            file=path,
            field=f"{TOPIC}.log_time",
        )
