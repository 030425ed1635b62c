"""The master's memory is bounded while it streams into the run log writer (issue 14's soak), and the
summary it keeps as running values equals the one computed from every record."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import tracemalloc

import numpy as np
import pytest

from rxcomm.execution.bench import back_and_forth
from rxcomm.execution.log import RunLogWriter, write_run_log
from rxcomm.execution.plan import prepare_plan
from rxcomm.execution.records import RunResult, StreamLog
from rxcomm.execution.session import RunSettings, StreamSettings
from rxcomm.execution.summary import MotionStats, run_summary, tcp_error_and_speed
from rxcomm.execution.trajectory_run import run_trajectory
from rxcomm.gateway import registers as R
from rxcomm.gateway.client import GatewayClient
from rxcomm.model.dynamics import prior_parameters

from .runs import CYCLE, DQ, Q0, cosine_plan

MOTION_FIELDS = (
    "max_lag_rad",
    "rms_lag_rad",
    "max_tcp_error_m",
    "rms_tcp_error_m",
    "duration_s",
    "tau_squared_integral_nm2_s",
    "electrical_energy_j",
)


def _synthetic(rx130l, n: int = 6000, lost: tuple[int, ...] = (0, 1, 2500, 2501, 2502, 5999)) -> RunResult:
    """A recorded stream with lost records (NaN rows) at the start, in the middle and at the end."""
    rng = np.random.default_rng(3)
    params = prior_parameters(rx130l)
    plan = prepare_plan(rx130l, cosine_plan(Q0, DQ, max(n - 1, 5999) * CYCLE), params, CYCLE)
    q = (plan.q - 2e-3 * plan.qd + 1e-6 * rng.standard_normal(plan.q.shape))[:n]
    tau = (plan.tau_ff + rng.standard_normal(plan.q.shape))[:n]
    q[list(lost)] = np.nan
    tau[list(lost)] = np.nan
    empty = {k: np.zeros(0) for k in ("t", "lead_s", "write_index", "status")}
    log = StreamLog(plan, 1, CYCLE, q, tau, empty, len(lost), 0, 0, np.full(10, 3e-4), 1.0, 0.1, True)
    return RunResult("127.0.0.1:1502", 1, CYCLE, log=log)


def _assert_same(a, b):
    """The motion fields agree to rounding; None (not measured) and NaN exactly."""
    for k in MOTION_FIELDS:
        x, y = a[k], b[k]
        if x is None or y is None or (isinstance(x, list) and None in x):
            assert x == y, k
        else:
            np.testing.assert_allclose(
                np.asarray(x, float), np.asarray(y, float), rtol=1e-12, equal_nan=True, err_msg=k
            )


@pytest.mark.slow  # 1.1 s CPU (make test-fast: the unit tier within 60 s)
def test_running_motion_figures_equal_the_array_computation(rx130l, tmp_path):
    """MotionStats fed in uneven chunks (a chunk boundary next to lost records too) gives the summary
    that run_summary computes from all the records at once, to rounding."""
    result = _synthetic(rx130l)
    log = result.log
    reference = run_summary(rx130l, result)
    assert reference["electrical_energy_j"] > 0 and reference["tau_squared_integral_nm2_s"] > 0
    tcp, _ = tcp_error_and_speed(rx130l, log.plan.q, log.plan.qd, log.q_actual)
    for cuts in ([1, 2, 3, 2500, 2502, 2503, 4000, 5999], list(range(0, 6000, 977)), [3000]):
        stats = MotionStats(rx130l, log.plan.sample_s)
        edges = [0, *sorted(set(c for c in cuts if 0 < c < log.n_records)), log.n_records]
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            stats.add(lo, log.plan.q[lo:hi], log.q_actual[lo:hi], log.tau_actual[lo:hi], tcp[lo:hi])
        _assert_same(run_summary(rx130l, result, motion=stats), reference)
    # and the log writer (which keeps only those running figures) writes the same summary
    _, written = write_run_log(
        tmp_path / "log.mcap",
        rx130l,
        result,
        inputs={},
        settings={},
        feedforward="prior",
        embedded_cell=False,
    )
    _assert_same(written, reference)


@pytest.mark.filterwarnings("ignore:Mean of empty slice")  # the array computation, all records lost
def test_edge_cases_of_the_running_figures(rx130l):
    """One record, two records, all records lost: as the array computation says."""
    for n, lost in ((1, ()), (2, ()), (3, (0, 1, 2)), (4, (1,))):
        result = _synthetic(rx130l, n, lost)
        log = result.log
        tcp, _ = tcp_error_and_speed(rx130l, log.plan.q[:n], log.plan.qd[:n], log.q_actual)
        stats = MotionStats(rx130l, log.plan.sample_s)
        for i in range(n):
            stats.add(
                i, log.plan.q[i : i + 1], log.q_actual[i : i + 1], log.tau_actual[i : i + 1], tcp[i : i + 1]
            )
        _assert_same(run_summary(rx130l, result, motion=stats), run_summary(rx130l, result))


_CELL = """
import sys, numpy as np
from rxcomm.cell.backend import IdealBackend
from rxcomm.cell.server import CellServer, ServerConfig, TimeMode
q0, rated = (np.array([float(x) for x in a.split(",")]) for a in sys.argv[1:3])
srv = CellServer(IdealBackend(q0, rated_torque_nm=rated), ServerConfig(time_mode=TimeMode.VIRTUAL)).start()
print(srv.port, flush=True)
sys.stdin.read()
srv.stop()
"""


@contextlib.contextmanager
def _cell_process(robot):
    """A virtual-time ideal cell in another process: tracemalloc traces (and slows) the master only."""
    csv = [",".join(repr(float(x)) for x in v) for v in (Q0, robot.tau_max)]
    proc = subprocess.Popen(
        [sys.executable, "-c", _CELL, *csv], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdin is not None
        yield int(proc.stdout.readline())
        proc.stdin.close()
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)


class _Discard:
    """A record sink that only counts: the master's side of the hand-over, without the writer's work."""

    period_s = 0.5

    def __init__(self) -> None:
        self.n = 0

    def begin(self, plan, ratio, cycle_s) -> None:
        pass

    def records(self, first, q_actual, tau_actual) -> None:
        assert first == self.n
        self.n += len(q_actual)

    def gateway(self, rows) -> None:
        pass


def _stream_peak_bytes(rx130l, port: int, duration_s: float, sink: bool) -> tuple[int, RunResult]:
    """tracemalloc's peak over one virtual-time run of ``duration_s`` at R = 1 (the plan allocated
    before), with or without a record sink."""
    params = prior_parameters(rx130l)
    plan = prepare_plan(rx130l, back_and_forth(rx130l, Q0, duration_s, period_s=1.0), params, CYCLE)
    # tracemalloc slows the master several times: a lenient watchdog
    settings = RunSettings(stream=StreamSettings(interpolation_ratio=1, watchdog_ms=R.WATCHDOG_MS_MAX))
    with GatewayClient("127.0.0.1", port, timeout_s=5.0) as client:
        discard = _Discard() if sink else None
        tracemalloc.start()
        try:
            base = tracemalloc.get_traced_memory()[0]
            result = run_trajectory(client, rx130l, plan, params, settings, sink=discard)
            peak = tracemalloc.get_traced_memory()[1] - base
        finally:
            tracemalloc.stop()
    assert result.error is None, result.error
    assert result.log.n_records == plan.n and result.log.lost_records == 0
    if discard is not None:
        assert discard.n == plan.n
    return peak, result


@pytest.mark.slow  # a soak: a cell process streaming to the master for seconds
def test_master_memory_is_bounded_with_a_record_sink(rx130l):
    """Streaming 4 × longer into a sink does not raise the master's peak memory (the records leave
    every 0.5 s), while a stream that keeps every record grows by at least what those records take."""
    with _cell_process(rx130l) as port:
        # a master stalled by a loaded machine hands a larger batch over once: the least peak of two
        # streams each is what the stream itself needs (CI saw +245 KB in one loaded 4 s stream)
        short = min(_stream_peak_bytes(rx130l, port, 1.0, sink=True)[0] for _ in range(2))
        (long, res), (long2, _) = (_stream_peak_bytes(rx130l, port, 4.0, sink=True) for _ in range(2))
        long = min(long, long2)
        kept_long, kept = _stream_peak_bytes(rx130l, port, 4.0, sink=False)
    assert res.log.q_actual.shape[0] == 0 and res.log.records_in_sink == res.log.n_records
    assert kept.log.q_actual.shape[0] == kept.log.n_records
    records_bytes = (res.log.n_records - int(1.0 / CYCLE)) * 2 * 6 * 8  # q_actual + tau_actual, 3 s more
    assert kept_long - short > records_bytes  # keeping every record: grows with the stream
    # with a sink: growth well under a third of those records (the round trips, one float per
    # block, grow; a flush or two may wait for the log's writer thread on a loaded machine)
    assert long - short < 0.3 * records_bytes, (short, long, records_bytes)


@pytest.mark.slow  # a soak of the log writer
def test_log_writer_memory_is_bounded(rx130l, tmp_path):
    """The writer keeps no record it wrote: 4 × more rows, the same memory (tcp errors, records and
    encoder angles beyond ``keep_encoder_s`` are not kept)."""
    params = prior_parameters(rx130l)
    plan = prepare_plan(rx130l, back_and_forth(rx130l, Q0, 4.0, period_s=2.0), params, CYCLE)
    rng = np.random.default_rng(1)
    q = plan.q + 1e-5 * rng.standard_normal(plan.q.shape)
    writer = RunLogWriter(
        tmp_path / "log.mcap", rx130l, inputs={}, settings={}, feedforward="prior", embedded_cell=False,
        keep_encoder_s=0.2,
    )  # fmt: skip
    writer.begin(plan, 1, CYCLE)
    chunk = int(0.25 / CYCLE)
    tracemalloc.start()
    try:
        used = []
        for first in range(0, plan.n, chunk):
            sl = slice(first, min(first + chunk, plan.n))
            writer.records(first, q[sl], plan.tau_ff[sl])
            used.append(tracemalloc.get_traced_memory()[0])
    finally:
        tracemalloc.stop()
    writer.abandon()
    assert writer.n_joint == plan.n
    assert writer.encoder_prefix.shape == (int(0.2 / CYCLE) + 1, 6)
    grown = used[-1] - used[len(used) // 4]  # after 1 s → after 4 s
    assert grown < 0.05 * (plan.n * 3 // 4) * 2 * 6 * 8, grown  # vs keeping those records
