"""Benchmark rows and timing helpers: medians over repeats, ratios against a peer in the same run."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Row:
    """One table line: `ours` and `peer` are numbers in `unit`; `paper` is the paper's figure as text."""

    stage: str
    metric: str
    unit: str
    ours: float
    paper: str = ""
    peer_name: str = ""
    peer: float | None = None
    target: str = ""

    @property
    def ratio(self) -> float | None:
        if self.peer is None or self.peer == 0:
            return None
        return self.ours / self.peer


def median_seconds(fn: Callable[[], object], repeats: int = 5, warmup: int = 1) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def median_cpu_seconds(fn: Callable[[], object], repeats: int = 5, warmup: int = 1) -> float:
    """As `median_seconds`, in this process's CPU time (time.process_time): on a loaded machine the
    wall time measures the other processes too."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return statistics.median(times)
