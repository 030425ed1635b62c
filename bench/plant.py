"""The MuJoCo plant beside ours (issue 26): cost per drive cycle of the plant alone and of the whole
simulated cell (drives, noise, tracker sampling) while the arm swings, and a realtime stream on it."""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from bench.table import Row
from rxcomm.cell.sim import simulated_cell
from rxcomm.execution.bench import bench_streaming

TRUTH = Path(__file__).resolve().parents[1] / "samples" / "rx130l" / "truth.yaml"
Q0 = np.array([0.0, -0.3, 1.2, 0.0, 0.6, 0.0])


def _per_cycle(plant: str, cycles: int, repeats: int) -> tuple[float, float]:
    """Median seconds per drive cycle (whole cell, plant step alone) over a 1 Hz swing of every joint."""
    cell = simulated_cell(TRUTH, plant=plant, q0=Q0)
    dt = cell.cycle_s
    on = np.ones(6, dtype=bool)
    amplitude = np.array([0.3, 0.2, 0.2, 0.4, 0.4, 0.6])
    whole, alone = [], []
    k = 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(cycles):
            demand = Q0 + amplitude * 0.5 * (1 - np.cos(2 * np.pi * k * dt))
            cell.cycle(demand, np.zeros(6), on)
            k += 1
        whole.append((time.perf_counter() - t0) / cycles)
        tau = cell.drives.control(Q0, np.zeros(6), on)
        t0 = time.perf_counter()
        for _ in range(cycles // 4):
            cell.plant.step(tau, ~on)
        alone.append((time.perf_counter() - t0) / (cycles // 4))
    return statistics.median(whole), statistics.median(alone)


def rows(quick: bool) -> list[Row]:
    cycles, repeats = (500, 3) if quick else (2500, 5)
    own_cell, own_plant = _per_cycle("own", cycles, repeats)
    mj_cell, mj_plant = _per_cycle("mujoco", cycles, repeats)
    out = [
        Row("cell", "MuJoCo plant step per drive cycle (RX130L, moving)", "s", mj_plant, target="< 400 µs",
            peer_name="own plant", peer=own_plant),
        Row("cell", "MuJoCo cell cycle (drives + plant + tracker), swinging", "s", mj_cell, target="< 400 µs",
            peer_name="own cell", peer=own_cell),
    ]  # fmt: skip
    # the same realtime stream on both plants: the MuJoCo one's figures with our plant's as the peer
    duration = 10.0 if quick else 60.0
    own = bench_streaming(duration, backend="sim")
    for r, peer in zip(bench_streaming(duration, backend="mujoco"), own, strict=True):
        out.append(Row(**r, peer_name="own plant", peer=peer["ours"]))
    return out
