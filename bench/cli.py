"""CLI start row: `rxcomm --help` as a user runs it, a fresh process each time (issue 18: ≤ 0.3 s CPU).

The process is run, not imported: importing rxcomm.cli here would measure a warm interpreter. CPU is
the child's user + system time (resource.getrusage of the children), wall the process's lifetime.
"""

from __future__ import annotations

import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench.table import Row


def rxcomm_executable() -> str:
    """The console script beside this interpreter (the venv's), else the one on PATH."""
    beside = Path(sys.executable).with_name("rxcomm")
    found = str(beside) if beside.exists() else shutil.which("rxcomm")
    if found is None:
        raise FileNotFoundError("rxcomm console script not found beside the interpreter or on PATH")
    return found


def start_times(args: list[str], repeats: int) -> tuple[float, float]:
    """(median wall s, median CPU s) of `rxcomm ARGS` over `repeats` fresh processes (after one warm-up)."""
    exe = rxcomm_executable()
    subprocess.run([exe, *args], capture_output=True, check=True)  # warm the file cache
    walls, cpus = [], []
    for _ in range(repeats):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([exe, *args], capture_output=True, check=True)
        walls.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return statistics.median(walls), statistics.median(cpus)


def rows(quick: bool) -> list[Row]:
    repeats = 5 if quick else 10
    wall, cpu = start_times(["--help"], repeats)
    v_wall, v_cpu = start_times(["--version"], repeats)
    return [
        Row("cli", f"start: rxcomm --help, CPU (median of {repeats})", "s", cpu, target="≤ 0.3 s"),
        Row("cli", f"start: rxcomm --help, wall (median of {repeats})", "s", wall),
        Row("cli", f"start: rxcomm --version, CPU (median of {repeats})", "s", v_cpu, target="≤ 0.3 s"),
        Row("cli", f"start: rxcomm --version, wall (median of {repeats})", "s", v_wall),
    ]
