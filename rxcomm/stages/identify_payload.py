"""`rxcomm identify-payload`: the payload on the flange from a run with it mounted (architecture §7).

Reads the robot, its identified dynamics (`dynamics.yaml`, held fixed) and a run log recorded with the
payload on (e.g. the excitation run again: `run --truth-payload` on the simulated cell), identifies the
payload's mass, centre of mass and inertia ± σ (`rxcomm.identification.payload`), validates them on
another log recorded with it (``--validate``) and writes ``payload.yaml`` (kind rxcomm/Payload, with the
forms controllers take), which plan-cp, plan-ptp, plan-cycles and run take as ``--payload``.
``--plot`` writes ``payload.png``: measured torque against the model alone and with the payload on the
validation log.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.io.yaml_io import read_yaml_artefact, write_yaml_artefact
from rxcomm.options import Dynamics as DynamicsOption
from rxcomm.options import JointLog, RobotDir, ValidateOption
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.schemas.payload import Payload
from rxcomm.stages.declarations import DECLARATIONS

if TYPE_CHECKING:
    from rxcomm.identification.payload import PayloadResult
    from rxcomm.model.robot import Robot


def plot_payload(robot: Robot, result: PayloadResult, path: Path) -> Path:
    """PNG: on the validation log, per joint, measured torque minus the model alone (what the payload
    must explain) beside the identified payload's share of the prediction."""
    plt = plotting.pyplot()
    without, loaded = result.without, result.with_payload
    rows = (robot.n + 1) // 2
    fig, axes = plt.subplots(rows, 2, sharex=True, figsize=(12, 2.6 * rows), squeeze=False)
    for j in range(robot.n):
        ax = axes[j // 2, j % 2]
        ax.plot(without.t, without.measured[:, j] - without.predicted[:, j], lw=1.0, label="measured − model")
        ax.plot(without.t, loaded.predicted[:, j] - without.predicted[:, j], lw=1.0, ls="--", label="payload")
        r0, r1 = without.rms_nm[j], loaded.rms_nm[j]
        scored = f"RMS {r0:.3g} → {r1:.3g} N·m with the payload" if np.isfinite(r0) else "not scored: still"
        ax.set_title(f"{robot.joint_names[j]}: {scored}", fontsize=9)
        ax.set_ylabel("N·m")
        ax.grid(alpha=0.3)
    if robot.n % 2:
        axes[-1, 1].set_visible(False)
    handles = axes[0, 0].get_legend_handles_labels()[0]
    fig.legend(handles=handles, loc="upper right", fontsize=8, ncol=2)
    fig.suptitle(f"payload validation ({without.source})", x=0.02, ha="left")
    return plotting.save_figure(fig, path, dpi=110, rect=(0, 0, 1, 0.96))


@console.stage_command
def run(
    robot_dir: Path,
    log: Path,
    dynamics: Path,
    output: Path,
    *,
    validate: Path | None = None,
    plot: bool = False,
) -> Payload:
    """The stage as a function (tests call it): returns the artefact written."""
    from rxcomm.identification.logs import load_joint_log
    from rxcomm.identification.payload import identify_payload
    from rxcomm.identification.payload_artefact import model_settings, payload_fields, payload_summary
    from rxcomm.model.base_parameters import load_dynamics
    from rxcomm.model.robot import load_robot

    output = Path(output)
    if output.suffix not in (".yaml", ".yml"):
        raise InputError("the output must be a .yaml file", field="output")
    if plot and validate is None:
        raise InputError("--plot draws the validation: give --validate LOG", field="plot")
    png = output.with_suffix(".png") if plot else None
    DECLARATIONS["identify-payload"].check(
        output=output, plot=plot, robot=robot_dir, log=log, dynamics=dynamics, validate=validate
    )
    robot = load_robot(robot_dir)
    opts = model_settings(read_yaml_artefact(dynamics, Dynamics))
    if opts.friction is not None and opts.friction != robot.friction_mode:
        robot = robot.with_friction(opts.friction)  # the model's own friction model
    params, robot = load_dynamics(dynamics, robot)  # the payload rides on the model's own kinematics
    val_log = None if validate is None else load_joint_log(validate, robot)
    with console.phase("identify-payload: estimating"):
        result = identify_payload(robot, params, load_joint_log(log, robot), opts, val_log)
    inputs = {
        "urdf": robot.urdf_path,
        "drives": robot.drives_path,
        "log": Path(log),
        "dynamics": Path(dynamics),
    }
    if validate is not None:
        inputs["validate"] = Path(validate)
    summary = payload_summary(result)
    art = Payload(**Payload.envelope(inputs, opts, summary), **payload_fields(robot, result, Path(log).name))
    output.parent.mkdir(parents=True, exist_ok=True)
    write_yaml_artefact(output, art)
    if png is not None:
        console.out.print(f"plot: {plot_payload(robot, result, png)}")
    console.summary_table(f"identify-payload → {output}", console_rows(art))
    return art


def console_rows(art: Payload) -> dict[str, object]:
    """The estimate ± σ (mm for the centre of mass) and the validation, "not measured" without one."""
    com, com_std = np.array(art.com_m) * 1e3, np.array(art.com_std_m) * 1e3
    rows: dict[str, object] = {
        "mass": f"{art.mass_kg:.4f} ± {art.mass_std_kg:.4f} kg",
        "centre of mass (flange)": ", ".join(f"{c:.2f} ± {s:.2f}" for c, s in zip(com, com_std, strict=True))
        + " mm",
        "inertia at CoM Ixx Ixy Iyy Ixz Iyz Izz": ", ".join(
            f"{v:.4g} ± {s:.2g}" for v, s in zip(art.inertia_com_kgm2, art.inertia_com_std_kgm2, strict=True)
        )
        + " kg·m²",
        "physically consistent": art.controller.physically_consistent,
        "fit": f"{art.fit.rows} rows, cond {art.fit.cond:.3g}",
    }
    val = art.validation
    if val is None:
        rows["validation"] = "not measured (no --validate log)"
    else:
        rows[f"validation on {val.log}: RMS all joints"] = (
            f"{val.total_rms_without_nm:.3g} N·m without the payload → "
            f"{val.total_rms_with_nm:.3g} N·m with it"
        )
    rows["seconds"] = f"{art.summary.seconds:.2f}"
    return rows


def command(
    robot_dir: RobotDir,
    log: Annotated[Path, JointLog],
    dynamics: Annotated[Path, DynamicsOption],
    output: Annotated[Path, typer.Option("-o", "--output", help="Output payload.yaml.")],
    validate: ValidateOption = None,
    plot: Annotated[bool, typer.Option(help="Write OUTPUT.png: the validation, per joint.")] = False,
) -> None:
    """Identify a payload on the flange (mass, centre of mass, inertia ± σ) with the robot model fixed."""
    run(robot_dir, log, dynamics, output, validate=validate, plot=plot)
