"""`rxcomm recover-log NAME.mcap.part`: a readable run log from what a killed `run` left behind.

`run` writes its log while the robot moves, flushing a chunk to ``NAME.mcap.part`` every 0.5 s; a
SIGKILL or a power cut of the PC leaves that file without its index and footer. This command
writes everything up to the last complete chunk as ``NAME.recovered.mcap`` (never ``NAME.mcap``: a
cut-off log is not a completed run) and warns what was recovered and what was lost.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from rxcomm import console
from rxcomm.stages.declarations import DECLARATIONS


def execute(part: Path, output: Path | None = None) -> Path:
    from rxcomm.execution.log import recover_run_log, recovered_path  # here: `--help` stays fast

    output = Path(output) if output is not None else recovered_path(part)
    DECLARATIONS["recover-log"].check(output=output, part=part)
    rec = recover_run_log(part, output)
    console.err.print(f"warning: {rec.warning()}")
    console.out.print(f"recovered run log → {rec.written}")
    return rec.written


def command(
    part: Annotated[Path, typer.Argument(help="The NAME.mcap.part a killed or stopped `run` left.")],
    output: Annotated[
        Path | None,
        typer.Option("-o", "--output", help="The recovered log (default NAME.recovered.mcap)."),
    ] = None,
) -> None:
    """Recover the run log of a killed `run` from its NAME.mcap.part, saying what was lost. Exit 2 if
    the file is not a run log."""
    console.stage_command(execute)(part, output)
