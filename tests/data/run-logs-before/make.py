"""Writes the run-log fixtures of the layouts before the grids (issue 32) with the code of that time.

Run once from a checkout of main before the change (d1f9a8e), so the files come from the old writer
itself, not from a layout switch of the new one:

    PYTHONPATH=/path/to/old/checkout .venv/bin/python tests/data/run-logs-before/make.py

It writes ``rows.mcap`` (one float32 protobuf message per sample) and ``json-columns.mcap`` (per-sample
JSON + float64 column blocks, before issue 32), each with its ``.yaml``, from the stream of
``bench.logs.synthetic_result(DURATION_S, rated)``; tests/test_run_log_rows.py reads them beside
the same stream written by today's writer.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import rxcomm
from rxcomm.execution.log import write_run_log
from rxcomm.model.robot import load_robot

DURATION_S = 0.1
HERE = Path(__file__).parent
# the stream generator of this checkout (the old one has no register-unit rounding), by file path so
# that rxcomm itself comes from the old checkout on PYTHONPATH
_spec = importlib.util.spec_from_file_location("bench_logs_now", HERE.parents[2] / "bench" / "logs.py")
assert _spec is not None and _spec.loader is not None
_bench_logs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_bench_logs)
synthetic_result = _bench_logs.synthetic_result


def main() -> None:
    robot = load_robot("samples/rx130l")
    result = synthetic_result(DURATION_S, robot.tau_cont)
    print("writer:", rxcomm.__file__)
    for layout in ("rows", "json-columns"):
        path = HERE / f"{layout}.mcap"
        write_run_log(
            path,
            robot,
            result,
            inputs={},
            settings={},
            feedforward="prior",
            embedded_cell=True,
            layout=layout,
        )
        print(path, path.stat().st_size)


if __name__ == "__main__":
    main()
