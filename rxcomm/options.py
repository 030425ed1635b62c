"""Command-line values that are not plain scalars, parsed once for every stage."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import typer

from rxcomm.errors import InputError

# The robot every stage works on: one option, one name, one help text (docs/cli.md).
ROBOT = typer.Option("--robot", help="Robot directory: a URDF + drives.yaml.")
RobotDir = Annotated[Path, ROBOT]
Plant = Annotated[str, typer.Option(help="The simulated cell's physics: own or mujoco (architecture §6).")]


def embedded_plant(plant: str, gateway: str | None) -> str:
    """`--plant` is the embedded cell's: refused beside `--gateway` (a real cell has its own physics)."""
    if gateway is not None and plant != "own":
        raise InputError("--plant chooses the embedded cell's physics: not with --gateway", field="--plant")
    return plant


# Options that mean the same in several stages, with one help text.
# plan-cp, plan-ptp: the optimal plan, or a generic controller's from the catalogue limits.
Timing = Literal["optimal", "catalogue"]
TRAJECTORY_OUTPUT = typer.Option("-o", "--output", help="Output trajectory NAME.mcap (+ NAME.yaml).")
# One meaning a name across stages (tests/test_cli_vocabulary.py): --dynamics is always the identified
# model a stage computes torques with; --cell always the cell description; --log a joint log.
DYNAMICS_HELP = (
    "Identified dynamics.yaml (rxcomm identify); where optional, the robot's prior model without it."
)
Dynamics = typer.Option("--dynamics", help=DYNAMICS_HELP)
CELL = typer.Option(
    "--cell",
    help="cell.yaml: workspace, allowed region, tracker and its noise, nominal layout (what each command "
    "uses of it: its description above).",
)
CellFile = Annotated[Path | None, CELL]
JointLog = typer.Option("--log", help="Run log MCAP (rxcomm run) or a robot CSV (docs/identify-csv.md).")
# identify, identify-payload: a log scored without refitting.
ValidateOption = Annotated[
    Path | None,
    typer.Option(
        help="Validation log: another motion (e.g. ISO 9283) scored without refitting; without it identify "
        "holds out the last 20 % of each of 5 blocks of LOG, identify-payload reports no validation."
    ),
]
# plan-cp, plan-ptp, plan-cycles, run: an identified payload on the flange (identify-payload).
PAYLOAD = typer.Option(
    "--payload", help="Identified payload.yaml (identify-payload): added to the model's last link."
)
TimeWeight = Annotated[float, typer.Option(help="Weight of time in ∫(k1 + k2·τᵀτ)dt.")]
# The one option of a declared input (the model a stage computes torques with): stages/stage_cli.py
# gives it to a stage's plain parameter of that name.
INPUT_OPTIONS = {"dynamics": Dynamics, "payload": PAYLOAD}
# plan-cp, plan-ptp, run: artefacts that claim another robot or an impossible one (issue 27); their
# declarations' `artefact_policy` adds both (stages/stage_cli.py).
OtherRobot = Annotated[
    bool,
    typer.Option(
        help="Accept a calibration or dynamics made for other robot files (their URDF / drives.yaml "
        "sha256 in its envelope differ), with a warning naming the difference."
    ),
]
AllowInconsistent = Annotated[
    bool,
    typer.Option(
        help="Accept physically inconsistent dynamics (M(q) not positive definite, a negative mass, "
        "rotor inertia or friction), with a warning."
    ),
]
# plan-poses, plan-cycles: a plan derived from catalogue timing.
PLAN_OUTPUT = typer.Option("-o", "--output", help="Output plan NAME.mcap (+ NAME.yaml).")
# plan-poses, iso9283: where the ISO 9283 path files are.
Iso9283Paths = Annotated[
    Path | None, typer.Option("--paths", help="Directory of the ISO 9283 path specs (default ROBOT/paths).")
]


def parse_numbers(text: str, count: int, field: str, unit: str = "") -> np.ndarray:
    """`count` finite comma-separated numbers, else InputError naming the option `field`.

    `unit` (e.g. "rad") only words the message; no conversion happens here."""
    what = f"{count} finite comma-separated numbers" + (f" ({unit})" if unit else "")
    try:
        values = np.array([float(p.strip()) for p in text.split(",")])
    except ValueError as e:
        raise InputError(f"expected {what}, got {text!r}", field=field) from e
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise InputError(f"expected {what}, got {text!r}", field=field)
    return values


POSE_PREFIX = "pose:"


def radians_text(rad: str | None, deg: str | None, option: str) -> str | None:
    """The joint vector of the option pair `--OPTION` (rad) / `--OPTION-deg` (deg) as radian text.

    A degree value may also be a TCP pose `pose:x,y,z,α,β,γ` (m, deg): its angles are converted, its
    position kept. The count is checked where the text is parsed; here only that numbers were given."""
    if rad is not None and deg is not None:
        raise InputError(f"give --{option} (rad) or --{option}-deg, not both", field=f"{option}-deg")
    if deg is None:
        return rad
    text = deg.strip()
    pose = text.lower().startswith(POSE_PREFIX)
    if pose:
        text = text[len(POSE_PREFIX) :]
    try:
        values = [float(p.strip()) for p in text.split(",")]
    except ValueError as e:
        raise InputError(f"expected comma-separated numbers (deg), got {deg!r}", field=f"{option}-deg") from e
    kept = values[:3] if pose else []
    rad_values = kept + [float(np.radians(v)) for v in values[len(kept) :]]
    return (POSE_PREFIX if pose else "") + ",".join(repr(v) for v in rad_values)


def radians_value(rad: float | None, deg: float | None, option: str, default_rad: float) -> float:
    """The angle of the option pair `--OPTION-rad` / `--OPTION-deg` in radians (`default_rad` if neither)."""
    if rad is not None and deg is not None:
        raise InputError(f"give --{option}-rad or --{option}-deg, not both", field=f"{option}-deg")
    if deg is not None:
        return float(np.radians(deg))
    return default_rad if rad is None else rad


# plan-cp, plan-ptp: what the optimal plan minimises (issue 29) and a fixed cycle time for it.
# One meaning: what the command's optimisation minimises (tests/test_cli_vocabulary.py).
OBJECTIVE_HELP = (
    "What the optimisation minimises. excite: cond (cond(W) of the unit-column base regressor) or logdet "
    "(−log det(WᵀW)/p); plan-cp, plan-ptp: torque (∫(k1 + k2·τᵀτ)dt, the paper's) or energy (the "
    "electrical energy drawn from the bus: copper losses, mechanical power, regeneration as drives.yaml "
    "says; at --duration-s)."
)
Objective = Annotated[Literal["torque", "energy"], typer.Option(help=OBJECTIVE_HELP)]
PlanDuration = Annotated[
    float | None,
    typer.Option("--duration-s", help="Fixed duration of the plan for --objective energy, s."),
]
