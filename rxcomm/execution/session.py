"""A streaming session on a drive gateway: checks, interpolation ratio, enable, stream + record, stop.

The order of a run (architecture §7 run):

1. identity and map version (``GatewayClient.identity``), the drive cycle against drives.yaml;
2. drive and gateway faults: refused unless ``fault_reset``;
3. the robot at the plan's start (per joint, rad), else refused unless an approach move is allowed —
   every move is planned and limit-checked *before* the drives are enabled, so nothing slow happens
   while the watchdog runs;
4. round trip measured with empty blocks, interpolation ratio R chosen so a 6-setpoint block lasts at
   least ``ROUND_TRIP_MARGIN`` × the mean round trip (``choose_ratio``); trace decimation R (one
   record per setpoint);
5. enable, stream (``rxcomm.gateway.stream``), every reply's trace and status kept in memory and, with
   a ``RecordSink`` (the run log writer), handed over every ``period_s`` of wall time so a killed
   run leaves its log up to then (the buffered lead, ≥ 0.1 s, rides out the writer's few tens of ms);
6. disable. Any stop after enabling — gateway stop bits, lost connection, Ctrl-C — quick-stops, waits
   until the demand stands still (bounded), disables, and is *returned* in ``RunResult.error`` with
   what was recorded up to it, so the caller can still write the log.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from rxcomm.errors import GatewayError, InputError, RxcommError, SafetyStop
from rxcomm.execution.approach import move_trajectory
from rxcomm.execution.plan import StreamPlan, distance_to_start, prepare_plan
from rxcomm.execution.record_sink import BackgroundSink, RecordSink
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.client import BlockReply, GatewayClient, RoundTripStats
from rxcomm.gateway.registers import DriveState, ErrorCode, Status, StopCause
from rxcomm.gateway.stream import STOP_BITS, stream
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.robot import Robot

ROUND_TRIP_MARGIN = 3.0  # a block must last this many mean empty-block round trips: a full block's
# encode/decode and the recording ride on it (measured: ≈ 1.5–2 × an empty poll on a loaded 2-core VM)
LATCHED_FAULT_BITS = (
    Status.WATCHDOG | Status.ESTOP | Status.AXIS_FAULT | Status.UNDERRUN | Status.SEQUENCE_ERROR
)
COMMUNICATION_ERRORS = (ErrorCode.HEARTBEAT, ErrorCode.UNDERRUN)  # the master's fault: exit 4
# In virtual time the cell's clock waits for setpoints: an underrun cannot happen and the lead is not
# held against a clock, so neither figure says anything about the master. Printed instead of a 0.
NOT_APPLICABLE_VIRTUAL = "not applicable (virtual time)"


def timing_figures(streams: list[StreamLog]) -> dict[str, object]:
    """Underruns and cell overruns of ``streams``: counts in real time, NOT_APPLICABLE_VIRTUAL in
    virtual time, None (not measured) when the gateway's counters could not be read."""
    if any(s.virtual_time for s in streams):
        return {"underruns": NOT_APPLICABLE_VIRTUAL, "cell_overruns": NOT_APPLICABLE_VIRTUAL}
    overruns = [s.overruns for s in streams]
    return {
        "underruns": int(sum(s.underruns for s in streams)),
        "cell_overruns": None if not streams or None in overruns else int(sum(overruns)),  # type: ignore[arg-type]
    }


class StreamSettings(BaseModel):
    """How setpoints are fed to the gateway."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    interpolation_ratio: int | None = Field(
        None,
        ge=1,
        le=R.INTERPOLATION_RATIO_MAX,
        description="drive cycles per setpoint; None: from the round trip",
    )
    lead_s: float = Field(
        1.0, gt=0, description="buffered setpoints kept ahead of execution, s (capped by the buffer)"
    )
    prefill_s: float = Field(0.25, gt=0, description="buffered before the stream starts, s")
    min_lead_s: float = Field(0.1, gt=0, description="the lead the run promises to keep, s")
    watchdog_ms: int = Field(
        500, ge=10, le=R.WATCHDOG_MS_MAX, description="no accepted write for this long: the cell faults"
    )
    round_trip_probes: int = Field(50, ge=5, description="empty blocks timed to choose the ratio")
    stop_timeout_s: float = Field(3.0, gt=0, description="wait for the stop ramp before disabling, s")


class RunSettings(BaseModel):
    """What `run` does with a trajectory plan."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    feedforward: bool = Field(True, description="stream τ_ff of the model; False: zeros")
    approach: bool = Field(False, description="move to the plan's start first (jerk-limited)")
    approach_speed_fraction: float = Field(0.2, gt=0, le=1, description="of velocity and acceleration limits")
    start_tolerance_rad: float = Field(1e-3, gt=0, description="per joint: 'at the start' within this")
    limit_tolerance: float = Field(1e-3, ge=0, description="limit ratios up to 1 + this pass")
    fault_reset: bool = Field(False, description="reset drive faults and latched gateway stops first")
    stream: StreamSettings = StreamSettings()


# ---- records --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class StreamLog:
    """One stream as recorded: the setpoints sent and, per setpoint reached, the drives' feedback.

    ``q_actual``/``tau_actual`` have one row per trace record kept (record r belongs to setpoint r;
    rows of lost records are NaN); ``gateway`` holds one entry per block reply (arrays of equal length).
    """

    plan: StreamPlan
    ratio: int
    cycle_s: float
    q_actual: np.ndarray
    tau_actual: np.ndarray
    gateway: dict[str, np.ndarray]
    lost_records: int
    busy_replies: int
    underruns: int
    round_trips_s: np.ndarray
    wall_s: float
    cpu_s: float
    completed: bool
    overruns: int | None = None  # drive cycles the gateway started late during the stream (None: unknown)
    virtual_time: bool = False  # the gateway's clock waits for setpoints: no underrun, no lead to keep

    @property
    def n_records(self) -> int:
        return int(self.q_actual.shape[0])

    @property
    def q_demand(self) -> np.ndarray:
        return self.plan.q[: self.n_records]

    @property
    def following_error(self) -> np.ndarray:
        return self.q_demand - self.q_actual

    def min_lead_s(self) -> float:
        """Smallest buffered lead while setpoints were still being sent and the stream ran."""
        g = self.gateway
        if len(g["lead_s"]) == 0:
            return float("nan")
        feeding = (g["write_index"] < self.plan.n) & ((g["status"] & int(Status.STREAMING)) != 0)
        return float(g["lead_s"][feeding].min()) if feeding.any() else float("nan")


@dataclass
class RunResult:
    """What a run produced. ``error`` is the stop that ended it early (None: completed)."""

    gateway: str
    ratio: int
    cycle_s: float
    log: StreamLog | None = None
    approach: StreamLog | None = None
    moves: list[StreamLog] = field(default_factory=list)
    error: RxcommError | None = None
    stop_note: str = ""
    round_trip_probe_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def outcome(self) -> str:
        if self.error is None:
            return "completed"
        return "communication_fault" if isinstance(self.error, GatewayError) else "safety_stop"


class _LastRoundTrip(RoundTripStats):
    """The client's round-trip statistics, also remembering the latest one (for the gateway topic)."""

    def __init__(self) -> None:
        super().__init__()
        self.last_s = math.nan

    def add(self, seconds: float) -> None:
        super().add(seconds)
        self.last_s = seconds


class _Recorder:
    """``stream(on_reply=...)``: keeps trace chunks and status rows, calls ``progress`` at ≤ 10 Hz and
    hands new rows to the ``sink`` every ``sink.period_s``."""

    def __init__(
        self,
        n: int,
        timing: _LastRoundTrip,
        progress: Callable[[float], None] | None,
        sink: RecordSink | None = None,
        ratio: int = 1,
        cycle_s: float = R.CYCLE_US * 1e-6,
    ) -> None:
        self.n = n
        self.timing = timing
        self.progress = progress
        self.chunks: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.rows: list[tuple[float, float, int, int, int, int, int]] = []
        self.t0 = time.perf_counter()
        self._next_progress = 0.0
        self.last_execute = 0
        self.sink = sink
        self.ratio, self.cycle_s = ratio, cycle_s
        self.emitted = 0  # records handed to the sink
        self._rows_emitted = 0
        self._chunks_emitted = 0
        self._trace_end = 0  # one past the highest record received
        self._next_emit = self.t0 + (sink.period_s if sink is not None else 0.0)

    def __call__(self, reply: BlockReply) -> None:
        tr = reply.trace
        if tr.count:
            self.chunks.append((tr.first, tr.position_rad, tr.torque_nm))
            self._trace_end = max(self._trace_end, tr.first + tr.count)
        st = reply.status
        if st is None:
            return
        wall = time.perf_counter() - self.t0
        self.last_execute = st.execute_index
        self.rows.append(
            (
                wall,
                self.timing.last_s,
                int(st.status),
                st.error,
                st.execute_index,
                st.write_index,
                st.buffer_level,
            )
        )
        if self.progress is not None and wall >= self._next_progress:
            self._next_progress = wall + 0.1
            self.progress(min(1.0, st.execute_index / self.n))
        if self.sink is not None and time.perf_counter() >= self._next_emit:
            self.emit()

    def emit(self) -> None:
        """Hand the sink the records of setpoints executed so far (not those of a stop ramp after the
        last executed setpoint: they have no planned demand) and the new status rows."""
        assert self.sink is not None
        end = min(self._trace_end, self.last_execute, self.n)
        if end > self.emitted:
            q = np.full((end - self.emitted, R.N_AXES), np.nan)  # NaN: a record lost to overflow
            tau = q.copy()
            for first, pos, tq in self.chunks[self._chunks_emitted :]:
                lo, hi = max(first, self.emitted), min(first + pos.shape[0], end)
                if hi > lo:
                    q[lo - self.emitted : hi - self.emitted] = pos[lo - first : hi - first]
                    tau[lo - self.emitted : hi - self.emitted] = tq[lo - first : hi - first]
            # a chunk reaching past ``end`` is looked at again next time
            while self._chunks_emitted < len(self.chunks):
                first, pos, _ = self.chunks[self._chunks_emitted]
                if first + pos.shape[0] > end:
                    break
                self._chunks_emitted += 1
            self.sink.records(self.emitted, q, tau)
            self.emitted = end
        if len(self.rows) > self._rows_emitted:
            self.sink.gateway(_gateway_arrays(self.rows[self._rows_emitted :], self.ratio, self.cycle_s))
            self._rows_emitted = len(self.rows)
        self._next_emit = time.perf_counter() + self.sink.period_s

    def trace(self, keep: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows 0..keep-1 by record index (NaN where a record never arrived)."""
        q = np.full((keep, R.N_AXES), np.nan)
        tau = np.full((keep, R.N_AXES), np.nan)
        for first, pos, tq in self.chunks:
            lo, hi = first, min(first + pos.shape[0], keep)
            if hi > lo:
                q[lo:hi] = pos[: hi - lo]
                tau[lo:hi] = tq[: hi - lo]
        return q, tau

    def gateway_arrays(self, ratio: int, cycle_s: float) -> dict[str, np.ndarray]:
        return _gateway_arrays(self.rows, ratio, cycle_s)


def _gateway_arrays(
    rows: list[tuple[float, float, int, int, int, int, int]], ratio: int, cycle_s: float
) -> dict[str, np.ndarray]:
    """Status rows as the ``/run/gateway`` columns."""
    a = np.array(rows, dtype=float).reshape(-1, 7)
    ex = a[:, 4].astype(np.int64)
    level = a[:, 6].astype(np.int64)
    return {
        "t": ex * ratio * cycle_s,
        "wall_s": a[:, 0],
        "round_trip_s": a[:, 1],
        "status": a[:, 2].astype(np.int64),
        "error": a[:, 3].astype(np.int64),
        "execute_index": ex,
        "write_index": a[:, 5].astype(np.int64),
        "buffer_level": level,
        "lead_s": level * ratio * cycle_s,
    }


# ---- the session ----------------------------------------------------------------------------------


def choose_ratio(round_trips_s: np.ndarray, cycle_s: float) -> int:
    """Smallest R whose 6-setpoint block lasts ≥ ROUND_TRIP_MARGIN × the mean round trip.

    The mean, hiccups included: the master must keep up on average over the whole run (R cannot change
    while streaming); the buffered lead absorbs single hiccups, not a sustained shortfall."""
    rt = np.asarray(round_trips_s, dtype=float)
    mean = float(rt.mean()) if len(rt) else 0.0
    r = math.ceil(ROUND_TRIP_MARGIN * mean / (R.MAX_CYCLES_PER_BLOCK * cycle_s))
    return int(min(max(r, 1), R.INTERPOLATION_RATIO_MAX))


class Session:
    """A master session on one gateway for one robot (one client connection, used by one thread)."""

    def __init__(self, client: GatewayClient, robot: Robot, settings: StreamSettings | None = None):
        self.client = client
        self.robot = robot
        self.settings = settings or StreamSettings()
        self.timing = _LastRoundTrip()
        client.timing = self.timing
        self.cycle_s = robot.drives.cycle_s
        self.capacity = 0
        self.ratio = 1
        self.probe_s = np.zeros(0)

    @property
    def address(self) -> str:
        return f"{self.client.host}:{self.client.port}"

    def check_identity(self) -> None:
        """Map v1 identity (GatewayError) and the drive cycle against drives.yaml (InputError)."""
        ident = self.client.identity()
        if ident.n_axes != self.robot.n:
            raise InputError(
                f"gateway drives {ident.n_axes} axes, the robot has {self.robot.n}", field="joints"
            )
        cycle_s = ident.cycle_us * 1e-6
        if abs(cycle_s - self.robot.drives.cycle_s) > 1e-9:
            raise InputError(
                f"gateway drive cycle is {ident.cycle_us} µs, "
                f"drives.yaml says {self.robot.drives.cycle_s * 1e6:g} µs",
                file=self.robot.drives_path,
                field="cycle_s",
            )
        self.cycle_s = cycle_s
        self.capacity = ident.buffer_capacity
        self.client.claim()  # one master at a time: refused here, before anything is written

    def check_faults(self, reset: bool) -> None:
        """Refuse (SafetyStop) drive faults or latched gateway stops, or clear them when ``reset``."""
        axes = self.client.axes()
        st = self.client.status()
        faulted = [
            f"{self.robot.joint_names[i]} {a.error_code:#06x}"
            for i, a in enumerate(axes)
            if a.state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
        ]
        latched = Status(st.status) & LATCHED_FAULT_BITS
        if not faulted and not latched:
            return
        if not reset:
            what = ", ".join(faulted) if faulted else f"gateway {latched!r} (error {st.error:#06x})"
            raise SafetyStop(f"the cell reports a stop before the run: {what}; clear it with --fault-reset")
        self.client.fault_reset()

    def positions(self) -> np.ndarray:
        return self.client.positions_rad()

    def demand(self) -> np.ndarray:
        return np.array([a.position_demand_rad for a in self.client.axes()])

    def configure(self) -> int:
        """Measure the round trip with empty blocks, choose R, write watchdog/prefill/R/D."""
        s = self.settings
        self.client.claim()  # again: planning may have outlasted the lease (the power-on watchdog)
        times = []
        for _ in range(s.round_trip_probes):
            t0 = time.perf_counter()
            self.client.poll()
            times.append(time.perf_counter() - t0)
        self.probe_s = np.array(times)
        self.ratio = s.interpolation_ratio or choose_ratio(self.probe_s, self.cycle_s)
        sample_s = self.ratio * self.cycle_s
        prefill = min(math.ceil(s.prefill_s / sample_s), self.capacity // 2)
        self.client.configure(
            watchdog_ms=s.watchdog_ms,
            prefill=prefill,
            interpolation_ratio=self.ratio,
            trace_decimation=self.ratio,
        )
        return self.ratio

    def high_level(self) -> int:
        """Buffer level the stream fills to: the lead, within the capacity (a block's room left)."""
        sample_s = self.ratio * self.cycle_s
        lead = max(self.settings.lead_s, self.settings.min_lead_s + 0.05)
        return int(min(math.ceil(lead / sample_s), self.capacity - 2 * R.MAX_CYCLES_PER_BLOCK))

    def stream(
        self,
        plan: StreamPlan,
        progress: Callable[[float], None] | None = None,
        sink: RecordSink | None = None,
    ) -> StreamLog:
        """Stream ``plan`` (subsampled to this session's ratio) and return what was recorded; a stop
        raises ``StreamStopped`` carrying the explained error and the log up to it. ``sink`` gets the
        records while the stream runs (the rest after it is up to the caller: ``sink.emitted``)."""
        sub = plan.subsample(self.ratio)
        if sink is not None:
            sink.begin(sub, self.ratio, self.cycle_s)
        writer = BackgroundSink(sink) if sink is not None else None
        rec = _Recorder(sub.n, self.timing, progress, writer, self.ratio, self.cycle_s)
        self.client.heartbeat(0)  # feeds the watchdog: a campaign reads tracker and encoders before this
        before = self._status()
        rt0 = self.timing.count
        wall0, cpu0 = time.perf_counter(), time.process_time()
        error: RxcommError | None = None
        busy = 0
        try:
            res = stream(self.client, sub.q, sub.tau_ff, high_level=self.high_level(), on_reply=rec)
            busy = res.busy_replies
        except (GatewayError, SafetyStop) as e:
            error = self._explain(e)
        except KeyboardInterrupt:  # stream() sent the quick stop already
            error = SafetyStop("interrupted by the user (Ctrl-C): quick stop sent")
        if error is not None:
            executed = rec.last_execute
            self._drain_trace(rec)  # the records up to the stop trail it: fetch them for the log
            # The drain's status knows the setpoints completed before the stop (the streaming replies
            # may predate it); a gateway that clears its buffer on a stop reports 0: keep the larger.
            rec.last_execute = max(executed, rec.last_execute)
        if writer is not None:
            writer.stop()
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        after = self._status()
        gw = rec.gateway_arrays(self.ratio, self.cycle_s)
        overruns = None
        if before is not None and after is not None:
            underruns = (after.underrun_count - before.underrun_count) % 0x10000
            overruns = (after.overruns - before.overruns) % 0x10000
        else:
            underruns = int(np.any(gw["status"] & int(Status.UNDERRUN)))
        virtual = before is not None and before.clock == R.Clock.VIRTUAL
        keep = sub.n if error is None else min(sub.n, rec.last_execute)
        q_act, tau_act = rec.trace(keep)
        if error is not None:  # records of the last setpoints before a stop may never have arrived
            arrived = np.flatnonzero(~np.isnan(q_act[:, 0]))
            keep = int(arrived[-1]) + 1 if arrived.size else 0
            q_act, tau_act = q_act[:keep], tau_act[:keep]
        log = StreamLog(
            plan=sub,
            ratio=self.ratio,
            cycle_s=self.cycle_s,
            q_actual=q_act,
            tau_actual=tau_act,
            gateway=gw,
            lost_records=int(np.isnan(q_act[:, 0]).sum()),
            busy_replies=busy,
            underruns=int(underruns),
            round_trips_s=self.timing.seconds()[rt0:],
            wall_s=wall,
            cpu_s=cpu,
            completed=error is None,
            overruns=overruns,
            virtual_time=virtual,
        )
        if error is not None:
            raise StreamStopped(error, log)
        return log

    def _drain_trace(self, rec: _Recorder, timeout_s: float = 2.0) -> None:
        """After a stop: poll (empty blocks) until the trace stops growing, bounded."""
        if not self.client_open:
            return
        deadline = time.monotonic() + timeout_s
        idle = 0
        try:
            while idle < 3 and time.monotonic() < deadline:
                reply = self.client.poll()
                rec(reply)
                idle = idle + 1 if reply.trace.count == 0 else 0
                if reply.trace.count == 0:
                    time.sleep(0.005)
        except (GatewayError, KeyboardInterrupt):
            return  # the log keeps what arrived

    @property
    def client_open(self) -> bool:
        return bool(self.client._open)  # the client closes itself on any communication error

    def _status(self) -> codec.GatewayStatus | None:
        try:
            return self.client.status()
        except GatewayError:
            return None

    def _explain(self, error: RxcommError) -> RxcommError:
        """The stop as the cell saw it: which axes faulted with which code, communication or safety."""
        if isinstance(error, GatewayError) and not self.client_open:
            # stream() reads the status after a refused block; if that fails too, the first error is the cause
            cause = error.__context__ if isinstance(error.__context__, GatewayError) else error
            return GatewayError(f"lost the connection to the gateway {self.address}: {cause}")
        try:
            st = self.client.status()
            axes = self.client.axes()
        except GatewayError:
            return error
        names = self.robot.joint_names
        faulted = [(names[i], a.error_code) for i, a in enumerate(axes) if a.error_code]
        code = st.error or (faulted[0][1] if faulted else 0)
        t_s = st.execute_index * self.ratio * self.cycle_s
        what = _cause_name(st.stop_cause) + ("" if not code else f", {_code_name(code)}")
        where = ", ".join(f"{n} {_code_name(c)}" for n, c in faulted)
        text = f"{what} at t = {t_s:.3f} s" + (f" ({where})" if where else "")
        if code in COMMUNICATION_ERRORS:
            return GatewayError(f"stream stopped by the gateway: {text}")
        if Status(st.status) & STOP_BITS or faulted:
            return SafetyStop(f"stream stopped by the gateway: {text}")
        return error

    def stop_drives(self, after_stop: bool) -> str:
        """Best effort: quick stop (after a stop), wait for the ramp, disable. Returns what happened."""
        c = self.client
        if not self.client_open:
            try:
                c.connect()
            except GatewayError:
                return f"gateway unreachable; its watchdog ({self.settings.watchdog_ms} ms) stops the drives"
        try:
            if after_stop:
                with contextlib.suppress(GatewayError):
                    c.quick_stop()
                self._wait_standstill()
            c.disable_all()
            return "drives disabled"
        except (GatewayError, SafetyStop) as e:
            return f"could not disable the drives ({e}); the gateway's watchdog stops them"

    def _wait_standstill(self) -> None:
        """Until the demand of every axis stops changing (the stop ramp ended), feeding the watchdog."""
        deadline = time.monotonic() + self.settings.stop_timeout_s
        last = self.demand()
        beat = 0
        while time.monotonic() < deadline:
            beat += 1
            self.client.heartbeat(beat)
            time.sleep(0.02)
            now = self.demand()
            if np.max(np.abs(now - last)) < 1e-6:
                return
            last = now


class StreamStopped(Exception):  # noqa: N818 - a carrier inside rxcomm.execution, never escapes run_*
    def __init__(self, error: RxcommError, log: StreamLog):
        super().__init__(str(error))
        self.error = error
        self.log = log


_CAUSES = {
    StopCause.NONE: "no stop cause reported",
    StopCause.UNDERRUN: "setpoint underrun",
    StopCause.WATCHDOG: "watchdog expired (no write from the master in time)",
    StopCause.CONNECTION_LOST: "the master's connection was lost",
    StopCause.ESTOP: "emergency stop",
    StopCause.AXIS_FAULT: "axis fault",
    StopCause.QUICK_STOP_COMMAND: "quick stop commanded",
    StopCause.STREAM_DISABLED: "stream enable withdrawn",
    StopCause.AXIS_LEFT_OPERATION: "a controlword took an axis out of operation enabled",
}


def _cause_name(cause: int) -> str:
    """Register 43 in words (with its number, for a PLC programmer's log)."""
    try:
        return f"{_CAUSES[StopCause(cause)]} (stop cause {cause})"
    except ValueError:
        return f"stop cause {cause}"


def _code_name(code: int) -> str:
    try:
        return f"{ErrorCode(code).name.lower().replace('_', ' ')} ({code:#06x})"
    except ValueError:
        return f"error {code:#06x}"


# ---- a trajectory run -----------------------------------------------------------------------------


def run_trajectory(
    client: GatewayClient,
    robot: Robot,
    plan: StreamPlan,
    params: DynamicParameters,
    settings: RunSettings | None = None,
    progress: Callable[[str, float], None] | None = None,
    sink: RecordSink | None = None,
) -> RunResult:
    """Execute a prepared ``plan`` (``prepare_plan``) on a connected gateway. ``params`` is the model
    for the approach move's feed-forward and limit check. Refusals before motion raise (InputError,
    GatewayError, SafetyStop); a stop during motion is returned in ``RunResult.error`` with the log
    recorded up to it. ``progress(what, fraction)`` is called at ≤ 10 Hz while streaming; ``sink`` (the
    run log writer) gets the plan's records while it streams."""
    settings = settings or RunSettings()
    ses = Session(client, robot, settings.stream)
    ses.check_identity()
    ses.check_faults(settings.fault_reset)
    q_now = ses.positions()
    dist = distance_to_start(robot, q_now, plan.q[0])
    approach: StreamPlan | None = None
    if max(dist.values()) > settings.start_tolerance_rad:
        if not settings.approach:
            far = ", ".join(f"{k} {v:.4f}" for k, v in dist.items())
            raise SafetyStop(
                f"the robot is not at the plan's start (distance per joint, rad: {far}; tolerance "
                f"{settings.start_tolerance_rad:g}); use --approach to move there first"
            )
        move = move_trajectory(robot, q_now, plan.q[0], ses.cycle_s, settings.approach_speed_fraction)
        approach = prepare_plan(
            robot,
            move,
            params,
            ses.cycle_s,
            feedforward=settings.feedforward,
            limit_tolerance=settings.limit_tolerance,
            what="approach move",
        )
    ses.configure()
    result = RunResult(
        gateway=ses.address, ratio=ses.ratio, cycle_s=ses.cycle_s, round_trip_probe_s=ses.probe_s
    )
    stage = "approach"
    try:
        client.enable_all()
        held = ses.demand()
        start = approach.q[0] if approach is not None else plan.q[0]
        if np.max(np.abs(held - start)) > settings.start_tolerance_rad:
            raise SafetyStop(f"the robot moved while enabling: {np.round(held - start, 5).tolist()} rad")
        if approach is not None:
            result.approach = ses.stream(approach, _named(progress, "approach"))
        stage = "plan"
        result.log = ses.stream(plan, _named(progress, "run"), sink)
        result.stop_note = ses.stop_drives(after_stop=False)
    except StreamStopped as s:
        if stage == "approach":
            result.approach = s.log
        else:
            result.log = s.log
        result.error = s.error
        result.stop_note = ses.stop_drives(after_stop=True)
    except (GatewayError, SafetyStop) as e:  # enable failed or refused after enabling
        result.error = e
        result.stop_note = ses.stop_drives(after_stop=True)
    except KeyboardInterrupt:
        result.error = SafetyStop("interrupted by the user (Ctrl-C)")
        result.stop_note = ses.stop_drives(after_stop=True)
    return result


def _named(progress: Callable[[str, float], None] | None, what: str) -> Callable[[float], None] | None:
    if progress is None:
        return None
    return lambda f: progress(what, f)
