"""Streaming rows (issue 3): realtime streaming of a long trajectory to a gateway in another process."""

from __future__ import annotations

from bench.table import Row
from rxcomm.execution.bench import bench_streaming


def rows(quick: bool) -> list[Row]:
    return [Row(**r) for r in bench_streaming(10.0 if quick else 60.0)]
