"""The fault matrix (issue 14): nothing lost, one master, only the documented protocol.

Every case asserts what the user sees (exit code, message) and what is left behind (a recoverable
log, stopped drives, an untouched stream). 127.0.0.1 only, bounded loops, hard timeouts; every
server a test starts, it stops.
"""

from __future__ import annotations

import faulthandler
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rxcomm.cell.backend import IdealBackend
from rxcomm.cell.server import CellServer, ServerConfig, TimeMode
from rxcomm.cli import app
from rxcomm.errors import GatewayError, SafetyStop
from rxcomm.execution import campaign
from rxcomm.execution.log import recover_run_log
from rxcomm.execution.plan import prepare_plan
from rxcomm.execution.records import NOT_APPLICABLE_VIRTUAL
from rxcomm.execution.session import RunSettings
from rxcomm.execution.summary import run_summary
from rxcomm.execution.trajectory_run import run_trajectory
from rxcomm.gateway import registers as R
from rxcomm.gateway.client import GatewayClient
from rxcomm.gateway.registers import DriveState, ErrorCode, Status, StopCause
from rxcomm.io.run_log import read_run_log
from rxcomm.io.trajectory import load_trajectory_mcap
from rxcomm.model.dynamics import prior_parameters
from rxcomm.reporting.markdown import render_sections
from rxcomm.reporting.runs import execution_section
from rxcomm.schemas.run_log import RunLogSummary
from rxcomm.stages import run as run_stage

from .conftest import ROOT, SAMPLES
from .runs import CYCLE, DQ, Q0, cosine_plan, save_plan, write_configs

pytestmark = pytest.mark.socket  # faults on a gateway served on 127.0.0.1

ROBOT_DIR = SAMPLES / "rx130l"
TRUTH = ROBOT_DIR / "truth.yaml"
CLI = [sys.executable, "-c", "from rxcomm.cli import main; main()"]


@pytest.fixture(autouse=True)
def hard_timeout():
    faulthandler.dump_traceback_later(300, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


def ideal_cell(rx130l, mode: TimeMode = TimeMode.VIRTUAL, **cfg) -> CellServer:
    backend = IdealBackend(Q0, rated_torque_nm=np.asarray(rx130l.tau_max))
    return CellServer(backend, ServerConfig(time_mode=mode, **cfg)).start()


def wait_for(pred, timeout_s: float, poll_s: float = 0.002) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(poll_s)
    return False


def streamed_s(srv: CellServer) -> float:
    with srv.lock:
        return srv.core.ring.read_index * srv.core.ratio * srv.core.dt


# ---- 3: SIGKILL of run leaves a recoverable log, the drives stop ----------------------------------


@pytest.mark.slow
def test_sigkill_of_run_leaves_a_recoverable_part_log_and_the_drives_stop(tmp_path, record_property):
    """A 60 s realtime trajectory, `run` killed 10 s in: ≥ 9 s of records come back from NAME.mcap.part,
    and the cell stops the drives within the watchdog time (500 ms, `run`'s setting)."""
    from rxcomm.cell.cia402 import State
    from rxcomm.cell.sim import start_embedded_cell

    home = np.zeros(6)  # the simulated cell's initial pose
    dq = 0.5 * np.array([1.0, 0.5, -0.5, 1.2, -0.7, 1.6])
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(home, dq, 60.0))
    out = tmp_path / "log.mcap"
    srv = start_embedded_cell(TRUTH, realtime=True)  # the cell outlives the killed master
    proc = None
    try:
        cmd = [*CLI, "run", str(plan), "--robot", str(ROBOT_DIR), "-o", str(out)]
        proc = subprocess.Popen(
            [*cmd, "--gateway", f"127.0.0.1:{srv.port}"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert wait_for(lambda: streamed_s(srv) >= 10.0 or proc.poll() is not None, 200, 0.005)
        assert proc.poll() is None, proc.stderr.read()
        os.kill(proc.pid, signal.SIGKILL)
        t_kill = time.monotonic()

        def stopped() -> bool:
            with srv.lock:
                return all(d.state is not State.OPERATION_ENABLED for d in srv.core.drives)

        assert wait_for(stopped, 2.0, 0.001)
        t_stop = time.monotonic() - t_kill
        proc.wait(timeout=10)
        with srv.lock:
            core = srv.core
            assert core.watchdog and core.error == ErrorCode.HEARTBEAT
            assert core.stop_cause in (StopCause.CONNECTION_LOST, StopCause.WATCHDOG)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        srv.stop()
    record_property("drives_stopped_after_kill_s", t_stop)
    assert t_stop <= 0.5  # within the watchdog time
    part = out.with_name("log.mcap.part")
    assert part.is_file() and not out.exists() and not out.with_suffix(".yaml").exists()
    res = CliRunner().invoke(app, ["recover-log", str(part)])
    assert res.exit_code == 0, res.output
    assert re.search(r"lost: everything after t = \d+\.\d{3} s of the 60\.\d{3} s planned", res.output)
    rec = recover_run_log(part, tmp_path / "again.mcap")
    record_property("recovered_s", rec.recovered_s)
    assert rec.recovered_s >= 9.0 and not rec.complete
    log = read_run_log(tmp_path / "log.recovered.mcap")  # a finished, strictly readable MCAP
    j = log.joints
    assert len(j) == rec.n_records and log.summary["outcome"] == "running"
    assert np.allclose(np.diff(j.t), j.t[1] - j.t[0])  # consecutive records from t = 0, none skipped
    assert j.t[0] == 0.0 and np.all(np.isfinite(j.q_actual))
    assert np.max(np.abs(j.following_error)) < 0.01  # real feedback of a moving arm, not placeholders
    assert np.ptp(j.q_actual[:, 0]) > 0.01


def test_recover_log_of_a_complete_part_and_of_a_non_log(tmp_path):
    """A stopped run's finished .part: nothing lost; a trajectory plan is no run log (exit 2)."""
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 0.2))
    res = CliRunner().invoke(app, ["recover-log", str(plan)])
    assert res.exit_code == 2 and "plan.mcap" in res.output and "rxcomm/RunLog" in res.output


# ---- 4: one master at a time ----------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.realtime  # "0 underruns" needs a quiet machine
def test_second_master_is_refused_while_the_first_streams_to_completion(rx130l):
    """Realtime cell: master A streams 4 s; master B, connected meanwhile, can neither start a run nor
    write a controlword, a quick stop or a block. A completes with 0 underruns and every record."""
    srv = ideal_cell(rx130l, TimeMode.REALTIME)
    params = prior_parameters(rx130l)
    plan = prepare_plan(rx130l, cosine_plan(Q0, DQ, 4.0), params, CYCLE)
    results = {}

    def master_a() -> None:
        with GatewayClient("127.0.0.1", srv.port, timeout_s=0.5) as a:
            results["a"] = run_trajectory(a, rx130l, plan, params, RunSettings())

    thread = threading.Thread(target=master_a, daemon=True)
    try:
        thread.start()
        assert wait_for(lambda: streamed_s(srv) >= 0.5, 30.0, 0.005)
        with GatewayClient("127.0.0.1", srv.port, timeout_s=0.5) as b:
            b.identity()
            with pytest.raises(GatewayError, match=r"in use by another master \(token 0x[0-9a-f]{4}\)"):
                run_trajectory(b, rx130l, plan, params, RunSettings())
            assert b.owner_token() not in (0, b.token)
            for disturb in (
                lambda: b.write_controlword(0, R.CW_SHUTDOWN),
                lambda: b._write(R.CTRL_CONTROLWORD_ALL, [R.CW_SHUTDOWN], "controlword"),
                b.quick_stop,
                lambda: b.heartbeat(1),
                lambda: b.configure(watchdog_ms=0),
                lambda: b.write_block(0, plan.q[:6], plan.tau_ff[:6]),
                b.claim,
            ):
                with pytest.raises(GatewayError, match="another master"):
                    disturb()
        thread.join(timeout=60)
        assert not thread.is_alive()
    finally:
        srv.stop()
    res = results["a"]
    assert res.error is None, res.error
    log = res.log
    assert log.completed and log.underruns == 0 and log.lost_records == 0
    assert log.n_records == log.plan.n and not log.virtual_time
    summary = run_summary(rx130l, res)
    # the realtime path measures what virtual time cannot: counts and a lead, not "not applicable"
    assert summary["underruns"] == 0 and isinstance(summary["cell_overruns"], int)
    assert summary["min_lead_s"] is not None and summary["min_lead_s"] >= 0.1


def test_claim_lease_is_the_watchdog_and_the_connection(rx130l):
    """A silent master loses its claim after its watchdog time; a closed one at once."""
    srv = ideal_cell(rx130l)
    try:
        with (
            GatewayClient("127.0.0.1", srv.port, timeout_s=1.0) as a,
            GatewayClient("127.0.0.1", srv.port, timeout_s=1.0) as b,
        ):
            a.configure(watchdog_ms=100)
            a.claim()
            assert b.owner_token() == a.token
            with pytest.raises(GatewayError, match="in use by another master"):
                b.claim()
            time.sleep(0.25)  # a says nothing for longer than its watchdog: the lease is gone
            b.claim()
            assert a.owner_token() == b.token
            with pytest.raises(GatewayError, match="another master"):
                a.heartbeat(1)
            b.claimed = False  # b's connection closes without a release: its end frees the gateway
        with GatewayClient("127.0.0.1", srv.port, timeout_s=1.0) as c:  # b closed: free again
            assert c.owner_token() == 0
            c.claim()
            c.release()
            assert c.owner_token() == 0
    finally:
        srv.stop()


def test_first_master_learns_why_it_was_stopped(rx130l):
    """Stop cause register 43: an e-stop from outside (fault injection is the world, open to anyone)
    stops A's stream; A's error names it instead of 'none (0x0000)'."""
    srv = ideal_cell(rx130l)
    params = prior_parameters(rx130l)
    plan = prepare_plan(rx130l, cosine_plan(Q0, DQ, 2.0), params, CYCLE)

    def press() -> None:
        if wait_for(lambda: streamed_s(srv) >= 0.3, 20.0):
            with GatewayClient("127.0.0.1", srv.port, timeout_s=1.0) as world:
                world.sim_estop(True)

    try:
        t = threading.Thread(target=press, daemon=True)
        t.start()
        with GatewayClient("127.0.0.1", srv.port, timeout_s=1.0) as a:
            res = run_trajectory(a, rx130l, plan, params, RunSettings())
            assert a.status().stop_cause == StopCause.ESTOP
        t.join(timeout=20)
    finally:
        srv.stop()
    assert isinstance(res.error, SafetyStop)
    assert "emergency stop (stop cause 4)" in str(res.error), res.error
    assert "none (0x0000)" not in str(res.error)


# ---- 7: only the documented protocol ---------------------------------------------------------------


def _raw(port: int, pdu: bytes, tid: int = 7) -> bytes:
    """One Modbus TCP request; the answer's PDU (b'' when the gateway does not answer)."""
    with socket.create_connection(("127.0.0.1", port), timeout=1.0) as s:
        s.settimeout(0.5)
        s.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu)
        try:
            data = s.recv(512)
        except TimeoutError:
            return b""
    return data[7:]


def test_only_documented_function_codes_are_answered(rx130l):
    srv = ideal_cell(rx130l)
    try:
        answered = {
            3: bytes([3]) + struct.pack(">HH", 0, 1),
            6: bytes([6]) + struct.pack(">HH", R.CTRL_HEARTBEAT, 5),
            16: bytes([16]) + struct.pack(">HHB", R.CTRL_HEARTBEAT, 1, 2) + b"\x00\x06",
            23: bytes([23]) + struct.pack(">HHHHB", 0, 1, R.CTRL_HEARTBEAT, 1, 2) + b"\x00\x07",
        }
        assert set(answered) == set(R.FUNCTION_CODES)
        for fc, pdu in answered.items():
            assert _raw(srv.port, pdu)[0] == fc, fc
        others = {
            1: struct.pack(">HH", 0, 1),  # read coils
            2: struct.pack(">HH", 0, 1),  # read discrete inputs
            4: struct.pack(">HH", 0, 1),  # read input registers
            5: struct.pack(">HH", 0, 0xFF00),  # write single coil
            7: b"",  # read exception status
            8: struct.pack(">HH", 0, 0x1234),  # diagnostics: echo
            11: b"",
            12: b"",
            15: struct.pack(">HHB", 0, 1, 1) + b"\x01",  # write multiple coils
            17: b"",  # report server id
            22: struct.pack(">HHH", R.CTRL_HEARTBEAT, 0xFFFF, 0),  # mask write register
            24: struct.pack(">H", 0),  # read FIFO queue
            43: bytes([14, 1, 0]),  # read device identification
            0x41: b"\x00\x01",  # user-defined
        }
        for fc, data in others.items():
            rsp = _raw(srv.port, bytes([fc]) + data)
            assert rsp[:2] == bytes([fc | 0x80, 1]), (fc, rsp.hex())  # exception 1: illegal function
    finally:
        srv.stop()


def test_undefined_bits_are_refused_and_change_nothing(rx130l):
    srv = ideal_cell(rx130l)
    try:
        with GatewayClient("127.0.0.1", srv.port, timeout_s=1.0) as c:
            c.identity()
            c.enable_all()
            refused = (
                (R.SIM_BASE + R.SIM_FAULT_AXES, 0x40),  # no valid axis bit
                (R.SIM_BASE + R.SIM_FAULT_AXES, 0x81),  # a valid one with an undefined one: all or nothing
                (R.SIM_BASE + R.SIM_ESTOP, 2),
                (R.SIM_BASE + R.SIM_DROP, 7),
                (R.CTRL_BITS, 1 << 5),
            )
            for addr, value in refused:
                with pytest.raises(GatewayError, match="exception 3"):
                    c._write(addr, [value], f"{addr} := {value:#x}")
            st = c.status()
            assert st.error == 0 and not st.status & (Status.AXIS_FAULT | Status.QUICK_STOP)
            assert all(a.state is DriveState.OPERATION_ENABLED for a in c.axes())
            block = [0, 0, 0, 0, 0b10]  # k = 0, flags bit 1 undefined
            rsp = c._mb.write_registers(address=R.BLOCK_BASE, values=block)
            assert rsp.isError() and rsp.exception_code == 3
            c.sim_fault(0b1)  # the defined bit still works
            assert c.status().error == ErrorCode.INJECTED and c.status().stop_cause == StopCause.AXIS_FAULT
    finally:
        srv.stop()


def test_malformed_frames_print_nothing_and_the_gateway_keeps_serving(rx130l, capfd):
    srv = ideal_cell(rx130l)
    try:
        junk = [
            bytes([3]) + struct.pack(">HH", 0, 0),  # count 0
            bytes([3]) + struct.pack(">HH", 0, 200),  # above the Modbus limit
            bytes([3, 0]),  # truncated
            bytes([16]) + struct.pack(">HHB", 21, 3, 2) + b"\x00\x01",  # count and bytes disagree
            bytes([23]) + struct.pack(">HHHHB", 2000, 117, 1000, 3, 6) + b"\x00" * 6,
            bytes([0x55, 1, 2, 3]),
        ]
        rng = np.random.default_rng(14)
        junk += [
            bytes([int(rng.choice([3, 6, 16, 23]))]) + rng.bytes(int(rng.integers(0, 20))) for _ in range(40)
        ]
        for pdu in junk:
            _raw(srv.port, pdu)
        with socket.create_connection(("127.0.0.1", srv.port), timeout=1.0) as s:  # not Modbus at all
            s.sendall(b"GET / HTTP/1.1\r\n\r\n" * 3)
            time.sleep(0.05)
        assert _raw(srv.port, bytes([3]) + struct.pack(">HH", 0, 2)) == bytes([3, 4, 0x52, 0x58, 0, 1])
    finally:
        srv.stop()
    err = capfd.readouterr().err
    assert err == "", err  # no traceback, no pymodbus log lines


@pytest.mark.process
def test_rxcomm_message_is_the_first_line_on_stderr(tmp_path):
    """An unreachable gateway: rxcomm's one-line error, no pymodbus line before it."""
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 2.0))
    proc = subprocess.run(
        [*CLI, "run", str(plan), "--robot", str(ROBOT_DIR), "-o", str(tmp_path / "log.mcap")]
        + ["--gateway", f"127.0.0.1:{port}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 4, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines and "cannot connect to gateway" in lines[0], proc.stderr
    assert "Connection to" not in proc.stderr  # pymodbus' own wording


# ---- 3 (campaign): each pose on disk as it is taken -----------------------------------------------


def test_campaign_writes_each_pose_as_it_is_taken(tmp_path, rx130l, monkeypatch):
    srv = ideal_cell(rx130l)
    poses = [Q0 + 0.3 * DQ, Q0 - 0.2 * DQ, Q0 + np.array([0.2, 0, 0, 0, 0, 0.5])]
    cfg = write_configs(tmp_path / "configs.yaml", rx130l, poses, ["fit", "validation", "baseline"])
    out = tmp_path / "calib-meas.yaml"
    seen: list[tuple[str, int, str]] = []
    real_write = campaign.write_yaml_artefact

    def spy(path, art):
        written = real_write(path, art)
        doc = yaml.safe_load(Path(written).read_text())  # on disk, complete, at that moment
        seen.append((Path(path).name, len(doc["poses"]), doc["summary"]["outcome"]))
        return written

    monkeypatch.setattr(campaign, "write_yaml_artefact", spy)
    try:
        run_stage.execute(
            cfg, ROBOT_DIR, out, gateway=f"127.0.0.1:{srv.port}", speed=0.5, show_progress=False
        )
    finally:
        srv.stop()
    part = "calib-meas.yaml.part"
    assert seen == [
        (part, 1, "running"),
        (part, 2, "running"),
        (part, 3, "running"),
        (out.name, 3, "completed"),
    ]
    assert out.is_file() and not (tmp_path / part).exists()


# ---- 9: virtual time says so ----------------------------------------------------------------------


def test_virtual_time_run_says_underruns_and_lead_are_not_applicable(tmp_path, rx130l, capsys):
    srv = ideal_cell(rx130l)
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 2.0))
    out = tmp_path / "log.mcap"
    try:
        summary = run_stage.execute(
            plan, ROBOT_DIR, out, gateway=f"127.0.0.1:{srv.port}", show_progress=False
        )
    finally:
        srv.stop()
    for key in ("underruns", "min_lead_s", "cell_overruns"):
        assert summary[key] == NOT_APPLICABLE_VIRTUAL, key
    console = capsys.readouterr().out
    assert console.count(NOT_APPLICABLE_VIRTUAL) >= 3  # underruns, cell_overruns, min_lead_s rows
    meta = yaml.safe_load(out.with_suffix(".yaml").read_text())
    assert meta["summary"]["underruns"] == NOT_APPLICABLE_VIRTUAL
    section = render_sections("r", "", [execution_section(RunLogSummary.model_validate(summary), None, None)])
    assert f"| underruns | {NOT_APPLICABLE_VIRTUAL} |" in section
    assert f"| min buffered lead while feeding | {NOT_APPLICABLE_VIRTUAL} |" in section
    traj, _ = load_trajectory_mcap(plan)
    assert summary["n_records"] == summary["n_setpoints"] > 0 and traj.duration_s == pytest.approx(2.0)


# ---- 8: the contract says what the code does -------------------------------------------------------


def test_gateway_doc_states_units_masters_and_function_codes():
    doc = (ROOT / "docs" / "gateway.md").read_text()

    def row(addr: int) -> str:
        return next((ln for ln in doc.splitlines() if ln.startswith(f"| {addr} | u16 |")), "")

    assert "setpoints" in row(4) and "cycles" not in row(4)
    assert "setpoints" in row(23)  # the prefill unit
    for addr in (R.CTRL_MASTER, R.ST_STOP_CAUSE, R.ST_OVERRUNS, R.ST_CLOCK):
        assert row(addr), addr
    fcs = ", ".join(str(f) for f in R.FUNCTION_CODES)
    assert f"Function codes answered: {fcs}" in doc and "exception 1" in doc
    for cause in StopCause:
        assert f"| {int(cause)} | {cause.name} |" in doc, cause
    # the buffer in seconds at R = 1 and R = 5 (4096 setpoints, 400 µs cycle)
    assert "1.64 s at R = 1" in doc and "8.19 s at R = 5" in doc
