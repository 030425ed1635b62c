"""Per-axis CiA 402 power state machine (device control, 0x6040/0x6041).

Commands are evaluated when the controlword is *written* (each write, even of the same value), not
re-evaluated every cycle: internal events (a gateway quick stop, a fault) then stick until the
master commands again. Quick stop option code 6: ramp down, stay in "quick stop active" with torque
on; "enable operation" returns to operation enabled (transition 16). Fault reaction: ramp down,
then "fault" with torque off. Fault reset acts on the rising edge of controlword bit 7 and only
when the cause is gone; while bit 7 is set the other command bits are ignored.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from rxcomm.gateway.registers import CW, STATUSWORD_OF_STATE, SW
from rxcomm.gateway.registers import DriveState as State


class Command(Enum):
    DISABLE_VOLTAGE = "disable voltage"
    QUICK_STOP = "quick stop"
    SHUTDOWN = "shutdown"
    SWITCH_ON = "switch on"  # also "disable operation"
    ENABLE_OPERATION = "enable operation"  # also "switch on + enable operation"


def decode_command(controlword: int) -> Command:
    """Device control command of a controlword (bits 0-3; bit 7 is handled separately)."""
    cw = CW(controlword & 0x0F)
    if CW.ENABLE_VOLTAGE not in cw:
        return Command.DISABLE_VOLTAGE
    if CW.QUICK_STOP not in cw:
        return Command.QUICK_STOP
    if CW.SWITCH_ON not in cw:
        return Command.SHUTDOWN
    return Command.ENABLE_OPERATION if CW.ENABLE_OPERATION in cw else Command.SWITCH_ON


S, C = State, Command
_TRANSITIONS: dict[tuple[State, Command], State] = {
    (S.SWITCH_ON_DISABLED, C.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 2
    (S.READY_TO_SWITCH_ON, C.SWITCH_ON): S.SWITCHED_ON,  # 3
    (S.READY_TO_SWITCH_ON, C.ENABLE_OPERATION): S.OPERATION_ENABLED,  # 3 + 4
    (S.READY_TO_SWITCH_ON, C.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 7
    (S.READY_TO_SWITCH_ON, C.QUICK_STOP): S.SWITCH_ON_DISABLED,  # 7
    (S.SWITCHED_ON, C.ENABLE_OPERATION): S.OPERATION_ENABLED,  # 4
    (S.SWITCHED_ON, C.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 6
    (S.SWITCHED_ON, C.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 10
    (S.SWITCHED_ON, C.QUICK_STOP): S.SWITCH_ON_DISABLED,  # 10
    (S.OPERATION_ENABLED, C.SWITCH_ON): S.SWITCHED_ON,  # 5
    (S.OPERATION_ENABLED, C.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 8
    (S.OPERATION_ENABLED, C.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 9
    (S.OPERATION_ENABLED, C.QUICK_STOP): S.QUICK_STOP_ACTIVE,  # 11
    (S.QUICK_STOP_ACTIVE, C.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 12
    (S.QUICK_STOP_ACTIVE, C.ENABLE_OPERATION): S.OPERATION_ENABLED,  # 16
}
del S, C

POWERED = frozenset({State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE})


def next_state(state: State, controlword: int) -> State:
    """The state after the master writes ``controlword`` (bit 7 not considered)."""
    return _TRANSITIONS.get((state, decode_command(controlword)), state)


@dataclass
class Drive402:
    """One axis' device control: state, latched error code, last controlword written."""

    state: State = State.SWITCH_ON_DISABLED
    error_code: int = 0
    controlword: int = 0

    @property
    def powered(self) -> bool:
        """Torque on (the backend must be told ``enabled``)."""
        return self.state in POWERED

    @property
    def faulted(self) -> bool:
        return self.state in (State.FAULT, State.FAULT_REACTION_ACTIVE)

    def write_controlword(self, controlword: int, *, fault_cause_active: bool = False) -> State:
        """Apply a controlword write; returns the new state."""
        rising_reset = bool(controlword & CW.FAULT_RESET) and not (self.controlword & CW.FAULT_RESET)
        self.controlword = controlword & 0xFFFF
        if controlword & CW.FAULT_RESET:
            if rising_reset:
                self.fault_reset(fault_cause_active=fault_cause_active)
            return self.state
        if not self.faulted:
            self.state = next_state(self.state, controlword)
        return self.state

    def fault_reset(self, *, fault_cause_active: bool = False) -> bool:
        """Transition 15 (fault -> switch on disabled) unless the cause persists."""
        if self.state is State.FAULT and not fault_cause_active:
            self.state = State.SWITCH_ON_DISABLED
            self.error_code = 0
            return True
        return False

    def quick_stop(self) -> bool:
        """An internal quick stop (gateway command, underrun): transition 11 if enabled."""
        if self.state is State.OPERATION_ENABLED:
            self.state = State.QUICK_STOP_ACTIVE
            return True
        return False

    def fault(self, code: int) -> bool:
        """Transition 13; the first error code is kept until a fault reset."""
        if self.faulted:
            return False
        self.state = State.FAULT_REACTION_ACTIVE if self.powered else State.FAULT
        self.error_code = code
        return True

    def reaction_done(self) -> None:
        """Transition 14: the fault-reaction ramp has finished, torque off."""
        if self.state is State.FAULT_REACTION_ACTIVE:
            self.state = State.FAULT

    def statusword(self, extra: int = 0) -> int:
        return int(STATUSWORD_OF_STATE[self.state] | SW.REMOTE) | extra
