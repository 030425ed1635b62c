"""The gateway's state machine, without registers, threads or sockets: six CiA 402 drives, the
stream's phases, every stop (quick stop, fault reaction, watchdog, E-stop) and one drive cycle at a
time (docs/gateway.md §3-§4).

``GatewayCore`` (``gateway_core.py``) puts the register map on top of it: ``register_writes.py``
turns writes into the events here, ``register_images.py`` renders this state as registers.

Not thread-safe: the caller serialises every call (the server holds one lock around each).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from rxcomm.cell.backend import AxisFeedback, CellBackend
from rxcomm.cell.cia402 import Drive402, State
from rxcomm.cell.rings import SetpointRing, TraceRing
from rxcomm.errors import GatewayError
from rxcomm.gateway import registers as R
from rxcomm.gateway.registers import Control, ErrorCode, Status, StopCause


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
    settle_max_cycles: int = 12500  # 5 s: a damped arm held by its integrators settles in 1.3–2.8 s
    standstill_rad_s: float = 1e-6


STREAM_OPEN = (Phase.IDLE, Phase.ARMED, Phase.RUNNING)  # phases in which blocks are accepted
STREAM_ON = (Phase.ARMED, Phase.RUNNING)  # stream enabled: settings fixed, any stop aborts it


class GatewayMachine:
    """The gateway and its six CiA 402 drives as state and events; registers are ``GatewayCore``'s."""

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
        self.mute_ms_requested = 0
        self.drop_requested = False
        # One master at a time (register 28): the claiming connection and its token (0 = unclaimed).
        self.owner: object | None = None
        self.owner_token = 0
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
            ("ALL_ENABLED", self.all_enabled()),
            ("SEQUENCE_ERROR", self.seq_error),
            ("END_OF_STREAM", self.eos),
            ("QUICK_STOP", State.QUICK_STOP_ACTIVE in states),
            ("TRACE_OVERFLOW", self.trace.overflowed),
        )
        return sum(_SB[name] for name, on in flags if on)

    # ---- events --------------------------------------------------------------------------------

    def set_error(self, code: int) -> None:
        if not self.error:
            self.error = int(code)

    def set_cause(self, cause: StopCause) -> None:
        if not self.stop_cause:
            self.stop_cause = int(cause)

    def release_owner(self) -> None:
        self.owner, self.owner_token = None, 0

    def _start_ramp(self, i: int) -> None:
        """Ramp from the demand velocity of the last cycle down to zero."""
        self.ramping[i] = True
        self.ramp_vel[i] = (self.demand_pos[i] - self._prev_demand[i]) / self.dt

    def _clear_ramp(self, i: int) -> None:
        self.ramping[i] = False
        self.ramp_vel[i] = 0.0

    def _unpowered(self, i: int) -> None:
        """Torque off (or about to come on): the demand tracks the actual position."""
        self._clear_ramp(i)
        self.demand_pos[i] = self._prev_demand[i] = self.fb.position_rad[i]
        self.tau_ff[i] = 0.0

    def _abort_stream(self) -> None:
        if self.phase in STREAM_ON:
            self.phase = Phase.ABORTED
        self.levels &= ~_STREAM_ENABLE

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
        self.set_error(code)
        self.quick_stop()

    def comm_lost(self, cause: StopCause = StopCause.CONNECTION_LOST) -> None:
        """Watchdog expiry or loss of the master's (or every) connection while torque is on."""
        if any(self.powered()):
            self.watchdog = True
            self.set_cause(cause)
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
            self.set_cause(StopCause.ESTOP)
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
            self._clear_ramp(axis)
        elif after is State.QUICK_STOP_ACTIVE:
            self._start_ramp(axis)
        elif not d.powered:
            self._unpowered(axis)
        if before is State.OPERATION_ENABLED and self.phase in STREAM_ON:
            self.set_cause(StopCause.AXIS_LEFT_OPERATION)
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

    def set_cursor(self, cursor16: int) -> None:
        """The master's trace cursor: records below it are acknowledged and dropped."""
        self.cursor16 = cursor16 & 0xFFFF
        self.trace.ack(self.trace.resolve(self.cursor16))

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

    # ---- the drive cycle -----------------------------------------------------------------------

    def needs_cycle(self) -> bool:
        """Virtual time: is there anywhere for the cell to go? (setpoints, a ramp, settling)."""
        if self.phase is Phase.RUNNING and (self._sub or self.ring.level):
            return True
        if any(self.ramping):
            return True
        # settling never interleaves with a stream: a hold cycle there would shift every setpoint
        return self.settle_left > 0 and self.phase not in STREAM_ON and self._moving()

    def _moving(self) -> bool:
        return bool(np.any(np.abs(self.fb.velocity_rad_s) > self.limits.standstill_rad_s))

    def _stream_demand(self, allow_underrun: bool) -> bool:
        """Advance the interpolation; returns True when the stream completed this cycle."""
        if self._sub == 0:
            if self.ring.level == 0:
                if allow_underrun and not self.eos:
                    self.underrun = True
                    self.underrun_count += 1
                    self.set_error(ErrorCode.UNDERRUN)
                    self.set_cause(StopCause.UNDERRUN)
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
            self.set_cause(StopCause.AXIS_FAULT)
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


# Plain-int copies of the flag bits: enum flag arithmetic is slow on the per-cycle path.
_SB = {f.name: int(f) for f in Status}
_STREAM_ENABLE = int(Control.STREAM_ENABLE)
