"""Register writes in, events out: what each writable section of map v1 does to the gateway's state
machine (docs/gateway.md §2.2, §2.4, §2.5, §2.8).

Every writer checks the whole write first and answers a Modbus exception code without changing
anything, or applies all of it and answers None. ``GatewayCore.handle_write`` finds the section,
refuses read-only ones and other masters' writes, and calls the writer named here.
"""

from __future__ import annotations

from collections.abc import Callable

from rxcomm.cell.gateway_machine import STREAM_ON, STREAM_OPEN, GatewayMachine, Phase
from rxcomm.cell.rings import Accept
from rxcomm.errors import GatewayError
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.registers import Control, ErrorCode, ModbusException, StopCause

EXC_ADDRESS = int(ModbusException.ILLEGAL_ADDRESS)
EXC_VALUE = int(ModbusException.ILLEGAL_VALUE)
EXC_BUSY = int(ModbusException.DEVICE_BUSY)

# Plain-int copies of the flag bits: enum flag arithmetic is slow on the per-request path.
_EOS_FLAG = int(R.BlockFlags.END_OF_STREAM)
_CB = {f.name: int(f) for f in Control}
_CONTROL_DEFINED = sum(_CB.values())


def write_control(m: GatewayMachine, offset: int, values: list[int], conn: object | None) -> int | None:
    """Control registers 20-28: settings (fixed while a stream is armed or running), heartbeat,
    trace cursor, the all-axes controlword, the master claim and the control bits."""
    regs = {R.CTRL_BASE + offset + i: v for i, v in enumerate(values)}
    streaming = m.phase in STREAM_ON
    settings = {  # register: (lowest, highest, the machine's attribute)
        R.CTRL_WATCHDOG_MS: (0, R.WATCHDOG_MS_MAX, "watchdog_ms"),
        R.CTRL_PREFILL: (0, m.ring.capacity, "prefill"),
        R.CTRL_INTERPOLATION_RATIO: (1, R.INTERPOLATION_RATIO_MAX, "ratio"),
        R.CTRL_TRACE_DECIMATION: (1, R.TRACE_DECIMATION_MAX, "decimation"),
    }
    for addr, (lo, hi, attr) in settings.items():
        if addr in regs:
            v = regs[addr]
            if not lo <= v <= hi or (streaming and v != getattr(m, attr)):
                return EXC_VALUE
    bits = regs.get(R.CTRL_BITS)
    if bits is not None and (exc := _check_control(m, bits)):
        return exc
    if R.CTRL_MASTER in regs:  # claim (token) or release (0); another master's write never gets here
        m.owner_token = regs[R.CTRL_MASTER]
        m.owner = conn if m.owner_token else None
    for addr, (_, _, attr) in settings.items():
        if addr in regs:
            setattr(m, attr, regs[addr])
    if R.CTRL_HEARTBEAT in regs:
        m.heartbeat = regs[R.CTRL_HEARTBEAT]
    if R.CTRL_TRACE_CURSOR in regs:
        m.set_cursor(regs[R.CTRL_TRACE_CURSOR])
    if R.CTRL_CONTROLWORD_ALL in regs:
        m.cw_all = regs[R.CTRL_CONTROLWORD_ALL]
        for i in range(R.N_AXES):
            m.write_controlword(i, m.cw_all)
    if bits is not None:
        _apply_control(m, bits)
    return None


def _check_control(m: GatewayMachine, bits: int) -> int | None:
    if bits & ~_CONTROL_DEFINED:
        return EXC_VALUE  # undefined bits
    clear = bool(bits & _CB["CLEAR"])
    if clear and m.phase is Phase.RUNNING:
        return EXC_VALUE
    phase = Phase.IDLE if clear else m.phase
    was_enabled = not clear and m.levels & _CB["STREAM_ENABLE"]
    rising = bits & _CB["STREAM_ENABLE"] and not was_enabled
    quick = bits & _CB["QUICK_STOP"]
    if rising and (phase is not Phase.IDLE or not m.all_enabled() or quick):
        return EXC_VALUE
    return None


def _apply_control(m: GatewayMachine, bits: int) -> None:
    if bits & _CB["CLEAR"]:
        m.clear()
    if bits & _CB["RESET"]:
        m.reset()
    if bits & _CB["QUICK_STOP"]:
        m.set_cause(StopCause.QUICK_STOP_COMMAND)
        m.quick_stop()
    if bits & _CB["END_OF_STREAM"] and m.phase in STREAM_OPEN:
        m.eos = True
    enable_bit = _CB["STREAM_ENABLE"]
    if bits & enable_bit and not m.levels & enable_bit:
        m.phase = Phase.ARMED
    elif not bits & enable_bit and m.levels & enable_bit:
        if m.phase is Phase.ARMED:
            m.phase = Phase.IDLE
        elif m.phase is Phase.RUNNING:
            m.set_cause(StopCause.STREAM_DISABLED)
            m.quick_stop()  # withdrawing stream enable mid-stream is a stop request
    m.levels = (bits & enable_bit) | (_CB["END_OF_STREAM"] if m.eos else 0)


def write_axes(m: GatewayMachine, offset: int, values: list[int], conn: object | None) -> int | None:
    """Axis registers 100 + 20·i: the controlword (and the mode, which must stay CSP)."""
    writes = [(divmod(offset + i, R.AXIS_STRIDE), v) for i, v in enumerate(values)]
    if any(reg >= R.AX_WRITABLE for (_, reg), _ in writes):
        return EXC_ADDRESS
    if any(reg == R.AX_MODE and v != R.MODE_CSP for (_, reg), v in writes):
        return EXC_VALUE
    for (axis, reg), v in writes:
        if reg == R.AX_CONTROLWORD:
            m.write_controlword(axis, v)
    return None


def write_block(m: GatewayMachine, offset: int, values: list[int], conn: object | None) -> int | None:
    """Setpoint block 1000-: all or nothing into the ring; the block's cursor acknowledges trace."""
    if offset != 0:
        return EXC_ADDRESS
    try:
        blk = codec.decode_block(values)
    except GatewayError:
        return EXC_VALUE
    if blk.count and blk.first_index + blk.count > m.ring.write_index:
        if m.phase not in STREAM_OPEN or m.eos:  # new data for a closed stream
            return EXC_VALUE
        pos = codec.counts_to_rad(blk.position_counts)
        tau = codec.torque_counts_to_nm(blk.torque_counts, m.rated_nm)
        result = m.ring.accept(blk.first_index, pos, tau)
        if result is Accept.GAP:
            m.seq_error = True
            return EXC_VALUE
        if result is Accept.FULL:
            return EXC_BUSY
    m.set_cursor(blk.trace_cursor)
    if blk.flags & _EOS_FLAG and m.phase in STREAM_OPEN:
        m.eos = True
        m.levels |= _CB["END_OF_STREAM"]
    return None


def write_sim(m: GatewayMachine, offset: int, values: list[int], conn: object | None) -> int | None:
    """Fault injection 3100-3103 (simulated cell only): E-stop, axis faults, mute, drop."""
    regs = {offset + i: v for i, v in enumerate(values)}
    if (
        regs.get(R.SIM_MUTE_MS, 0) > R.SIM_MUTE_MS_MAX
        or regs.get(R.SIM_ESTOP, 0) not in (0, 1)
        or regs.get(R.SIM_FAULT_AXES, 0) & ~R.SIM_FAULT_AXES_MASK
        or regs.get(R.SIM_DROP, 0) not in (0, R.SIM_DROP_VALUE)
    ):
        return EXC_VALUE  # out of range or undefined bits: nothing happens
    if R.SIM_ESTOP in regs:
        m.set_estop(bool(regs[R.SIM_ESTOP]))
    if mask := regs.get(R.SIM_FAULT_AXES, 0):
        m.set_cause(StopCause.AXIS_FAULT)
        m.fault_axes([bool((mask >> i) & 1) for i in range(R.N_AXES)], ErrorCode.INJECTED)
    if regs.get(R.SIM_MUTE_MS):
        m.mute_ms_requested = regs[R.SIM_MUTE_MS]
    if regs.get(R.SIM_DROP):
        m.drop_requested = True
    return None


Writer = Callable[[GatewayMachine, int, list[int], object | None], int | None]

# The writable sections of registers.sections(), by name.
WRITERS: dict[str, Writer] = {
    "control": write_control,
    "axes": write_axes,
    "block": write_block,
    "sim": write_sim,
}
