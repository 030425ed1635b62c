"""What a stream records, and how the records leave the master while it runs (architecture §7 run).

``_Recorder`` is the stream's ``on_reply``: it gathers trace chunks (one record per setpoint) and
gateway status rows. Without a ``RecordSink`` it keeps them all and ``StreamLog`` holds the whole
stream (a campaign's short moves, the streaming bench). With a sink (the run log writer) it hands
them over every ``sink.period_s`` of wall time and **drops** what it handed over, so the master's
memory is bounded by one period of records however long the stream runs; at the end of the stream
the rest goes to the sink as well and the ``StreamLog`` holds counts only (``records_in_sink``). The
figures the summary needs of the dropped rows are kept as running values: lost records, the smallest
buffered lead, the status bits seen (the writer keeps the motion's, ``summary.MotionStats``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from rxcomm.errors import GatewayError, RxcommError
from rxcomm.execution.guards import raise_if_terminated
from rxcomm.execution.plan import StreamPlan
from rxcomm.execution.record_sink import RecordSink
from rxcomm.execution.stalls import StallWatch
from rxcomm.gateway import registers as R
from rxcomm.gateway.client import BlockReply, RoundTripStats
from rxcomm.gateway.registers import Status

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


@dataclass(frozen=True, eq=False)
class StreamLog:
    """One stream as recorded: the setpoints sent and, per setpoint reached, the drives' feedback.

    ``q_actual``/``tau_actual`` hold the trace records from ``records_in_sink`` on (record r belongs
    to setpoint r; rows of lost records are NaN): all of them without a sink, none when a
    ``RecordSink`` took them while streaming. ``gateway`` holds the block replies' status rows not
    handed to a sink (arrays of equal length). ``n_records`` counts both.
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
    records_in_sink: int = 0  # leading records handed to the RecordSink (not held here)
    gateway_rows_in_sink: int = 0  # leading status rows handed to the RecordSink
    sink_min_lead_s: float = math.nan  # smallest lead while feeding among the rows handed over

    @property
    def n_records(self) -> int:
        return self.records_in_sink + int(self.q_actual.shape[0])

    @property
    def q_demand(self) -> np.ndarray:
        """The planned setpoints of the records held (rows ``records_in_sink…n_records``)."""
        return self.plan.q[self.records_in_sink : self.n_records]

    @property
    def following_error(self) -> np.ndarray:
        """q_demand − q_actual of the records held."""
        return self.q_demand - self.q_actual

    def min_lead_s(self) -> float:
        """Smallest buffered lead while setpoints were still being sent and the stream ran."""
        held = _min_lead(self.gateway, self.plan.n)
        both = [x for x in (held, self.sink_min_lead_s) if np.isfinite(x)]
        return float(min(both)) if both else math.nan


def _min_lead(g: dict[str, np.ndarray], n_plan: int) -> float:
    if len(g["lead_s"]) == 0:
        return math.nan
    feeding = (g["write_index"] < n_plan) & ((g["status"] & int(Status.STREAMING)) != 0)
    return float(g["lead_s"][feeding].min()) if feeding.any() else math.nan


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


class LastRoundTrip(RoundTripStats):
    """The client's round-trip statistics, also remembering the latest one (for the gateway topic)."""

    def __init__(self) -> None:
        super().__init__()
        self.last_s = math.nan

    def add(self, seconds: float) -> None:
        super().add(seconds)
        self.last_s = seconds


Row = tuple[float, float, int, int, int, int, int]


class _Recorder:
    """``stream(on_reply=...)``: keeps trace chunks and status rows, calls ``progress`` at ≤ 10 Hz and
    hands new rows to the ``sink`` every ``sink.period_s``, dropping them then (module docstring)."""

    def __init__(
        self,
        n: int,
        timing: LastRoundTrip,
        progress: Callable[[float], None] | None,
        sink: RecordSink | None = None,
        ratio: int = 1,
        cycle_s: float = R.CYCLE_US * 1e-6,
    ) -> None:
        self.n = n
        self.timing = timing
        self.progress = progress
        self.chunks: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.rows: list[Row] = []
        self.t0 = time.perf_counter()
        self._next_progress = 0.0
        self.last_execute = 0
        self.sink = sink
        self.ratio, self.cycle_s = ratio, cycle_s
        self.emitted = 0  # records handed to the sink
        self.rows_emitted = 0  # status rows handed to the sink
        self.lost_emitted = 0  # NaN rows (records never received) among those handed over
        self.min_lead_emitted = math.nan
        self.status_seen = 0  # OR of every status word received
        self._trace_end = 0  # one past the highest record received
        self._next_emit = self.t0 + (sink.period_s if sink is not None else 0.0)
        # also every period_s of stream time: in virtual time the cell runs faster than the wall clock,
        # and a batch of period_s wall time grew with the machine's speed (2.5x on an idle one)
        self._emit_records = max(1, round(sink.period_s / (ratio * cycle_s))) if sink is not None else 0
        self.stalls: StallWatch | None = None  # the pauses between replies, for a stop's message

    def __call__(self, reply: BlockReply) -> None:
        raise_if_terminated()  # a SIGTERM between two transactions: stop as Ctrl-C does
        st = reply.status
        if self.stalls is not None:
            self.stalls.reply(*((st.write_index, st.execute_index) if st is not None else ()))
        tr = reply.trace
        if tr.count:
            self.chunks.append((tr.first, tr.position_rad, tr.torque_nm))
            self._trace_end = max(self._trace_end, tr.first + tr.count)
        if st is None:
            return
        wall = time.perf_counter() - self.t0
        self.last_execute = st.execute_index
        self.status_seen |= int(st.status)
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
        if self.sink is not None and (
            time.perf_counter() >= self._next_emit or self._trace_end - self.emitted >= self._emit_records
        ):
            self.emit()

    def emit(self, end: int | None = None) -> None:
        """Hand the sink the records up to ``end`` (default: of the setpoints executed so far, not
        those of a stop ramp after the last executed setpoint: they have no planned demand) and the
        new status rows, then drop them."""
        assert self.sink is not None
        if end is None:
            end = min(self._trace_end, self.last_execute, self.n)
        if end > self.emitted:
            q = np.full((end - self.emitted, R.N_AXES), np.nan)  # NaN: a record lost to overflow
            tau = q.copy()
            for first, pos, tq in self.chunks:
                lo, hi = max(first, self.emitted), min(first + pos.shape[0], end)
                if hi > lo:
                    q[lo - self.emitted : hi - self.emitted] = pos[lo - first : hi - first]
                    tau[lo - self.emitted : hi - self.emitted] = tq[lo - first : hi - first]
            # a chunk reaching past ``end`` is looked at again next time; the others are done
            self.chunks = [c for c in self.chunks if c[0] + c[1].shape[0] > end]
            self.sink.records(self.emitted, q, tau)
            self.lost_emitted += int(np.isnan(q[:, 0]).sum())
            self.emitted = end
        if self.rows:
            g = _gateway_arrays(self.rows, self.ratio, self.cycle_s)
            self.sink.gateway(g)
            lead = _min_lead(g, self.n)
            if np.isfinite(lead):
                self.min_lead_emitted = float(np.fmin(self.min_lead_emitted, lead))
            self.rows_emitted += len(self.rows)
            self.rows = []
        self._next_emit = time.perf_counter() + self.sink.period_s

    def arrived_end(self, keep: int) -> int:
        """One past the last record below ``keep`` that arrived, among the chunks still held."""
        ends = [min(first + pos.shape[0], keep) for first, pos, _ in self.chunks if first < keep]
        return max(ends, default=0)

    def trace(self, keep: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows emitted..keep-1 by record index (NaN where a record never arrived)."""
        m = max(keep - self.emitted, 0)
        q = np.full((m, R.N_AXES), np.nan)
        tau = np.full((m, R.N_AXES), np.nan)
        for first, pos, tq in self.chunks:
            lo, hi = max(first, self.emitted), min(first + pos.shape[0], keep)
            if hi > lo:
                q[lo - self.emitted : hi - self.emitted] = pos[lo - first : hi - first]
                tau[lo - self.emitted : hi - self.emitted] = tq[lo - first : hi - first]
        return q, tau

    def gateway_arrays(self) -> dict[str, np.ndarray]:
        return _gateway_arrays(self.rows, self.ratio, self.cycle_s)


def _gateway_arrays(rows: list[Row], ratio: int, cycle_s: float) -> dict[str, np.ndarray]:
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
