"""Run-log rows: writing and reading the MCAP of a 60 s run at 2.5 kHz (issue 18), the reader beside
the per-sample JSON it replaced.

The log is a real ``write_run_log`` file (every /run/joints field, the gateway blocks, the 3D panel's
frame transforms) of a synthetic stream: motion along a smooth joint path, a lagging actual position.
"""

from __future__ import annotations

import time
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np

from bench.table import Row, median_seconds
from rxcomm.execution.log import write_run_log
from rxcomm.execution.plan import StreamPlan
from rxcomm.execution.records import RunResult, StreamLog
from rxcomm.io.mcap_io import read_mcap
from rxcomm.io.run_log import read_run_log
from rxcomm.model.robot import load_robot
from rxcomm.schemas.run_log import GATEWAY_FIELDS, JOINTS_TOPIC

ROBOT = Path("samples/rx130l")
RATE_HZ = 2500.0


def synthetic_result(duration_s: float) -> RunResult:
    """A completed stream of ``duration_s`` at 2.5 kHz (R = 1) with a gateway block every 6 cycles."""
    dt = 1.0 / RATE_HZ
    t = np.arange(int(duration_s * RATE_HZ) + 1) * dt
    w = 2 * np.pi * np.array([0.2, 0.15, 0.25, 0.3, 0.35, 0.4])
    q = 0.3 * np.sin(np.outer(t, w))
    qd = 0.3 * np.cos(np.outer(t, w)) * w
    qdd = -0.3 * np.sin(np.outer(t, w)) * w**2
    tau = 50.0 * qdd + 20.0 * np.sign(qd)
    plan = StreamPlan(dt, q, qd, qdd, tau)
    rng = np.random.default_rng(0)
    q_actual = q - 2e-3 * qd + 1e-6 * rng.standard_normal(q.shape)
    tg = t[::6]
    k = np.arange(len(tg))
    gateway = {"t": tg} | {name: np.zeros(len(tg)) for name in GATEWAY_FIELDS}
    gateway |= {"status": np.full(len(tg), 0x27), "error": np.zeros(len(tg), dtype=int)}
    gateway |= {"execute_index": 6 * k, "write_index": 6 * k + 24, "buffer_level": np.full(len(tg), 24)}
    gateway |= {"lead_s": np.full(len(tg), 24 * dt), "round_trip_s": np.full(len(tg), 3e-4), "wall_s": tg}
    log = StreamLog(
        plan, 1, dt, q_actual, tau + rng.standard_normal(q.shape), gateway, 0, 0, 0,
        np.full(len(tg), 3e-4), duration_s, 0.1 * duration_s, True, virtual_time=True,
    )  # fmt: skip
    return RunResult("127.0.0.1:1502", 1, dt, log=log)


def bench_logs(quick: bool = False) -> dict[str, float]:
    robot = load_robot(ROBOT)
    duration = 10.0 if quick else 60.0
    result = synthetic_result(duration)
    with TemporaryDirectory() as tmp:
        path = Path(tmp) / "log.mcap"
        t0 = time.perf_counter()
        write_run_log(path, robot, result, inputs={}, settings={}, feedforward="prior", embedded_cell=True)
        write_s = time.perf_counter() - t0
        size = path.stat().st_size
        n = len(read_run_log(path).joints)
        assert n == result.log.n_records, (n, result.log.n_records)
        repeats = 3 if quick else 10
        read_s = median_seconds(lambda: read_run_log(path), repeats=repeats)
        per_message_s = median_seconds(lambda: read_mcap(path, [JOINTS_TOPIC], columns=False), repeats=1)
    return {
        "duration_s": duration,
        "samples": float(n),
        "write_s": write_s,
        "size_mb": size / 1e6,
        "read_s": read_s,
        "read_per_message_s": per_message_s,
    }


def rows(quick: bool) -> list[Row]:
    b = bench_logs(quick)
    what = f"{b['duration_s']:.0f} s at 2.5 kHz ({int(b['samples'])} samples)"
    return [
        Row(
            "run log",
            f"read a {what} (median): columns",
            "s",
            b["read_s"],
            peer_name="per-sample JSON (before)",
            peer=b["read_per_message_s"],
            target="≤ 0.3 s",
        ),
        Row("run log", f"write a {what}, incl. FK for the 3D view", "s", b["write_s"]),
        Row("run log", f"file size, {what}", "MB", b["size_mb"]),
    ]
