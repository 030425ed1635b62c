"""The `rxcomm` command: one subcommand per stage (architecture §9).

This is the composition root: the only library module that imports `rxcomm.stages`. Stages are
registered by module name in `STAGES` and imported only when their command runs (or shows its
help, or completes): `rxcomm --help` / `--version` must answer at once, and the stages pull in
toppra, matplotlib, scipy, casadi and pinocchio. A new stage is one `STAGES` entry.

Old option spellings (docs/cli.md, "deprecated") are rewritten to the current ones before click
parses, with a warning on stderr, so they work without showing in `--help`.
"""

from __future__ import annotations

import importlib
import sys
from dataclasses import dataclass
from typing import Annotated

import typer
from typer.core import TyperCommand, TyperGroup


@dataclass(frozen=True)
class Stage:
    module: str  # under rxcomm.stages; exposes a typer command function `command`
    short_help: str  # the listing's line: the start of `command`'s docstring (a test checks)
    example: str  # one typical invocation on the sample robot, shown at the end of --help
    deprecated: tuple[tuple[str, str], ...] = ()  # (old spelling, current spelling), docs/cli.md


STAGES: dict[str, Stage] = {
    "robot-info": Stage(
        "robot_info",
        "Print a robot's DOF, limits, reach, mass, the stretched-pose gravity load and identifiability.",
        "rxcomm robot-info --robot samples/rx130l",
    ),
    "select-configs": Stage(
        "select_configs",
        "Select measurement poses that make the geometric error parameters well identifiable.",
        "rxcomm select-configs --robot samples/rx130l --cell samples/rx130l/cell.yaml --poses 32 "
        "--measure-baseline -o build/configs.yaml",
        (("-n", "--poses"), ("--n", "--poses"), ("--intervals", "--grid-intervals"))
        + (("--n-validation", "--validation-poses"),),
    ),
    "calibrate": Stage(
        "calibrate",
        "Identify the robot's geometric errors from tracker measurements; write the calibration.",
        "rxcomm calibrate --robot samples/rx130l --measurements build/calib-meas.yaml "
        "--cell samples/rx130l/cell.yaml --urdf-out build/calibrated.urdf -o build/calibration.yaml",
        (("--holdout", "--holdout-fraction"), ("--model", "--error-model")),
    ),
    "run": Stage(
        "run",
        "Execute a trajectory (or a pose list) on the cell",
        "rxcomm run build/cp.mcap --robot samples/rx130l --approach --dynamics build/dynamics.yaml "
        "-o build/run-ff.mcap",
        (("--speed", "--speed-fraction"),),
    ),
    "cell-sim": Stage(
        "cell_sim",
        "Serve the simulated robot cell (drives, true dynamics, tracker) as a Modbus TCP drive gateway.",
        "rxcomm cell-sim --truth samples/rx130l/truth.yaml --port 1502 --start-deg 0,-30,60,0,45,0",
        (("--q0", "--start"),),
    ),
    "excite": Stage(
        "excite",
        "Design the optimal exciting trajectory (min cond of the base regressor) within every limit.",
        "rxcomm excite --robot samples/rx130l --cell samples/rx130l/cell.yaml --position-margin-deg 3 "
        "-o build/excitation.yaml",
        (("--omega", "--omega-rad-s"), ("--position-margin", "--position-margin-rad")),
    ),
    "identify": Stage(
        "identify",
        "Identify the base dynamic parameters (+ friction, rotor inertia, spring) and validate them.",
        "rxcomm identify --robot samples/rx130l --log build/excite-log.mcap "
        "--validate build/validation-log.mcap -o build/dynamics.yaml",
        (("--model", "--dynamics"), ("--torques-csv", "--torques-out"), ("--min-speed", "--min-speed-rad-s"))
        + (("--max-gap", "--max-gap-s"), ("--torque-lag", "--torque-lag-s"))
        + (("--stick-guard", "--stick-guard-s"),),
    ),
    "score": Stage(
        "score",
        "Score an identified dynamics.yaml on another log without refitting: identify's validation figures.",
        "rxcomm score --robot samples/rx130l --dynamics build/dynamics.yaml --log build/validation-log.mcap",
    ),
    "identify-payload": Stage(
        "identify_payload",
        "Identify a payload on the flange (mass, centre of mass, inertia ± σ) with the robot model fixed.",
        "rxcomm identify-payload --robot samples/rx130l --log build/excite-log-payload.mcap "
        "--dynamics build/dynamics.yaml --validate build/validation-log-payload.mcap -o build/payload.yaml",
    ),
    "plan-cp": Stage(
        "plan_cp",
        "Plan the time-optimal (or time/energy-weighted) timing of a TCP path and write it for `run`.",
        "rxcomm plan-cp --robot samples/rx130l --path samples/rx130l/paths/line-near-singularity.yaml "
        "--path-intervals 200 -o build/cp.mcap",
        (("-N", "--path-intervals"), ("--intervals", "--path-intervals"))
        + (("--torque-rate", "--torque-rate-limits"), ("--no-torque-rate", "--no-torque-rate-limits"))
        + (("--tcp-speed-max", "--max-tcp-speed-m-s"),)
        + (("--tcp-acceleration-max", "--max-tcp-acceleration-m-s2"),),
    ),
    "iso9283-paths": Stage(
        "iso9283_paths",
        "Write the robot's ISO 9283 test-plane paths (line, circles, rectangle) as path files to a "
        "directory.",
        "rxcomm iso9283-paths --robot samples/rx130l --cell samples/rx130l/cell.yaml -o robots/arm/paths",
    ),
    "plan-ptp": Stage(
        "plan_ptp",
        "Plan the time/energy-optimal rest-to-rest motion between two joint states or TCP poses.",
        "rxcomm plan-ptp --robot samples/rx130l --start-deg 0,-30,60,0,45,0 --goal-deg 60,0,30,0,60,0 "
        "-o build/ptp.mcap",
        (("-N", "--time-intervals"), ("--intervals", "--time-intervals"), ("--margin", "--margin-fraction"))
        + (("--tcp-box", "--tcp-box-m"), ("--max-wall", "--max-wall-s")),
    ),
    "report": Stage(
        "report",
        "Write the commissioning report",
        "rxcomm report build",
    ),
    "recover-log": Stage(
        "recover_log",
        "Recover the run log of a killed `run` from its NAME.mcap.part, saying what was lost.",
        "rxcomm recover-log build/run-ff.mcap.part",
    ),
    "export": Stage(
        "export",
        "Export artefacts for other tools, by kind and --format, each with its parity figure",
        "rxcomm export build/cp.mcap --format ros2-trajectory",
    ),
    "accept": Stage(
        "accept",
        "Write the acceptance verdict: each criterion for the factory and the commissioned state.",
        "rxcomm accept --thresholds samples/rx130l/acceptance.yaml "
        "--factory-iso9283 build/iso9283-factory.yaml "
        "--commissioned-iso9283 build/iso9283.yaml -o build/verdict.yaml",
    ),
    "iso9283": Stage(
        "iso9283",
        "ISO 9283 criteria (AP/RP at P1–P5, AT/RT/AV/RV on the paths, CO on the rectangle) from run logs",
        "rxcomm iso9283 --robot samples/rx130l --pose-log build/run-poses.mcap -o build/iso9283.yaml",
    ),
    "plan-poses": Stage(
        "plan_poses",
        "Plan the ISO 9283 pose cycle P1 → P5 → P4 → P3 → P2 at the catalogue limits, for `run`.",
        "rxcomm plan-poses --robot samples/rx130l --paths samples/rx130l/paths -o build/poses.mcap",
    ),
    "plan-cycles": Stage(
        "plan_cycles",
        "Repeat a test path's plan for the ISO 9283 cycles, with return moves at the catalogue limits.",
        "rxcomm plan-cycles build/iso-line.mcap --robot samples/rx130l --cycles 10 "
        "-o build/iso-line-cycles.mcap",
    ),
    "import-robot": Stage(
        "import_robot",
        "Write a robot directory (URDF + drives.yaml, the model kept beside) from a MuJoCo model.",
        "rxcomm import-robot arm.xml -o robots/arm",
    ),
    "truth": Stage(
        "truth",
        "Draw a plausible hidden truth for any robot (errors, dynamics, noise) for the simulated cell.",
        "rxcomm truth --robot robots/arm --seed 1 -o robots/arm/truth.yaml",
    ),
    "import-tracker": Stage(
        "import_tracker",
        "Put a real tracker's CSV export on a run log's time axis and write the log with its /run/tracker",
        "rxcomm import-tracker build/run-ff.mcap --robot samples/rx130l --tracker-csv tracker.csv "
        "-o build/run-ff-tracked.mcap",
    ),
}

# Commands whose old form took a positional argument that is now an option (docs/cli.md).
POSITIONAL_ALIASES = {"robot-info": "--robot"}


def rewrite_deprecated(name: str, args: list[str]) -> list[str]:
    """`args` with the old spellings of `name`'s options replaced by the current ones (a warning each)."""
    aliases = dict(STAGES[name].deprecated)
    out: list[str] = []
    for i, a in enumerate(args):
        if a == "--":
            out += args[i:]
            break
        key, eq, value = a.partition("=")
        if key in aliases:
            typer.echo(f"rxcomm {name}: {key} is deprecated, use {aliases[key]}", err=True)
            a = aliases[key] + eq + value
        out.append(a)
    opt = POSITIONAL_ALIASES.get(name)
    if opt and out and not out[0].startswith("-"):
        typer.echo(f"rxcomm {name}: the positional argument is deprecated, use {opt} {out[0]}", err=True)
        out.insert(0, opt)
    return out


class LazyStages(TyperGroup):
    """A group whose stage commands are imported on first use, not when the group is built."""

    _listing = False

    def list_commands(self, ctx: typer.Context) -> list[str]:
        # a command registered eagerly (`app.command(...)`) still works, only not lazily
        return list(STAGES) + [c for c in super().list_commands(ctx) if c not in STAGES]

    def get_command(self, ctx: typer.Context, cmd_name: str) -> TyperCommand | None:
        stage = STAGES.get(cmd_name)
        if stage is None:
            return super().get_command(ctx, cmd_name)
        if self._listing:  # the group's own --help: a stand-in with the short help, no import
            return TyperCommand(cmd_name, help=stage.short_help)
        return stage_command(cmd_name)

    def format_help(self, ctx: typer.Context, formatter: object) -> None:
        self._listing = True
        try:
            super().format_help(ctx, formatter)
        finally:
            self._listing = False


_loaded: dict[str, TyperCommand] = {}


def stage_command(name: str) -> TyperCommand:
    """The click command of stage `name` (imports its module once)."""
    if name not in _loaded:
        stage = STAGES[name]
        module = importlib.import_module(f"rxcomm.stages.{stage.module}")
        single = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
        shown = "Example:" in (module.command.__doc__ or "")  # the stage's help has its own already
        single.command(name, epilog=None if shown else f"Example:  {stage.example}")(module.command)
        cmd = typer.main.get_command(single)
        parse = cmd.parse_args

        def parse_args(ctx: typer.Context, args: list[str], _parse=parse, _name=name) -> list[str]:
            return _parse(ctx, rewrite_deprecated(_name, list(args)))

        cmd.parse_args = parse_args  # type: ignore[method-assign]
        _loaded[name] = cmd
    return _loaded[name]


app = typer.Typer(
    name="rxcomm",
    cls=LazyStages,
    help="Commissioning pipeline for 6-axis industrial robots: calibration, dynamic identification, "
    "time/energy-optimal planning and model-based execution. Every stage reads and writes files.",
    epilog="Example:  rxcomm robot-info --robot samples/rx130l  (options: docs/cli.md)",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        from rxcomm.code_identity import code_identity

        typer.echo(f"rxcomm {code_identity()}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """rxcomm: commission a robot step by step, each step one subcommand."""


def main() -> None:
    try:
        app(prog_name="rxcomm", args=sys.argv[1:])
    except OSError as e:  # outside a stage's own handling (importing it, writing help): still one line
        from rxcomm import console

        console.err.print(f"error: {console.os_error(e)}", markup=False)
        sys.exit(2)
