"""Drive gateway register map v1: the one definition server and client share.

Holding registers, 0-based addresses, one 16-bit word each. 32-bit values occupy two words, high
word first. Positions are signed 32-bit counts of 1 µrad, torques signed 16-bit counts of 0.1 % of
the axis' rated torque (rated torque itself is u32 mN·m). ``docs/gateway.md`` is the prose contract;
this module is its machine-readable twin, and a change to one is a change to both.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

MAGIC = 0x5258  # "RX"
MAP_VERSION = 1
FUNCTION_CODES = (3, 6, 16, 23)  # all the gateway answers; any other: exception 1 (illegal function)
N_AXES = 6
CYCLE_US = 400
MAX_CYCLES_PER_BLOCK = 6

POSITION_LSB_EXPONENT = -6  # one position count = 10**-6 rad
POSITION_LSB_RAD = 10.0**POSITION_LSB_EXPONENT
VELOCITY_LSB_RAD_S = 1e-6
TORQUE_LSB_PERMILLE = 1  # one torque count = 0.1 % of rated torque
TORQUE_LSB_FRACTION = TORQUE_LSB_PERMILLE / 1000.0
RATED_TORQUE_LSB_NM = 1e-3  # rated torque register unit: mN·m
TRACKER_POSITION_LSB_M = 1e-6
TRACKER_QUATERNION_LSB = 1e-9

I16_MIN, I16_MAX = -(2**15), 2**15 - 1
I32_MIN, I32_MAX = -(2**31), 2**31 - 1
U16_MAX = 2**16 - 1
U32_MAX = 2**32 - 1

# --- 0-8 identity (RO) -------------------------------------------------------------------------
ID_BASE = 0
ID_MAGIC = 0
ID_MAP_VERSION = 1
FUNCTION_CODES = (3, 6, 16, 23)  # all the gateway answers; any other: exception 1 (illegal function)
ID_N_AXES = 2
ID_CYCLE_US = 3
ID_BUFFER_CAPACITY = 4  # setpoint ring, cycles (setpoints)
ID_MAX_CYCLES_PER_BLOCK = 5
ID_POSITION_LSB_EXPONENT = 6  # i16
ID_TRACE_CAPACITY = 7  # trace ring, records
ID_TORQUE_LSB_PERMILLE = 8
ID_COUNT = 9

# --- 20-27 control (RW) ------------------------------------------------------------------------
CTRL_BASE = 20
CTRL_BITS = 20
CTRL_HEARTBEAT = 21
CTRL_WATCHDOG_MS = 22
CTRL_PREFILL = 23
CTRL_TRACE_CURSOR = 24
CTRL_INTERPOLATION_RATIO = 25
CTRL_TRACE_DECIMATION = 26
CTRL_CONTROLWORD_ALL = 27
CTRL_MASTER = 28  # ownership: write a non-zero token to claim, 0 to release; reads the owner's token
CTRL_COUNT = 9

WATCHDOG_MS_MAX = 60_000
INTERPOLATION_RATIO_MAX = 64
TRACE_DECIMATION_MAX = 1000


class Control(IntFlag):
    """Register 20. STREAM_ENABLE and END_OF_STREAM are levels; the others are commands that
    execute when written as 1 and read back as 0."""

    STREAM_ENABLE = 1 << 0
    CLEAR = 1 << 1
    RESET = 1 << 2
    QUICK_STOP = 1 << 3
    END_OF_STREAM = 1 << 4


CONTROL_LEVELS = Control.STREAM_ENABLE | Control.END_OF_STREAM
CONTROL_COMMANDS = Control.CLEAR | Control.RESET | Control.QUICK_STOP

# --- 30-42 status (RO) -------------------------------------------------------------------------
ST_BASE = 30
ST_BITS = 30
ST_CYCLE_COUNTER = 31  # u32
ST_EXECUTE_INDEX = 33  # u32
ST_WRITE_INDEX = 35  # u32
ST_BUFFER_LEVEL = 37
ST_UNDERRUN_COUNT = 38
ST_ERROR = 39
ST_TRACE_COUNT = 40  # u32, records produced since clear
ST_HEARTBEAT_ECHO = 42
ST_STOP_CAUSE = 43  # why the last stream or quick stop ended (StopCause), until CLEAR / RESET
ST_OVERRUNS = 44  # drive cycles the gateway started more than one cycle late (since power-on, saturates)
ST_CLOCK = 45  # Clock: what paces the drive cycles
ST_COUNT = 16


class Clock(IntEnum):
    """Register 45."""

    REALTIME = 0  # a drive cycle every cycle_us of wall time (a real gateway; the simulator --realtime)
    VIRTUAL = 1  # simulator: cycles run only when setpoints are buffered, so underruns cannot happen


class Status(IntFlag):
    """Register 30 (and 2000). Latched bits stay set until CLEAR or RESET (docs/gateway.md)."""

    STREAMING = 1 << 0
    DONE = 1 << 1
    UNDERRUN = 1 << 2
    WATCHDOG = 1 << 3
    ESTOP = 1 << 4
    AXIS_FAULT = 1 << 5
    ALL_ENABLED = 1 << 6
    SEQUENCE_ERROR = 1 << 7
    ARMED = 1 << 8
    END_OF_STREAM = 1 << 9
    QUICK_STOP = 1 << 10
    TRACE_OVERFLOW = 1 << 11


# --- 100 + 20 i: axis i ------------------------------------------------------------------------
AXIS_BASE = 100
AXIS_STRIDE = 20
AX_CONTROLWORD = 0  # RW
AX_MODE = 1  # RW, only MODE_CSP accepted
AX_STATUSWORD = 2
AX_MODE_DISPLAY = 3
AX_POSITION_ACTUAL = 4  # i32 µrad
AX_VELOCITY_ACTUAL = 6  # i32 µrad/s
AX_TORQUE_ACTUAL = 8  # i16 0.1 % rated
AX_ERROR_CODE = 9
AX_FOLLOWING_ERROR = 10  # i32 µrad
AX_POSITION_DEMAND = 12  # i32 µrad
AX_RATED_TORQUE = 14  # u32 mN·m
AX_TORQUE_FF = 16  # i16 0.1 % rated, feed-forward in use
AX_WRITABLE = 2  # offsets 0..1 are RW, the rest RO
MODE_CSP = 8  # cyclic synchronous position


def axis_base(axis: int) -> int:
    return AXIS_BASE + AXIS_STRIDE * axis


# --- 1000-1112 setpoint block (W) --------------------------------------------------------------
BLOCK_BASE = 1000
BLK_FIRST_INDEX = 0  # u32
BLK_COUNT = 2
BLK_TRACE_CURSOR = 3  # low 16 bits of the next trace record wanted
BLK_FLAGS = 4
BLK_HEADER = 5
CYCLE_WORDS = 2 * N_AXES + N_AXES  # 6 × i32 position + 6 × i16 feed-forward torque
BLOCK_MAX_WORDS = BLK_HEADER + MAX_CYCLES_PER_BLOCK * CYCLE_WORDS  # 113


class BlockFlags(IntFlag):
    END_OF_STREAM = 1 << 0


# --- 2000-2116 status + trace window (RO) ------------------------------------------------------
WINDOW_BASE = 2000
WIN_STATUS = 0
WIN_ERROR = 1
WIN_EXECUTE_INDEX = 2  # u32
WIN_WRITE_INDEX = 4  # u32
WIN_BUFFER_LEVEL = 6
WIN_TRACE_FIRST = 7  # low 16 bits of the first record's index
WIN_TRACE_COUNT = 8
WIN_HEADER = 9
RECORD_WORDS = 2 * N_AXES + N_AXES  # 6 × i32 position actual + 6 × i16 torque actual
MAX_RECORDS_PER_WINDOW = 6
WINDOW_WORDS = WIN_HEADER + MAX_RECORDS_PER_WINDOW * RECORD_WORDS  # 117

# --- 3000-3017 tracker (RO, sim only) ----------------------------------------------------------
TRACKER_BASE = 3000
TRK_VALID = 0
TRK_SEQUENCE = 1
TRK_POSITION = 2  # 3 × i32 µm
TRK_QUATERNION = 8  # 4 × i32 (w, x, y, z) × 1e-9
TRK_CYCLE = 16  # u32 cycle counter at the sample
TRACKER_WORDS = 18

# --- 3100-3103 fault injection (RW, sim only) --------------------------------------------------
SIM_BASE = 3100
SIM_ESTOP = 0  # 1 = pressed, 0 = released
SIM_FAULT_AXES = 1  # command: bit i faults axis i with ERR_INJECTED
SIM_MUTE_MS = 2  # command: answer nothing for this long
SIM_DROP = 3  # command: close every client connection
SIM_WORDS = 4
SIM_MUTE_MS_MAX = 10_000


SIM_FAULT_AXES_MASK = (1 << N_AXES) - 1  # 3101: bits above the axes are undefined (exception 3)
SIM_DROP_VALUE = 1  # 3103: the only defined command value


class ErrorCode(IntEnum):
    """Axis and gateway error codes (CiA 301/402 where one fits, 0xFFxx rxcomm-specific)."""

    NONE = 0x0000
    EXTERNAL_ESTOP = 0x9000  # CiA 301 "external error": the emergency stop chain opened
    HEARTBEAT = 0x8130  # CiA 301 "life guard / heartbeat error": the watchdog expired
    FOLLOWING_ERROR = 0x8611  # CiA 402 "following error"
    UNDERRUN = 0xFF01  # setpoint buffer empty before end of stream
    INJECTED = 0xFF02  # sim: forced axis fault


class StopCause(IntEnum):
    """Register 43: the first cause of a stream abort or quick stop since the last CLEAR / RESET."""

    NONE = 0
    UNDERRUN = 1  # setpoint buffer empty before end of stream
    WATCHDOG = 2  # no accepted write from the master for watchdog ms
    CONNECTION_LOST = 3  # the master's (or the last) connection closed
    ESTOP = 4
    AXIS_FAULT = 5  # following error or an injected fault
    QUICK_STOP_COMMAND = 6  # control bit QUICK_STOP
    STREAM_DISABLED = 7  # STREAM_ENABLE withdrawn while running
    AXIS_LEFT_OPERATION = 8  # a controlword took an axis out of operation enabled mid-stream


class ModbusException(IntEnum):
    """The exception codes the gateway answers with."""

    ILLEGAL_FUNCTION = 1  # a function code other than 3, 6, 16, 23
    ILLEGAL_ADDRESS = 2  # outside the map, or a write to a read-only register
    ILLEGAL_VALUE = 3  # gap in block indices, malformed block, refused command or value
    DEVICE_BUSY = 6  # setpoint buffer full: retry the same block later
    NO_RESPONSE = 11  # sim: answered after a mute period


# --- CiA 402 controlword / statusword bits -----------------------------------------------------
class CW(IntFlag):
    """Controlword (0x6040) bits."""

    SWITCH_ON = 1 << 0
    ENABLE_VOLTAGE = 1 << 1
    QUICK_STOP = 1 << 2  # active low: 0 commands a quick stop
    ENABLE_OPERATION = 1 << 3
    FAULT_RESET = 1 << 7


CW_SHUTDOWN = 0x06
CW_SWITCH_ON = 0x07
CW_ENABLE_OPERATION = 0x0F
CW_DISABLE_VOLTAGE = 0x00
CW_QUICK_STOP = 0x02
CW_FAULT_RESET = 0x80


class SW(IntFlag):
    """Statusword (0x6041) bits."""

    READY_TO_SWITCH_ON = 1 << 0
    SWITCHED_ON = 1 << 1
    OPERATION_ENABLED = 1 << 2
    FAULT = 1 << 3
    VOLTAGE_ENABLED = 1 << 4
    QUICK_STOP = 1 << 5  # active low: 0 while a quick stop is active
    SWITCH_ON_DISABLED = 1 << 6
    WARNING = 1 << 7
    REMOTE = 1 << 9
    TARGET_REACHED = 1 << 10
    FOLLOWING_ERROR = 1 << 13


SW_STATE_MASK = 0x6F  # bits 0-3, 5, 6 identify the state


class DriveState(IntEnum):
    """CiA 402 power states."""

    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7


_RDY, _ON, _OP, _FLT = SW.READY_TO_SWITCH_ON, SW.SWITCHED_ON, SW.OPERATION_ENABLED, SW.FAULT
_QS, _VOLT = SW.QUICK_STOP, SW.VOLTAGE_ENABLED
STATUSWORD_OF_STATE: dict[DriveState, SW] = {
    DriveState.SWITCH_ON_DISABLED: SW.SWITCH_ON_DISABLED,  # x1xx 0000
    DriveState.READY_TO_SWITCH_ON: _RDY | _QS | _VOLT,  # x01x 0001
    DriveState.SWITCHED_ON: _RDY | _ON | _QS | _VOLT,  # x01x 0011
    DriveState.OPERATION_ENABLED: _RDY | _ON | _OP | _QS | _VOLT,  # x01x 0111
    DriveState.QUICK_STOP_ACTIVE: _RDY | _ON | _OP | _VOLT,  # x00x 0111
    DriveState.FAULT_REACTION_ACTIVE: _RDY | _ON | _OP | _FLT | _VOLT,  # x0xx 1111
    DriveState.FAULT: _FLT,  # x0xx 1000
}
del _RDY, _ON, _OP, _FLT, _QS, _VOLT


def state_from_statusword(statusword: int) -> DriveState | None:
    """The CiA 402 state a statusword reports (bits 0-3, 5, 6), None for an undefined pattern."""
    masked = statusword & SW_STATE_MASK
    for st, sw in STATUSWORD_OF_STATE.items():
        if int(sw) & SW_STATE_MASK == masked:
            return st
    return None


def sections() -> tuple[tuple[str, int, int, bool], ...]:
    """(name, first address, word count, read-only) of every defined range; anything else is
    answered with exception 2."""
    return (
        ("identity", ID_BASE, ID_COUNT, True),
        ("control", CTRL_BASE, CTRL_COUNT, False),
        ("status", ST_BASE, ST_COUNT, True),
        ("axes", AXIS_BASE, N_AXES * AXIS_STRIDE, False),
        ("block", BLOCK_BASE, BLOCK_MAX_WORDS, False),
        ("window", WINDOW_BASE, WINDOW_WORDS, True),
        ("tracker", TRACKER_BASE, TRACKER_WORDS, True),
        ("sim", SIM_BASE, SIM_WORDS, False),
    )
