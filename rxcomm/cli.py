"""The `rxcomm` command: one subcommand per stage (architecture §9).

This is the composition root: the only library module that imports `rxcomm.stages`. Each stage
module exposes a typer command function; registering it here is all a new stage needs.
"""

from __future__ import annotations

from typing import Annotated

import typer

from rxcomm import __version__
from rxcomm.stages import (
    accept,
    calibrate,
    cell_sim,
    excite,
    export,
    identify,
    import_tracker,
    iso9283,
    plan_cp,
    plan_cycles,
    plan_poses,
    plan_ptp,
    recover_log,
    report,
    robot_info,
    run,
    select_configs,
)

app = typer.Typer(
    name="rxcomm",
    help="Commissioning pipeline for 6-axis industrial robots: calibration, dynamic identification, "
    "time/energy-optimal planning and model-based execution. Every stage reads and writes files.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"rxcomm {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """rxcomm: commission a robot step by step, each step one subcommand."""


# Stage registrations (one line each).
app.command("robot-info")(robot_info.command)
app.command("select-configs")(select_configs.command)
app.command("calibrate")(calibrate.command)
app.command("run")(run.command)
app.command("cell-sim")(cell_sim.command)
app.command("excite")(excite.command)
app.command("identify")(identify.command)
app.command("plan-cp")(plan_cp.command)
app.command("plan-ptp")(plan_ptp.command)
app.command("report")(report.command)
app.command("recover-log")(recover_log.command)
app.command("accept")(accept.command)
app.command("iso9283")(iso9283.command)
app.command("plan-poses")(plan_poses.command)
app.command("plan-cycles")(plan_cycles.command)
app.command("import-tracker")(import_tracker.command)
app.command("export")(export.command)


def main() -> None:
    app()
