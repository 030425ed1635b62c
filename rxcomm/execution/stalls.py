"""What held the master when a realtime stream underran (issue 27, case 16): the longest pause
between two gateway replies, how much of it this process spent on a CPU, and the garbage collector's
pauses, so a stop names its stall's cause instead of leaving a lost lead unexplained.

A pause with little CPU time of our own was the operating system not scheduling the master (a loaded
machine: the busy loops beside it); one spent on our CPU with a long GC pause was the collector; one
on our CPU without GC was the master's own work (or another thread holding the GIL: the log writer).
"""

from __future__ import annotations

import gc
import math
import time


class StallWatch:
    """Notes the time of every gateway reply and every GC pause while a stream runs."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self._last = self.t0
        self._last_cpu = time.process_time()
        self.longest_s = 0.0
        self.longest_at_s = math.nan
        self.longest_cpu_s = 0.0
        self.gc_longest_s = 0.0
        self.gc_total_s = 0.0
        self._gc_start = 0.0
        self.last_s = self.last_cpu_s = 0.0  # the pause that ended at the latest reply (or the stop)

    def __enter__(self) -> StallWatch:
        gc.callbacks.append(self._gc)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._gc in gc.callbacks:
            gc.callbacks.remove(self._gc)

    def _gc(self, phase: str, info: dict) -> None:
        now = time.perf_counter()
        if phase == "start":
            self._gc_start = now
        elif self._gc_start:
            pause = now - self._gc_start
            self.gc_total_s += pause
            self.gc_longest_s = max(self.gc_longest_s, pause)

    def reply(self) -> None:
        """A gateway reply (or the error that ended the stream) arrived."""
        now, cpu = time.perf_counter(), time.process_time()
        gap = now - self._last
        self.last_s, self.last_cpu_s = gap, cpu - self._last_cpu
        if gap > self.longest_s:
            self.longest_s, self.longest_at_s = gap, self._last - self.t0
            self.longest_cpu_s = cpu - self._last_cpu
        self._last, self._last_cpu = now, cpu

    def describe(self) -> str:
        """One clause for a stop message: the longest pause and its likely cause."""
        if not math.isfinite(self.longest_at_s):
            return "no gateway reply was timed"
        share = self.longest_cpu_s / self.longest_s if self.longest_s > 0 else 0.0
        if self.gc_longest_s >= 0.5 * self.longest_s:
            cause = "the garbage collector"
        elif share < 0.5:
            cause = "the master was not scheduled (a loaded machine)"
        else:
            cause = "the master's own work or another thread holding the GIL"
        last = ""
        if self.last_s < self.longest_s:
            last_share = self.last_cpu_s / self.last_s if self.last_s > 0 else 0.0
            last = f"; the pause just before the stop {self.last_s:.2f} s ({last_share:.0%} on its CPU)"
        return (
            f"the master's longest pause between gateway replies was {self.longest_s:.2f} s "
            f"{self.longest_at_s:.2f} s into the stream ({share:.0%} of it on this process's CPU, "
            f"longest GC pause {self.gc_longest_s:.3f} s): {cause}{last}"
        )
