"""Streaming figures in realtime mode: underruns, round trips, the master's CPU share (architecture §8).

``bench_streaming`` serves a gateway in a **separate process** (so the process CPU time measured here is
the master's alone: encode, FC23 round trips, trace decode, recording), wall-clock paced at 400 µs,
and streams ``duration_s`` of trajectory through the same session `rxcomm run` uses. Rows are plain
dicts with the fields of ``bench.table.Row`` (stage, metric, unit, ours, paper, target): the library
does not import the bench package.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from rxcomm.errors import GatewayError
from rxcomm.execution.log import RunLogWriter
from rxcomm.execution.plan import prepare_plan
from rxcomm.execution.session import RunSettings
from rxcomm.execution.trajectory_run import run_trajectory
from rxcomm.gateway.client import GatewayClient
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.dynamics import prior_parameters
from rxcomm.model.robot import Robot, load_robot

SAMPLE_ROBOT = Path(__file__).resolve().parents[2] / "samples" / "rx130l"

# The server process: prints its port, serves until its stdin closes.
_SERVER = """
import sys, numpy as np
from rxcomm.cell.server import CellServer, ServerConfig, TimeMode
kind, truth = sys.argv[1], sys.argv[4]
q0, rated = (np.array([float(x) for x in a.split(",")]) for a in sys.argv[2:4])
if kind in ("sim", "mujoco"):
    from rxcomm.cell.sim import start_embedded_cell
    srv = start_embedded_cell(truth, realtime=True, q0=q0, plant="mujoco" if kind == "mujoco" else "own")
else:
    from rxcomm.cell.backend import IdealBackend
    config = ServerConfig(time_mode=TimeMode.REALTIME)
    srv = CellServer(IdealBackend(q0, rated_torque_nm=rated), config).start()
print(srv.port, flush=True)
sys.stdin.read()
print(srv.resyncs, srv.max_late_s, flush=True)
srv.stop()
"""


def back_and_forth(robot: Robot, q0: np.ndarray, duration_s: float, period_s: float = 4.0) -> Trajectory:
    """Rest-to-rest swings q0 → q0 + dq → q0 every ``period_s`` for ``duration_s`` (a multiple of it),
    sampled at the drive cycle, within about a third of the speed and acceleration limits."""
    dt = robot.drives.cycle_s
    duration_s = period_s * max(1, round(duration_s / period_s))
    t = np.arange(int(round(duration_s / dt)) + 1) * dt
    w = 2 * np.pi / period_s
    # amplitude: peak speed dq·w/2 ≤ v_max/3 and peak acceleration dq·w²/2 ≤ a_max/3
    dq = np.minimum(np.minimum(2 * robot.v_max / (3 * w), 2 * robot.a_max / (3 * w * w)), 0.8)
    s, sd, sdd = 0.5 - 0.5 * np.cos(w * t), 0.5 * w * np.sin(w * t), 0.5 * w * w * np.cos(w * t)
    return Trajectory(t, q0 + np.outer(s, dq), np.outer(sd, dq), np.outer(sdd, dq))


def _csv(values: np.ndarray) -> str:
    return ",".join(repr(float(v)) for v in values)


def bench_streaming(
    duration_s: float = 60.0,
    *,
    robot_dir: str | Path = SAMPLE_ROBOT,
    backend: str = "ideal",
    interpolation_ratio: int | None = None,
) -> list[dict[str, Any]]:
    """Stream ``duration_s`` of trajectory to a realtime gateway in another process; one row per figure.

    ``backend``: "ideal" (the protocol double: measures streaming alone), "sim" (the simulated cell,
    whose physics must then keep up with 2.5 kHz on this machine too) or "mujoco" (the simulated cell
    on the MuJoCo plant).
    """
    robot = load_robot(robot_dir)
    q0 = np.array([0.0, -0.3, 1.2, 0.0, 0.6, 0.0])
    traj = back_and_forth(robot, q0, duration_s)
    params = prior_parameters(robot)
    t_prep = time.perf_counter()
    plan = prepare_plan(robot, traj, params, robot.drives.cycle_s)
    prep_s = time.perf_counter() - t_prep
    truth = str(Path(robot_dir) / "truth.yaml")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            _SERVER,
            backend,
            _csv(q0),
            _csv(robot.tau_max),
            truth,
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdin is not None
        line = proc.stdout.readline()
        if not line.strip().isdigit():
            raise GatewayError(f"bench gateway process did not start (said {line!r})")
        port = int(line)
        with GatewayClient("127.0.0.1", port, timeout_s=1.0) as client:
            settings = RunSettings(stream={"interpolation_ratio": interpolation_ratio})
            result = run_trajectory(client, robot, plan, params, settings)
        proc.stdin.close()
        tail = proc.stdout.read().split()
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
    log = result.log
    if log is None or log.n_records == 0:
        raise GatewayError(f"bench stream failed before streaming: {result.error}")
    rts = log.round_trips_s
    resyncs = int(tail[0]) if tail else -1
    label = f"{duration_s:g} s realtime, {backend} backend, R = {result.ratio}"
    stopped = "" if result.error is None else f": stopped, {result.error}"
    rows = [
        (f"trajectory completed{stopped}", "", float(result.error is None), "1"),
        ("underruns", "", float(log.underruns), "0"),
        ("lost trace records", "", float(log.lost_records), "0"),
        ("FC23 round trip p50", "s", float(np.percentile(rts, 50)), "≤ 2.4 ms per block"),
        ("FC23 round trip p99", "s", float(np.percentile(rts, 99)), "< buffered lead"),
        ("master CPU share (process CPU / wall)", "", log.cpu_s / log.wall_s, "< 1 core"),
        ("min buffered lead while feeding", "s", log.min_lead_s(), "≥ 0.1 s"),
        ("stream wall time / trajectory time", "", log.wall_s / plan.duration_s, "≈ 1"),
        ("trajectory streamed", "s", log.n_records * log.plan.sample_s, f"{plan.duration_s:g} s"),
        ("plan preparation (resample, τ_ff, dense check)", "s", prep_s, ""),
        ("gateway schedule resyncs", "", float(resyncs), "0"),
    ]
    return [
        {
            "stage": "run",
            "metric": f"{m} ({label})",
            "unit": u,
            "ours": v,
            "paper": "400 µs cycle",
            "target": tgt,
        }
        for m, u, v, tgt in rows
    ]


def _rss_bytes(pid: int) -> float:
    """Resident set size of a process (Linux /proc), bytes; NaN where unavailable."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return float("nan")


def bench_soak(
    duration_s: float = 600.0,
    stream_s: float = 60.0,
    *,
    robot_dir: str | Path = SAMPLE_ROBOT,
    backend: str = "ideal",
) -> list[dict[str, Any]]:
    """Realtime soak: the same ``stream_s`` trajectory streamed back to back for ``duration_s`` over one
    connection to a realtime gateway in another process (enable, stream, disable each time, as
    `run` does, each stream written as a run log while it runs, as `run` does, then deleted),
    looking for what only time shows: underruns, lost records, the cell's own cycle overruns, the
    round-trip tail, and memory growth (RSS) of master and cell after the first minute (a leak grows
    without bound; a plateau is allocation warming up). Of each stream only its figures are kept."""
    robot = load_robot(robot_dir)
    q0 = np.array([0.0, -0.3, 1.2, 0.0, 0.6, 0.0])
    params = prior_parameters(robot)
    plan = prepare_plan(robot, back_and_forth(robot, q0, stream_s), params, robot.drives.cycle_s)
    n_streams = max(1, round(duration_s / plan.duration_s))
    truth = str(Path(robot_dir) / "truth.yaml")
    proc = subprocess.Popen(
        [sys.executable, "-c", _SERVER, backend, _csv(q0), _csv(robot.tau_max), truth],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    me = os.getpid()
    samples: list[tuple[float, float, float]] = []  # (wall s since start, master RSS, cell RSS)
    logs: list[tuple[int, int, int | None, np.ndarray]] = []  # underruns, lost, overruns, round trips
    errors = []
    try:
        assert proc.stdout is not None and proc.stdin is not None
        line = proc.stdout.readline()
        if not line.strip().isdigit():
            raise GatewayError(f"bench gateway process did not start (said {line!r})")
        t0 = time.perf_counter()
        samples.append((0.0, _rss_bytes(me), _rss_bytes(proc.pid)))
        with (
            GatewayClient("127.0.0.1", int(line), timeout_s=1.0) as client,
            tempfile.TemporaryDirectory() as tmp,
        ):
            for i in range(n_streams):
                writer = RunLogWriter(
                    Path(tmp) / f"soak-{i}.mcap", robot, inputs={}, settings={}, feedforward="prior",
                    embedded_cell=False,
                )  # fmt: skip
                result = run_trajectory(client, robot, plan, params, RunSettings(), sink=writer)
                written, _ = writer.close(result)
                written.unlink()
                written.with_suffix(".yaml").unlink(missing_ok=True)
                lg = result.log
                if lg is not None:
                    logs.append((lg.underruns, lg.lost_records, lg.overruns, lg.round_trips_s))
                if result.error is not None:
                    errors.append(str(result.error))
                    break
                samples.append((time.perf_counter() - t0, _rss_bytes(me), _rss_bytes(proc.pid)))
        proc.stdin.close()
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
    wall = samples[-1][0]
    # growth after the first minute: from the first sample at ≥ 60 s (or the first stream's end)
    first = next((s for s in samples if s[0] >= 60.0), samples[min(1, len(samples) - 1)])
    last = samples[-1]

    def growth(k: int) -> float:
        return (last[k] - first[k]) / first[k] if first is not last else float("nan")

    rts = np.concatenate([lg[3] for lg in logs]) if logs else np.zeros(0)
    overruns = [lg[2] for lg in logs]
    label = f"{wall:.0f} s realtime soak, {len(logs)} × {plan.duration_s:g} s, {backend} backend"
    stopped = "" if not errors else f": stopped, {errors[0]}"
    rows = [
        (f"streams completed{stopped}", "", float(len(logs) - len(errors)), f"{n_streams}"),
        ("underruns", "", float(sum(lg[0] for lg in logs)), "0"),
        ("lost trace records", "", float(sum(lg[1] for lg in logs)), "0"),
        (
            "cell cycle overruns (cycles started > 1 cycle late)",
            "",
            float(sum(overruns)) if None not in overruns else float("nan"),
            "reported",
        ),
        ("FC23 round trip p99", "s", float(np.percentile(rts, 99)) if rts.size else float("nan"), "< lead"),
        ("master RSS growth after the first minute", "%", 100 * growth(1), "≤ 10 %"),
        ("cell RSS growth after the first minute", "%", 100 * growth(2), "≤ 10 %"),
        ("master RSS at the end", "MB", last[1] / 1e6, ""),
        ("cell RSS at the end", "MB", last[2] / 1e6, ""),
    ]
    return [
        {"stage": "run", "metric": f"{m} ({label})", "unit": u, "ours": v, "paper": "", "target": tgt}
        for m, u, v, tgt in rows
    ]


if __name__ == "__main__":  # python -m rxcomm.execution.bench [seconds] [ideal|sim] [soak]
    secs = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    kind = sys.argv[2] if len(sys.argv) > 2 else "ideal"
    bench = bench_soak if sys.argv[3:4] == ["soak"] else bench_streaming
    for row in bench(secs, backend=kind):
        print(f"{row['metric']:<100} {row['ours']:.6g} {row['unit']}")
