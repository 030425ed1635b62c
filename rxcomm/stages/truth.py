"""`rxcomm truth --robot DIR --seed N -o truth.yaml`: draw a plausible hidden truth for a robot.

So an imported robot can be commissioned in simulation at once (`run --truth`, `--plant own|mujoco`).
What is drawn and how large: `rxcomm.cell.truth_draw`. The file is checked by loading it as the
simulated cell does before it is moved into place.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from rxcomm import console
from rxcomm.options import RobotDir
from rxcomm.stages.declarations import DECLARATIONS


def command(
    robot_dir: RobotDir,
    output: Annotated[Path, typer.Option("-o", "--output", help="The truth file to write (truth.yaml).")],
    seed: Annotated[int, typer.Option(help="Seed of the draw (and of the cell's noise).")] = 0,
    compliance: Annotated[
        bool,
        typer.Option(help="Make joints 2 and 3 compliant (≈ 0.2 mrad sag under the largest holding torque)."),
    ] = False,
) -> None:
    """Draw a plausible hidden truth for any robot (errors, dynamics, noise) for the simulated cell."""
    console.stage_command(run)(robot_dir, output, seed=seed, compliance=compliance)


def run(robot_dir: Path, output: Path, *, seed: int = 0, compliance: bool = False) -> dict[str, object]:
    from rxcomm.cell.truth import load_truth
    from rxcomm.cell.truth_draw import DRIVE_OF_NEED, draw_truth, drive_torque_nm
    from rxcomm.io.files import atomic_write_text, part_path
    from rxcomm.io.yaml_io import dump_yaml, read_yaml_model
    from rxcomm.model.robot import load_robot
    from rxcomm.schemas.cell import Cell

    output = Path(output)
    DECLARATIONS["truth"].check(output=output, robot=robot_dir)
    robot = load_robot(robot_dir)
    cell_path = robot.drives_path.parent / "cell.yaml"
    cell = read_yaml_model(cell_path, Cell) if cell_path.exists() else None
    truth = draw_truth(robot, output, seed, compliance=compliance, cell=cell)
    text = (
        f"# HIDDEN TRUTH of the simulated cell, drawn by `rxcomm truth --seed {seed}` for {robot.name}.\n"
        "# Only the simulator (rxcomm.cell) and recovery-scoring tests read it; stages never do.\n"
        + dump_yaml(truth.model_dump(mode="json"))
    )
    check = part_path(output, ".check")
    try:
        check.write_text(text)
        load_truth(check)  # loads as the cell will (robot path, links, sizes) or nothing is written
    finally:
        check.unlink(missing_ok=True)
    atomic_write_text(output, text)
    compliant = ", ".join(truth.geometry.joint_stiffness_nm_per_rad) or "none"
    console.out.print(
        f"truth for {robot.name} (seed {seed}) → {output}: 48 geometric errors, compliant joints: {compliant}"
    )
    drive, peak = drive_torque_nm(robot), robot.tau_max
    capped = [
        f"{n} {d:.3g} (peak {p:.4g})" for n, d, p in zip(robot.joint_names, drive, peak, strict=True) if d < p
    ]
    if capped:
        console.out.print(
            f"  torque offset and noise drawn for a drive of {DRIVE_OF_NEED:g}× the joint's largest need, "
            f"not its stated peak (a simulation's force clamp?), N·m: {', '.join(capped)}"
        )
    return {"truth": str(output), "seed": seed}
