"""`rxcomm import-tracker LOG.mcap --tracker-csv FILE`: a real tracker's export joins the run log it measured.

The CSV (docs/tracker-csv.md: the tracker's own time stamps, TCP position and optionally orientation
in the tracker frame, optionally the stream-start trigger's stamp) is put on the log's time axis by
the trigger and/or the cross-correlation of the TCP velocities with FK of the encoders
(`--alignment`), and written with the log as ``-o NAME.mcap`` (+ ``NAME.yaml``): the same
``/run/tracker`` channel the simulated cell's tracker fills during `run`, so `iso9283` reads both.
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from rxcomm import console
from rxcomm.io.files import mcap_summary_path
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.options import RobotDir
from rxcomm.schemas.run_log import RunLog, TrackerChannel
from rxcomm.stages.declarations import DECLARATIONS


class Alignment(StrEnum):
    auto = "auto"
    trigger = "trigger"
    cross_correlation = "cross-correlation"


def execute(
    log: Path, tracker_csv: Path, robot_dir: Path, output: Path, alignment: str = "auto"
) -> TrackerChannel:
    """The stage as a function (tests call it): returns the channel record written. Raises RxcommError."""
    from rxcomm.acceptance.alignment import tracker_channel
    from rxcomm.execution.tracker_log import attach_tracker
    from rxcomm.io.run_log import read_run_log
    from rxcomm.io.tracker_csv import read_tracker_csv
    from rxcomm.model.robot import load_robot

    log, tracker_csv, output = Path(log), Path(tracker_csv), Path(output)
    DECLARATIONS["import-tracker"].check(output=output, log=log, tracker_csv=tracker_csv, robot=robot_dir)
    robot = load_robot(robot_dir)
    export = read_tracker_csv(tracker_csv)
    data = read_run_log(log, fields=("q_actual",))
    sample_s = read_yaml_artefact(mcap_summary_path(log), RunLog).sample_s
    channel = tracker_channel(
        robot, export, data.joints.q_actual, sample_s, method=alignment, source_file=tracker_csv.name
    )
    written = attach_tracker(
        log,
        output,
        export.t_s,
        export.position_m,
        export.quaternion_wxyz,
        channel,
        {"tracker csv": tracker_csv},
    )
    rows = {
        "alignment": channel.alignment,
        "offset_s": channel.offset_s,
        "trigger_offset_s": channel.trigger_offset_s
        if channel.trigger_offset_s is not None
        else "no trigger",
        "correlation": channel.correlation if channel.correlation is not None else "not used",
        "rate_hz": channel.rate_hz,
    }
    console.summary_table(f"tracker → {written}", rows)
    return channel


def command(
    log: Annotated[
        Path, typer.Argument(help="The run log NAME.mcap (NAME.yaml beside it) the tracker measured.")
    ],
    tracker_csv: Annotated[
        Path, typer.Option("--tracker-csv", help="The tracker's export (docs/tracker-csv.md).")
    ],
    robot: RobotDir,
    output: Annotated[
        Path, typer.Option("-o", "--output", help="The run log with /run/tracker (NAME.mcap).")
    ],
    alignment: Annotated[
        Alignment,
        typer.Option(help="trigger (its stamp), cross-correlation (TCP velocities), auto (trigger refined)."),
    ] = Alignment.auto,
) -> None:
    """Put a real tracker's CSV export on a run log's time axis and write the log with its /run/tracker
    channel, for `rxcomm iso9283`. Exit 2 on bad input or when no alignment is found.

    Example: rxcomm import-tracker line.mcap --tracker-csv line-tracker.csv --robot samples/rx130l
    -o line-tracked.mcap"""
    console.stage_command(execute)(log, tracker_csv, robot, output, alignment.value)
