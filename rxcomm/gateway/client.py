"""Drive gateway client (map v1) over pymodbus' synchronous TCP client.

Motion-safe settings: no automatic retries (a retried request is indistinguishable from a new one
unless the protocol makes it idempotent, and a late answer is worse than none), no reconnect: after
any communication error the connection is closed and every later call raises GatewayError until
``connect()`` is called again. Only loopback addresses unless ``allow_remote=True``.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType

import numpy as np
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.pdu import ModbusPDU

from rxcomm.errors import GatewayError, SafetyStop
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.net import is_loopback, quiet_pymodbus
from rxcomm.gateway.registers import Control, state_from_statusword
from rxcomm.gateway.registers import DriveState as State
from rxcomm.gateway.registers import ModbusException as Exc

quiet_pymodbus()


@dataclass(frozen=True)
class AxisState:
    state: State | None
    statusword: int
    error_code: int
    position_rad: float
    velocity_rad_s: float
    torque_nm: float
    following_error_rad: float
    position_demand_rad: float
    rated_torque_nm: float


@dataclass(frozen=True)
class TraceChunk:
    first: int  # full record index of the first row
    position_rad: np.ndarray  # (n, 6) position actual
    torque_nm: np.ndarray  # (n, 6) torque actual
    lost: int  # records skipped before ``first`` (trace overflow)

    @property
    def count(self) -> int:
        return int(self.position_rad.shape[0])


@dataclass(frozen=True)
class BlockReply:
    accepted: bool  # False: buffer full (exception 6), send the same block again later
    status: codec.StreamStatus | None  # None when not accepted
    trace: TraceChunk


@dataclass(frozen=True)
class TrackerSample:
    sequence: int
    position_m: np.ndarray  # (3,)
    quaternion_wxyz: np.ndarray  # (4,)
    cycle: int


class RoundTripStats:
    """Durations of completed requests (bounded memory)."""

    def __init__(self, maxlen: int = 200_000):
        self._d: deque[float] = deque(maxlen=maxlen)

    def add(self, seconds: float) -> None:
        self._d.append(seconds)

    def clear(self) -> None:
        self._d.clear()

    @property
    def count(self) -> int:
        return len(self._d)

    def seconds(self) -> np.ndarray:
        return np.fromiter(self._d, dtype=float, count=len(self._d))

    def percentile_s(self, q: float) -> float:
        return float(np.percentile(self.seconds(), q)) if self._d else float("nan")


_tokens = itertools.count(1)


def _new_token() -> int:
    """A non-zero 16-bit master token, different for each client of this process (and, through the
    process id, likely different from other processes' clients): a label to tell masters apart."""
    return ((os.getpid() << 4) + next(_tokens)) % 0xFFFF + 1


def _empty_chunk(first: int) -> TraceChunk:
    z = np.zeros((0, R.N_AXES))
    return TraceChunk(first, z, z.copy(), 0)


class GatewayClient:
    """One master connection to a drive gateway speaking register map v1."""

    def __init__(
        self, host: str = "127.0.0.1", port: int = 1502, timeout_s: float = 0.5, *, allow_remote: bool = False
    ):
        if not is_loopback(host) and not allow_remote:
            raise GatewayError(f"refusing non-loopback gateway {host} (allow_remote=False)")
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self._mb = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0, reconnect_delay=0)
        self._open = False
        self.timing = RoundTripStats()
        self._ident: codec.Identity | None = None
        self._rated_nm: np.ndarray | None = None
        self._levels = Control(0)
        self._trace_next = 0
        self.prefill = 0
        self.ratio = 1
        self.decimation = 1
        self.token = _new_token()  # register 28: who this master is (non-zero, one per client)
        self.claimed = False

    # ---- connection ----------------------------------------------------------------------------

    def connect(self) -> GatewayClient:
        if not self._mb.connect():
            raise GatewayError(f"cannot connect to gateway {self.host}:{self.port}")
        self._open = True
        return self

    def close(self) -> None:
        if self.claimed and self._open and self._mb.connected:
            with contextlib.suppress(GatewayError):  # closing the connection releases it too
                self.release()
        self.claimed = False
        self._open = False
        self._mb.close()

    def __enter__(self) -> GatewayClient:
        return self.connect()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _call(self, what: str, fn: Callable[..., ModbusPDU], **kwargs: object) -> ModbusPDU:
        """One request; returns the response (possibly an exception response)."""
        if not self._open or not self._mb.connected:
            self._open = False
            raise GatewayError(f"{what}: not connected to {self.host}:{self.port}")
        t0 = time.perf_counter()
        try:
            rsp = fn(**kwargs)
        except (ModbusException, OSError) as e:  # OSError: the peer reset or closed the socket
            self.close()  # never reuse a connection that may deliver a stale answer
            raise GatewayError(f"{what}: {self._in_our_words(e)}") from e
        self.timing.add(time.perf_counter() - t0)
        return rsp

    def _in_our_words(self, e: BaseException) -> str:
        """A pymodbus or socket error as what happened, with the gateway's address."""
        at = f"{self.host}:{self.port}"
        text = str(e)
        if isinstance(e, OSError):
            return f"the connection to the gateway {at} was lost ({e.strerror or text or type(e).__name__})"
        if "No response" in text:
            return (
                f"no valid Modbus TCP answer from the gateway {at} within {self.timeout_s:g} s (silent, "
                "or not an rxcomm drive gateway)"
            )
        if "decode" in text.lower() or "invalid" in text.lower():
            return f"the gateway {at} answered with something that is not a Modbus TCP reply"
        return f"Modbus error talking to the gateway {at}: {text.removeprefix('Modbus Error: ')}"

    def _read(self, address: int, count: int, what: str) -> list[int]:
        rsp = self._call(what, self._mb.read_holding_registers, address=address, count=count)
        if rsp.isError():
            raise GatewayError(f"{what}: exception {getattr(rsp, 'exception_code', '?')} at {address}")
        return list(rsp.registers)

    def _write(self, address: int, values: list[int], what: str) -> None:
        rsp = self._call(what, self._mb.write_registers, address=address, values=values)
        if rsp.isError():
            code = getattr(rsp, "exception_code", "?")
            raise GatewayError(f"{what}: refused with exception {code}{self._other_master(code)}")

    def owner_token(self) -> int:
        """Register 28: the token of the master that claimed the gateway (0: unclaimed)."""
        return self._read(R.CTRL_MASTER, 1, "master register")[0]

    def _other_master(self, code: object) -> str:
        """Why a write was refused, when the reason is another master's claim (else '')."""
        if code != Exc.ILLEGAL_VALUE or not self._open:
            return ""
        try:
            owner = self.owner_token()
        except GatewayError:
            return ""
        if owner and (not self.claimed or owner != self.token):
            return f" (the gateway is claimed by another master, token {owner:#06x})"
        return ""

    # ---- ownership: one master at a time ----------------------------------------------------------

    def claim(self) -> None:
        """Claim the gateway (register 28 := token) so no other connection can write to it. The claim
        lasts while this connection is open and keeps the watchdog fed (the watchdog is the lease);
        claiming again is harmless. GatewayError if another master holds it."""
        rsp = self._call("claim", self._mb.write_registers, address=R.CTRL_MASTER, values=[self.token])
        if rsp.isError():
            code = getattr(rsp, "exception_code", "?")
            owner = self.owner_token() if code == Exc.ILLEGAL_VALUE else 0
            if owner:  # the gateway refuses a claim only while another connection holds it
                raise GatewayError(
                    f"gateway {self.host}:{self.port} is in use by another master (token {owner:#06x}): "
                    "one master at a time; it is free once that master releases it, disconnects or "
                    "stays silent for its watchdog time"
                )
            raise GatewayError(f"claim: refused with exception {code}")
        self.claimed = True

    def release(self) -> None:
        """Give up the claim (register 28 := 0)."""
        self._write(R.CTRL_MASTER, [0], "release")
        self.claimed = False

    # ---- identity and state --------------------------------------------------------------------

    def identity(self) -> codec.Identity:
        """Read and check registers 0-8 and the rated torques; GatewayError on any mismatch."""
        ident = codec.decode_identity(self._read(R.ID_BASE, R.ID_COUNT, "identity"))
        expected = {
            "magic": R.MAGIC,
            "map_version": R.MAP_VERSION,
            "n_axes": R.N_AXES,
            "max_cycles_per_block": R.MAX_CYCLES_PER_BLOCK,
            "position_lsb_exponent": R.POSITION_LSB_EXPONENT,
            "torque_lsb_permille": R.TORQUE_LSB_PERMILLE,
        }
        for name, want in expected.items():
            got = getattr(ident, name)
            if got != want:
                raise GatewayError(f"gateway {name} is {got:#x}, this client speaks {want:#x} (map v1)")
        self._ident = ident
        self._rated_nm = np.array([a.rated_torque_nm for a in self.axes()])
        if np.any(self._rated_nm <= 0):
            raise GatewayError(f"gateway reports non-positive rated torque {self._rated_nm}")
        return ident

    @property
    def rated_torque_nm(self) -> np.ndarray:
        if self._rated_nm is None:
            self.identity()
        assert self._rated_nm is not None
        return self._rated_nm

    def axes(self) -> list[AxisState]:
        words = self._read(R.AXIS_BASE, R.N_AXES * R.AXIS_STRIDE, "axis registers")
        out = []
        for i in range(R.N_AXES):
            a = codec.decode_axis(words[i * R.AXIS_STRIDE : (i + 1) * R.AXIS_STRIDE])
            rated = a.rated_torque_mnm * R.RATED_TORQUE_LSB_NM
            out.append(
                AxisState(
                    state=state_from_statusword(a.statusword),
                    statusword=a.statusword,
                    error_code=a.error_code,
                    position_rad=a.position_counts * R.POSITION_LSB_RAD,
                    velocity_rad_s=a.velocity_counts * R.VELOCITY_LSB_RAD_S,
                    torque_nm=a.torque_counts * rated * R.TORQUE_LSB_FRACTION,
                    following_error_rad=a.following_error_counts * R.POSITION_LSB_RAD,
                    position_demand_rad=a.position_demand_counts * R.POSITION_LSB_RAD,
                    rated_torque_nm=rated,
                )
            )
        return out

    def positions_rad(self) -> np.ndarray:
        return np.array([a.position_rad for a in self.axes()])

    def status(self) -> codec.GatewayStatus:
        return codec.decode_status(self._read(R.ST_BASE, R.ST_COUNT, "status"))

    # ---- drive power -----------------------------------------------------------------------------

    def _command_all(self, cw: int, accept: set[State], timeout_s: float) -> None:
        self._write(R.CTRL_CONTROLWORD_ALL, [cw], f"controlword {cw:#04x}")
        deadline = time.monotonic() + timeout_s
        while True:
            axes = self.axes()
            if all(a.state in accept for a in axes):
                return
            faulted = [
                (i, a.error_code)
                for i, a in enumerate(axes)
                if a.state in (State.FAULT, State.FAULT_REACTION_ACTIVE)
            ]
            if faulted and State.FAULT not in accept:
                codes = ", ".join(f"axis {i}: {c:#06x}" for i, c in faulted)
                raise SafetyStop(f"drive fault ({codes}); fault_reset() first")
            if time.monotonic() > deadline:
                states = [a.state.name if a.state else hex(a.statusword) for a in axes]
                raise GatewayError(
                    f"controlword {cw:#04x}: drives did not reach {accept} in {timeout_s} s: {states}"
                )
            time.sleep(0.001)

    def write_controlword(self, axis: int, controlword: int) -> None:
        """One axis' controlword (register 100 + 20·axis), as a PLC would write it."""
        self._write(R.axis_base(axis) + R.AX_CONTROLWORD, [controlword & 0xFFFF], f"axis {axis} controlword")

    def enable_all(self, timeout_s: float = 1.0) -> None:
        """CiA 402 handshake on every axis: shutdown 0x06 -> switch on 0x07 -> enable operation 0x0F."""
        if all(a.state is State.OPERATION_ENABLED for a in self.axes()):
            return
        qs = State.QUICK_STOP_ACTIVE  # ignores 0x06/0x07, returns to operation on 0x0F (transition 16)
        self._command_all(R.CW_SHUTDOWN, {State.READY_TO_SWITCH_ON, qs}, timeout_s)
        self._command_all(R.CW_SWITCH_ON, {State.SWITCHED_ON, qs}, timeout_s)
        self._command_all(R.CW_ENABLE_OPERATION, {State.OPERATION_ENABLED}, timeout_s)

    def disable_all(self, timeout_s: float = 1.0) -> None:
        """Disable voltage (0x00) on every axis: torque off, brakes on, from any powered state."""
        self._command_all(R.CW_DISABLE_VOLTAGE, {State.SWITCH_ON_DISABLED, State.FAULT}, timeout_s)

    def fault_reset(self, timeout_s: float = 1.0) -> None:
        """Rising edge of controlword bit 7 on every axis (torque off first), then the gateway RESET
        command (clears latched gateway errors). SafetyStop if a fault persists (e.g. e-stop)."""
        self._write(R.CTRL_CONTROLWORD_ALL, [R.CW_DISABLE_VOLTAGE], "fault reset")
        self._write(R.CTRL_CONTROLWORD_ALL, [R.CW_FAULT_RESET], "fault reset")
        self._command_all(R.CW_DISABLE_VOLTAGE, {State.SWITCH_ON_DISABLED, State.FAULT}, timeout_s)
        self._levels = Control(0)  # a reset ends any stream; the gateway's level may already be off
        self._control(Control.RESET)
        still = [(i, a.error_code) for i, a in enumerate(self.axes()) if a.state is State.FAULT]
        if still:
            raise SafetyStop(f"fault persists after reset: {still} (e-stop pressed?)")

    # ---- stream control ------------------------------------------------------------------------

    def _control(self, command: Control | None = None) -> None:
        command = command if command is not None else Control(0)
        self._write(R.CTRL_BITS, [int(self._levels | command)], f"control {command!r}")

    def configure(
        self,
        watchdog_ms: int = 200,
        prefill: int = 0,
        interpolation_ratio: int = 1,
        trace_decimation: int = 1,
    ) -> None:
        """Registers 22-26 (outside a stream; exception 3 -> GatewayError while streaming)."""
        values = [watchdog_ms, prefill, self._trace_next & 0xFFFF, interpolation_ratio, trace_decimation]
        self._write(R.CTRL_WATCHDOG_MS, values, "configure")
        self.prefill, self.ratio, self.decimation = prefill, interpolation_ratio, trace_decimation

    def clear_stream(self) -> None:
        self._levels = Control(0)
        self._control(Control.CLEAR)
        self._trace_next = 0

    def start_stream(self) -> None:
        self._levels = Control.STREAM_ENABLE
        self._control()

    def end_stream(self) -> None:
        self._levels |= Control.END_OF_STREAM
        self._control()

    def quick_stop(self) -> None:
        self._levels = Control(0)
        self._control(Control.QUICK_STOP)

    def heartbeat(self, value: int) -> None:
        self._write(R.CTRL_HEARTBEAT, [value & 0xFFFF], "heartbeat")

    # ---- setpoints and trace -------------------------------------------------------------------

    def write_block(
        self,
        first_index: int,
        pos_rad: np.ndarray,
        tau_ff_nm: np.ndarray,
        *,
        end_of_stream: bool = False,
    ) -> BlockReply:
        """One FC23: ≤ 6 setpoints at ``first_index`` out, status + ≤ 6 new trace records back.

        Retrying the same block after a lost answer is safe (indices already accepted are ignored).
        A full buffer returns ``accepted=False``; an index gap or a closed stream raises GatewayError.
        """
        pos = np.atleast_2d(np.asarray(pos_rad, dtype=float))
        tau = np.atleast_2d(np.asarray(tau_ff_nm, dtype=float)).reshape(pos.shape)
        if pos.shape[0] == 0:
            pos = tau = np.zeros((0, R.N_AXES))
        block = codec.SetpointBlock(
            first_index=first_index,
            trace_cursor=self._trace_next & 0xFFFF,
            flags=R.BlockFlags.END_OF_STREAM if end_of_stream else R.BlockFlags(0),
            position_counts=codec.rad_to_counts(pos),
            torque_counts=codec.nm_to_torque_counts(tau, self.rated_torque_nm),
        )
        rsp = self._call(
            "setpoint block",
            self._mb.readwrite_registers,
            read_address=R.WINDOW_BASE,
            read_count=R.WINDOW_WORDS,
            write_address=R.BLOCK_BASE,
            values=codec.encode_block(block),
        )
        if rsp.isError():
            code = getattr(rsp, "exception_code", None)
            if code == Exc.DEVICE_BUSY:
                return BlockReply(False, None, _empty_chunk(self._trace_next))
            why = self._other_master(code) or (
                " (index gap or stream not open)" if code == Exc.ILLEGAL_VALUE else ""
            )
            raise GatewayError(f"block at index {first_index} refused with exception {code}{why}")
        status, records = codec.decode_window(list(rsp.registers))
        return BlockReply(True, status, self._take_trace(records))

    def poll(self) -> BlockReply:
        """An empty block: keeps the watchdog fed and fetches status and trace."""
        return self.write_block(0, np.zeros((0, R.N_AXES)), np.zeros((0, R.N_AXES)))

    def _take_trace(self, rec: codec.TraceRecords) -> TraceChunk:
        if rec.count == 0:
            return _empty_chunk(self._trace_next)
        first = codec.unwrap16(rec.first, self._trace_next)
        lost = max(0, first - self._trace_next)
        self._trace_next = first + rec.count
        return TraceChunk(
            first=first,
            position_rad=codec.counts_to_rad(rec.position_counts),
            torque_nm=codec.torque_counts_to_nm(rec.torque_counts, self.rated_torque_nm),
            lost=lost,
        )

    @property
    def trace_next(self) -> int:
        """Index of the next trace record this client will ask for."""
        return self._trace_next

    # ---- tracker (simulated cell) --------------------------------------------------------------

    def read_tracker(self) -> TrackerSample | None:
        """A fresh tracker sample, or None while the robot moves or the probe is hidden."""
        t = codec.decode_tracker(self._read(R.TRACKER_BASE, R.TRACKER_WORDS, "tracker"))
        if not t.valid:
            return None
        return TrackerSample(
            sequence=t.sequence,
            position_m=t.position_um * R.TRACKER_POSITION_LSB_M,
            quaternion_wxyz=t.quaternion_counts * R.TRACKER_QUATERNION_LSB,
            cycle=t.cycle,
        )

    # ---- fault injection (simulated cell only) -------------------------------------------------

    def sim_estop(self, pressed: bool) -> None:
        self._write(R.SIM_BASE + R.SIM_ESTOP, [int(pressed)], "sim e-stop")

    def sim_fault(self, axes_mask: int) -> None:
        self._write(R.SIM_BASE + R.SIM_FAULT_AXES, [axes_mask & 0x3F], "sim fault")

    def sim_mute(self, ms: int) -> None:
        self._write(R.SIM_BASE + R.SIM_MUTE_MS, [ms], "sim mute")

    def sim_drop(self) -> None:
        self._write(R.SIM_BASE + R.SIM_DROP, [1], "sim drop")
