"""The gateway over Modbus TCP on 127.0.0.1 ephemeral ports: server + client end to end."""

from __future__ import annotations

import asyncio
import faulthandler
import threading
import time

import numpy as np
import pytest
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from rxcomm.cell.backend import IdealBackend
from rxcomm.cell.server import CellServer, ServerConfig, TimeMode
from rxcomm.errors import GatewayError, SafetyStop
from rxcomm.gateway import registers as R
from rxcomm.gateway.client import GatewayClient
from rxcomm.gateway.registers import DriveState, ErrorCode, Status
from rxcomm.gateway.stream import stream

pytestmark = pytest.mark.socket  # every test serves a gateway on 127.0.0.1

Q0 = np.array([0.1, -0.5, 1.2, 0.0, 0.4, -0.2])


@pytest.fixture(autouse=True)
def hard_timeout():
    """Kill the run (with tracebacks) instead of hanging on a network bug."""
    faulthandler.dump_traceback_later(60, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


def start_cell(mode: TimeMode = TimeMode.VIRTUAL, **cfg) -> CellServer:
    return CellServer(IdealBackend(Q0), ServerConfig(time_mode=mode, **cfg)).start()


@pytest.fixture
def cell(request):
    srv = start_cell(getattr(request, "param", TimeMode.VIRTUAL))
    yield srv
    srv.stop()


@pytest.fixture
def client(cell):
    c = GatewayClient("127.0.0.1", cell.port, timeout_s=1.0).connect()
    c.identity()
    yield c
    c.close()


def wait_for(pred, timeout_s: float = 2.0, poll_s: float = 0.002) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(poll_s)
    return False


def trajectory(n: int, amplitude: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * 400e-6
    s = 0.5 - 0.5 * np.cos(np.pi * t / t[-1])  # rest to rest
    pos = Q0 + amplitude * np.outer(s, [1.0, -0.8, 0.6, 1.5, -1.2, 2.0])
    tau = np.outer(np.sin(2 * np.pi * t), [50.0, 80.0, 30.0, 5.0, 4.0, 2.0])
    return pos, tau


# ---- identity, addressing, enable ---------------------------------------------------------------


def test_identity_on_ephemeral_port(cell, client):
    assert cell.port > 0
    ident = client.identity()
    assert (ident.magic, ident.map_version, ident.n_axes, ident.cycle_us) == (R.MAGIC, 1, 6, 400)
    assert ident.buffer_capacity == 4096 and ident.trace_capacity == 8192
    np.testing.assert_allclose(client.rated_torque_nm, IdealBackend().rated_torque_nm)
    np.testing.assert_allclose(client.positions_rad(), Q0, atol=1e-6)


def test_identity_mismatch_is_refused():
    """A Modbus device that is not an rxcomm gateway v1 (wrong magic)."""
    ready, port = threading.Event(), []
    loop = asyncio.new_event_loop()

    async def serve():
        words = [0x1234, 1, 6, 400, 4096, 6, 0xFFFA, 8192, 1]
        dev = SimDevice(0, simdata=[SimData(0, values=words, datatype=DataType.REGISTERS)])
        srv = ModbusTcpServer(dev, address=("127.0.0.1", 0))
        await srv.serve_forever(background=True)
        port.append(srv.transport.sockets[0].getsockname()[1])
        ready.set()
        return srv

    def run():
        asyncio.set_event_loop(loop)
        srv = loop.run_until_complete(serve())
        loop.run_forever()
        loop.run_until_complete(srv.shutdown())
        loop.close()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    assert ready.wait(5)
    try:
        with GatewayClient(port=port[0], timeout_s=1.0) as c, pytest.raises(GatewayError, match="magic"):
            c.identity()
    finally:
        loop.call_soon_threadsafe(loop.stop)
        th.join(5)


def test_non_loopback_refused_unless_allowed():
    with pytest.raises(GatewayError, match="loopback"):
        GatewayClient("192.0.2.10", 502)
    with pytest.raises(GatewayError, match="loopback"):
        CellServer(IdealBackend(), ServerConfig(host="0.0.0.0"))
    GatewayClient("192.0.2.10", 502, allow_remote=True)  # constructing does not connect


def test_enable_handshake(client):
    assert all(a.state is DriveState.SWITCH_ON_DISABLED for a in client.axes())
    client.write_controlword(0, R.CW_ENABLE_OPERATION)  # 0x0F without 0x06 first: no transition
    assert client.axes()[0].state is DriveState.SWITCH_ON_DISABLED
    for cw, state in [(0x06, DriveState.READY_TO_SWITCH_ON), (0x07, DriveState.SWITCHED_ON)]:
        client.write_controlword(0, cw)
        assert client.axes()[0].state is state
    client.enable_all()
    axes = client.axes()
    assert all(a.state is DriveState.OPERATION_ENABLED for a in axes)
    assert all(a.statusword & 0x6F == 0x27 for a in axes)
    assert client.status().status & Status.ALL_ENABLED
    np.testing.assert_allclose([a.position_demand_rad for a in axes], Q0, atol=1e-6)  # no jump
    client.disable_all()
    assert all(a.state is DriveState.SWITCH_ON_DISABLED for a in client.axes())


# ---- streaming --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "cell", [TimeMode.VIRTUAL, pytest.param(TimeMode.REALTIME, marks=pytest.mark.slow)], indirect=True
)
def test_stream_two_seconds_complete_trace(cell, client, record_property):
    pos, tau = trajectory(5000)
    client.enable_all()
    # Realtime: client and server share one process (and its GIL) on a possibly loaded 2-core
    # machine, so keep 0.8 s of lead, as `run` does when it measures slow round trips.
    realtime = cell.config.time_mode is TimeMode.REALTIME
    client.configure(watchdog_ms=500, prefill=2000 if realtime else 500)
    client.timing.clear()
    t0 = time.perf_counter()
    res = stream(client, pos, tau, high_level=3000 if realtime else 1500)
    wall = time.perf_counter() - t0
    st = client.status()
    assert st.underrun_count == 0 and not st.status & Status.UNDERRUN
    assert st.status & Status.DONE and st.execute_index == 5000 and st.trace_count == 5000
    assert res.position_rad.shape == (5000, 6) and res.lost_records == 0
    # IdealBackend: actual = demand, torque = feed-forward, up to the register quantisation
    np.testing.assert_allclose(res.position_rad, pos, atol=0.5e-6 + 1e-12)
    np.testing.assert_allclose(res.torque_nm, tau, atol=0.5e-3 * client.rated_torque_nm.max() + 1e-9)
    p50, p99 = client.timing.percentile_s(50), client.timing.percentile_s(99)
    record_property("round_trip_p50_ms", p50 * 1e3)
    record_property("round_trip_p99_ms", p99 * 1e3)
    record_property("cycles_per_s", 5000 / wall)
    print(
        f"\n{cell.config.time_mode}: {5000 / wall:.0f} cycles/s, "
        f"round trip p50 {p50 * 1e3:.3f} ms, p99 {p99 * 1e3:.3f} ms"
    )
    if cell.config.time_mode is TimeMode.REALTIME:
        assert wall > 5000 * 400e-6  # paced by the wall clock, never faster
        record_property("realtime_resyncs", cell.resyncs)
        record_property("realtime_max_late_ms", cell.max_late_s * 1e3)
    assert p50 < 0.02  # sanity only: numbers are reported, not gated, on a shared machine


def test_loopback_round_trip(client, record_property):
    client.configure(watchdog_ms=0)
    client.clear_stream()
    client.timing.clear()
    for _ in range(1000):
        client.poll()  # one FC23: 5 registers out, 117 back
    p50, p99 = client.timing.percentile_s(50), client.timing.percentile_s(99)
    record_property("poll_round_trip_p50_ms", p50 * 1e3)
    record_property("poll_round_trip_p99_ms", p99 * 1e3)
    print(f"\nidle FC23 poll: p50 {p50 * 1e3:.3f} ms, p99 {p99 * 1e3:.3f} ms")
    assert p50 < 0.02


def test_interpolation_ratio_over_the_wire(client):
    client.enable_all()
    client.configure(watchdog_ms=500, prefill=12, interpolation_ratio=5, trace_decimation=5)
    pos, tau = trajectory(300, amplitude=0.05)
    res = stream(client, pos, tau)
    assert client.status().cycle_counter >= 1500  # 5 drive cycles per setpoint
    np.testing.assert_allclose(res.position_rad, pos, atol=0.5e-6 + 1e-12)  # one record per setpoint


def test_duplicate_block_ignored_and_gap_refused(client):
    client.enable_all()
    client.configure(watchdog_ms=500)
    client.clear_stream()
    pos, tau = trajectory(12)
    r1 = client.write_block(0, pos[:6], tau[:6])
    r2 = client.write_block(0, pos[:6] + 0.1, tau[:6])  # a retry must not be applied twice
    assert r1.accepted and r2.accepted and r2.status.write_index == 6
    with pytest.raises(GatewayError, match="exception 3"):
        client.write_block(12, pos[6:], tau[6:])
    assert client.status().status & Status.SEQUENCE_ERROR
    client.write_block(6, pos[6:], tau[6:], end_of_stream=True)
    client.start_stream()
    assert wait_for(lambda: client.status().status & Status.DONE)
    np.testing.assert_allclose(client.positions_rad(), pos[-1], atol=1e-6)
    chunk = client.poll().trace
    chunks = [chunk]
    while client.trace_next < 12:
        chunks.append(client.poll().trace)
    got = np.concatenate([c.position_rad for c in chunks])
    np.testing.assert_allclose(got, pos, atol=1e-6)  # the first copy of block 0 was executed


def test_buffer_full_answers_busy_then_accepts():
    srv = start_cell(buffer_capacity_cycles=24)
    try:
        with GatewayClient(port=srv.port, timeout_s=1.0) as c:
            c.identity()
            c.enable_all()
            c.configure(watchdog_ms=500, prefill=24)
            c.clear_stream()
            pos, tau = trajectory(36, amplitude=0.01)
            for i in range(0, 24, 6):
                assert c.write_block(i, pos[i : i + 6], tau[i : i + 6]).accepted
            busy = c.write_block(24, pos[24:30], tau[24:30])
            assert not busy.accepted and busy.status is None
            assert c.status().write_index == 24
            c.start_stream()  # virtual time drains the buffer
            assert wait_for(lambda: c.write_block(24, pos[24:30], tau[24:30]).accepted)
            assert c.write_block(30, pos[30:], tau[30:], end_of_stream=True).accepted
            assert wait_for(lambda: c.status().status & Status.DONE)
    finally:
        srv.stop()


# ---- stops ------------------------------------------------------------------------------------


@pytest.mark.parametrize("cell", [pytest.param(TimeMode.REALTIME, marks=pytest.mark.realtime)], indirect=True)
def test_underrun_quick_stops(cell, client):
    client.enable_all()
    client.configure(watchdog_ms=1000, prefill=60)
    client.clear_stream()
    pos, tau = trajectory(5000)
    for i in range(0, 120, 6):
        client.write_block(i, pos[i : i + 6], tau[i : i + 6])
    client.start_stream()
    assert wait_for(lambda: client.status().status & Status.UNDERRUN, timeout_s=1.0)
    st = client.status()
    assert st.underrun_count == 1 and st.error == ErrorCode.UNDERRUN and st.execute_index == 120
    assert not st.status & Status.STREAMING
    assert all(a.state is DriveState.QUICK_STOP_ACTIVE for a in client.axes())
    assert wait_for(lambda: max(abs(a.velocity_rad_s) for a in client.axes()) == 0.0)
    with pytest.raises(GatewayError, match="exception 3"):  # the stream is closed until clear
        client.write_block(120, pos[120:126], tau[120:126])
    client.fault_reset()  # clears the latched underrun; quick stop active is not a fault
    client.clear_stream()
    client.enable_all()  # transition 16 back to operation enabled
    assert all(a.state is DriveState.OPERATION_ENABLED for a in client.axes())


@pytest.mark.parametrize("cell", [pytest.param(TimeMode.REALTIME, marks=pytest.mark.realtime)], indirect=True)
def test_watchdog_faults_0x8130(cell, client):
    client.enable_all()
    client.configure(watchdog_ms=50)
    t0 = time.monotonic()
    assert wait_for(lambda: client.status().status & Status.WATCHDOG, timeout_s=1.0)  # reads do not feed it
    assert time.monotonic() - t0 >= 0.045
    assert wait_for(lambda: all(a.state is DriveState.FAULT for a in client.axes()))
    assert all(a.error_code == 0x8130 for a in client.axes())
    with pytest.raises(SafetyStop):
        client.enable_all()
    client.fault_reset()
    client.configure(watchdog_ms=1000)
    client.enable_all()


@pytest.mark.parametrize(
    "mode", [TimeMode.VIRTUAL, pytest.param(TimeMode.REALTIME, marks=pytest.mark.realtime)]
)
def test_disconnect_mid_stream_stops_drives(mode):
    srv = start_cell(mode)
    try:
        c = GatewayClient(port=srv.port, timeout_s=1.0).connect()
        c.identity()
        c.enable_all()
        c.configure(watchdog_ms=1000, prefill=60)
        c.clear_stream()
        pos, tau = trajectory(5000)
        for i in range(0, 600, 6):
            c.write_block(i, pos[i : i + 6], tau[i : i + 6])
        c.start_stream()
        time.sleep(0.02)
        c.close()  # cable pulled mid-stream
        with GatewayClient(port=srv.port, timeout_s=1.0) as m:
            assert wait_for(lambda: all(a.state is DriveState.FAULT for a in m.axes()), timeout_s=1.0)
            axes = m.axes()
            assert all(a.error_code == ErrorCode.HEARTBEAT for a in axes)
            assert all(a.velocity_rad_s == 0.0 for a in axes)
            st = m.status()
            assert st.status & Status.WATCHDOG and not st.status & Status.STREAMING
            assert st.execute_index <= 600
    finally:
        srv.stop()


def test_estop_during_stream_and_fault_reset(client):
    client.enable_all()
    client.configure(watchdog_ms=500, prefill=60)
    pos, tau = trajectory(2000)
    pressed = []

    def press_after_some_blocks(reply):
        if reply.status.execute_index > 300 and not pressed:
            client.sim_estop(True)
            pressed.append(reply.status.execute_index)

    with pytest.raises(SafetyStop, match="ESTOP"):
        stream(client, pos, tau, on_reply=press_after_some_blocks)
    assert wait_for(lambda: all(a.state is DriveState.FAULT for a in client.axes()))
    assert all(a.error_code == ErrorCode.EXTERNAL_ESTOP for a in client.axes())
    with pytest.raises(SafetyStop, match="persists"):
        client.fault_reset()
    client.sim_estop(False)
    client.fault_reset()
    assert not client.status().status & (Status.ESTOP | Status.AXIS_FAULT)
    client.enable_all()
    here = client.positions_rad()
    back = np.linspace(here, pos[0], 600)
    res = stream(client, back, np.zeros_like(back))  # a fresh stream after the reset
    np.testing.assert_allclose(res.position_rad[-1], pos[0], atol=1e-6)


def test_injected_axis_fault_then_reset(client):
    client.enable_all()
    client.configure(watchdog_ms=500)
    client.sim_fault(0b000100)
    axes = client.axes()
    assert axes[2].state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
    assert axes[2].error_code == ErrorCode.INJECTED
    assert all(a.state is DriveState.QUICK_STOP_ACTIVE for i, a in enumerate(axes) if i != 2)
    assert client.status().error == ErrorCode.INJECTED
    client.fault_reset()
    assert all(a.state is DriveState.SWITCH_ON_DISABLED for a in client.axes())
    assert client.status().error == 0
    client.enable_all()


def test_gateway_that_stops_answering(cell):
    with GatewayClient(port=cell.port, timeout_s=0.2) as c:
        c.identity()
        c.enable_all()
        c.configure(watchdog_ms=100)
        c.sim_mute(600)
        t0 = time.monotonic()
        with pytest.raises(GatewayError):
            c.status()
        assert 0.15 < time.monotonic() - t0 < 0.5  # the client's timeout, not the mute, ends the wait
        with pytest.raises(GatewayError, match="not connected"):  # no silent reconnect
            c.status()
    time.sleep(0.6)
    with GatewayClient(port=cell.port, timeout_s=1.0) as m:
        assert all(a.error_code == ErrorCode.HEARTBEAT for a in m.axes())


def test_dropped_connection(cell, client):
    client.enable_all()
    client.configure(watchdog_ms=1000)
    client.sim_drop()
    time.sleep(0.05)
    with pytest.raises(GatewayError):
        client.status()
    with GatewayClient(port=cell.port, timeout_s=1.0) as m:
        assert wait_for(lambda: all(a.state is DriveState.FAULT for a in m.axes()))


# ---- tracker ----------------------------------------------------------------------------------


def test_tracker_only_when_standing_still(client):
    client.enable_all()
    client.configure(watchdog_ms=500, prefill=60)
    s1 = client.read_tracker()
    assert s1 is not None and abs(np.linalg.norm(s1.quaternion_wxyz) - 1) < 1e-8
    np.testing.assert_allclose(
        s1.position_m, [1 + 0.1 * np.sin(Q0[0]), 0.1 * np.sin(Q0[1]), 0.5 + 0.1 * np.sin(Q0[2])], atol=1e-6
    )
    pos, tau = trajectory(600)
    seen_moving = []

    def probe(reply):
        if reply.status.status & Status.STREAMING and not seen_moving:
            seen_moving.append(client.read_tracker())

    stream(client, pos, tau, on_reply=probe)
    assert seen_moving == [None]
    s2 = client.read_tracker()
    assert s2 is not None and s2.sequence == s1.sequence + 1
    q = pos[-1]
    np.testing.assert_allclose(
        s2.position_m, [1 + 0.1 * np.sin(q[0]), 0.1 * np.sin(q[1]), 0.5 + 0.1 * np.sin(q[2])], atol=1e-6
    )


@pytest.mark.parametrize("cell", [TimeMode.VIRTUAL], indirect=True)
def test_a_stream_still_executing_is_not_timed_out(cell, client, monkeypatch):
    """A virtual-time cell slower than its stream time (a loaded machine) is not a timeout while it
    executes setpoints; one executing nothing is, after PROGRESS_TIMEOUT_S (issue 27: `make
    commission` stopped at 57 % of a moving plan)."""
    from rxcomm.gateway import stream as stream_mod

    pos, tau = trajectory(2500)  # 1 s of stream time
    client.enable_all()
    client.configure(watchdog_ms=2000, prefill=60)
    monkeypatch.setattr(stream_mod, "PROGRESS_TIMEOUT_S", 1.0)
    slow = cell.core.run_cycle

    def run_cycle_slowly(*a, **k):  # ≤ 1250 cycles/s: ≥ 2 s of wall time for the 1 s stream
        time.sleep(0.0008)
        return slow(*a, **k)

    monkeypatch.setattr(cell.core, "run_cycle", run_cycle_slowly)
    t0 = time.monotonic()
    res = stream(client, pos, tau, timeout_s=1.0)  # less than the wall time it takes
    assert time.monotonic() - t0 > 2.0 and res.final.status & Status.DONE and res.lost_records == 0
    client.clear_stream()
    monkeypatch.setattr(cell.core, "needs_cycle", lambda: False)  # a clock that never runs a cycle
    t0 = time.monotonic()
    with pytest.raises(
        GatewayError, match=r"(at setpoint \d+ of 2500|not done in time).*\(nothing executed for 1\.\d s\)"
    ):
        stream(client, pos, tau, timeout_s=1.0)
    assert 1.0 < time.monotonic() - t0 < 4.0
