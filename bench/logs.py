"""Run-log rows: writing and reading the MCAP of a 60 s run at 2.5 kHz in the row layout (issue 32)
beside the layout before it (per-sample JSON + column blocks), the same stream in the same run. CPU
times (time.process_time) beside wall times: on the shared machine the wall times follow the load.

The log is a real ``write_run_log`` file (every /run/joints field, the gateway blocks, the 3D panel's
frame transforms) of a synthetic stream: motion along a smooth joint path, a lagging actual position.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np

from bench.table import Row, median_seconds
from rxcomm.execution.log import LAYOUTS, write_run_log
from rxcomm.execution.plan import StreamPlan
from rxcomm.execution.records import RunResult, StreamLog
from rxcomm.gateway import codec
from rxcomm.io.run_log import read_run_log
from rxcomm.model.robot import load_robot
from rxcomm.schemas.run_log import GATEWAY_FIELDS

ROBOT = Path("samples/rx130l")
RATE_HZ = 2500.0


def synthetic_result(duration_s: float, rated_nm: np.ndarray | None = None) -> RunResult:
    """A completed stream of ``duration_s`` at 2.5 kHz (R = 1) with a gateway block every 6 cycles.
    With ``rated_nm`` (the drives' rated torques) the actual values come in the gateway's register
    units, as a real run's do: positions in counts of 1 µrad, torques in counts of 0.1 % rated."""
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
    tau_actual = tau + rng.standard_normal(q.shape)
    if rated_nm is not None:
        q_actual = codec.counts_to_rad(codec.rad_to_counts(q_actual))
        tau_actual = codec.torque_counts_to_nm(codec.nm_to_torque_counts(tau_actual, rated_nm), rated_nm)
    tg = t[::6]
    k = np.arange(len(tg))
    gateway = {"t": tg} | {name: np.zeros(len(tg)) for name in GATEWAY_FIELDS}
    gateway |= {"status": np.full(len(tg), 0x27), "error": np.zeros(len(tg), dtype=int)}
    gateway |= {"execute_index": 6 * k, "write_index": 6 * k + 24, "buffer_level": np.full(len(tg), 24)}
    gateway |= {"lead_s": np.full(len(tg), 24 * dt), "round_trip_s": np.full(len(tg), 3e-4), "wall_s": tg}
    log = StreamLog(
        plan, 1, dt, q_actual, tau_actual, gateway, 0, 0, 0,
        np.full(len(tg), 3e-4), duration_s, 0.1 * duration_s, True, virtual_time=True,
    )  # fmt: skip
    return RunResult("127.0.0.1:1502", 1, dt, log=log)


def _one_layout(robot, result, tmp: Path, layout: str, repeats: int) -> dict[str, float]:
    path = Path(tmp) / f"{layout}.mcap"
    t0, c0 = time.perf_counter(), time.process_time()
    write_run_log(
        path, robot, result, inputs={}, settings={}, feedforward="prior", embedded_cell=True, layout=layout
    )
    write_s, write_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    n = len(read_run_log(path).joints)
    assert n == result.log.n_records, (n, result.log.n_records)
    cpu = []
    for _ in range(repeats):
        c0 = time.process_time()
        read_run_log(path)
        cpu.append(time.process_time() - c0)
    return {
        "samples": float(n),
        "write_s": write_s,
        "write_cpu_s": write_cpu_s,
        "size_mb": path.stat().st_size / 1e6,
        "read_s": median_seconds(lambda: read_run_log(path), repeats=repeats),
        "read_cpu_s": statistics.median(cpu),
    }


def bench_logs(quick: bool = False) -> dict[str, dict[str, float]]:
    """Both layouts of the same stream: "rows" (issue 32) and "json-columns" (before it)."""
    robot = load_robot(ROBOT)
    duration = 10.0 if quick else 60.0
    result = synthetic_result(duration)
    repeats = 3 if quick else 10
    with TemporaryDirectory() as tmp:
        out = {layout: _one_layout(robot, result, Path(tmp), layout, repeats) for layout in LAYOUTS}
    out["rows"]["duration_s"] = duration
    return out


def rows(quick: bool) -> list[Row]:
    b = bench_logs(quick)
    new, old = b["rows"], b["json-columns"]
    duration = new["duration_s"]
    what = f"{duration:.0f} s at 2.5 kHz ({int(new['samples'])} samples)"
    before = "before: JSON per sample + columns"
    return [
        Row("run log", f"file size, {what}", "MB", new["size_mb"], peer_name=before, peer=old["size_mb"],
            target=f"≤ {15 * duration / 60:.3g} MB"),
        Row("run log", f"write a {what}, CPU time", "s", new["write_cpu_s"], peer_name=before,
            peer=old["write_cpu_s"], target=f"≤ {duration / 30:.3g} s (30x realtime)"),
        Row("run log", f"write a {what}, wall (load-dependent)", "s", new["write_s"], peer_name=before,
            peer=old["write_s"]),
        Row("run log", f"read a {what} (median), CPU time", "s", new["read_cpu_s"], peer_name=before,
            peer=old["read_cpu_s"], target="≤ 0.15 s"),
        Row("run log", f"read a {what} (median), wall", "s", new["read_s"], peer_name=before,
            peer=old["read_s"]),
    ]  # fmt: skip
