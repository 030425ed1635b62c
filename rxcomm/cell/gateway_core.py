"""The gateway's logic, without threads or sockets: register writes in, register images out, one
drive cycle at a time. ``server.py`` wraps it in pymodbus and a clock; tests can drive it directly.

Not thread-safe: the caller serialises every call (the server holds one lock around each).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from rxcomm.cell.backend import AxisFeedback, CellBackend
from rxcomm.cell.cia402 import Drive402, State
from rxcomm.errors import GatewayError
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.registers import Control, ErrorCode, ModbusException, Status, StopCause

EXC_ADDRESS = int(ModbusException.ILLEGAL_ADDRESS)
EXC_VALUE = int(ModbusException.ILLEGAL_VALUE)
EXC_BUSY = int(ModbusException.DEVICE_BUSY)


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


class Phase(Enum):
    IDLE = "idle"  # after clear: blocks accepted (prefill)
    ARMED = "armed"  # stream enabled, waiting for the prefill level
    RUNNING = "running"
    DONE = "done"  # end of stream reached: holding the last setpoint
    ABORTED = "aborted"  # underrun, fault, quick stop: clear before the next stream


@dataclass(frozen=True)
class CoreLimits:
    """Sizes and rules fixed at start-up (identity registers 0-8 report them)."""

    buffer_capacity: int = 4096
    trace_capacity: int = 8192
    watchdog_ms: int = 200
    settle_max_cycles: int = 2500
    standstill_rad_s: float = 1e-6


_STREAM_OPEN = (Phase.IDLE, Phase.ARMED, Phase.RUNNING)
_SECTIONS = R.sections()


class GatewayCore:
    """Register-level behaviour of the gateway and its six CiA 402 drives (docs/gateway.md)."""

    def __init__(self, backend: CellBackend, limits: CoreLimits = CoreLimits()):
        if backend.n_axes != R.N_AXES:
            raise GatewayError(f"map v1 has {R.N_AXES} axes, backend has {backend.n_axes}")
        if not 0 < limits.buffer_capacity <= R.U16_MAX or not 0 < limits.trace_capacity <= 0x8000:
            raise GatewayError("buffer capacity must fit u16 and trace capacity be ≤ 32768")
        n = R.N_AXES
        self.backend = backend
        self.limits = limits
        self.dt = backend.cycle_s
        self.rated_nm = np.asarray(backend.rated_torque_nm, dtype=float)
        self._fe_limit = np.asarray(backend.following_error_limit_rad, dtype=float)
        self.drives = [Drive402() for _ in range(n)]
        self.ring = SetpointRing(limits.buffer_capacity, n)
        self.trace = TraceRing(limits.trace_capacity, n)
        self.phase = Phase.IDLE
        self.levels = 0  # Control level bits as stored
        self.eos = False
        self.heartbeat = 0
        self.cw_all = 0
        self.watchdog_ms = limits.watchdog_ms
        self.prefill = 0
        self.ratio = 1
        self.decimation = 1
        self.cursor16 = 0
        self.underrun = self.watchdog = self.seq_error = self.estop_latched = False
        self.estop_pressed = False
        self.error = 0
        self.underrun_count = 0
        self.cycle_counter = 0
        self.fb: AxisFeedback = backend.feedback()
        self.demand_pos = np.array(self.fb.position_rad, dtype=float)
        self._prev_demand = self.demand_pos.copy()
        self.tau_ff = np.zeros(n)
        self.ramping = [False] * n  # axis i follows the stop ramp at ramp_vel[i]
        self.ramp_vel = np.zeros(n)
        self._seg_from = self._seg_tau_from = self._seg_to = self._seg_tau = np.zeros(n)
        self._sub = 0
        self.stream_cycle = 0
        self.trace_active = False
        self.settle_left = 0
        self.last_write_s = 0.0
        self.connections = 0
        self.tracker_seq = 0
        self._tracker_words = [0] * R.TRACKER_WORDS
        self.mute_ms_requested = 0
        self.drop_requested = False
        # One master at a time (register 28): the claiming connection and its token (0 = unclaimed).
        self.owner: object | None = None
        self.owner_token = 0
        self._conn: object | None = None  # the connection of the write being handled
        self.stop_cause = 0  # StopCause of the first stop since CLEAR / RESET (register 43)
        self.overruns = 0  # realtime: cycles the clock started more than a cycle late (register 44)
        self.clock = int(R.Clock.VIRTUAL)  # the server sets what paces it (register 45)

    # ---- derived state -------------------------------------------------------------------------

    def powered(self) -> list[bool]:
        return [d.powered for d in self.drives]

    def all_enabled(self) -> bool:
        return all(d.state is State.OPERATION_ENABLED for d in self.drives)

    def status_bits(self) -> int:
        states = [d.state for d in self.drives]
        flags = (
            ("STREAMING", self.phase is Phase.RUNNING),
            ("DONE", self.phase is Phase.DONE),
            ("ARMED", self.phase is Phase.ARMED),
            ("UNDERRUN", self.underrun),
            ("WATCHDOG", self.watchdog),
            ("ESTOP", self.estop_pressed or self.estop_latched),
            ("AXIS_FAULT", State.FAULT in states or State.FAULT_REACTION_ACTIVE in states),
            ("ALL_ENABLED", all(st is State.OPERATION_ENABLED for st in states)),
            ("SEQUENCE_ERROR", self.seq_error),
            ("END_OF_STREAM", self.eos),
            ("QUICK_STOP", State.QUICK_STOP_ACTIVE in states),
            ("TRACE_OVERFLOW", self.trace.overflowed),
        )
        return sum(_SB[name] for name, on in flags if on)

    # ---- events --------------------------------------------------------------------------------

    def _set_error(self, code: int) -> None:
        if not self.error:
            self.error = int(code)

    def _set_cause(self, cause: StopCause) -> None:
        if not self.stop_cause:
            self.stop_cause = int(cause)

    def release_owner(self) -> None:
        self.owner, self.owner_token = None, 0

    def _start_ramp(self, i: int) -> None:
        """Ramp from the demand velocity of the last cycle down to zero."""
        self.ramping[i] = True
        self.ramp_vel[i] = (self.demand_pos[i] - self._prev_demand[i]) / self.dt

    def _unpowered(self, i: int) -> None:
        """Torque off (or about to come on): the demand tracks the actual position."""
        self.ramping[i] = False
        self.ramp_vel[i] = 0.0
        self.demand_pos[i] = self._prev_demand[i] = self.fb.position_rad[i]
        self.tau_ff[i] = 0.0

    def _abort_stream(self) -> None:
        if self.phase in (Phase.ARMED, Phase.RUNNING):
            self.phase = Phase.ABORTED
        self.levels &= ~_CB["STREAM_ENABLE"]

    def quick_stop(self) -> None:
        """Gateway-level quick stop: abort the stream, ramp every enabled axis down."""
        self._abort_stream()
        for i, d in enumerate(self.drives):
            if d.quick_stop():
                self._start_ramp(i)

    def fault_axes(self, mask: list[bool] | np.ndarray, code: int) -> None:
        """Fault the masked axes (fault reaction ramp), quick-stop the others, abort the stream."""
        for i, d in enumerate(self.drives):
            was_powered = d.powered
            if mask[i] and d.fault(code):
                if was_powered:
                    self._start_ramp(i)
                else:
                    self._unpowered(i)
        self._set_error(code)
        self.quick_stop()

    def comm_lost(self, cause: StopCause = StopCause.CONNECTION_LOST) -> None:
        """Watchdog expiry or loss of the master's (or every) connection while torque is on."""
        if any(self.powered()):
            self.watchdog = True
            self._set_cause(cause)
            self.fault_axes([True] * R.N_AXES, ErrorCode.HEARTBEAT)

    def check_watchdog(self, now_s: float) -> None:
        if not self.watchdog_ms or now_s - self.last_write_s <= self.watchdog_ms / 1e3:
            return
        self.release_owner()  # the watchdog is the master's lease: silent that long, it is gone
        if any(self.powered()):
            self.comm_lost(StopCause.WATCHDOG)

    def connection_changed(self, opened: bool, conn: object | None = None) -> None:
        self.connections = max(0, self.connections + (1 if opened else -1))
        owner_left = not opened and self.owner_token and conn is not None and conn is self.owner
        if owner_left:
            self.release_owner()
        if self.connections == 0 or owner_left:
            self.comm_lost()

    def set_estop(self, pressed: bool) -> None:
        if pressed and not self.estop_pressed:
            self.estop_latched = True
            self._set_cause(StopCause.ESTOP)
            self.fault_axes([True] * R.N_AXES, ErrorCode.EXTERNAL_ESTOP)
        self.estop_pressed = pressed

    def write_controlword(self, axis: int, cw: int) -> None:
        d = self.drives[axis]
        before = d.state
        d.write_controlword(cw, fault_cause_active=self.estop_pressed)
        after = d.state
        if after is before:
            return
        if after is State.OPERATION_ENABLED:
            if before is not State.QUICK_STOP_ACTIVE:
                self._unpowered(axis)  # take over the actual position: no jump on enable
            self.ramping[axis] = False
            self.ramp_vel[axis] = 0.0
        elif after is State.QUICK_STOP_ACTIVE:
            self._start_ramp(axis)
        elif not d.powered:
            self._unpowered(axis)
        if before is State.OPERATION_ENABLED and self.phase in (Phase.ARMED, Phase.RUNNING):
            self._set_cause(StopCause.AXIS_LEFT_OPERATION)
            self.quick_stop()  # a stream needs every axis: one leaving stops it and the others

    def reset(self) -> None:
        """Control RESET: fault reset every axis, clear latched gateway errors whose cause is gone."""
        for d in self.drives:
            d.fault_reset(fault_cause_active=self.estop_pressed)
        self.watchdog = self.underrun = self.seq_error = False
        self.stop_cause = 0
        if not self.estop_pressed:
            self.estop_latched = False
        self.error = next((d.error_code for d in self.drives if d.faulted), 0)

    def clear(self) -> None:
        self.ring.clear()
        self.trace.clear()
        self.cursor16 = 0
        self.phase = Phase.IDLE
        self.levels = 0
        self.eos = False
        self.underrun = self.seq_error = False
        self.stop_cause = 0
        self._sub = 0
        self.stream_cycle = 0
        self.trace_active = False

    def advance_phase(self) -> None:
        """ARMED -> RUNNING at the prefill level; RUNNING -> DONE when drained after end of stream."""
        if self.phase is Phase.ARMED and (self.ring.level >= max(self.prefill, 1) or self.eos):
            self.phase = Phase.RUNNING
            if (trigger := getattr(self.backend, "stream_started", None)) is not None:
                trigger()  # the tracker's trigger input, when the backend has a tracker that takes one
            self.trace_active = True
            self.stream_cycle = 0
            self.settle_left = 0
        if self.phase is Phase.RUNNING and self.eos and self._sub == 0 and self.ring.level == 0:
            self._finish_stream()

    def _finish_stream(self) -> None:
        self.phase = Phase.DONE
        self.trace_active = False
        self.settle_left = self.limits.settle_max_cycles

    # ---- register writes -----------------------------------------------------------------------

    def handle_write(
        self, address: int, values: list[int], now_s: float, conn: object | None = None
    ) -> int | None:
        """Apply a write from connection ``conn``; None or a Modbus exception code.

        While a master has claimed the gateway (register 28), writes from any other connection are
        refused with exception 3, except to the simulator's fault injection (the world outside)."""
        end = address + len(values)
        for name, base, count, read_only in _SECTIONS:
            if base <= address and end <= base + count:
                if read_only:
                    return EXC_ADDRESS
                if self.owner_token and conn is not self.owner and name != "sim":
                    return EXC_VALUE
                self._conn = conn
                exc = getattr(self, f"_write_{name}")(address - base, values)
                if exc is None or exc == EXC_BUSY:  # a busy answer proves the master alive
                    self.last_write_s = now_s
                if exc is None:
                    self.advance_phase()
                return exc
        return EXC_ADDRESS

    def _write_control(self, offset: int, values: list[int]) -> int | None:
        regs = {R.CTRL_BASE + offset + i: v for i, v in enumerate(values)}
        streaming = self.phase in (Phase.ARMED, Phase.RUNNING)
        ranges = {
            R.CTRL_WATCHDOG_MS: (0, R.WATCHDOG_MS_MAX, "watchdog_ms"),
            R.CTRL_PREFILL: (0, self.ring.capacity, "prefill"),
            R.CTRL_INTERPOLATION_RATIO: (1, R.INTERPOLATION_RATIO_MAX, "ratio"),
            R.CTRL_TRACE_DECIMATION: (1, R.TRACE_DECIMATION_MAX, "decimation"),
        }
        for addr, (lo, hi, attr) in ranges.items():
            if addr in regs:
                v = regs[addr]
                if not lo <= v <= hi or (streaming and v != getattr(self, attr)):
                    return EXC_VALUE
        bits = regs.get(R.CTRL_BITS)
        if bits is not None and (exc := self._check_control(bits)):
            return exc
        if R.CTRL_MASTER in regs:  # claim (token) or release (0); another master's write never gets here
            self.owner_token = regs[R.CTRL_MASTER]
            self.owner = self._conn if self.owner_token else None
        for addr, (_, _, attr) in ranges.items():
            if addr in regs:
                setattr(self, attr, regs[addr])
        if R.CTRL_HEARTBEAT in regs:
            self.heartbeat = regs[R.CTRL_HEARTBEAT]
        if R.CTRL_TRACE_CURSOR in regs:
            self._set_cursor(regs[R.CTRL_TRACE_CURSOR])
        if R.CTRL_CONTROLWORD_ALL in regs:
            self.cw_all = regs[R.CTRL_CONTROLWORD_ALL]
            for i in range(R.N_AXES):
                self.write_controlword(i, self.cw_all)
        if bits is not None:
            self._apply_control(bits)
        return None

    def _check_control(self, bits: int) -> int | None:
        if bits & ~_CONTROL_DEFINED:
            return EXC_VALUE  # undefined bits
        clear = bool(bits & _CB["CLEAR"])
        if clear and self.phase is Phase.RUNNING:
            return EXC_VALUE
        phase = Phase.IDLE if clear else self.phase
        was_enabled = not clear and self.levels & _CB["STREAM_ENABLE"]
        rising = bits & _CB["STREAM_ENABLE"] and not was_enabled
        quick = bits & _CB["QUICK_STOP"]
        if rising and (phase is not Phase.IDLE or not self.all_enabled() or quick):
            return EXC_VALUE
        return None

    def _apply_control(self, bits: int) -> None:
        if bits & _CB["CLEAR"]:
            self.clear()
        if bits & _CB["RESET"]:
            self.reset()
        if bits & _CB["QUICK_STOP"]:
            self._set_cause(StopCause.QUICK_STOP_COMMAND)
            self.quick_stop()
        if bits & _CB["END_OF_STREAM"] and self.phase in _STREAM_OPEN:
            self.eos = True
        enable_bit = _CB["STREAM_ENABLE"]
        if bits & enable_bit and not self.levels & enable_bit:
            self.phase = Phase.ARMED
        elif not bits & enable_bit and self.levels & enable_bit:
            if self.phase is Phase.ARMED:
                self.phase = Phase.IDLE
            elif self.phase is Phase.RUNNING:
                self._set_cause(StopCause.STREAM_DISABLED)
                self.quick_stop()  # withdrawing stream enable mid-stream is a stop request
        self.levels = (bits & enable_bit) | (_CB["END_OF_STREAM"] if self.eos else 0)

    def _set_cursor(self, cursor16: int) -> None:
        self.cursor16 = cursor16 & 0xFFFF
        self.trace.ack(self.trace.resolve(self.cursor16))

    def _write_axes(self, offset: int, values: list[int]) -> int | None:
        writes = [(divmod(offset + i, R.AXIS_STRIDE), v) for i, v in enumerate(values)]
        if any(reg >= R.AX_WRITABLE for (_, reg), _ in writes):
            return EXC_ADDRESS
        if any(reg == R.AX_MODE and v != R.MODE_CSP for (_, reg), v in writes):
            return EXC_VALUE
        for (axis, reg), v in writes:
            if reg == R.AX_CONTROLWORD:
                self.write_controlword(axis, v)
        return None

    def _write_block(self, offset: int, values: list[int]) -> int | None:
        if offset != 0:
            return EXC_ADDRESS
        try:
            blk = codec.decode_block(values)
        except GatewayError:
            return EXC_VALUE
        if blk.count and blk.first_index + blk.count > self.ring.write_index:
            if self.phase not in _STREAM_OPEN or self.eos:  # new data for a closed stream
                return EXC_VALUE
            pos = codec.counts_to_rad(blk.position_counts)
            tau = codec.torque_counts_to_nm(blk.torque_counts, self.rated_nm)
            result = self.ring.accept(blk.first_index, pos, tau)
            if result is Accept.GAP:
                self.seq_error = True
                return EXC_VALUE
            if result is Accept.FULL:
                return EXC_BUSY
        self._set_cursor(blk.trace_cursor)
        if blk.flags & _EOS_FLAG and self.phase in _STREAM_OPEN:
            self.eos = True
            self.levels |= _CB["END_OF_STREAM"]
        return None

    def _write_sim(self, offset: int, values: list[int]) -> int | None:
        regs = {offset + i: v for i, v in enumerate(values)}
        if (
            regs.get(R.SIM_MUTE_MS, 0) > R.SIM_MUTE_MS_MAX
            or regs.get(R.SIM_ESTOP, 0) not in (0, 1)
            or regs.get(R.SIM_FAULT_AXES, 0) & ~R.SIM_FAULT_AXES_MASK
            or regs.get(R.SIM_DROP, 0) not in (0, R.SIM_DROP_VALUE)
        ):
            return EXC_VALUE  # out of range or undefined bits: nothing happens
        if R.SIM_ESTOP in regs:
            self.set_estop(bool(regs[R.SIM_ESTOP]))
        if mask := regs.get(R.SIM_FAULT_AXES, 0):
            self._set_cause(StopCause.AXIS_FAULT)
            self.fault_axes([bool((mask >> i) & 1) for i in range(R.N_AXES)], ErrorCode.INJECTED)
        if regs.get(R.SIM_MUTE_MS):
            self.mute_ms_requested = regs[R.SIM_MUTE_MS]
        if regs.get(R.SIM_DROP):
            self.drop_requested = True
        return None

    # ---- register reads ------------------------------------------------------------------------

    def handle_read(self, address: int, count: int) -> list[int] | int:
        """Words for [address, address + count), or exception code 2 for undefined addresses."""
        end = address + count
        words: list[int] = []
        pos = address
        for name, base, n, _ in _SECTIONS:
            if base <= pos < base + n:
                image = getattr(self, f"_image_{name}")(sample=(name == "tracker" and pos == base))
                words += image[pos - base : min(end, base + n) - base]
                pos = min(end, base + n)
                if pos == end:
                    return words
        return EXC_ADDRESS

    def identity(self) -> codec.Identity:
        return codec.Identity(
            magic=R.MAGIC,
            map_version=R.MAP_VERSION,
            n_axes=R.N_AXES,
            cycle_us=round(self.dt * 1e6),
            buffer_capacity=self.ring.capacity,
            max_cycles_per_block=R.MAX_CYCLES_PER_BLOCK,
            position_lsb_exponent=R.POSITION_LSB_EXPONENT,
            trace_capacity=self.trace.capacity,
            torque_lsb_permille=R.TORQUE_LSB_PERMILLE,
        )

    def _image_identity(self, sample: bool) -> list[int]:
        return codec.encode_identity(self.identity())

    def _image_control(self, sample: bool) -> list[int]:
        return [
            self.levels,
            self.heartbeat,
            self.watchdog_ms,
            self.prefill,
            self.cursor16,
            self.ratio,
            self.decimation,
            self.cw_all,
            self.owner_token,
        ]

    def stream_status(self) -> codec.StreamStatus:
        return codec.StreamStatus(
            self.status_bits(),
            self.error,
            self.ring.read_index,
            self.ring.write_index,
            self.ring.level,
        )

    def gateway_status(self) -> codec.GatewayStatus:
        st = self.stream_status()
        return codec.GatewayStatus(
            status=st.status,
            cycle_counter=self.cycle_counter,
            execute_index=st.execute_index,
            write_index=st.write_index,
            buffer_level=st.buffer_level,
            underrun_count=self.underrun_count,
            error=self.error,
            trace_count=self.trace.next,
            heartbeat_echo=self.heartbeat,
            stop_cause=self.stop_cause,
            overruns=self.overruns,
            clock=self.clock,
        )

    def _image_status(self, sample: bool) -> list[int]:
        return codec.encode_status(self.gateway_status())

    def _image_axes(self, sample: bool) -> list[int]:
        fb = self.fb
        pos = codec.rad_to_counts(fb.position_rad)
        vel = np.rint(fb.velocity_rad_s / R.VELOCITY_LSB_RAD_S).astype(np.int64)
        tq = codec.nm_to_torque_counts(fb.torque_nm, self.rated_nm)
        fe = codec.rad_to_counts(fb.following_error_rad)
        dem = codec.rad_to_counts(self.demand_pos)
        ff = codec.nm_to_torque_counts(self.tau_ff, self.rated_nm)
        rated = np.rint(self.rated_nm / R.RATED_TORQUE_LSB_NM).astype(np.int64)
        words: list[int] = []
        for i, d in enumerate(self.drives):
            extra = int(R.SW.FOLLOWING_ERROR) if d.error_code == ErrorCode.FOLLOWING_ERROR else 0
            words += codec.encode_axis(
                codec.AxisRegisters(
                    controlword=d.controlword,
                    mode=R.MODE_CSP,
                    statusword=d.statusword(extra),
                    mode_display=R.MODE_CSP,
                    position_counts=int(pos[i]),
                    velocity_counts=int(vel[i]),
                    torque_counts=int(tq[i]),
                    error_code=d.error_code,
                    following_error_counts=int(fe[i]),
                    position_demand_counts=int(dem[i]),
                    rated_torque_mnm=int(rated[i]),
                    torque_ff_counts=int(ff[i]),
                )
            )
        return words

    def _image_block(self, sample: bool) -> list[int]:
        return [0] * R.BLOCK_MAX_WORDS  # write-only: reads as zeros

    def _image_window(self, sample: bool) -> list[int]:
        cursor = self.trace.resolve(self.cursor16)
        records = self.trace.read(cursor, R.MAX_RECORDS_PER_WINDOW, self.rated_nm)
        return codec.encode_window(self.stream_status(), records)

    def _image_tracker(self, sample: bool) -> list[int]:
        if sample:
            reading = None if self.phase is Phase.RUNNING else self.backend.tracker()
            if reading is None:
                self._tracker_words = [0] * R.TRACKER_WORDS
            else:
                q = np.asarray(reading.quaternion_wxyz, dtype=float)
                q = q / np.linalg.norm(q) * (1.0 if q[0] >= 0 else -1.0)  # one sign: w >= 0
                self.tracker_seq = (self.tracker_seq + 1) & 0xFFFF
                self._tracker_words = codec.encode_tracker(
                    codec.TrackerWords(
                        valid=True,
                        sequence=self.tracker_seq,
                        position_um=np.rint(np.asarray(reading.position_m) / R.TRACKER_POSITION_LSB_M),
                        quaternion_counts=np.rint(q / R.TRACKER_QUATERNION_LSB),
                        cycle=self.cycle_counter,
                    )
                )
        return self._tracker_words

    def _image_sim(self, sample: bool) -> list[int]:
        return [int(self.estop_pressed), 0, 0, 0]

    # ---- the drive cycle -----------------------------------------------------------------------

    def needs_cycle(self) -> bool:
        """Virtual time: is there anywhere for the cell to go? (setpoints, a ramp, settling)."""
        if self.phase is Phase.RUNNING and (self._sub or self.ring.level):
            return True
        if any(self.ramping):
            return True
        # settling never interleaves with a stream: a hold cycle there would shift every setpoint
        return self.settle_left > 0 and self.phase not in (Phase.ARMED, Phase.RUNNING) and self._moving()

    def _moving(self) -> bool:
        return bool(np.any(np.abs(self.fb.velocity_rad_s) > self.limits.standstill_rad_s))

    def _stream_demand(self, allow_underrun: bool) -> bool:
        """Advance the interpolation; returns True when the stream completed this cycle."""
        if self._sub == 0:
            if self.ring.level == 0:
                if allow_underrun and not self.eos:
                    self.underrun = True
                    self.underrun_count += 1
                    self._set_error(ErrorCode.UNDERRUN)
                    self._set_cause(StopCause.UNDERRUN)
                    self.quick_stop()
                return False
            self._seg_from, self._seg_tau_from = self.demand_pos, self.tau_ff
            self._seg_to, self._seg_tau = self.ring.peek()
        self._sub += 1
        if self._sub == self.ratio:
            self.demand_pos, self.tau_ff = self._seg_to, self._seg_tau
            self.ring.pop()
            self._sub = 0
            return self.ring.level == 0 and self.eos
        f = self._sub / self.ratio
        self.demand_pos = self._seg_from + f * (self._seg_to - self._seg_from)
        self.tau_ff = self._seg_tau_from + f * (self._seg_tau - self._seg_tau_from)
        return False

    def _ramp_demand(self) -> None:
        """Quick-stop / fault-reaction ramp on the demand (per axis, at the backend's deceleration)."""
        dv = np.asarray(self.backend.quick_stop_decel_rad_s2) * self.dt
        v = self.ramp_vel
        self.ramp_vel = np.where(self.ramping, np.sign(v) * np.maximum(np.abs(v) - dv, 0.0), 0.0)
        self.demand_pos = self.demand_pos + self.ramp_vel * self.dt

    def run_cycle(self, *, allow_underrun: bool) -> None:
        """One drive cycle. ``allow_underrun`` is False in virtual time (time waits for setpoints)."""
        self.advance_phase()
        prev = self.demand_pos
        finished = self.phase is Phase.RUNNING and self._stream_demand(allow_underrun)
        if any(self.ramping):
            self._ramp_demand()
        powered = self.powered()
        for i in (i for i, p in enumerate(powered) if not p):
            self._unpowered(i)
        self._prev_demand = prev
        self.fb = self.backend.cycle(self.demand_pos.copy(), self.tau_ff.copy(), np.array(powered))
        self.cycle_counter += 1
        if self.trace_active:
            self.stream_cycle += 1
            if self.stream_cycle % self.decimation == 0:
                self.trace.push(self.fb.position_rad, self.fb.torque_nm)
        trip = np.abs(self.fb.following_error_rad) > self._fe_limit
        if trip.any():
            self._set_cause(StopCause.AXIS_FAULT)
            self.fault_axes(trip & np.array(powered), ErrorCode.FOLLOWING_ERROR)
        if any(self.ramping):
            self._end_ramps()
        if finished and self.phase is Phase.RUNNING:
            self._finish_stream()
        elif self.settle_left:
            self.settle_left -= 1
        self.trace_active = self.trace_active and (self.phase is Phase.RUNNING or any(self.ramping))

    def _end_ramps(self) -> None:
        for i in range(R.N_AXES):
            if self.ramping[i] and self.ramp_vel[i] == 0.0:
                self.ramping[i] = False
                self.drives[i].reaction_done()
                if not self.drives[i].powered:
                    self._unpowered(i)
        if not any(self.ramping):
            self.settle_left = self.limits.settle_max_cycles


# Plain-int copies of the flag bits: enum flag arithmetic is slow on the per-request path.
_EOS_FLAG = int(R.BlockFlags.END_OF_STREAM)
_SB = {f.name: int(f) for f in Status}
_CB = {f.name: int(f) for f in Control}
_CONTROL_DEFINED = sum(_CB.values())
