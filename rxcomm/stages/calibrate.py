"""`rxcomm calibrate`: geometric calibration from tracker measurements (paper §3.1–3.2, architecture §7).

Reads the robot and a measurements file (a `rxcomm/Measurements` artefact written by `run`, or a
tracker CSV — see `rxcomm.calibration.measurements.CSV_HELP`), fits the identifiable geometric error
parameters and writes `calibration.yaml` (kind `rxcomm/Calibration`: parameters ± σ, what was dropped and why,
the paper's Table 2 before/after on fitted and held-out poses, the base + tool baseline, and — when
the file has `baseline` poses — the same calibration from those, judged on the same held-out poses)
and, with `--urdf-out`, a calibrated URDF (load it with `load_robot(ROBOT_DIR, urdf=...)`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
import typer

from rxcomm import console
from rxcomm.errors import InputError
from rxcomm.io.validate import settings_from_options
from rxcomm.io.yaml_io import read_yaml_model, write_yaml_artefact
from rxcomm.options import CellFile, RobotDir, parse_numbers
from rxcomm.schemas.cell import Cell
from rxcomm.stages.stage_cli import stage

if TYPE_CHECKING:
    import pinocchio as pin

    from rxcomm.calibration.fit import CalibrationResult
    from rxcomm.model.robot import Robot


Model = Literal["auto", "frames", "offsets", "full", "full+compliance"]
Loss = Literal["linear", "soft_l1", "huber", "cauchy"]


def print_table(res: CalibrationResult) -> None:
    """The paper's Table 2 on the console: mm and degrees."""
    out = console.out
    out.print("  Table 2 (max |e| / peak-to-peak; x y z in mm, α β γ in deg)")
    for pose_set in ("fit", "heldout"):
        for model in ("nominal", "frames_only", "baseline_poses", "rigid", "calibrated"):
            st = res.tables.get((pose_set, model))
            if st is None:
                continue
            scale = np.array([1e3] * 3 + [np.degrees(1.0)] * 3)
            cells = [
                f"{m:7.3f}/{p:7.3f}" if np.isfinite(m) else "      –      "
                for m, p in zip(st.max_abs * scale, st.peak_to_peak * scale, strict=True)
            ]
            out.print(f"  {pose_set:<8}{model:<15}({st.n_poses:3d}) " + " ".join(cells))


def print_model_and_noise(robot: Robot, res: CalibrationResult, source: str) -> None:
    """The noise used, the model comparison, compliance, undetermined parameters, notes."""
    from rxcomm.calibration.artefact import compliance_estimates

    out = console.out
    n = res.noise
    ori = "" if n.orientation_sigma_rad is None else f", {n.orientation_sigma_rad * 1e3:.4g} mrad"
    out.print(f"  tracker noise ({source}): {n.position_sigma_m * 1e3:.4g} mm{ori} (1σ per axis)")
    if res.settings.regularise:
        out.print(f"  priors: the manufacturing classes × {res.prior_scale:.3g} (the data's scale)")
    out.print(
        "  candidate models (cross-validated over the fit poses, a report; the estimate is regularised by "
        "the priors; rms position / orientation):"
    )
    for c in res.candidates:
        mark = "→" if c.name == res.model else " "
        if c.cv_misfit is None:
            out.print(f"   {mark} {c.name:<16}{c.n_parameters:3d} p   not scored: {c.note}")
            continue
        o = "" if c.cv_rms_orientation_rad is None else f" / {c.cv_rms_orientation_rad * 1e3:.4g} mrad"
        out.print(
            f"   {mark} {c.name:<16}{c.n_parameters:3d} p   {c.cv_rms_position_m * 1e3:.4g} mm{o}"
            f"   misfit {c.cv_misfit:.4g} ± {c.cv_se or 0.0:.2g}"
        )
    for est in compliance_estimates(robot, res.fit):
        k = "–" if est.stiffness_nm_per_rad is None else f"{est.stiffness_nm_per_rad:.4g} N·m/rad"
        out.print(
            f"  {est.joint}: compliance {est.compliance_rad_per_nm:.4g} ± {est.std:.2g} rad/(N·m), "
            f"stiffness {k}"
        )
    if res.undetermined:
        out.print(
            f"  [yellow]not determined by these data (σ > {res.settings.undetermined_std_ratio:g} × the "
            f"position noise at the TCP, or above 70 % of the prior's: left near the prior): "
            f"{', '.join(res.undetermined)}[/yellow]"
        )
    for note in res.notes:
        out.print(f"  [yellow]note:[/yellow] {note}")


def _parse_sigma(text: str | None) -> tuple[float | None, float | None]:
    """`--tracker-sigma POS_M[,ORI_RAD]`: (σ_p, σ_o or None)."""
    if text is None:
        return None, None
    vals = parse_numbers(text, 2 if "," in text else 1, "tracker-sigma", "POS_M[,ORI_RAD]")
    if not np.all(vals > 0):
        raise InputError(f"noise must be > 0, got {text!r}", field="tracker-sigma")
    return float(vals[0]), float(vals[1]) if vals.size == 2 else None


# The options, named here so that `command` reads as a list.
MeasurementsOption = Annotated[
    Path, typer.Option(help="Measurements: a rxcomm/Measurements YAML (from run) or a tracker CSV.")
]
UrdfOutOption = Annotated[
    Path | None,
    typer.Option("--urdf-out", help="Also write the calibrated URDF here (with the TCP as link 'tcp')."),
]
MdhOutOption = Annotated[
    Path | None,
    typer.Option(
        "--mdh-out",
        help="Also write the calibrated kinematics as modified DH parameters and joint zero offsets "
        "here (YAML, and a CSV beside it), with the residual MDH cannot express.",
    ),
]
CellOption = CellFile  # its nominal tracker_to_base and tracker noise (else from the measurements)
HoldoutOption = Annotated[
    float | None,
    typer.Option(
        "--holdout-fraction",
        help="Fraction of fit poses held out (default: 0 with validation poses, else 0.25).",
    ),
]
TrackerSigmaOption = Annotated[
    str | None,
    typer.Option(
        help="Tracker noise POS_M[,ORI_RAD] (1σ per axis), e.g. 5e-5,1e-4; overrides the cell's. "
        "Default: the cell's, the measurement file's, else estimated from the residuals."
    ),
]
ModelOption = Annotated[
    Model,
    typer.Option("--error-model", help="Error model; auto: chosen by cross-validation over the fit poses."),
]


def _cell_and_noise(
    cell: Path | None, tracker_sigma: str | None, inputs: dict[str, Path]
) -> tuple[pin.SE3 | None, dict[str, float], str | None]:
    """(the cell's tracker_to_base guess, noise settings, where the noise came from): the cell's
    tracker, overridden by `--tracker-sigma`; None: the measurements' or estimated."""
    from rxcomm.model.geometric_errors import placement_to_se3

    t2b, overrides, source = None, {}, None
    if cell is not None:
        tr = read_yaml_model(cell, Cell).tracker
        t2b = placement_to_se3(tr.tracker_to_base.xyz_m, tr.tracker_to_base.rpy_rad)
        overrides = {
            "position_sigma_m": tr.position_sigma_m,
            "orientation_sigma_rad": tr.orientation_sigma_rad,
        }
        inputs["cell"] = Path(cell)
        source = "cell"
    sp, so = _parse_sigma(tracker_sigma)
    if sp is not None:
        overrides, source = {"position_sigma_m": sp, "orientation_sigma_rad": so}, "option"
    return t2b, {k: v for k, v in overrides.items() if v is not None}, source


def _write_exports(
    robot: Robot, res: CalibrationResult, inputs: dict[str, Path], urdf_out: Path | None, mdh_out: Path | None
) -> dict[str, object]:
    """The calibrated URDF (with the TCP frame) and the MDH + zero-offset tables; returns the MDH
    residuals for the calibration's summary."""
    from rxcomm.calibration.exports import kinematics_artefact, write_kinematics
    from rxcomm.calibration.urdf import write_calibrated_urdf

    if urdf_out is not None:
        Path(urdf_out).parent.mkdir(parents=True, exist_ok=True)
        write_calibrated_urdf(robot, res.fit.errors, urdf_out)
    if mdh_out is None:
        return {}
    Path(mdh_out).parent.mkdir(parents=True, exist_ok=True)
    with console.err.status("calibrate: fitting the MDH tables"):
        kin = kinematics_artefact(robot, res.fit.errors, inputs)
    _, csv_path = write_kinematics(mdh_out, kin)
    console.out.print(f"  MDH + zero offsets → {mdh_out}, {csv_path}")
    for note in kin.notes:
        console.out.print(f"  [yellow]note:[/yellow] {note}")
    return kin.summary.model_dump(exclude={"n_sample_poses"})


@stage("calibrate", check=True)
def command(
    robot_dir: RobotDir,
    measurements: MeasurementsOption,
    output: Annotated[Path, typer.Option("-o", "--output", help="Output calibration.yaml.")],
    urdf_out: UrdfOutOption = None,
    mdh_out: MdhOutOption = None,
    cell: CellOption = None,
    holdout: HoldoutOption = None,
    loss: Annotated[Loss, typer.Option(help="Robust loss on the weighted residuals.")] = "linear",
    outlier_sigma: Annotated[float, typer.Option(help="Flag poses beyond this many robust σ.")] = 5.0,
    keep_outliers: Annotated[bool, typer.Option(help="Keep flagged poses in the final fit.")] = False,
    seed: Annotated[int, typer.Option(help="Seed of the held-out split.")] = 0,
    tracker_sigma: TrackerSigmaOption = None,
    model: ModelOption = "auto",
    dynamics: Path | None = None,  # its holding torques bend the joints in the compliance model
) -> dict[str, object]:
    """Identify the robot's geometric errors from tracker measurements; write the calibration.

    --cell: its nominal tracker_to_base and tracker noise (else from the measurements). --dynamics: its
    holding torques bend the joints in the compliance model (default: the prior model)."""
    from rxcomm.calibration.artefact import calibration_artefact
    from rxcomm.calibration.fit import calibrate
    from rxcomm.calibration.measurements import read_measurements
    from rxcomm.calibration.settings import CalibrateSettings
    from rxcomm.model.base_parameters import load_dynamics
    from rxcomm.model.robot import load_robot

    output = Path(output)
    robot = load_robot(robot_dir)
    ms = read_measurements(measurements, robot)
    inputs: dict[str, Path] = {
        "urdf": robot.urdf_path,
        "drives": robot.drives_path,
        "measurements": Path(measurements),
    }
    t2b, overrides, noise_source = _cell_and_noise(cell, tracker_sigma, inputs)
    settings = settings_from_options(
        CalibrateSettings,
        dict(
            holdout_fraction=holdout,
            seed=seed,
            loss=loss,
            outlier_sigma=outlier_sigma,
            drop_outliers=not keep_outliers,
            model=model,
            **overrides,
        ),
        {"holdout_fraction": "holdout", "outlier_sigma": "outlier-sigma"},
    )
    params = None
    if dynamics is not None:
        params = load_dynamics(dynamics, robot).params  # the fit's torques: on the kinematics it estimates
        inputs["dynamics"] = Path(dynamics)
    with console.phase(f"calibrate: fitting {robot.name} to {ms.n} poses"):
        res = calibrate(robot, ms, settings, tracker_to_base=t2b, dynamics=params)
    output.parent.mkdir(parents=True, exist_ok=True)
    exported = _write_exports(robot, res, inputs, urdf_out, mdh_out)
    art = calibration_artefact(robot, res, inputs, urdf_out, noise_source)
    figures = {**art.summary.model_dump(exclude_unset=True), **exported}
    art = art.model_copy(update={"summary": type(art.summary).model_validate(figures)})
    write_yaml_artefact(output, art)
    console.summary_table(f"calibrate → {output}", art.summary)
    print_table(res)
    print_model_and_noise(robot, res, art.tracker_noise.source)
    if res.outlier_idx.size:
        console.out.print(f"  outlier poses: {res.outlier_idx.tolist()}")
    if res.baseline is not None and res.baseline.fit is None:
        console.out.print(f"  baseline poses: no fit ({res.baseline.note})")
    return art.summary
