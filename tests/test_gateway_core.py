"""Gateway logic without sockets: buffers, interpolation, stop ramps, watchdog, trips."""

from __future__ import annotations

import numpy as np
import pytest

from rxcomm.cell.backend import AxisFeedback, IdealBackend
from rxcomm.cell.gateway_core import GatewayCore
from rxcomm.cell.gateway_machine import CoreLimits, Phase
from rxcomm.cell.rings import Accept, SetpointRing
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.registers import Control, DriveState, ErrorCode, Status

DT = 400e-6


def enable(core: GatewayCore) -> None:
    for cw in (R.CW_SHUTDOWN, R.CW_SWITCH_ON, R.CW_ENABLE_OPERATION):
        assert core.handle_write(R.CTRL_CONTROLWORD_ALL, [cw], 0.0) is None
    assert core.all_enabled()


def send(core: GatewayCore, first: int, pos: np.ndarray, tau: np.ndarray | None = None, **kw) -> int | None:
    tau = np.zeros_like(pos) if tau is None else tau
    blk = codec.SetpointBlock(
        first,
        kw.get("cursor", 0),
        int(R.BlockFlags.END_OF_STREAM) if kw.get("eos") else 0,
        codec.rad_to_counts(pos),
        codec.nm_to_torque_counts(tau, core.rated_nm),
    )
    return core.handle_write(R.BLOCK_BASE, codec.encode_block(blk), kw.get("now", 0.0))


def stream_all(core: GatewayCore, pos: np.ndarray, *, realtime: bool = False) -> None:
    """Send everything (buffer permitting), start, and run cycles until done."""
    assert core.handle_write(R.CTRL_BITS, [int(Control.CLEAR)], 0.0) is None
    for i in range(0, len(pos), 6):
        assert send(core, i, pos[i : i + 6], eos=(i + 6 >= len(pos))) is None
    assert core.handle_write(R.CTRL_BITS, [int(Control.STREAM_ENABLE)], 0.0) is None
    while core.needs_cycle():
        core.run_cycle(allow_underrun=realtime)


def test_ring_is_idempotent_refuses_gaps_and_overfill():
    ring = SetpointRing(12, 6)
    six = np.arange(36.0).reshape(6, 6)
    assert ring.accept(0, six, six) is Accept.NEW
    assert ring.accept(0, six, six) is Accept.DUPLICATE and ring.write_index == 6
    assert ring.accept(3, six, six) is Accept.NEW and ring.write_index == 9  # overlap: tail only
    assert ring.accept(10, six[:1], six[:1]) is Accept.GAP
    assert ring.accept(9, six, six) is Accept.FULL and ring.write_index == 9  # all or nothing
    np.testing.assert_array_equal(ring.peek()[0], six[0])


def test_interpolation_ratio_and_trace_decimation():
    core = GatewayCore(IdealBackend())
    enable(core)
    core.handle_write(R.CTRL_INTERPOLATION_RATIO, [4, 4], 0.0)  # ratio 4, decimation 4
    pos = np.outer(np.arange(1, 13) * 1e-3, np.ones(6))  # 12 setpoints, 1 mrad apart
    demands = []
    orig = core.backend.cycle

    def spy(q, tau, en):
        demands.append(q[0])
        return orig(q, tau, en)

    core.backend.cycle = spy  # type: ignore[method-assign]
    stream_all(core, pos)
    assert core.phase is Phase.DONE and core.ring.read_index == 12
    # linear from the previous setpoint (start: 0) to each setpoint over 4 drive cycles, then a
    # settling cycle at the last setpoint (virtual time runs until standstill)
    expected = np.r_[np.arange(1, 49) * 0.25e-3, 12e-3]
    np.testing.assert_allclose(demands, expected, atol=1e-12)
    rec = core.trace.read(0, 100, core.rated_nm)
    assert core.trace.next == 12
    np.testing.assert_array_equal(rec.position_counts[:, 0], np.arange(1, 13) * 1000)


def test_underrun_quick_stop_ramp_obeys_deceleration():
    backend = IdealBackend(quick_stop_decel_rad_s2=50.0)
    core = GatewayCore(backend)
    enable(core)
    v = 1.0  # rad/s on every axis
    pos = np.outer(np.arange(1, 601) * v * DT, np.ones(6))
    core.handle_write(R.CTRL_BITS, [int(Control.CLEAR)], 0.0)
    send_all = [send(core, i, pos[i : i + 6]) for i in range(0, 600, 6)]
    assert all(r is None for r in send_all)
    core.handle_write(R.CTRL_BITS, [int(Control.STREAM_ENABLE)], 0.0)
    for _ in range(600):
        core.run_cycle(allow_underrun=True)
    q_at_underrun = backend.feedback().position_rad.copy()
    assert not core.needs_cycle()  # virtual time would wait here; real time cannot
    core.run_cycle(allow_underrun=True)  # the cycle that finds the buffer empty
    n = 1
    while core.needs_cycle():
        core.run_cycle(allow_underrun=True)
        n += 1
        assert n < 10_000
    st = core.status_bits()
    assert st & Status.UNDERRUN and st & Status.QUICK_STOP and not st & Status.STREAMING
    assert core.underrun_count == 1 and core.error == ErrorCode.UNDERRUN
    assert all(d.state is DriveState.QUICK_STOP_ACTIVE and d.powered for d in core.drives)
    # v = 1 rad/s at 50 rad/s²: 20 ms = 50 cycles, distance v²/2a = 10 mm·rad
    travel = backend.feedback().position_rad - q_at_underrun
    np.testing.assert_allclose(travel, v**2 / (2 * 50.0), rtol=0.03)
    assert 49 <= n <= 52
    core.run_cycle(allow_underrun=True)
    np.testing.assert_array_equal(backend.feedback().velocity_rad_s, 0.0)  # holds


def test_virtual_time_waits_instead_of_underrunning():
    core = GatewayCore(IdealBackend())
    enable(core)
    core.handle_write(R.CTRL_BITS, [int(Control.CLEAR | Control.STREAM_ENABLE)], 0.0)
    assert not core.needs_cycle()  # nothing buffered: the clock does not run
    send(core, 0, np.full((6, 6), 1e-4))
    while core.needs_cycle():
        core.run_cycle(allow_underrun=False)
    assert core.phase is Phase.RUNNING and core.underrun_count == 0 and core.cycle_counter == 6
    send(core, 6, np.full((3, 6), 2e-4), eos=True)
    while core.needs_cycle():
        core.run_cycle(allow_underrun=False)
    assert core.phase is Phase.DONE and core.cycle_counter == 9  # last setpoints equal: already still


def test_enable_takes_over_actual_position():
    q0 = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
    core = GatewayCore(IdealBackend(q0))
    enable(core)
    for _ in range(5):
        core.run_cycle(allow_underrun=True)
    np.testing.assert_array_equal(core.fb.position_rad, q0)


def test_watchdog_faults_all_axes_after_silence():
    core = GatewayCore(IdealBackend(), CoreLimits(watchdog_ms=100))
    enable(core)  # last write at t = 0
    core.check_watchdog(0.099)
    assert core.all_enabled()
    core.check_watchdog(0.101)
    assert core.status_bits() & Status.WATCHDOG and core.error == ErrorCode.HEARTBEAT
    while core.needs_cycle():
        core.run_cycle(allow_underrun=True)
    assert all(d.state is DriveState.FAULT and d.error_code == 0x8130 for d in core.drives)
    core.check_watchdog(10.0)  # unpowered: nothing more to guard
    core.handle_write(R.CTRL_BITS, [int(Control.RESET)], 10.0)
    assert all(d.state is DriveState.SWITCH_ON_DISABLED for d in core.drives) and core.error == 0


class LaggingBackend(IdealBackend):
    """Actual position lags the demand by one cycle: following error = v·dt."""

    def cycle(self, q, tau, en):
        prev = self.feedback().position_rad.copy()
        fb = super().cycle(q, tau, en)
        return AxisFeedback(np.where(en, prev, fb.position_rad), fb.velocity_rad_s, fb.torque_nm, q - prev)


def test_following_error_trip():
    core = GatewayCore(LaggingBackend(following_error_limit_rad=1e-3))
    enable(core)
    fast = np.outer(np.arange(1, 13) * 2e-3, [1, 0, 0, 0, 0, 0])  # 2 mrad per cycle on axis 0
    stream_all(core, fast)
    assert core.drives[0].state is DriveState.FAULT and core.drives[0].error_code == ErrorCode.FOLLOWING_ERROR
    assert core.drives[0].statusword() & 0x08
    assert all(d.state is DriveState.QUICK_STOP_ACTIVE for d in core.drives[1:])
    assert core.phase is Phase.ABORTED and core.error == ErrorCode.FOLLOWING_ERROR


def test_commands_refused_in_the_wrong_state():
    core = GatewayCore(IdealBackend())
    assert core.handle_write(R.CTRL_BITS, [int(Control.STREAM_ENABLE)], 0.0) == 3  # not enabled
    enable(core)
    assert core.handle_write(R.CTRL_BITS, [int(Control.STREAM_ENABLE)], 0.0) is None
    assert core.handle_write(R.CTRL_INTERPOLATION_RATIO, [2], 0.0) == 3  # config frozen while armed
    assert core.handle_write(R.CTRL_INTERPOLATION_RATIO, [1], 0.0) is None  # same value: fine
    assert core.handle_write(R.axis_base(0) + R.AX_MODE, [1], 0.0) == 3  # only CSP
    assert core.handle_write(R.axis_base(0) + R.AX_STATUSWORD, [0], 0.0) == 2  # read-only
    assert core.handle_write(R.ST_BASE, [0], 0.0) == 2
    assert core.handle_read(10, 1) == 2 and core.handle_read(8, 2) == 2  # gap after identity


def test_trace_overflow_never_blocks_motion():
    core = GatewayCore(IdealBackend(), CoreLimits(trace_capacity=10))
    enable(core)
    stream_all(core, np.outer(np.arange(30) * 1e-5, np.ones(6)))
    assert core.phase is Phase.DONE and core.ring.read_index == 30
    assert core.status_bits() & Status.TRACE_OVERFLOW
    rec = core.trace.read(0, 6, core.rated_nm)
    assert rec.first == 20  # the 10 newest records survive


@pytest.mark.parametrize("mask", [0b000001, 0b100100])
def test_injected_fault_and_estop(mask):
    core = GatewayCore(IdealBackend())
    enable(core)
    core.handle_write(R.SIM_BASE + R.SIM_FAULT_AXES, [mask], 0.0)
    faulted = [bool(mask >> i & 1) for i in range(6)]
    assert [d.faulted for d in core.drives] == faulted
    assert all(
        d.state is DriveState.QUICK_STOP_ACTIVE for d, f in zip(core.drives, faulted, strict=True) if not f
    )
    core.handle_write(R.SIM_BASE + R.SIM_ESTOP, [1], 0.0)
    while core.needs_cycle():
        core.run_cycle(allow_underrun=True)
    assert all(d.state is DriveState.FAULT for d in core.drives)
    core.handle_write(R.CTRL_BITS, [int(Control.RESET)], 0.0)
    assert all(d.state is DriveState.FAULT for d in core.drives)  # e-stop still pressed
    core.handle_write(R.SIM_BASE + R.SIM_ESTOP, [0], 0.0)
    core.handle_write(R.CTRL_BITS, [int(Control.RESET)], 0.0)
    assert all(d.state is DriveState.SWITCH_ON_DISABLED for d in core.drives)
    assert not core.status_bits() & (Status.ESTOP | Status.AXIS_FAULT)
