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
5. enable, stream (``rxcomm.gateway.stream``), every reply's trace and status recorded
   (``rxcomm.execution.records``): with a ``RecordSink`` (the run log writer) handed over every
   ``period_s`` of wall time and dropped, so a killed run leaves its log up to then and the master's
   memory stays bounded (the buffered lead, ≥ 0.1 s, rides out the writer's few tens of ms);
6. disable. Any stop after enabling — gateway stop bits, lost connection, Ctrl-C — quick-stops, waits
   until the demand stands still (bounded), disables, and is *returned* in ``RunResult.error`` with
   what was recorded up to it, so the caller can still write the log.
"""

from __future__ import annotations

import contextlib
import gc
import math
import time
from collections.abc import Callable

import numpy as np
from pydantic import Field

from rxcomm.errors import DriveTrip, GatewayError, InputError, RxcommError, SafetyStop, Terminated
from rxcomm.execution.plan import StreamPlan
from rxcomm.execution.record_sink import BackgroundSink
from rxcomm.execution.records import (
    LastRoundTrip,
    RecordSink,
    StreamLog,
    _Recorder,
)
from rxcomm.execution.stalls import StallWatch, raised_priority
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.client import GatewayClient
from rxcomm.gateway.registers import DriveState, ErrorCode, Status, StopCause
from rxcomm.gateway.stream import STOP_BITS, stream
from rxcomm.model.limits import SAMPLED_LIMIT_TOLERANCE
from rxcomm.model.robot import Robot
from rxcomm.schemas.strict import Strict

ROUND_TRIP_MARGIN = 3.0  # a block must last this many mean empty-block round trips: a full block's
# encode/decode and the recording ride on it (measured: ≈ 1.5–2 × an empty poll on a loaded 2-core VM)
LATCHED_FAULT_BITS = (
    Status.WATCHDOG | Status.ESTOP | Status.AXIS_FAULT | Status.UNDERRUN | Status.SEQUENCE_ERROR
)
COMMUNICATION_ERRORS = (ErrorCode.HEARTBEAT, ErrorCode.UNDERRUN)  # the master's fault: exit 4


# The embedded cell in virtual time waits for setpoints, so a master paused on a loaded machine changes
# nothing in the run; its watchdog then only has to notice a master that is gone. 500 ms of wall time
# stopped `make commission` three times in one afternoon at load 3–4; a real gateway keeps the default.
# The same holds for the master's wait on a reply: the cell simulates a setpoint block's cycles before
# it answers, in the master's process, and at load ≈ 4.7 one reply took longer than 0.5 s (a measurement
# campaign stopped at pose 49 of 55).
VIRTUAL_CELL_WATCHDOG_MS = 5000
VIRTUAL_CELL_REQUEST_TIMEOUT_S = 5.0
REQUEST_TIMEOUT_S = 0.5  # a real gateway or a realtime cell: a reply later than this is a fault


class StreamSettings(Strict):
    """How setpoints are fed to the gateway."""

    interpolation_ratio: int | None = Field(
        None,
        ge=1,
        le=R.INTERPOLATION_RATIO_MAX,
        description="drive cycles per setpoint; None: from the round trip",
    )
    lead_s: float = Field(
        1.0, gt=0, description="buffered setpoints kept ahead of execution, s (capped by the buffer)"
    )
    prefill_s: float = Field(
        1.0,
        gt=0,
        description="buffered before the stream starts, s (capped at half the buffer): the whole lead, so "
        "a master slower than the stream on a loaded machine starts with all its reserve",
    )
    min_lead_s: float = Field(0.1, gt=0, description="the lead the run promises to keep, s")
    watchdog_ms: int = Field(
        500, ge=10, le=R.WATCHDOG_MS_MAX, description="no accepted write for this long: the cell faults"
    )
    round_trip_probes: int = Field(50, ge=5, description="empty blocks timed to choose the ratio")
    stop_timeout_s: float = Field(3.0, gt=0, description="wait for the stop ramp before disabling, s")


class RunSettings(Strict):
    """What `run` does with a trajectory plan."""

    feedforward: bool = Field(True, description="stream τ_ff of the model; False: zeros")
    approach: bool = Field(False, description="move to the plan's start first (jerk-limited)")
    handover: bool = Field(
        False,
        description="first hand the model's static torque over to the drives' integrators: a run without "
        "feed-forward on drives just powered on (the simulated cell `run` starts; rxcomm.execution.handover)",
    )
    approach_speed_fraction: float = Field(0.2, gt=0, le=1, description="of velocity and acceleration limits")
    start_tolerance_rad: float = Field(1e-3, gt=0, description="per joint: 'at the start' within this")
    limit_tolerance: float = Field(
        SAMPLED_LIMIT_TOLERANCE, ge=0, description="limit ratios up to 1 + this pass"
    )
    fault_reset: bool = Field(False, description="reset drive faults and latched gateway stops first")
    trip_is_result: bool = Field(
        False,
        description="a drive trip on the motion (`DriveTrip`) ends the run as its result: the log "
        "written whole with the stop in its summary (the plan without feed-forward, paper Fig. 2)",
    )
    stream: StreamSettings = StreamSettings()


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
        self.timing = LastRoundTrip()
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
        records while the stream runs and the rest at its end; the log then holds only counts and
        running figures of them (``rxcomm.execution.records``)."""
        sub = plan.subsample(self.ratio)
        if sink is not None:
            sink.begin(sub, self.ratio, self.cycle_s)
        writer = BackgroundSink(sink) if sink is not None else None  # the log's work off this loop
        rec = _Recorder(sub.n, self.timing, progress, writer, self.ratio, self.cycle_s)
        self.client.heartbeat(0)  # feeds the watchdog: a campaign reads tracker and encoders before this
        before = self._status()
        rt0 = self.timing.count
        wall0, cpu0 = time.perf_counter(), time.process_time()
        error: RxcommError | None = None
        writer_failed = False
        busy = 0
        rec.stalls = StallWatch(self.ratio * self.cycle_s)
        gc.freeze()  # the objects of the model, plans and libraries are not scanned again while it streams
        # (full collections paused the master up to 0.09 s at load 7 on 2 cores)
        realtime = before is None or before.clock != R.Clock.VIRTUAL  # a virtual clock waits for us
        try:
            with rec.stalls, raised_priority() if realtime else contextlib.nullcontext("") as prio:
                rec.stalls.priority = prio
                res = stream(
                    self.client,
                    sub.q,
                    sub.tau_ff,
                    high_level=self.high_level(),
                    on_reply=rec,
                    keep_trace=False,  # the recorder has it (and drops it once a sink took it)
                )
            busy = res.busy_replies
        except (GatewayError, SafetyStop) as e:
            rec.stalls.reply()  # the pause before the stop counts too
            error = self._explain(e, rec.stalls)
        except KeyboardInterrupt as e:  # stream() sent the quick stop already
            error = SafetyStop(f"{interrupt_reason(e)}: quick stop sent")
        except OSError as e:  # the run log's writer failed (a full disk): stop the motion, keep the log
            with contextlib.suppress(GatewayError):
                self.client.quick_stop()
            error = log_write_error(e, sink)
            writer_failed = True
        except BaseException:  # what was handed over still reaches the log before this propagates
            if writer is not None:
                with contextlib.suppress(Exception):
                    writer.stop()
            raise
        finally:
            gc.unfreeze()
        if error is not None:
            executed = rec.last_execute
            self._drain_trace(rec)  # the records up to the stop trail it: fetch them for the log
            # The drain's status knows the setpoints completed before the stop (the streaming replies
            # may predate it); a gateway that clears its buffer on a stop reports 0: keep the larger.
            rec.last_execute = max(executed, rec.last_execute)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        keep = sub.n if error is None else min(sub.n, rec.last_execute)
        if sink is not None and not writer_failed:  # the rest to the sink too: the log holds counts only
            # after a stop, up to the last record that arrived (those of the last setpoints before
            # it may never come)
            rec.emit(keep if error is None else max(rec.emitted, rec.arrived_end(keep)))
        if writer is not None:
            try:
                writer.stop()  # every hand-over written before the caller closes the log
            except OSError:
                if not writer_failed:
                    raise
        after = self._status()
        gw = rec.gateway_arrays()
        overruns = None
        if before is not None and after is not None:
            underruns = (after.underrun_count - before.underrun_count) % 0x10000
            overruns = (after.overruns - before.overruns) % 0x10000
        else:
            underruns = int(bool(rec.status_seen & int(Status.UNDERRUN)))
        virtual = before is not None and before.clock == R.Clock.VIRTUAL
        q_act, tau_act = rec.trace(keep)
        if error is not None and sink is None:
            # records of the last setpoints before a stop may never have arrived
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
            lost_records=rec.lost_emitted + int(np.isnan(q_act[:, 0]).sum()),
            busy_replies=busy,
            underruns=int(underruns),
            round_trips_s=self.timing.seconds()[rt0:],
            wall_s=wall,
            cpu_s=cpu,
            completed=error is None,
            overruns=overruns,
            virtual_time=virtual,
            records_in_sink=rec.emitted,
            gateway_rows_in_sink=rec.rows_emitted,
            sink_min_lead_s=rec.min_lead_emitted,
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

    def _explain(self, error: RxcommError, stalls: StallWatch | None = None) -> RxcommError:
        """The stop as the cell saw it: which axes faulted with which code, communication or safety;
        an underrun or a watchdog stop also says what held the master (``StallWatch``)."""
        if isinstance(error, GatewayError) and not self.client_open:
            # stream() reads the status after a refused block; if that fails too, the first error is the cause
            cause = error.__context__ if isinstance(error.__context__, GatewayError) else error
            held = f"; {stalls.describe()}" if stalls is not None else ""  # a late reply: what held us
            return GatewayError(f"lost the connection to the gateway {self.address}: {cause}{held}")
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
        if stalls is not None and (code in COMMUNICATION_ERRORS or st.stop_cause == StopCause.UNDERRUN):
            text += f"; {stalls.describe(watchdog=st.stop_cause != StopCause.UNDERRUN)}"
        if code in COMMUNICATION_ERRORS:
            return GatewayError(f"stream stopped by the gateway: {text}")
        if faulted:
            return DriveTrip(f"stream stopped by the gateway: {text}")
        if Status(st.status) & STOP_BITS:
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
            return self._drive_states()
        except (GatewayError, SafetyStop) as e:
            return f"could not disable the drives ({e}); the gateway's watchdog stops them"

    def _drive_states(self) -> str:
        """What the drives are in after the disable, as read back: "drives disabled", or the axes in
        fault with their codes (a watchdog that fired while the gateway was silent faults them)."""
        try:
            axes = self.client.axes()
        except GatewayError:
            return "drives disabled (not read back)"
        faulted = [
            f"{self.robot.joint_names[i]} {a.error_code:#06x}"
            for i, a in enumerate(axes)
            if a.state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
        ]
        if len(faulted) == len(axes):
            return f"drives in fault, not disabled ({', '.join(faulted)}): clear with --fault-reset"
        if faulted:
            return f"drives disabled except {', '.join(faulted)} in fault: clear with --fault-reset"
        on = DriveState.OPERATION_ENABLED
        enabled = [self.robot.joint_names[i] for i, a in enumerate(axes) if a.state == on]
        if enabled:
            return f"drives still enabled: {', '.join(enabled)}"
        return "drives disabled"

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


def interrupt_reason(e: BaseException) -> str:
    """Why the run was interrupted: SIGTERM (rxcomm.errors.Terminated) or Ctrl-C."""
    return "terminated (SIGTERM)" if isinstance(e, Terminated) else "interrupted by the user (Ctrl-C)"


def log_write_error(e: OSError, sink: object) -> InputError:
    """A run log that cannot be written (a full disk) as exit 2 naming the file: the motion stops."""
    part = getattr(sink, "part_path", None) or e.filename
    reason = e.strerror or str(e)
    return InputError(f"the run log could not be written ({reason}): quick stop sent", file=part)


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
