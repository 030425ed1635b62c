"""`rxcomm score`: an identified model scored on another log without refitting (paper §4.3).

Reads the robot, a `dynamics.yaml` (kind rxcomm/Dynamics) and a joint log (`run`'s MCAP or a robot
CSV), and prints the validation figures `identify` gives (RMS, NRMSE, R² per joint on the rows where
the joint moves), with the model's own processing (cut-off, friction model). `-o` writes the model
again with this log's validation figures; `--torques-out` the measured and predicted torques per row.
Was `identify --dynamics D --validate LOG` (a hidden alias now, with a deprecation note).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from rxcomm.options import Dynamics, JointLog, RobotDir
from rxcomm.stages.identify import CalibrationOption, TorquesOut, score_run


def command(
    robot_dir: RobotDir,
    dynamics: Annotated[Path, Dynamics],
    log: Annotated[Path, JointLog],
    output: Annotated[
        Path | None,
        typer.Option("-o", "--output", help="The model written again with this log's validation figures."),
    ] = None,
    torques_out: TorquesOut = None,
    calibration: CalibrationOption = None,
) -> None:
    """Score an identified dynamics.yaml on another log without refitting: identify's validation figures."""
    score_run(robot_dir, dynamics, log, torques_out=torques_out, output=output, calibration=calibration)
