"""Pure encode/decode of the gateway's register blocks (map v1, ``registers.py``).

Every block is a big-endian ``struct`` layout over 16-bit words: a 32-bit value packed ``>i``/``>I``
is exactly "two words, high word first". Everything here works in integer register units (position
counts of 1 µrad, torque counts of 0.1 % rated); the SI conversions are separate functions so the
server (drives in SI) and the client (trajectories in SI) share one rounding rule.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from rxcomm.errors import GatewayError, InputError
from rxcomm.gateway import registers as R

_ROW = f"{R.N_AXES}i{R.N_AXES}h"  # one setpoint cycle or one trace record: 6 × i32, 6 × i16


def to_words(fmt: str, *values: int) -> list[int]:
    """Pack values with a big-endian struct format and return the 16-bit words."""
    try:
        raw = struct.pack(">" + fmt, *values)
    except struct.error as e:
        raise InputError(f"value out of range for register layout {fmt!r}: {e}", field=fmt) from e
    return list(struct.unpack(f">{len(raw) // 2}H", raw))


def from_words(fmt: str, words: list[int] | tuple[int, ...]) -> tuple[int, ...]:
    """Inverse of ``to_words`` (words beyond the format's size are ignored)."""
    size = struct.calcsize(">" + fmt) // 2
    if len(words) < size:
        raise GatewayError(f"{len(words)} words, layout {fmt!r} needs {size}")
    return struct.unpack(">" + fmt, struct.pack(f">{size}H", *words[:size]))


def _rows(pos_counts: np.ndarray, tq_counts: np.ndarray) -> list[int]:
    return np.concatenate([pos_counts, tq_counts], axis=1).astype(np.int64).ravel().tolist()


def _split_rows(values: tuple[int, ...], k: int) -> tuple[np.ndarray, np.ndarray]:
    a = np.array(values, dtype=np.int64).reshape(k, 2 * R.N_AXES)
    return a[:, : R.N_AXES], a[:, R.N_AXES :]


# --- SI scaling --------------------------------------------------------------------------------


def rad_to_counts(rad: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(rad, dtype=float) * (1.0 / R.POSITION_LSB_RAD)).astype(np.int64)


def counts_to_rad(counts: np.ndarray) -> np.ndarray:
    return np.asarray(counts, dtype=float) * R.POSITION_LSB_RAD


def nm_to_torque_counts(nm: np.ndarray, rated_nm: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(nm, dtype=float) / (np.asarray(rated_nm) * R.TORQUE_LSB_FRACTION)).astype(
        np.int64
    )


def torque_counts_to_nm(counts: np.ndarray, rated_nm: np.ndarray) -> np.ndarray:
    return np.asarray(counts, dtype=float) * (np.asarray(rated_nm) * R.TORQUE_LSB_FRACTION)


def saturate(v: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Register images of actual values saturate instead of failing (a drive reports, never refuses)."""
    return np.minimum(np.maximum(v, lo), hi)


def unwrap16(low16: int, reference: int) -> int:
    """The full index whose low 16 bits are ``low16``, nearest to ``reference`` (±32767)."""
    delta = (low16 - reference) & 0xFFFF
    return reference + (delta - 0x10000 if delta >= 0x8000 else delta)


# --- identity 0-8 ------------------------------------------------------------------------------

_IDENTITY = "6Hh2H"


@dataclass(frozen=True)
class Identity:
    magic: int
    map_version: int
    n_axes: int
    cycle_us: int
    buffer_capacity: int
    max_cycles_per_block: int
    position_lsb_exponent: int
    trace_capacity: int
    torque_lsb_permille: int


def encode_identity(ident: Identity) -> list[int]:
    return to_words(
        _IDENTITY,
        ident.magic,
        ident.map_version,
        ident.n_axes,
        ident.cycle_us,
        ident.buffer_capacity,
        ident.max_cycles_per_block,
        ident.position_lsb_exponent,
        ident.trace_capacity,
        ident.torque_lsb_permille,
    )


def decode_identity(words: list[int]) -> Identity:
    return Identity(*from_words(_IDENTITY, words))


# --- setpoint block 1000- ----------------------------------------------------------------------

_BLOCK_HEADER = "I3H"  # first index, count, trace cursor, flags


@dataclass(frozen=True)
class SetpointBlock:
    """One block of ≤ 6 consecutive cycles, in register units."""

    first_index: int
    trace_cursor: int  # low 16 bits
    flags: int  # registers.BlockFlags bits
    position_counts: np.ndarray  # (k, n_axes) int
    torque_counts: np.ndarray  # (k, n_axes) int

    @property
    def count(self) -> int:
        return int(self.position_counts.shape[0])


def encode_block(block: SetpointBlock) -> list[int]:
    k = block.count
    if not 0 <= k <= R.MAX_CYCLES_PER_BLOCK:
        raise InputError(f"{k} cycles in one block, at most {R.MAX_CYCLES_PER_BLOCK}", field="count")
    if block.position_counts.shape != (k, R.N_AXES) or block.torque_counts.shape != (k, R.N_AXES):
        raise InputError(f"block arrays must be ({k}, {R.N_AXES})", field="setpoints")
    header = (block.first_index, k, block.trace_cursor & 0xFFFF, int(block.flags))
    return to_words(_BLOCK_HEADER + _ROW * k, *header, *_rows(block.position_counts, block.torque_counts))


def decode_block(words: list[int]) -> SetpointBlock:
    """GatewayError (the server answers exception 3) on a malformed block."""
    if len(words) < R.BLK_HEADER:
        raise GatewayError(f"setpoint block of {len(words)} words, header needs {R.BLK_HEADER}")
    k = words[R.BLK_COUNT]
    if k > R.MAX_CYCLES_PER_BLOCK or len(words) != R.BLK_HEADER + k * R.CYCLE_WORDS:
        raise GatewayError(f"setpoint block: count {k} does not match {len(words)} words")
    v = from_words(_BLOCK_HEADER + _ROW * k, words)
    if v[3] & ~int(R.BlockFlags.END_OF_STREAM):
        raise GatewayError(f"setpoint block: undefined flag bits {v[3]:#06x}")
    pos, tq = _split_rows(v[4:], k)
    return SetpointBlock(v[0], v[2], v[3], pos, tq)


# --- status + trace window 2000- ---------------------------------------------------------------

_WINDOW_HEADER = "2H2I3H"  # status, error, execute index, write index, level, trace first, count


@dataclass(frozen=True)
class StreamStatus:
    """Header of the window (the gist of registers 30-42)."""

    status: int  # registers.Status bits (decoded as R.Status)
    error: int
    execute_index: int
    write_index: int
    buffer_level: int


@dataclass(frozen=True)
class TraceRecords:
    first: int  # low 16 bits of the first record's index
    position_counts: np.ndarray  # (n, n_axes)
    torque_counts: np.ndarray  # (n, n_axes)

    @property
    def count(self) -> int:
        return int(self.position_counts.shape[0])


def encode_window(st: StreamStatus, trace: TraceRecords) -> list[int]:
    n = trace.count
    pos = saturate(trace.position_counts, R.I32_MIN, R.I32_MAX)
    tq = saturate(trace.torque_counts, R.I16_MIN, R.I16_MAX)
    header = (int(st.status), st.error, st.execute_index, st.write_index)
    header += (min(st.buffer_level, R.U16_MAX), trace.first & 0xFFFF, n)
    words = to_words(_WINDOW_HEADER + _ROW * n, *header, *(_rows(pos, tq) if n else ()))
    return words + [0] * (R.WINDOW_WORDS - len(words))


def decode_window(words: list[int]) -> tuple[StreamStatus, TraceRecords]:
    h = from_words(_WINDOW_HEADER, words)
    n = h[6]
    if n > R.MAX_RECORDS_PER_WINDOW:
        raise GatewayError(f"status window announces {n} trace records, at most {R.MAX_RECORDS_PER_WINDOW}")
    body = from_words(_ROW * n, words[R.WIN_HEADER :]) if n else ()
    pos, tq = _split_rows(body, n)
    return StreamStatus(R.Status(h[0]), h[1], h[2], h[3], h[4]), TraceRecords(h[5], pos, tq)


# --- status registers 30-45 --------------------------------------------------------------------

_STATUS = "H3I3HI4H"


@dataclass(frozen=True)
class GatewayStatus:
    status: int  # registers.Status bits (decoded as R.Status)
    cycle_counter: int
    execute_index: int
    write_index: int
    buffer_level: int
    underrun_count: int
    error: int
    trace_count: int
    heartbeat_echo: int
    stop_cause: int = 0  # registers.StopCause
    overruns: int = 0  # drive cycles started more than one cycle late
    clock: int = 0  # registers.Clock


def encode_status(s: GatewayStatus) -> list[int]:
    return to_words(
        _STATUS,
        int(s.status),
        s.cycle_counter & R.U32_MAX,
        s.execute_index,
        s.write_index,
        min(s.buffer_level, R.U16_MAX),
        min(s.underrun_count, R.U16_MAX),
        s.error,
        s.trace_count & R.U32_MAX,
        s.heartbeat_echo & 0xFFFF,
        int(s.stop_cause),
        min(s.overruns, R.U16_MAX),
        int(s.clock),
    )


def decode_status(words: list[int]) -> GatewayStatus:
    v = from_words(_STATUS, words)
    return GatewayStatus(R.Status(v[0]), *v[1:])


# --- axis registers 100 + 20 i -----------------------------------------------------------------

_AXIS = "4H2ihH2iIh6x"  # 20 words


@dataclass(frozen=True)
class AxisRegisters:
    controlword: int
    mode: int
    statusword: int
    mode_display: int
    position_counts: int
    velocity_counts: int
    torque_counts: int
    error_code: int
    following_error_counts: int
    position_demand_counts: int
    rated_torque_mnm: int
    torque_ff_counts: int


def encode_axis(a: AxisRegisters) -> list[int]:
    def i32(v: int) -> int:
        return min(max(v, R.I32_MIN), R.I32_MAX)

    def i16(v: int) -> int:
        return min(max(v, R.I16_MIN), R.I16_MAX)

    return to_words(
        _AXIS,
        a.controlword,
        a.mode,
        a.statusword,
        a.mode_display,
        i32(a.position_counts),
        i32(a.velocity_counts),
        i16(a.torque_counts),
        a.error_code,
        i32(a.following_error_counts),
        i32(a.position_demand_counts),
        a.rated_torque_mnm,
        i16(a.torque_ff_counts),
    )


def decode_axis(words: list[int]) -> AxisRegisters:
    return AxisRegisters(*from_words(_AXIS, words))


# --- tracker 3000- -----------------------------------------------------------------------------

_TRACKER = "2H3i4iI"


@dataclass(frozen=True)
class TrackerWords:
    valid: bool
    sequence: int
    position_um: np.ndarray  # (3,) int
    quaternion_counts: np.ndarray  # (4,) int, w x y z
    cycle: int


def encode_tracker(t: TrackerWords) -> list[int]:
    pos = [int(x) for x in t.position_um]
    quat = [int(x) for x in t.quaternion_counts]
    return to_words(_TRACKER, int(t.valid), t.sequence & 0xFFFF, *pos, *quat, t.cycle & R.U32_MAX)


def decode_tracker(words: list[int]) -> TrackerWords:
    v = from_words(_TRACKER, words)
    return TrackerWords(bool(v[0]), v[1], np.array(v[2:5]), np.array(v[5:9]), v[9])
