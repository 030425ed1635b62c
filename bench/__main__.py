"""`make bench`: one table of every stage's compute time and quality figure against the paper and a peer.

Machines are shared and noisy: every timing is a median over repeats, and each peer runs in the same
process right beside ours so their ratio is meaningful.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as rxcomm does; set before numpy loads

import argparse
import importlib
import sys
import traceback

from rich.console import Console
from rich.table import Table

from bench.table import Row

# Each module exposes `rows(quick: bool) -> list[Row]`.
SECTIONS = [
    "bench.cli",
    "bench.foundation",
    "bench.calibration",
    "bench.run",
    "bench.plant",
    "bench.identification",
    "bench.logs",
    "bench.plan_ptp",
    "bench.plan_cp",
    "bench.acceptance",
    "bench.iso9283",
]


def _fmt(x: float | None, unit: str) -> str:
    if x is None:
        return "—"
    if unit == "s" and x < 1e-3:
        return f"{x * 1e6:.1f} µs"
    if unit == "s" and x < 1:
        return f"{x * 1e3:.2f} ms"
    return f"{x:.4g} {unit}".strip()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer repeats and smaller problems (CI)")
    ap.add_argument("--only", nargs="*", help="section module names to run")
    args = ap.parse_args()
    rows: list[Row] = []
    failed = []
    for name in args.only or SECTIONS:
        try:
            rows += importlib.import_module(name).rows(args.quick)
        except Exception:  # a broken section must not hide the others' numbers; it is reported below
            failed.append(name)
            traceback.print_exc()
    table = Table(title="rxcomm benchmarks (medians; ratio = ours / peer)")
    for col in ("stage", "metric", "ours", "target", "paper", "peer", "peer value", "ratio"):
        table.add_column(col)
    for r in rows:
        table.add_row(
            r.stage,
            r.metric,
            _fmt(r.ours, r.unit),
            r.target,
            r.paper,
            r.peer_name,
            _fmt(r.peer, r.unit),
            "—" if r.ratio is None else f"{r.ratio:.3g}",
        )
    Console(width=240).print(table)
    if failed:
        print(f"sections that failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
