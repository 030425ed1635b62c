"""`rxcomm identify`: base dynamic parameters from a run log or a real robot's CSV (paper §4.1, §4.3).

Reads the robot and a joint log (`run`'s MCAP, topic /run/joints, or a CSV: docs/identify-csv.md),
identifies the base parameters (`rxcomm.identification.fit`), validates them on another log
(``--validate``, e.g. an ISO 9283 path) or on the held-out last 20 % of the log, and writes
``dynamics.yaml`` (kind rxcomm/Dynamics), which plan-cp, plan-ptp and run load. ``--plot`` writes
``dynamics.png``: measured against predicted torques on the validation data (paper Fig. 5b).
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.identification.fit import Identification, IdentifySettings, identify, load_joint_log
from rxcomm.io.files import check_outputs
from rxcomm.io.validate import settings_from_options
from rxcomm.io.yaml_io import write_yaml_artefact
from rxcomm.model.base_parameters import dynamics_artefact_fields
from rxcomm.model.robot import Robot, load_robot, robot_files
from rxcomm.schemas.dynamics import Dynamics


class Method(StrEnum):
    wls = "wls"
    ols = "ols"


def plot_validation(robot: Robot, result: Identification, path: Path) -> Path:
    """PNG: measured and predicted joint torques on the validation data, one panel per joint."""
    plt = plotting.pyplot()

    val = result.validation
    n = robot.n
    fig, axes = plt.subplots((n + 1) // 2, 2, sharex=True, figsize=(12, 2.2 * ((n + 1) // 2)))
    for j, ax in enumerate(axes.ravel()[:n]):
        ax.plot(val.t, val.measured[:, j], lw=1.0, label="measured")
        ax.plot(val.t, val.predicted[:, j], lw=1.0, ls="--", label="identified model")
        ax.set_ylabel(f"{robot.joint_names[j]} [N·m]")
        ax.set_title(f"RMS {val.rms_nm[j]:.3g} N·m, NRMSE {100 * val.nrmse[j]:.2f} %", fontsize=9)
        ax.grid(alpha=0.3)
    axes.ravel()[0].legend(fontsize=8)
    for ax in axes.ravel()[-2:]:
        ax.set_xlabel("t [s]")
    fig.suptitle(f"validation ({val.source})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def command(
    robot_dir: Annotated[Path, typer.Option("--robot", help="Robot directory: a URDF + drives.yaml.")],
    log: Annotated[
        Path, typer.Option(help="Run log MCAP (rxcomm run) or a robot CSV (docs/identify-csv.md).")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="Output dynamics.yaml.")],
    validate: Annotated[
        Path | None,
        typer.Option(help="Validation log (another trajectory, e.g. ISO 9283); default: last 20 % of LOG."),
    ] = None,
    physical: Annotated[
        bool,
        typer.Option(help="Write the physically consistent estimate (positive-definite pseudo-inertias)."),
    ] = False,
    method: Annotated[Method, typer.Option(help="Weighted (per-joint noise) or ordinary least squares.")] = (
        Method.wls
    ),
    cutoff_hz: Annotated[float, typer.Option(help="Low-pass cut-off of positions and torques, Hz.")] = 10.0,
    decimate_hz: Annotated[
        float, typer.Option(help="Sample rate after filtering, Hz (2 × cut-off keeps rows uncorrelated).")
    ] = 20.0,
    min_speed: Annotated[
        float, typer.Option(help="Rows of joints slower than this are rejected, rad/s.")
    ] = 0.05,
    max_cond: Annotated[
        float, typer.Option(help="Refuse a worse conditioned (unit-column) regressor.")
    ] = 1e4,
    max_gap: Annotated[
        float, typer.Option(help="Longest gap in the log bridged by interpolation, s.")
    ] = 0.01,
    torque_lag: Annotated[
        float | None,
        typer.Option(
            help="The torque acting at a position sample is logged this much later, s "
            "(default: one drive cycle for a run log, 0 for a CSV)."
        ),
    ] = None,
    stick_guard: Annotated[
        float | None,
        typer.Option(help="Reject rows this close to a joint's slow samples, s (default 1/cutoff)."),
    ] = None,
    plot: Annotated[bool, typer.Option(help="Write OUTPUT.png: measured vs predicted torques.")] = False,
) -> None:
    """Identify the base dynamic parameters (+ friction, rotor inertia, spring) and validate them."""
    values = {
        "physical": physical,
        "method": method.value,
        "cutoff_hz": cutoff_hz,
        "decimate_hz": decimate_hz,
        "min_speed_rad_s": min_speed,
        "max_cond": max_cond,
        "max_gap_s": max_gap,
        "torque_lag_s": torque_lag,
        "stick_guard_s": stick_guard,
    }
    run(robot_dir, log, output, validate=validate, settings=values, plot=plot)


@console.stage_command
def run(
    robot_dir: Path,
    log: Path,
    output: Path,
    *,
    validate: Path | None = None,
    settings: IdentifySettings | dict | None = None,
    plot: bool = False,
) -> Dynamics:
    """The stage as a function (tests call it): returns the artefact written."""
    output = Path(output)
    if output.suffix not in (".yaml", ".yml"):
        raise InputError("the output must be a .yaml file", field="output")
    check_outputs(
        {"output": output, "plot": output.with_suffix(".png") if plot else None},
        {"log": log, "validate": validate, **robot_files(robot_dir)},
    )
    robot = load_robot(robot_dir)
    values = settings.model_dump() if isinstance(settings, IdentifySettings) else dict(settings or {})
    opts = settings_from_options(IdentifySettings, values)
    joint_log = load_joint_log(log, robot)
    val_log = None if validate is None else load_joint_log(validate, robot)
    for lg in (joint_log, val_log):
        if lg is not None and lg.cycles_per_sample > 1:
            console.err.print(
                f"[yellow]warning:[/] {lg.source} was recorded with --interpolation-ratio "
                f"{lg.cycles_per_sample}: each torque sample is one drive cycle of {lg.cycles_per_sample}, "
                "at one phase of the setpoint interpolation, which biases the inertias; record "
                "identification runs with --interpolation-ratio 1"
            )
    with console.err.status("identify: estimating"):
        result = identify(robot, joint_log, opts, validation_log=val_log)
    est = result.estimate
    std = np.sqrt(np.maximum(np.diag(est.cov), 0.0))
    with np.errstate(divide="ignore"):
        rel = np.where(np.abs(result.p_b) > 0, std / np.abs(result.p_b), np.inf)
    fields = dynamics_artefact_fields(
        robot,
        result.bset,
        result.p_b,
        relative_std=rel,
        full=result.params if result.physical else None,
        full_method=(
            "physically consistent: log-Cholesky pseudo-inertias, least squares in the WLS information metric"
            if result.physical
            else None
        ),
    )
    inputs = {"urdf": robot.urdf_path, "drives": robot.drives_path, "log": Path(log)}
    if validate is not None:
        inputs["validate"] = Path(validate)
    summary = result.summary()
    art = Dynamics(**Dynamics.envelope(inputs, opts, summary), **fields)
    output.parent.mkdir(parents=True, exist_ok=True)
    write_yaml_artefact(output, art)
    if plot:
        png = plot_validation(robot, result, output.with_suffix(".png"))
        console.out.print(f"plot: {png}")
    shown = {
        k: summary[k]
        for k in (
            "n_base_params",
            "cond",
            "validation",
            "validation_nrmse",
            "validation_rms_nm",
            "fit_rms_nm",
            "max_relative_std",
            "n_inconsistent_links",
            "consistency_distance_sigma",
            "method",
            "seconds",
        )
    }
    console.summary_table(f"identify → {output}", shown)
    return art
