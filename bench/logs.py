"""Run-log rows: writing and reading the MCAP of a 60 s run at 2.5 kHz in today's layout (row messages
on the fields' grids, issue 32) beside the layouts before it (float32 rows, main before the grids;
per-sample JSON + column blocks, before issue 32), the same stream in the same run, and the joint
chunks under each chunk compression. CPU times (time.process_time) beside wall times: on the shared
machine the wall times follow the load.

The log is a real ``write_run_log`` file (every /run/joints field, the gateway blocks, the 3D panel's
frame transforms) of a synthetic stream: motion along a smooth joint path, a lagging actual position,
the actual values in the gateway's register units (1 µrad, 0.1 % of the rated torque) as a run's are.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from tempfile import TemporaryDirectory

import lz4.frame
import numpy as np
import zstandard
from mcap.reader import make_reader

from bench.table import Row, median_cpu_seconds, median_seconds
from rxcomm.execution.log import LAYOUTS, write_run_log
from rxcomm.execution.plan import StreamPlan
from rxcomm.execution.records import RunResult, StreamLog
from rxcomm.gateway import codec
from rxcomm.io.mcap_rows import chunk_records
from rxcomm.io.run_log import read_run_log
from rxcomm.model.robot import load_robot
from rxcomm.schemas.run_log import GATEWAY_FIELDS, JOINTS_TOPIC

ROBOT = Path("samples/rx130l")
RATE_HZ = 2500.0
ZSTD_LEVELS = (1, 3, 9)  # 19 takes ~9 s a minute of log for ~20 % less (docs/logs.md §2)


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


def _write(robot, result, path: Path, layout: str) -> tuple[float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    write_run_log(
        path, robot, result, inputs={}, settings={}, feedforward="prior", embedded_cell=True, layout=layout
    )
    return time.perf_counter() - t0, time.process_time() - c0


def _one_layout(robot, result, tmp: Path, layout: str, writes: int, reads: int) -> dict[str, float]:
    """Median write (wall, CPU) of ``writes`` writes, size, median read of ``reads`` reads."""
    path = Path(tmp) / f"{layout}.mcap"
    wall, cpu = zip(*(_write(robot, result, path, layout) for _ in range(writes)), strict=True)
    n = len(read_run_log(path).joints)
    assert n == result.log.n_records, (n, result.log.n_records)
    return {
        "samples": float(n),
        "write_s": statistics.median(wall),
        "write_cpu_s": statistics.median(cpu),
        "size_mb": path.stat().st_size / 1e6,
        "read_s": median_seconds(lambda: read_run_log(path), repeats=reads),
        "read_cpu_s": median_cpu_seconds(lambda: read_run_log(path), repeats=reads),
    }


def joint_chunks(path: Path) -> list[bytes]:
    """The decompressed records of every chunk of ``/run/joints`` in a run log."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        ids = {c.id for c in summary.channels.values() if c.topic == JOINTS_TOPIC}
        return [
            bytes(chunk_records(f, ci.chunk_start_offset))
            for ci in summary.chunk_indexes
            if ids & set(ci.message_index_offsets)
        ]


def chunk_codecs(path: Path) -> dict[str, dict[str, float]]:
    """The joint chunks of ``path`` under each chunk compression the mcap writers offer: size (MB),
    compress and decompress CPU time (s): what chooses the writer's compression (docs/logs.md §2)."""
    chunks = joint_chunks(path)
    codecs = {f"zstd level {lv}": zstandard.ZstdCompressor(level=lv).compress for lv in ZSTD_LEVELS}
    codecs["lz4"] = lz4.frame.compress
    out = {}
    for name, compress in codecs.items():
        c0 = time.process_time()
        packed = [compress(c) for c in chunks]
        c1 = time.process_time()
        for c, raw in zip(packed, chunks, strict=True):
            back = lz4.frame.decompress(c) if name == "lz4" else zstandard.ZstdDecompressor().decompress(c)
            assert len(back) == len(raw)
        c2 = time.process_time()
        out[name] = {"mb": sum(map(len, packed)) / 1e6, "compress_s": c1 - c0, "decompress_s": c2 - c1}
    out["none"] = {"mb": sum(map(len, chunks)) / 1e6, "compress_s": 0.0, "decompress_s": 0.0}
    return out


def bench_logs(quick: bool = False) -> dict[str, dict[str, float]]:
    """Every layout of the same stream, in one run: "rows" (now), "rows-float32" (issue 32's first
    step, main before the grids) and "json-columns" (before issue 32); and the joint chunks of "rows"
    under each chunk compression."""
    robot = load_robot(ROBOT)
    duration = 10.0 if quick else 60.0
    result = synthetic_result(duration, robot.tau_cont)  # actual values in register units, as a run's
    reads = 3 if quick else 10
    with TemporaryDirectory() as tmp:
        _write(robot, synthetic_result(1.0), Path(tmp) / "warm-up.mcap", "rows")  # imports, first calls
        out = {
            layout: _one_layout(
                robot, result, Path(tmp), layout, 1 if quick or "json" in layout else 3, reads
            )
            for layout in LAYOUTS
        }
        codecs = chunk_codecs(Path(tmp) / "rows.mcap")
    out["rows"]["duration_s"] = duration
    return out | {f"chunks: {k}": v for k, v in codecs.items()}


def rows(quick: bool) -> list[Row]:
    b = bench_logs(quick)
    new, main, old = b["rows"], b["rows-float32"], b["json-columns"]
    duration = new["duration_s"]
    what = f"{duration:.0f} s at 2.5 kHz"
    before = "before: float32 rows (main)"
    realtime = {
        k: {w: duration / v[w] for w in ("write_cpu_s", "write_s")} for k, v in b.items() if "mb" not in v
    }
    out = [
        Row(
            "run log",
            f"file size, {what} ({int(new['samples'])} samples)",
            "MB",
            new["size_mb"],
            peer_name=before,
            peer=main["size_mb"],
            target=f"≤ {15 * duration / 60:.3g} MB",
        ),
        Row(
            "run log",
            f"file size, {what}, against the layout before issue 32",
            "MB",
            new["size_mb"],
            peer_name="JSON per sample + columns",
            peer=old["size_mb"],
        ),
        Row(
            "run log",
            f"write a {what}, CPU time as × realtime (median)",
            "×",
            realtime["rows"]["write_cpu_s"],
            peer_name=before,
            peer=realtime["rows-float32"]["write_cpu_s"],
            target="≥ 30×",
        ),
        Row(
            "run log",
            f"write a {what}, wall as × realtime (load-dependent)",
            "×",
            realtime["rows"]["write_s"],
            peer_name=before,
            peer=realtime["rows-float32"]["write_s"],
            target="≥ 30×",
        ),
        Row(
            "run log",
            "write, layout before issue 32, CPU as × realtime",
            "×",
            realtime["rows"]["write_cpu_s"],
            peer_name="JSON per sample + columns",
            peer=realtime["json-columns"]["write_cpu_s"],
        ),
        Row(
            "run log",
            f"read a {what} (median), CPU time",
            "s",
            new["read_cpu_s"],
            peer_name=before,
            peer=main["read_cpu_s"],
            target="≤ 0.15 s",
        ),
        Row(
            "run log",
            f"read a {what} (median), wall",
            "s",
            new["read_s"],
            peer_name=before,
            peer=main["read_s"],
            target="≤ 0.15 s",
        ),
        Row(
            "run log",
            "read, layout before issue 32 (median), CPU time",
            "s",
            new["read_cpu_s"],
            peer_name="JSON per sample + columns",
            peer=old["read_cpu_s"],
        ),
    ]
    none = b["chunks: none"]["mb"]
    for name in [f"zstd level {lv}" for lv in ZSTD_LEVELS] + ["lz4"]:
        c = b[f"chunks: {name}"]
        out.append(
            Row(
                "run log",
                f"joint chunks ({none:.1f} MB) as {name}: compress {c['compress_s']:.2f} s, "
                f"decompress {c['decompress_s']:.3f} s CPU",
                "MB",
                c["mb"],
                target="the writer's: zstd 3" if name == "zstd level 3" else "",
            )
        )
    return out  # fmt: skip
