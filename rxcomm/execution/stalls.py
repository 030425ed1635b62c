"""What held the master when a realtime stream underran (issue 27, case 16), so a stop names its
stall's cause instead of leaving a lost lead unexplained.

Two ways to lose the lead, told apart by what the replies show:

- **one pause** that ate it: the longest pause between two gateway replies, how much of it this
  process spent on a CPU, and the garbage collector's pauses. A pause with little CPU time of our
  own was the operating system not scheduling the master (a loaded machine: the busy loops beside
  it); one spent on our CPU with a long GC pause was the collector; one on our CPU without GC was
  the master's own work (or another thread holding the GIL: the log writer, the embedded cell);
- **falling behind** with no pause near the lead: the master wrote fewer setpoints per second than
  the stream consumed (measured at the ratio 1 excitation at load 7 on 2 cores: 1700 written/s
  against 2500 consumed/s, the lead drained from its 0.25 s prefill in 0.9 s with no pause over
  0.3 s). The message gives both rates over the last ``RATE_WINDOW_S`` before the stop and the
  process's CPU share then.

Against the first kind on a shared machine, a realtime stream runs its process's threads at a raised
priority where the system allows it (``raised_priority``: nice ``STREAM_NICE``, as a real master runs
above the jobs beside it); the message says whether it did.
"""

from __future__ import annotations

import contextlib
import gc
import math
import os
import time
from collections import deque
from collections.abc import Iterator

RATE_WINDOW_S = 1.0  # the feed and CPU rates a stop reports are over this long before it
PAUSE_ATE_LEAD = 0.8  # a pause at least this share of the lead's peak lost it on its own
STREAM_NICE = -10  # CFS weight ≈ 9.3x a nice-0 job's: two busy loops beside no longer starve it


@contextlib.contextmanager
def raised_priority(nice: int = STREAM_NICE) -> Iterator[str]:
    """Every thread of this process at ``nice`` (Linux keeps a nice per thread; threads started
    meanwhile inherit it) until the block ends, then back; yields what was done, for a stop message.
    Lowering a nice needs root or CAP_SYS_NICE: without it nothing changes."""
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    before: dict[int, int] = {}
    refused = ""
    for tid in tids:
        try:
            old = os.getpriority(os.PRIO_PROCESS, tid)
            if old > nice:
                os.setpriority(os.PRIO_PROCESS, tid, nice)
                before[tid] = old
        except OSError as e:  # EPERM without the capability; ESRCH for a thread that ended
            refused = refused or (e.strerror or str(e))
    if before:
        note = f"the stream ran at nice {nice}"
    else:
        note = (
            f"the stream's priority was not raised ({refused})"
            if refused
            else f"the stream ran at nice ≤ {nice}"
        )
    try:
        yield note
    finally:
        for tid, old in before.items():
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, tid, old)


class StallWatch:
    """Notes the time of every gateway reply (with the stream's write and execute indices when the
    reply has them) and every GC pause while a stream runs. ``sample_s``: stream time per setpoint."""

    def __init__(self, sample_s: float = math.nan) -> None:
        self.t0 = time.perf_counter()
        self.sample_s = sample_s
        self._last = self.t0
        self._last_cpu = time.process_time()
        self.longest_s = 0.0
        self.longest_at_s = math.nan
        self.longest_cpu_s = 0.0
        self.gc_longest_s = 0.0
        self.gc_total_s = 0.0
        self._gc_start = 0.0
        self.last_s = self.last_cpu_s = 0.0  # the pause that ended at the latest reply (or the stop)
        self.peak_lead_s = 0.0  # the largest buffered lead seen
        # (wall, cpu, write_index, execute_index) of the replies in the last RATE_WINDOW_S
        self._window: deque[tuple[float, float, int, int]] = deque()
        self.priority = ""  # what ``raised_priority`` did, for the message

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

    def reply(self, write_index: int | None = None, execute_index: int | None = None) -> None:
        """A gateway reply (or the error that ended the stream) arrived, with the stream's indices."""
        now, cpu = time.perf_counter(), time.process_time()
        gap = now - self._last
        self.last_s, self.last_cpu_s = gap, cpu - self._last_cpu
        if gap > self.longest_s:
            self.longest_s, self.longest_at_s = gap, self._last - self.t0
            self.longest_cpu_s = cpu - self._last_cpu
        self._last, self._last_cpu = now, cpu
        if write_index is None or execute_index is None:
            return
        self.peak_lead_s = max(self.peak_lead_s, (write_index - execute_index) * self.sample_s)
        self._window.append((now, cpu, write_index, execute_index))
        while len(self._window) > 2 and now - self._window[1][0] >= RATE_WINDOW_S:
            self._window.popleft()

    def describe(self, watchdog: bool = False) -> str:
        """One clause for a stop message: the longest pause and its likely cause, or the master
        falling behind the stream (module docstring); a ``watchdog`` stop is a pause's, lead or not."""
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
        pause = (
            f"the master's longest pause between gateway replies was {self.longest_s:.2f} s "
            f"{self.longest_at_s:.2f} s into the stream ({share:.0%} of it on this process's CPU, "
            f"longest GC pause {self.gc_longest_s:.3f} s)"
        )
        rates, behind = self._rates()
        prio = f"; {self.priority}" if self.priority else ""
        if behind and not watchdog and self.longest_s < PAUSE_ATE_LEAD * self.peak_lead_s:
            return f"the master fell behind the stream, {rates}; {pause}{last}{prio}"
        return f"{pause}: {cause}{last}" + (f"; {rates}" if rates else "") + prio

    def _rates(self) -> tuple[str, bool]:
        """The feed against the stream over the window before the last reply ("" if unknown), and
        whether the master wrote fewer setpoints per second than the stream needs."""
        if len(self._window) < 2 or not self.sample_s > 0:
            return "", False
        (w0, c0, wr0, ex0), (w1, c1, wr1, ex1) = self._window[0], self._window[-1]
        span = w1 - w0
        if span <= 0:
            return "", False
        need, wrote = 1.0 / self.sample_s, (wr1 - wr0) / span
        text = (
            f"over the last {span:.2f} s it wrote {wrote:.0f} setpoints/s, the stream needs "
            f"{need:.0f}/s (executed {(ex1 - ex0) / span:.0f}/s), its lead peaked at "
            f"{self.peak_lead_s:.2f} s, this process had {(c1 - c0) / span:.0%} of a CPU"
        )
        return text, wrote < need
