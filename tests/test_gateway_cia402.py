"""CiA 402 device-control state machine of the simulated drives."""

from __future__ import annotations

import pytest

from rxcomm.cell.cia402 import Command, Drive402, decode_command, next_state
from rxcomm.gateway.registers import DriveState as S
from rxcomm.gateway.registers import state_from_statusword


@pytest.mark.parametrize(
    ("cw", "cmd"),
    [
        (0x06, Command.SHUTDOWN),
        (0x07, Command.SWITCH_ON),
        (0x0F, Command.ENABLE_OPERATION),
        (0x00, Command.DISABLE_VOLTAGE),
        (0x0D, Command.DISABLE_VOLTAGE),  # bit 1 low wins
        (0x02, Command.QUICK_STOP),
        (0x0B, Command.QUICK_STOP),
    ],
)
def test_command_decoding(cw, cmd):
    assert decode_command(cw) is cmd


def test_enable_handshake_and_disable_paths():
    d = Drive402()
    assert d.state is S.SWITCH_ON_DISABLED and not d.powered
    assert d.write_controlword(0x0F) is S.SWITCH_ON_DISABLED  # enable without shutdown: refused
    assert d.write_controlword(0x06) is S.READY_TO_SWITCH_ON
    assert d.write_controlword(0x07) is S.SWITCHED_ON and not d.powered
    assert d.write_controlword(0x0F) is S.OPERATION_ENABLED and d.powered
    assert d.write_controlword(0x07) is S.SWITCHED_ON  # 5: disable operation
    assert d.write_controlword(0x0F) is S.OPERATION_ENABLED
    assert d.write_controlword(0x06) is S.READY_TO_SWITCH_ON  # 8
    assert d.write_controlword(0x0F) is S.OPERATION_ENABLED  # 3 + 4 in one write
    assert d.write_controlword(0x00) is S.SWITCH_ON_DISABLED  # 9


def test_quick_stop_option_code_6():
    d = Drive402(state=S.OPERATION_ENABLED)
    assert d.write_controlword(0x02) is S.QUICK_STOP_ACTIVE and d.powered  # 11, torque stays on
    assert d.write_controlword(0x06) is S.QUICK_STOP_ACTIVE  # shutdown is no transition from here
    assert d.write_controlword(0x0F) is S.OPERATION_ENABLED  # 16
    assert d.quick_stop() and d.state is S.QUICK_STOP_ACTIVE  # internal (gateway) quick stop
    assert d.write_controlword(0x00) is S.SWITCH_ON_DISABLED  # 12


def test_fault_reaction_and_reset_on_rising_edge_only():
    d = Drive402(state=S.OPERATION_ENABLED, controlword=0x0F)
    assert d.fault(0x8611)
    assert d.state is S.FAULT_REACTION_ACTIVE and d.powered and d.error_code == 0x8611
    assert not d.fault(0x8130)  # the first code is kept
    d.write_controlword(0x0F)
    assert d.state is S.FAULT_REACTION_ACTIVE  # commands ignored while faulted
    d.reaction_done()
    assert d.state is S.FAULT and not d.powered
    d.write_controlword(0x80)  # rising edge...
    assert d.state is S.SWITCH_ON_DISABLED and d.error_code == 0
    d.fault(0xFF02)
    d.write_controlword(0x86)  # bit 7 still high: no edge, and other bits ignored
    assert d.state is S.FAULT
    d.write_controlword(0x06)
    d.write_controlword(0x80)
    assert d.state is S.SWITCH_ON_DISABLED


def test_fault_reset_refused_while_cause_persists():
    d = Drive402()
    d.fault(0x9000)
    assert d.state is S.FAULT  # not powered: straight to fault
    d.write_controlword(0x80, fault_cause_active=True)
    assert d.state is S.FAULT
    d.write_controlword(0x00)
    d.write_controlword(0x80, fault_cause_active=False)
    assert d.state is S.SWITCH_ON_DISABLED


@pytest.mark.parametrize("state", list(S))
def test_statusword_matches_cia402_patterns(state):
    sw = Drive402(state=state).statusword()
    # CiA 402 table: (mask, value) per state
    patterns = {
        S.SWITCH_ON_DISABLED: (0x4F, 0x40),
        S.READY_TO_SWITCH_ON: (0x6F, 0x21),
        S.SWITCHED_ON: (0x6F, 0x23),
        S.OPERATION_ENABLED: (0x6F, 0x27),
        S.QUICK_STOP_ACTIVE: (0x6F, 0x07),
        S.FAULT_REACTION_ACTIVE: (0x4F, 0x0F),
        S.FAULT: (0x4F, 0x08),
    }
    mask, value = patterns[state]
    assert sw & mask == value
    assert state_from_statusword(sw) is state


def test_next_state_is_pure():
    assert next_state(S.SWITCHED_ON, 0x0F) is S.OPERATION_ENABLED
    assert next_state(S.FAULT, 0x0F) is S.FAULT
