"""`rxcomm identify`: base dynamic parameters from a run log or a real robot's CSV (paper §4.1, §4.3).

Reads the robot and a joint log (`run`'s MCAP, topic /run/joints, or a CSV: docs/identify-csv.md),
identifies the base parameters (`rxcomm.identification.fit`), validates them on another log
(``--validate``, e.g. an ISO 9283 path) or on held-out parts of the log (the last 20 % of each of
5 blocks), and writes
``dynamics.yaml`` (kind rxcomm/Dynamics), which plan-cp, plan-ptp and run load. ``--plot`` writes
``dynamics.png``: measured against predicted torques on the validation data (paper Fig. 5b).
``--calibration calibration.yaml`` fits on the calibrated kinematics (`rxcomm.identification.kinematics`:
the nominal ones bias the base parameters by the robot's geometric errors).

Scoring an identified model on another log without refitting is `rxcomm score` (`stages/score.py`;
``--dynamics D --validate LOG`` here is its old spelling, hidden).
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.io.validate import settings_from_options
from rxcomm.io.yaml_io import read_yaml_artefact, write_yaml_artefact
from rxcomm.options import JointLog, RobotDir, ValidateOption
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.stages.stage_cli import checking

if TYPE_CHECKING:
    from rxcomm.identification.fit import Identification
    from rxcomm.identification.settings import IdentifySettings
    from rxcomm.identification.validation import Validation
    from rxcomm.model.geometric_errors import ErrorModel
    from rxcomm.model.robot import Robot


class Method(StrEnum):
    wls = "wls"
    ols = "ols"


class Friction(StrEnum):
    joint = "joint"
    motor = "motor"
    both = "both"


NOT_SCORED = "not scored"
REGROUPED_WHY = (
    "the calibrated axis tilt gives an effect this log cannot tell from J1's friction offset; "
    "a wider J1 swing separates it"
)


def per_joint(
    values: list[float | None], scale: float = 1.0, unit: str = "", none: str = NOT_SCORED, fmt: str = ".3g"
) -> str:
    """Per-joint figures; a joint that did not move on the validation data reads "not scored"."""
    return ", ".join(none if v is None else f"{v * scale:{fmt}}{unit}" for v in values)


def plot_validation(robot: Robot, result: Identification, path: Path) -> Path:
    """PNG (the paper's Fig. 5b): measured and predicted joint torques on the validation data, one
    panel per joint, each over its residual (measured − predicted), legend outside the data."""
    plt = plotting.pyplot()

    val = result.validation
    n, rows = robot.n, (robot.n + 1) // 2
    fig, axes = plt.subplots(
        2 * rows, 2, sharex=True, figsize=(12, 3.0 * rows), gridspec_kw={"height_ratios": [3, 1] * rows}
    )
    for j in range(n):
        ax, res = axes[2 * (j // 2), j % 2], axes[2 * (j // 2) + 1, j % 2]
        ax.plot(val.t, val.measured[:, j], lw=1.0, label="measured")
        ax.plot(val.t, val.predicted[:, j], lw=1.0, ls="--", label="identified model")
        res.plot(val.t, val.measured[:, j] - val.predicted[:, j], ".", ms=2, color="C3", label="residual")
        res.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel(f"{robot.joint_names[j]} [N·m]")
        res.set_ylabel("resid. [N·m]", fontsize=8)
        if val.scored[j]:
            title = f"RMS {val.rms_nm[j]:.3g} N·m, NRMSE {100 * val.nrmse[j]:.2f} %, R² {val.r2[j]:.3f}"
        else:
            title = "not scored: the joint did not move"
        ax.set_title(title, fontsize=9)
        for a in (ax, res):
            a.grid(alpha=0.3)
    if n % 2:  # an odd joint count leaves the last torque and residual axes empty
        axes[-2, 1].set_visible(False)
        axes[-1, 1].set_visible(False)
    for a in axes[-1, :]:
        a.set_xlabel("t [s]")
    handles = [*axes[0, 0].get_legend_handles_labels()[0], *axes[1, 0].get_legend_handles_labels()[0]]
    fig.legend(handles=handles, loc="upper right", fontsize=8, ncol=3, bbox_to_anchor=(1.0, 1.0))
    fig.suptitle(f"validation ({val.source})", x=0.02, ha="left")
    return plotting.save_figure(fig, path, dpi=110, rect=(0, 0, 1, 0.96))


# Options whose help needs more than a line
CutoffOption = Annotated[
    str,
    typer.Option(
        metavar="HZ|auto",
        help="Low-pass cut-off of positions and torques, Hz, or auto (default): the one of 5, 10, 20, "
        "40 Hz whose fit predicts held-out folds best; 10 Hz, with the reason on the console, when the "
        "folds cannot tell.",
    ),
]
DecimateOption = Annotated[
    float | None,
    typer.Option(help="Sample rate after filtering, Hz (default 2 × cut-off: rows uncorrelated)."),
]
FoldsOption = Annotated[
    int, typer.Option(help="Blocked cross-validation: contiguous folds in time (0: none).")
]
ParamsOutOption = Annotated[
    Path | None,
    typer.Option(
        help="Write the identified base parameters ± σ as CSV (name, value, std, unit, definition)."
    ),
]
TorqueLagOption = Annotated[
    float | None,
    typer.Option(
        "--torque-lag-s",
        help="The torque acting at a position sample is logged this much later, s "
        "(default: one drive cycle for a run log, 0 for a CSV).",
    ),
]
CalibrationOption = Annotated[
    Path | None,
    typer.Option(
        help="calibration.yaml (make PLANT=mujoco: calibration-prior.yaml): fit on the calibrated "
        "kinematics, the nominal base set regrouped on them (default: the nominal kinematics)."
    ),
]
TorquesOut = Annotated[
    Path | None,
    typer.Option("--torques-out", help="Write the validation rows' measured and predicted torques as CSV."),
]


def command(
    robot_dir: RobotDir,
    log: Annotated[Path | None, JointLog] = None,
    output: Annotated[Path | None, typer.Option("-o", "--output", help="Output dynamics.yaml.")] = None,
    model: Annotated[Path | None, typer.Option("--dynamics", hidden=True)] = None,  # old `rxcomm score`
    torques_csv: TorquesOut = None,
    validate: ValidateOption = None,
    calibration: CalibrationOption = None,
    friction: Annotated[
        Friction | None,
        typer.Option(help="Friction model: joint, motor or both (default: drives.yaml's friction)."),
    ] = None,
    physical: Annotated[
        bool | None,
        typer.Option(
            "--physical/--no-physical",
            help="Write a physically consistent estimate (positive-definite pseudo-inertias): of those "
            "within one σ of the nearest, the one closest to the prior. Default: where the unconstrained "
            "one is inconsistent and the nearest consistent one lies within √n_base σ.",
        ),
    ] = None,
    method: Annotated[Method, typer.Option(help="Weighted (per-joint noise) or ordinary least squares.")] = (
        Method.wls
    ),
    cutoff_hz: CutoffOption = "auto",
    decimate_hz: DecimateOption = None,
    folds: FoldsOption = 5,
    params_out: ParamsOutOption = None,
    min_speed: Annotated[
        float, typer.Option("--min-speed-rad-s", help="Rows of joints slower than this are rejected, rad/s.")
    ] = 0.05,
    max_cond: Annotated[
        float, typer.Option(help="Refuse a worse conditioned (unit-column) regressor.")
    ] = 1e4,
    max_gap: Annotated[
        float, typer.Option("--max-gap-s", help="Longest gap in the log bridged by interpolation, s.")
    ] = 0.01,
    torque_lag: TorqueLagOption = None,
    stick_guard: Annotated[
        float | None,
        typer.Option(
            "--stick-guard-s", help="Reject rows this close to a joint's slow samples, s (default 1/cutoff)."
        ),
    ] = None,
    plot: Annotated[bool, typer.Option(help="Write OUTPUT.png: measured vs predicted torques.")] = False,
) -> None:
    """Identify the base dynamic parameters (+ friction, rotor inertia, spring) and validate them."""
    values = {
        "physical": physical,
        "method": method.value,
        "cutoff_hz": cutoff_hz if cutoff_hz == "auto" else _number(cutoff_hz, "cutoff-hz"),
        "decimate_hz": decimate_hz,
        "folds": folds,
        "min_speed_rad_s": min_speed,
        "max_cond": max_cond,
        "max_gap_s": max_gap,
        "torque_lag_s": torque_lag,
        "stick_guard_s": stick_guard,
        "friction": None if friction is None else friction.value,
    }
    _check_mode(model, log, output, validate, params_out)
    common = {"settings": values, "torques_out": torques_csv, "calibration": calibration}
    if model is not None:
        console.err.print(
            "identify --dynamics D --validate LOG is deprecated: use rxcomm score --dynamics D --log LOG"
        )
        score_run(robot_dir, model, validate, output=output, **common)
        return
    run(robot_dir, log, output, validate=validate, plot=plot, params_out=params_out, **common)


@console.stage_command
def _number(text: str, option: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(f"expected a number of Hz or auto, got {text!r}", field=option) from None


@console.stage_command
def _check_mode(
    model: Path | None, log: Path | None, output: Path | None, validate: Path | None, params_out: Path | None
) -> None:
    if model is not None:
        if validate is None or log is not None or params_out is not None:
            raise InputError(
                "--dynamics scores a model on --validate LOG: give --validate, not --log or --params-out",
                field="dynamics",
            )
    elif log is None or output is None:
        raise InputError("give --log and -o (or --dynamics with --validate to score a model)", field="log")


def fit_kinematics(robot: Robot, calibration: Path | None) -> Robot:
    """The robot whose kinematics the fit uses: `robot`, or `robot` with a calibration's errors."""
    errors = kinematics_errors(robot, calibration)
    return robot if errors is None else errors.apply(robot)


def kinematics_errors(robot: Robot, calibration: Path | None) -> ErrorModel | None:
    """A calibration's geometric errors on `robot` (None without one): what the fit's kinematics add."""
    if calibration is None:
        return None
    from rxcomm.calibration.loading import calibration_errors

    return calibration_errors(robot, calibration)


def _settings(settings: IdentifySettings | dict | None) -> IdentifySettings:
    from rxcomm.identification.settings import IdentifySettings

    values = settings.model_dump() if isinstance(settings, IdentifySettings) else dict(settings or {})
    return settings_from_options(IdentifySettings, values)


def validation_rows(val: Validation) -> dict[str, object]:
    """The console lines of a validation (per joint; "not scored" where the joint did not move)."""
    from rxcomm.identification.validation import nan_list
    from rxcomm.reporting.identification import in_band_labels

    in_band = in_band_labels(
        nan_list(val.standstill_in_band_fraction), val.band_below_noise, val.standstill_rows.tolist()
    )
    return {
        "validation": val.source,
        "validation_rms_nm (moving rows)": per_joint(
            [None if not ok else float(v) for v, ok in zip(val.rms_nm, val.scored, strict=True)]
        ),
        "validation_nrmse": per_joint(
            [None if not ok else float(v) for v, ok in zip(val.nrmse, val.scored, strict=True)], 100, " %"
        ),
        "validation_r2": per_joint([None if not np.isfinite(v) else float(v) for v in val.r2], fmt=".4f"),
        "validation_rms_nm (every row)": per_joint([float(v) for v in val.rms_all_nm]),
        "validation_rms_nm (all joints: moving / every row)": (
            f"{val.total_rms_moving_nm:.3g} / {val.total_rms_every_row_nm:.3g}"
            if np.isfinite(val.total_rms_moving_nm)
            else "not scored"
        ),
        "standstill rows in the stiction band": ", ".join(in_band),
    }


def artefact_fields(robot: Robot, result: Identification, std: np.ndarray) -> dict:
    """dynamics.yaml's data fields: the base parameters with their relative σ, and the full
    consistent vector when it is the result."""
    from rxcomm.model.base_parameters import dynamics_artefact_fields

    with np.errstate(divide="ignore"):
        rel = np.where(np.abs(result.p_b) > 0, std / np.abs(result.p_b), np.inf)
    return dynamics_artefact_fields(
        robot,
        result.bset,
        result.p_b,
        relative_std=rel,
        std=std,
        full=result.params if result.physical else None,
        full_method=(
            "physically consistent: of the bodies within one σ of the nearest consistent estimate (WLS "
            "information metric, pseudo-inertias positive definite), the one closest to the prior"
            if result.physical
            else None
        ),
    )


def console_rows(result: Identification, summary: dict[str, object]) -> dict[str, object]:
    """The console table of an identification: the set, the validation, fit beside held-out error,
    consistency."""
    shown = {k: summary[k] for k in ("n_base_params", "friction", "cond", "cutoff_hz", "sample_hz")}
    shown["rows_per_parameter"] = f"{summary['rows_per_parameter']:.1f} ({result.estimate.n_rows} rows)"
    shown.update(validation_rows(result.validation))
    shown.update(fit_and_cv_rows(result))
    for k in ("max_relative_std", "n_inconsistent_links"):
        shown[k] = summary[k]
    if summary["inconsistent_links"]:
        shown["inconsistent_links"] = (
            f"{summary['inconsistent_links']}: pseudo-inertia not positive definite (no body has that mass "
            f"distribution); {result.consistency_note()}"
        )
    for k in ("consistency_distance_sigma", "consistency_written_sigma", "method", "seconds"):
        if summary[k] is not None:
            shown[k] = summary[k]
    return shown


def fit_and_cv_rows(result: Identification) -> dict[str, object]:
    """The console lines of the fit error beside the cross-validated held-out error, and the cut-off
    choice when it was automatic."""
    cv = result.cross_validation
    rows: dict[str, object] = {"fit_rms_nm": per_joint([float(v) for v in result.estimate.residual_rms_nm])}
    if cv is None or cv.folds_scored == 0:
        rows["cv_rms_nm (held-out folds)"] = "not measured" + (" (--folds 0)" if cv is None else "")
    else:
        rows[f"cv_rms_nm ({cv.folds_scored} of {cv.folds} held-out folds)"] = per_joint(
            [None if not np.isfinite(v) else float(v) for v in cv.rms_nm]
        )
    if result.cutoff_choice is not None:
        rows["cutoff_choice"] = result.cutoff_choice.reason
    return rows


@console.stage_command
@checking("score")
def score_run(
    robot_dir: Path,
    dynamics: Path,
    log: Path,
    *,
    settings: IdentifySettings | dict | None = None,
    torques_out: Path | None = None,
    output: Path | None = None,
    calibration: Path | None = None,
) -> Validation:
    """Score an identified model (dynamics.yaml) on a log without refitting; returns the validation.
    `output`: the model written again there with its validation figures those of this log (the
    parameters unchanged, `inputs.validate` the log)."""
    from rxcomm.identification.export import write_torques_csv
    from rxcomm.identification.fit import score
    from rxcomm.identification.logs import load_joint_log
    from rxcomm.identification.settings import MODEL_SETTINGS, IdentifySettings
    from rxcomm.model.base_parameters import dynamics_from_artefact, fitted_kinematics
    from rxcomm.model.robot import load_robot

    art = read_yaml_artefact(dynamics, Dynamics)
    nominal = load_robot(robot_dir)
    # the model's own kinematics when it records them; --calibration for a model that does not
    robot = (
        fitted_kinematics(art, nominal, dynamics)
        if art.kinematics_errors
        else fit_kinematics(nominal, calibration)
    )
    values = settings.model_dump() if isinstance(settings, IdentifySettings) else dict(settings or {})
    # The model's own processing and friction model, unless given other than the defaults here.
    fields = IdentifySettings.model_fields
    for k in MODEL_SETTINGS:
        given = values.get(k, fields[k].default)
        if given == fields[k].default and getattr(art.settings, k) is not None:
            values[k] = getattr(art.settings, k)
    if values.get("cutoff_hz") == "auto":  # the model's chosen cut-off and its decimation
        values["cutoff_hz"] = art.summary.cutoff_hz
    opts = _settings(values)
    if opts.friction is not None:
        robot = robot.with_friction(opts.friction)
    try:
        params = dynamics_from_artefact(art, robot)
    except InputError as e:
        raise InputError(e.reason, file=dynamics, field=e.field) from e
    noise = art.summary.noise_sigma_nm  # the model's own fit noise: its stiction band scored against it
    noise_nm = None if noise is None else np.array([np.nan if v is None else v for v in noise])
    val = score(robot, params, load_joint_log(log, robot), opts, noise_nm)
    if torques_out is not None:
        console.out.print(f"torques: {write_torques_csv(torques_out, robot.joint_names, val)}")
    if output is not None:
        from rxcomm.identification.fit import validation_summary
        from rxcomm.schemas.plain import sha256_file

        scored = art.model_copy(
            update={
                "inputs": {**art.inputs, "validate": sha256_file(log)},
                "summary": art.summary.model_validate(
                    {**art.summary.model_dump(), **validation_summary(val, robot.joint_names)}
                ),
            }
        )
        Path(output).parent.mkdir(parents=True, exist_ok=True)
        write_yaml_artefact(Path(output), scored)
        console.out.print(f"scored model: {output}")
    console.summary_table(f"identify: {Path(dynamics).name} scored on {Path(log).name}", validation_rows(val))
    return val


@console.stage_command
@checking("identify")
def run(
    robot_dir: Path,
    log: Path,
    output: Path,
    *,
    validate: Path | None = None,
    settings: IdentifySettings | dict | None = None,
    plot: bool = False,
    torques_out: Path | None = None,
    params_out: Path | None = None,
    calibration: Path | None = None,
) -> Dynamics:
    """The stage as a function (tests call it): returns the artefact written."""
    from rxcomm.identification.export import write_parameters_csv, write_torques_csv
    from rxcomm.identification.fit import identify
    from rxcomm.identification.kinematics import identify_on
    from rxcomm.identification.logs import load_joint_log
    from rxcomm.model.base_parameters import base_parameters
    from rxcomm.model.robot import load_robot

    output = Path(output)
    if output.suffix not in (".yaml", ".yml"):
        raise InputError("the output must be a .yaml file", field="output")
    opts = _settings(settings)
    nominal = load_robot(robot_dir)
    if opts.friction is not None and opts.friction != nominal.friction_mode:
        nominal = nominal.with_friction(opts.friction)  # --friction overrides drives.yaml's, artefact too
    errors = kinematics_errors(nominal, calibration)
    robot = nominal if errors is None else errors.apply(nominal)
    joint_log = load_joint_log(log, robot)
    val_log = None if validate is None else load_joint_log(validate, robot)
    for warning in filter(None, (lg.interpolation_warning() for lg in (joint_log, val_log) if lg)):
        console.err.print(f"[yellow]warning:[/] {warning}")
    regrouped: tuple[str, ...] | None = None
    with console.phase("identify: estimating"):
        if calibration is None:
            result = identify(robot, joint_log, opts, validation_log=val_log)
        else:
            result, _, regrouped = identify_on(robot, base_parameters(nominal), joint_log, opts, val_log)
    std = np.sqrt(np.maximum(np.diag(result.estimate.cov), 0.0))
    fields = artefact_fields(robot, result, std)
    inputs = {"urdf": robot.urdf_path, "drives": robot.drives_path, "log": Path(log)}
    if validate is not None:
        inputs["validate"] = Path(validate)
    if calibration is not None:
        inputs["calibration"] = Path(calibration)
    summary = {
        "kinematics": "nominal" if calibration is None else "calibrated",
        "kinematics_regrouped": None if regrouped is None else ", ".join(regrouped),
        **result.summary(),
    }
    fields["kinematics_errors"] = None if errors is None else errors.as_dict()  # run and plans use them
    art = Dynamics(**Dynamics.envelope(inputs, opts, summary), **fields)
    output.parent.mkdir(parents=True, exist_ok=True)
    write_yaml_artefact(output, art)
    if plot:
        png = plot_validation(robot, result, output.with_suffix(".png"))
        console.out.print(f"plot: {png}")
    if torques_out is not None:
        path = write_torques_csv(torques_out, robot.joint_names, result.validation)
        console.out.print(f"torques: {path}")
    if params_out is not None:
        console.out.print(f"parameters: {write_parameters_csv(art, params_out, output.name)}")
    shown = console_rows(result, summary)
    console.summary_table(f"identify → {output}", shown)
    for w in result.warnings(opts):
        console.err.print(f"[yellow]warning:[/] {w}")
    if regrouped:
        console.err.print(f"note: fitted regrouped: {', '.join(regrouped)} ({REGROUPED_WHY})")
    return art
