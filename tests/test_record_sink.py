"""The run log is written off the streaming thread: a hand-over returns at once however slow the
writer, records arrive in order and complete, and a writer's error reaches the stream."""

import time

import numpy as np
import pytest

from rxcomm.execution.record_sink import BackgroundSink


class SlowSink:
    period_s = 0.5

    def __init__(self, seconds: float, fail_at: int | None = None) -> None:
        self.seconds, self.fail_at = seconds, fail_at
        self.calls: list[tuple[str, int]] = []

    def begin(self, plan, ratio, cycle_s) -> None:
        self.calls.append(("begin", ratio))

    def records(self, first, q_actual, tau_actual) -> None:
        time.sleep(self.seconds)
        if self.fail_at is not None and first >= self.fail_at:
            raise OSError(28, "No space left on device")
        self.calls.append(("records", first))

    def gateway(self, rows) -> None:
        self.calls.append(("gateway", len(rows["t"])))


def test_a_slow_writer_does_not_hold_the_stream_and_loses_nothing():
    inner = SlowSink(0.05)
    bg = BackgroundSink(inner)
    q = np.zeros((10, 6))
    handed = []
    bg.begin(None, 1, 4e-4)
    for k in range(8):  # 8 flushes that take 0.4 s to write
        t0 = time.perf_counter()
        bg.records(10 * k, q, q)
        bg.gateway({"t": np.zeros(3)})
        handed.append(time.perf_counter() - t0)
    assert max(handed) < 0.02  # the writer's 50 ms per flush stays off the loop
    assert len(inner.calls) < 17  # still writing when the stream is done
    bg.stop()
    assert inner.calls[0] == ("begin", 1)
    assert [c for c in inner.calls if c[0] == "records"] == [("records", 10 * k) for k in range(8)]
    assert sum(c[0] == "gateway" for c in inner.calls) == 8


def test_the_writers_error_reaches_the_stream_and_stop():
    inner = SlowSink(0.0, fail_at=20)
    bg = BackgroundSink(inner)
    q = np.zeros((10, 6))
    with pytest.raises(OSError, match="No space left"):
        for k in range(200):
            bg.records(10 * k, q, q)
            time.sleep(0.002)
    with pytest.raises(OSError, match="No space left"):
        bg.stop()
    assert [c[1] for c in inner.calls] == [0, 10]  # nothing written after the failure


def test_a_full_queue_makes_the_stream_wait_instead_of_growing():
    inner = SlowSink(0.03)
    bg = BackgroundSink(inner, max_pending=2)
    q = np.zeros((1, 6))
    t0 = time.perf_counter()
    for k in range(6):
        bg.records(k, q, q)
    waited = time.perf_counter() - t0
    assert waited >= 0.03 * (6 - 2 - 1) * 0.9  # bounded: the loop waited for the writer
    bg.stop()
    assert [c[1] for c in inner.calls] == list(range(6))
