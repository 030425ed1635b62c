"""The gateway's two bounded buffers, addressed by absolute index: setpoints in, trace records out.

``SetpointRing`` holds the setpoints the master streams (blocks addressed by cycle index: a repeated
block is harmless, a gap is refused); ``TraceRing`` holds the feedback records the master has not yet
acknowledged with its 16-bit cursor (docs/gateway.md §4.2 and §4.5).
"""

from __future__ import annotations

from enum import Enum

import numpy as np

from rxcomm.gateway import codec


class Accept(Enum):
    NEW = "new"
    DUPLICATE = "duplicate"
    GAP = "gap"
    FULL = "full"


class SetpointRing:
    """Bounded FIFO of setpoints addressed by absolute cycle index (idempotent, gap-refusing)."""

    def __init__(self, capacity: int, n_axes: int):
        self.capacity = capacity
        self._pos = np.zeros((capacity, n_axes))
        self._tau = np.zeros((capacity, n_axes))
        self.read_index = 0  # next setpoint to execute (= setpoints completed)
        self.write_index = 0  # next index a block must carry

    @property
    def level(self) -> int:
        return self.write_index - self.read_index

    def accept(self, first: int, pos_rad: np.ndarray, tau_nm: np.ndarray) -> Accept:
        """All or nothing; cycles below ``write_index`` were accepted before and are ignored."""
        k = pos_rad.shape[0]
        if first > self.write_index:
            return Accept.GAP
        skip = self.write_index - first
        if skip >= k:
            return Accept.DUPLICATE
        new = k - skip
        if self.level + new > self.capacity:
            return Accept.FULL
        slots = np.arange(self.write_index, self.write_index + new) % self.capacity
        self._pos[slots] = pos_rad[skip:]
        self._tau[slots] = tau_nm[skip:]
        self.write_index += new
        return Accept.NEW

    def peek(self) -> tuple[np.ndarray, np.ndarray]:
        slot = self.read_index % self.capacity
        return self._pos[slot].copy(), self._tau[slot].copy()

    def pop(self) -> None:
        self.read_index += 1

    def clear(self) -> None:
        self.read_index = self.write_index = 0


class TraceRing:
    """Bounded record buffer; records below the master's cursor are acknowledged and dropped.
    Rows are kept in SI and quantised when read, which keeps the per-cycle cost to two copies."""

    def __init__(self, capacity: int, n_axes: int):
        self.capacity = capacity
        self._pos = np.zeros((capacity, n_axes))
        self._tq = np.zeros((capacity, n_axes))
        self.base = 0  # oldest record still held
        self.next = 0  # index the next record gets
        self.overflowed = False

    def push(self, pos_rad: np.ndarray, torque_nm: np.ndarray) -> None:
        if self.next - self.base >= self.capacity:  # unacknowledged record lost: motion never waits
            self.base += 1
            self.overflowed = True
        slot = self.next % self.capacity
        self._pos[slot] = pos_rad
        self._tq[slot] = torque_nm
        self.next += 1

    def resolve(self, cursor16: int) -> int:
        """Full index of a 16-bit cursor; a cursor is never ahead of ``next``."""
        return self.next - ((self.next - cursor16) & 0xFFFF)

    def ack(self, cursor: int) -> None:
        self.base = min(max(self.base, cursor), self.next)

    def read(self, cursor: int, max_records: int, rated_nm: np.ndarray) -> codec.TraceRecords:
        start = max(cursor, self.base)
        n = max(0, min(max_records, self.next - start))
        slots = np.arange(start, start + n) % self.capacity
        return codec.TraceRecords(
            start & 0xFFFF,
            codec.rad_to_counts(self._pos[slots]),
            codec.nm_to_torque_counts(self._tq[slots], rated_nm),
        )

    def clear(self) -> None:
        self.base = self.next = 0
        self.overflowed = False
