"""Streaming rows (issue 3): realtime streaming of a long trajectory to a gateway in another process;
and (not with --quick, so never in CI) the 10-minute realtime soak of issue 14."""

from __future__ import annotations

from bench.table import Row
from rxcomm.execution.bench import bench_soak, bench_streaming


def rows(quick: bool) -> list[Row]:
    rows = [Row(**r) for r in bench_streaming(10.0 if quick else 60.0)]
    if not quick:
        rows += [Row(**r) for r in bench_soak(600.0)]
    return rows
