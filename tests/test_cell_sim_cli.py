"""`rxcomm cell-sim` and `start_embedded_cell`: start on an ephemeral loopback port, answer a client,
stop on a bounded duration, SIGTERM or a stop event. Hard timeouts everywhere; 127.0.0.1 only."""

from __future__ import annotations

import faulthandler
import re
import subprocess
import sys
import threading

import numpy as np
import pytest
from typer.testing import CliRunner

from rxcomm.cell.sim import start_embedded_cell
from rxcomm.cli import app
from rxcomm.gateway import registers as R
from rxcomm.gateway.client import GatewayClient
from rxcomm.model.robot import load_robot
from rxcomm.stages import cell_sim

from .conftest import SAMPLES

TRUTH = SAMPLES / "rx130l" / "truth.yaml"
Q_VISIBLE = (-0.4, 0.2, 1.2, 0.0, 0.8, 0.0)
CLI = [sys.executable, "-c", "from rxcomm.cli import main; main()"]


@pytest.fixture(autouse=True)
def hard_timeout():
    faulthandler.dump_traceback_later(60, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


def _port_from(line: str) -> int:
    m = re.search(r"listening on 127\.0\.0\.1:(\d+)", line)
    assert m, line
    return int(m.group(1))


def _check_identity(port: int) -> None:
    with GatewayClient("127.0.0.1", port, timeout_s=1.0).connect() as c:
        ident = c.identity()
        assert ident.n_axes == 6 and ident.cycle_us == 400 and ident.map_version == R.MAP_VERSION
        np.testing.assert_allclose(c.rated_torque_nm, load_robot(SAMPLES / "rx130l").tau_cont, atol=1e-3)


@pytest.mark.slow  # a fresh interpreter importing the whole CLI: ~10 s on a loaded VM
def test_cell_sim_serves_then_stops_after_its_duration():
    proc = subprocess.Popen(
        [*CLI, "cell-sim", "--truth", str(TRUTH), "--port", "0", "--duration-s", "3"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        first = proc.stdout.readline()
        assert "map v1" in first
        _check_identity(_port_from(first))
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert proc.returncode == 0, err
    assert "cell stopped" in out


@pytest.mark.slow  # a fresh interpreter importing the whole CLI: ~10 s on a loaded VM
def test_cell_sim_stops_cleanly_on_sigterm():
    proc = subprocess.Popen(
        [*CLI, "cell-sim", "--truth", str(TRUTH), "--port", "0", "--realtime", "--duration-s", "30"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _check_identity(_port_from(proc.stdout.readline()))
        proc.terminate()
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert proc.returncode == 0, err
    m = re.search(r"cell stopped after (\d+) drive cycles", out)
    assert m and int(m.group(1)) > 0  # realtime: the cycles ran while it served


@pytest.mark.socket
def test_stage_function_serves_until_stopped():
    facts: list[dict] = []
    ready, stop = threading.Event(), threading.Event()

    def serve():
        cell_sim.run(
            TRUTH,
            port=0,
            q0=",".join(map(str, Q_VISIBLE)),
            on_ready=lambda f: (facts.append(f), ready.set()),
            stop=stop,
        )

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        assert ready.wait(20)
        port = int(facts[0]["address"].rsplit(":", 1)[1])
        with GatewayClient("127.0.0.1", port, timeout_s=1.0).connect() as c:
            c.identity()
            np.testing.assert_allclose(c.positions_rad(), Q_VISIBLE, atol=1e-6)
            assert c.read_tracker() is not None  # standing still, the probe faces the tracker
    finally:
        stop.set()
        t.join(20)
    assert not t.is_alive()
    assert facts[0]["q0_rad"] == pytest.approx(Q_VISIBLE) and facts[0]["cycle_us"] == 400


@pytest.mark.socket
def test_embedded_cell_for_run():
    srv = start_embedded_cell(TRUTH, port=0, q0=Q_VISIBLE)  # started: the caller stops it
    try:
        assert srv.port > 0 and srv.host == "127.0.0.1"
        with GatewayClient("127.0.0.1", srv.port, timeout_s=1.0).connect() as c:
            c.identity()
            c.enable_all()
            np.testing.assert_allclose(c.positions_rad(), Q_VISIBLE, atol=1e-6)
            c.disable_all()
    finally:
        srv.stop()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--host", "0.0.0.0"], "--allow-remote"),
        (["--start", "0,0,0"], "--start"),
        (["--start", "0,0,0,0,3.0,0"], "joint_5"),
        (["--duration-s", "-1"], "--duration-s"),
    ],
)
def test_bad_options_exit_2_with_the_reason(args, needle):
    r = CliRunner().invoke(app, ["cell-sim", "--truth", str(TRUTH), "--port", "0", *args])
    assert r.exit_code == 2, r.output
    assert needle in r.output


def test_bad_truth_file_exits_2_naming_file_and_field(tmp_path):
    bad = tmp_path / "truth.yaml"
    bad.write_text(TRUTH.read_text().replace("kind: rxcomm/CellTruth", "kind: rxcomm/Nope"))
    r = CliRunner().invoke(app, ["cell-sim", "--truth", str(bad), "--port", "0", "--duration-s", "1"])
    assert r.exit_code == 2 and "truth.yaml" in r.output and "kind" in r.output
