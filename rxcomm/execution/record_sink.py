"""Where a stream's records go while it runs (`RecordSink`: the run log writer), and the writing
kept off the streaming thread (`BackgroundSink`).

The stream's loop must answer the gateway within its watchdog (500 ms by default) and, in real time,
within the buffered lead. Writing a flush of the run log (forward kinematics for the 3D view, JSON,
chunk compression) held that loop up to 0.34 s on a 2-core machine at load 2–3 (0.08 s with this
writer thread), and once long enough for `make commission` to stop on the watchdog.
`BackgroundSink` hands each flush to a writer thread and returns at once; the writer works through
them in order. A bounded queue keeps memory bounded when the disk is slower than the stream: the
loop then waits for one flush, as it did before.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from rxcomm.execution.plan import StreamPlan


class RecordSink(Protocol):
    """Takes a stream's records while it runs (the run log writer): ``records`` gets consecutive
    rows of setpoints already executed, ``gateway`` the status rows since the last call."""

    period_s: float  # wall time between hand-overs

    def begin(self, plan: StreamPlan, ratio: int, cycle_s: float) -> None: ...

    def records(self, first: int, q_actual: np.ndarray, tau_actual: np.ndarray) -> None: ...

    def gateway(self, rows: dict[str, np.ndarray]) -> None: ...


_Call = tuple[Callable[..., None], tuple[Any, ...]]
MAX_PENDING_FLUSHES = 16  # ~8 s of records at the writer's 0.5 s period (≈ 2 MB at R = 1)


class BackgroundSink:
    """A `RecordSink` that runs another sink's calls on a writer thread, in the order they came.

    An error of the writer (a full disk) is raised on the stream's next hand-over and by `stop`, so
    the stream stops as it would have with the writer inline. `stop` waits for every flush handed
    over; call it before the wrapped sink is closed or read.
    """

    def __init__(self, sink: RecordSink, max_pending: int = MAX_PENDING_FLUSHES) -> None:
        self.sink = sink
        self.period_s = sink.period_s
        self._pending: queue.Queue[tuple[Callable[..., None], tuple[Any, ...]] | None] = queue.Queue(
            max_pending
        )
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._work, name="rxcomm-run-log-writer", daemon=True)
        self._thread.start()

    def begin(self, plan: StreamPlan, ratio: int, cycle_s: float) -> None:
        self._hand_over(self.sink.begin, plan, ratio, cycle_s)

    def records(self, first: int, q_actual: np.ndarray, tau_actual: np.ndarray) -> None:
        self._hand_over(self.sink.records, first, q_actual, tau_actual)

    def gateway(self, rows: dict[str, np.ndarray]) -> None:
        self._hand_over(self.sink.gateway, rows)

    def stop(self) -> None:
        """Wait until every flush handed over is written and the writer thread has ended; raise the
        writer's error, if it had one."""
        if self._thread.is_alive():
            self._pending.put(None)
            self._thread.join()
        self._raise()

    def _hand_over(self, call: Callable[..., None], *args: Any) -> None:
        self._raise()
        if not self._thread.is_alive():
            raise RuntimeError("the run log writer was stopped")
        self._pending.put((call, args))

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def _work(self) -> None:
        while (item := self._pending.get()) is not None:
            if self._error is not None:
                continue  # after an error nothing more is written; the stream hears of it
            call, args = item
            try:
                call(*args)
            except BaseException as e:  # carried to the streaming thread, raised there
                self._error = e
