"""The run log: ``NAME.mcap`` (Foxglove-plottable time series) + ``NAME.yaml`` (kind `rxcomm/RunLog`).

The contract `identify` reads (see ``rxcomm.schemas.run_log``): ``/run/joints`` at the setpoint rate
(the drive cycle when R = 1) and ``/run/gateway`` once per block reply. Written while the robot
moves (``RunLogWriter``, the session's record sink): to ``NAME.mcap.part`` in chunks flushed to the
OS every ``FLUSH_PERIOD_S`` of wall time, renamed to ``NAME.mcap`` (and ``NAME.yaml`` written) when
the run completes. The writer keeps no record it wrote: the summary's motion figures are running
values (``summary.MotionStats``), and only the first ``keep_encoder_s`` of encoder angles stay in
memory (``encoder_prefix``: what `run` aligns the embedded cell's tracker samples with, the
cross-correlation window of ``rxcomm.acceptance.alignment``). A run that ended in a stop keeps
``NAME.mcap.part``: a finished, readable MCAP
whose envelope summary says ``outcome`` and ``stop_reason``; no ``NAME.yaml``. A killed run (SIGKILL,
power cut of the PC) leaves an unfinished ``.part`` whose envelope says ``outcome: running``;
``recover_run_log`` (`rxcomm recover-log`) turns it into a readable log and says what was lost.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rxcomm.errors import InputError
from rxcomm.execution.frames import VIEW_DECIMALS, CalibratedView, FoxgloveFrames
from rxcomm.execution.log_grid import joint_grid_steps, on_grid
from rxcomm.execution.plan import StreamPlan
from rxcomm.execution.records import RunResult
from rxcomm.execution.summary import MotionStats, run_summary, tcp_error_and_speed
from rxcomm.io.files import part_path
from rxcomm.io.mcap_io import McapWriter, number_field, recover_mcap, vector_field
from rxcomm.io.mcap_rows import GRID
from rxcomm.io.validate import check_kind
from rxcomm.io.yaml_io import mcap_summary, summary_yaml_path, write_mcap_summary
from rxcomm.model.robot import Robot
from rxcomm.schemas.run_log import (
    GATEWAY_FIELDS,
    GATEWAY_TOPIC,
    JOINT_FIELDS,
    JOINTS_TOPIC,
    TRACKER_FIELDS,
    TRACKER_TOPIC,
    RunLog,
    RunLogTopic,
    TrackerChannel,
)

FLUSH_PERIOD_S = 0.5  # wall time between chunks handed to the OS: what a killed run can lose
# "rows": one protobuf message per sample, float32 joint values on the fields' grids (docs/logs.md §1,
# log_grid); "rows-float32": the same without the grids (issue 32's first step); "json-columns": the
# layout before issue 32 (per-sample JSON + float64 column blocks). The last two stay writable for the
# bench's before columns and the tests that every layout reads alike.
LAYOUTS = ("rows", "rows-float32", "json-columns")
JOINT_DTYPE = "<f4"  # 2.4e-7 rad at 4 rad, below the gateway's 1 µrad count; torque to 6e-8 relative


class RunLogWriter:
    """The run log, written while the robot moves (the session's ``RecordSink``).

    ``begin`` (called when the plan's stream starts) opens ``NAME.mcap.part`` with the envelope
    (summary ``outcome: running``) and both channels; ``records``/``gateway`` append rows and flush a
    chunk each time (every ``period_s``); ``close(result)`` appends what the stream recorded after the
    last hand-over, writes the final summary and finishes: ``NAME.mcap`` + ``NAME.yaml`` when the run
    completed, the finished ``NAME.mcap.part`` after a stop. Before ``begin`` nothing is on disk.
    """

    def __init__(
        self,
        path: str | Path,
        robot: Robot,
        *,
        inputs: Mapping[str, str | Path],
        settings: Mapping[str, Any],
        feedforward: str,
        embedded_cell: bool,
        period_s: float = FLUSH_PERIOD_S,
        keep_encoder_s: float = 0.0,
        layout: str = "rows",
        view: CalibratedView | None = None,
    ) -> None:
        """``view`` (run --calibration): the log's 3D view on the calibrated robot, with the tracker
        frame (``FoxgloveFrames``); the data channels stay on ``robot``."""
        self.path = Path(path)
        self.view = view
        summary_yaml_path(self.path)  # refuses a name not ending in .mcap before anything is written
        self.robot = robot
        self.inputs, self.settings = dict(inputs), dict(settings)
        self.feedforward, self.embedded_cell = feedforward, embedded_cell
        self.period_s = period_s
        if layout not in LAYOUTS:
            raise ValueError(f"run log layout {layout!r} is not one of {LAYOUTS}")
        self.layout = layout
        self._w: McapWriter | None = None
        self._plan: StreamPlan | None = None
        self.n_joint = 0  # /run/joints rows written
        self.n_gw = 0
        self.keep_encoder_s = keep_encoder_s
        self._encoders: list[np.ndarray] = []  # q_actual of the first keep_encoder_s
        self._n_encoders = 0
        self.motion: MotionStats | None = None  # running figures of the rows written
        self._tracker: TrackerChannel | None = None
        self._foxglove: FoxgloveFrames | None = None

    @property
    def part_path(self) -> Path:
        return part_path(self.path)

    @property
    def begun(self) -> bool:
        """The stream started and the log is open."""
        return self._w is not None

    def begin(self, plan: StreamPlan, ratio: int, cycle_s: float) -> None:
        if self._w is not None:
            raise ValueError("run log already begun")
        self._plan = plan
        self.motion = MotionStats(self.robot, plan.sample_s)
        running = {
            "outcome": "running",
            "stop_reason": "the log was cut off (the run was killed) if this still says running",
            "interpolation_ratio": ratio,
            "sample_s": plan.sample_s,
            "n_setpoints": plan.n,
            "planned_duration_s": (plan.n - 1) * plan.sample_s,
        }
        env = RunLog.envelope(self.inputs, self.settings, running)
        w = McapWriter(self.path, env, flush_period_s=self.period_s)
        try:
            # Channels first, with units in the schema, so even a log stopped before its first record
            # has them.
            names = {"joint_names": list(self.robot.joint_names)}
            if self.layout.startswith("rows"):
                grid = {GRID: json.dumps(joint_grid_steps())} if self.layout == "rows" else {}
                w.add_row_channel(
                    JOINTS_TOPIC, "rxcomm.RunJoints", joint_rows(self.robot.n), constants=names, metadata=grid
                )
                w.add_row_channel(GATEWAY_TOPIC, "rxcomm.RunGateway", gateway_rows())
            else:  # the layout before issue 32 (per-sample JSON + column blocks): benches and tests
                w.add_channel(JOINTS_TOPIC, "rxcomm.RunJoints", _joint_schema(self.robot.n), constants=names)
                w.add_channel(GATEWAY_TOPIC, "rxcomm.RunGateway", _gateway_schema())
            digits = VIEW_DECIMALS if self.layout == "rows" else None  # the layouts before: every digit
            self._foxglove = FoxgloveFrames(w, self.robot, plan.sample_s, self.view, digits)
            w.flush()
        except BaseException:
            w.abort()
            raise
        self._w = w

    def records(self, first: int, q_actual: np.ndarray, tau_actual: np.ndarray) -> None:
        """Rows ``first…`` of ``/run/joints`` (consecutive: ``first`` must be the rows written so far)."""
        assert self._w is not None and self._plan is not None
        if first != self.n_joint:
            raise ValueError(f"run log rows must be consecutive: got {first}, expected {self.n_joint}")
        m = q_actual.shape[0]
        if m == 0:
            return
        p = self._plan
        sl = slice(first, first + m)
        tcp, speed = tcp_error_and_speed(self.robot, p.q[sl], p.qd[sl], q_actual)
        cols = {
            "q_demand": p.q[sl],
            "qd_demand": p.qd[sl],
            "qdd_demand": p.qdd[sl],
            "q_actual": q_actual,
            "tau_actual": tau_actual,
            "tau_ff": p.tau_ff[sl],
            "following_error": p.q[sl] - q_actual,
            "tcp_error_m": tcp,
            "tcp_speed_m_s": speed,
        }
        if self.layout == "rows":
            cols = on_grid(cols)
        self._w.write_arrays(JOINTS_TOPIC, np.arange(first, first + m) * p.sample_s, cols, digits=10)
        assert self._foxglove is not None
        self._foxglove.write(first, p.q[sl], q_actual)
        self._w.flush()
        assert self.motion is not None
        self.motion.add(first, p.q[sl], q_actual, tau_actual, tcp)
        wanted = int(self.keep_encoder_s / p.sample_s) + 1 if self.keep_encoder_s > 0 else 0
        if self._n_encoders < wanted:
            part = q_actual[: wanted - self._n_encoders].copy()
            self._encoders.append(part)
            self._n_encoders += len(part)
        self.n_joint += m

    @property
    def encoder_prefix(self) -> np.ndarray:
        """q_actual [k, n] of the first rows written, up to ``keep_encoder_s`` (NaN rows: lost)."""
        if not self._encoders:
            return np.zeros((0, self.robot.n))
        return np.concatenate(self._encoders)

    def gateway(self, rows: Mapping[str, np.ndarray]) -> None:
        assert self._w is not None
        n = len(rows["t"])
        if n:
            self._w.write_arrays(GATEWAY_TOPIC, rows["t"], {k: rows[k] for k in GATEWAY_FIELDS}, digits=10)
            self._w.flush()
            self.n_gw += n

    def tracker(
        self,
        t_tracker_s: np.ndarray,
        position_m: np.ndarray,
        quaternion_wxyz: np.ndarray,
        channel: TrackerChannel,
    ) -> None:
        """The ``/run/tracker`` channel: samples stamped on the tracker clock, put on the joint log's
        time axis by ``channel.offset_s`` (samples before the stream start are dropped), and their
        ``/run/tracker_pose`` view channel (at most FOXGLOVE_RATE_HZ). Once, before ``close``."""
        assert self._w is not None
        if self._tracker is not None:
            raise ValueError("tracker channel already written")
        self._tracker = write_tracker_channel(
            self._w, t_tracker_s, position_m, quaternion_wxyz, channel, rows=self.layout != "json-columns"
        )
        # the 3D view's copy: the same samples (those kept) as /run/tracker_pose
        t = np.asarray(t_tracker_s) - channel.offset_s
        keep = t >= 0
        assert self._foxglove is not None
        self._foxglove.tracker(
            t[keep], np.asarray(position_m)[keep], np.asarray(quaternion_wxyz)[keep], channel.rate_hz
        )

    def close(self, result: RunResult, stop_is_result: bool = False) -> tuple[Path, dict[str, Any]]:
        """Write the rest of ``result.log`` and the summary; returns (the file written, the summary).

        Completed (or stopped with `stop_is_result`: the stop is what the run measured): ``NAME.mcap``
        + ``NAME.yaml``. Stopped: ``NAME.mcap.part`` only (finished, readable).
        """
        log = result.log
        if self._w is None:  # stopped before the plan's stream began (or a log written after the fact)
            plan = log.plan if log is not None else None
            if plan is None:
                plan = StreamPlan(result.ratio * result.cycle_s, *(np.zeros((1, self.robot.n)),) * 4)
            self.begin(plan, result.ratio, result.cycle_s)
        w = self._w
        assert w is not None
        try:
            if log is not None:
                # the records and status rows this writer has not had (all of them for a log
                # written after the fact; none when the stream handed them all over)
                if log.n_records > self.n_joint:
                    i = self.n_joint - log.records_in_sink
                    self.records(self.n_joint, log.q_actual[i:], log.tau_actual[i:])
                g = log.gateway
                if log.gateway_rows_in_sink + len(g["t"]) > self.n_gw:
                    i = self.n_gw - log.gateway_rows_in_sink
                    self.gateway({k: v[i:] for k, v in g.items()})
            summary = run_summary(self.robot, result, motion=self.motion if log is not None else None)
            data = self._yaml_data(result, summary)
            mcap_summary(RunLog, data, self.path)  # a bad summary is a bug: the .part stays
            w.set_summary(summary)
        except BaseException:
            w.abort()
            raise
        if result.error is not None and not stop_is_result:
            return w.abort(), summary
        return w.finish(before_rename=lambda part: write_mcap_summary(RunLog, data, self.path, part)), summary

    def abandon(self) -> Path | None:
        """The stage failed outside the run (a bug, an interrupt): keep what is on disk as ``.part``."""
        return None if self._w is None else self._w.abort()

    def _yaml_data(self, result: RunResult, summary: dict[str, Any]) -> dict[str, Any]:
        env = RunLog.envelope(self.inputs, self.settings, summary)
        sample_s = result.ratio * result.cycle_s
        return {
            **env,
            "joint_names": list(self.robot.joint_names),
            "cycle_s": result.cycle_s,
            "interpolation_ratio": result.ratio,
            "sample_s": sample_s,
            "feedforward": self.feedforward,
            "gateway": result.gateway,
            "embedded_cell": self.embedded_cell,
            "topics": [
                RunLogTopic(
                    topic=JOINTS_TOPIC, period_s=sample_s, n_messages=self.n_joint, fields=JOINT_FIELDS
                ),
                RunLogTopic(topic=GATEWAY_TOPIC, period_s=None, n_messages=self.n_gw, fields=GATEWAY_FIELDS),
                *([tracker_topic(self._tracker)] if self._tracker is not None else []),
                *(self._foxglove.topics() if self._foxglove is not None else ()),
            ],
            "tracker": self._tracker,
        }


def write_run_log(
    path: str | Path,
    robot: Robot,
    result: RunResult,
    *,
    inputs: Mapping[str, str | Path],
    settings: Mapping[str, Any],
    feedforward: str,
    embedded_cell: bool,
    layout: str = "rows",
) -> tuple[Path, dict[str, Any]]:
    """Write the log of a finished ``result`` in one go (``RunLogWriter`` does it during the run);
    returns (the file written, the summary)."""
    w = RunLogWriter(
        path,
        robot,
        inputs=inputs,
        settings=settings,
        feedforward=feedforward,
        embedded_cell=embedded_cell,
        layout=layout,
    )
    return w.close(result)


def joint_rows(n: int) -> dict[str, tuple[str, int]]:
    """``/run/joints`` row fields: vectors of ``n`` float32, the TCP figures float32 scalars."""
    return {k: (JOINT_DTYPE, 0 if k.startswith("tcp_") else n) for k in JOINT_FIELDS}


def gateway_rows() -> dict[str, tuple[str, int]]:
    """``/run/gateway`` row fields: the counters as int64, the times as float64."""
    return {k: ("<f8" if k in ("lead_s", "round_trip_s", "wall_s") else "<i8", 0) for k in GATEWAY_FIELDS}


def _joint_schema(n: int) -> dict[str, dict[str, Any]]:
    return {
        k: number_field(d) if k.startswith("tcp_") else vector_field(n, d) for k, d in JOINT_FIELDS.items()
    }


def write_tracker_channel(
    w: McapWriter,
    t_tracker_s: np.ndarray,
    position_m: np.ndarray,
    quaternion_wxyz: np.ndarray,
    channel: TrackerChannel,
    *,
    rows: bool = True,
) -> TrackerChannel:
    """Add ``/run/tracker`` to `w`: the samples at t = t_tracker_s − offset_s (those before the
    stream start dropped), as a row channel (float64) unless ``rows`` is False (the old layout);
    returns `channel` with the samples kept."""
    t = np.asarray(t_tracker_s) - channel.offset_s
    keep = t >= 0
    if rows:
        sizes = {"position_m": 3, "quaternion_wxyz": 4}
        fields = {k: ("<f8", sizes.get(k, 0)) for k in TRACKER_FIELDS}
        w.add_row_channel(TRACKER_TOPIC, "rxcomm.RunTracker", fields)
    else:
        w.add_channel(TRACKER_TOPIC, "rxcomm.RunTracker", tracker_schema())
    w.write_arrays(
        TRACKER_TOPIC,
        t[keep],
        {
            "position_m": np.asarray(position_m)[keep],
            "quaternion_wxyz": np.asarray(quaternion_wxyz)[keep],
            "t_tracker_s": np.asarray(t_tracker_s)[keep],
        },
        digits=12,  # a tracker clock may count from its power-on: 0.1 µs at 10^5 s
    )
    w.flush()
    return channel.model_copy(update={"n_samples": int(keep.sum())})


def tracker_topic(channel: TrackerChannel) -> RunLogTopic:
    """The summary's entry for the ``/run/tracker`` channel of `channel`'s samples."""
    return RunLogTopic(
        topic=TRACKER_TOPIC,
        period_s=1.0 / channel.rate_hz,
        n_messages=channel.n_samples,
        fields=TRACKER_FIELDS,
    )


def tracker_schema() -> dict[str, dict[str, Any]]:
    sizes = {"position_m": 3, "quaternion_wxyz": 4}
    return {
        k: vector_field(sizes[k], d) if k in sizes else number_field(d) for k, d in TRACKER_FIELDS.items()
    }


def _gateway_schema() -> dict[str, dict[str, Any]]:
    floats = ("lead_s", "round_trip_s", "wall_s")
    return {
        k: number_field(d) if k in floats else {"type": "integer", "description": d}
        for k, d in GATEWAY_FIELDS.items()
    }


@dataclass(frozen=True)
class Recovery:
    """What ``recover_run_log`` got back from a run log's ``.part``."""

    source: Path
    written: Path
    n_records: int  # /run/joints rows recovered
    recovered_s: float  # their span, s (0 with fewer than two rows)
    planned_s: float | None  # the plan's duration as the log's first envelope said (None: unknown)
    complete: bool  # the .part was a finished file (a stopped run), nothing was cut off
    stopped_because: str | None

    def warning(self) -> str:
        """One line: what was recovered and what was lost."""
        got = f"recovered {self.recovered_s:.3f} s of {JOINTS_TOPIC} ({self.n_records} records)"
        if self.complete:
            return f"{got} from {self.source}: the file was finished (a stopped run's log), nothing lost"
        plan = f" of the {self.planned_s:.3f} s planned" if self.planned_s is not None else ""
        lost = (
            f"lost: everything after t = {self.recovered_s:.3f} s{plan} "
            f"(the writer was killed; {self.stopped_because})"
        )
        return f"{got} from {self.source}; {lost}"


def recovered_path(part: str | Path) -> Path:
    """``run.mcap.part`` -> ``run.recovered.mcap`` (a moved-aside ``run.mcap.part.2`` ->
    ``run.2.recovered.mcap``): never the completed log's name, so neither make nor a later stage
    mistakes a cut-off log for a complete run."""
    part = Path(part)
    name, _, n = part.name.rpartition(".part.")
    if not (name and n.isdigit()):
        name, n = part.name.removesuffix(".part"), ""
    stem = name.removesuffix(".mcap") + (f".{n}" if n else "")
    return part.with_name(f"{stem}.recovered.mcap")


def recover_run_log(part: str | Path, out: str | Path | None = None) -> Recovery:
    """Turn the ``NAME.mcap.part`` of a killed (or stopped) run into a finished, readable run log at
    ``out`` (default ``NAME.recovered.mcap``): everything up to the last chunk the writer flushed,
    plus an ``rxcomm/recovered`` record saying from where and why reading stopped. InputError if the
    file is not a run log."""
    part = Path(part)
    out = Path(out) if out is not None else recovered_path(part)
    if out.resolve() == part.resolve():
        raise InputError("the recovered log must not overwrite the file it is read from", file=out)
    contents = recover_mcap(part)
    env = contents.envelope
    if not env:
        raise InputError("no rxcomm envelope: not an rxcomm run log (or cut off before it)", file=part)
    check_kind(env, RunLog, file=part, prefix="envelope")
    if JOINTS_TOPIC not in contents.topics:
        raise InputError(f"no {JOINTS_TOPIC} channel: cut off before the run began", file=part)
    recover_mcap(part, out)
    joints = contents.topics[JOINTS_TOPIC]
    n = len(joints)
    planned = env.get("summary", {}).get("planned_duration_s")
    return Recovery(
        source=part,
        written=out,
        n_records=n,
        recovered_s=float(joints.t[-1] - joints.t[0]) if n > 1 else 0.0,
        planned_s=float(planned) if isinstance(planned, int | float) else None,
        complete=contents.complete,
        stopped_because=contents.stopped_because,
    )
