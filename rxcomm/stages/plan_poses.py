"""`rxcomm plan-poses`: the ISO 9283 pose-cycle plan through P1–P5 (ISO 9283 §7.2.1, issue 17).

Reads the robot, its ISO 9283 paths (`rxcomm iso9283-paths`: the iso9283-rectangle spec defines the
test cube) and optionally a calibration (the poses' IK on the calibrated robot), and writes the plan
`run` executes: ``NAME.mcap`` with ``NAME.yaml`` beside it: a dwell at P1, then N cycles of
P5 → P4 → P3 → P2 → P1, each move a cycloidal profile at the catalogue limits (`model.catalogue`),
each pose held for the dwell the tracker measures in (`rxcomm iso9283 --pose-log`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from rxcomm import console
from rxcomm.errors import InputError
from rxcomm.io.files import trajectory_output
from rxcomm.io.yaml_io import read_yaml_artefact, read_yaml_model
from rxcomm.options import PLAN_OUTPUT, Iso9283Paths, RobotDir
from rxcomm.schemas.calibration import Calibration
from rxcomm.schemas.path import PathSpec
from rxcomm.schemas.trajectory import TrajectorySummary
from rxcomm.stages.declarations import DECLARATIONS
from rxcomm.stages.stage_cli import stage
from rxcomm.stages.summary import motion_summary

PLAN_CYCLES = 8  # the plan is sampled every 8 drive cycles: it dwells and moves slowly (run resamples)


@stage("plan-poses")
def command(
    robot_dir: RobotDir,
    output: Annotated[Path, PLAN_OUTPUT],
    paths: Iso9283Paths = None,
    calibration: Annotated[
        Path | None, typer.Option(help="calibration.yaml: the poses' IK on the calibrated robot.")
    ] = None,
    dynamics: Path | None = None,
    cycles: Annotated[int, typer.Option(help="Pose cycles (ISO 9283: 30).")] = 30,
    dwell_s: Annotated[float, typer.Option(help="Hold at each pose, s (the tracker measures in it).")] = 0.5,
) -> dict[str, object]:
    """Plan the ISO 9283 pose cycle P1 → P5 → P4 → P3 → P2 at the catalogue limits, for `run`."""
    from rxcomm.calibration.loading import load_calibrated_robot
    from rxcomm.io.trajectory import save_trajectory_mcap
    from rxcomm.model.base_parameters import load_dynamics
    from rxcomm.model.catalogue import catalogue_limits
    from rxcomm.model.robot import load_robot
    from rxcomm.planning.catalogue_timing import pose_cycle_plan
    from rxcomm.planning.ptp_problem import PtpDynamics

    t_all, output = time.perf_counter(), trajectory_output(output)
    rectangle = (Path(paths) if paths is not None else Path(robot_dir) / "paths") / "iso9283-rectangle.yaml"
    DECLARATIONS["plan-poses"].check(
        output=output, robot=robot_dir, paths=rectangle, calibration=calibration, dynamics=dynamics
    )
    if not rectangle.is_file():
        raise InputError("no iso9283-rectangle.yaml (write them with rxcomm iso9283-paths)", file=rectangle)
    nominal = load_robot(robot_dir)
    catalogue = catalogue_limits(nominal)  # the maker's, as the factory state's timing
    robot = nominal if calibration is None else load_calibrated_robot(nominal, calibration)
    params, fitted = (None, nominal) if dynamics is None else load_dynamics(dynamics, nominal)
    encoder, compliance = _commanded(fitted, calibration, params)
    spec = read_yaml_model(rectangle, PathSpec)
    sample_s = PLAN_CYCLES * robot.drives.cycle_s
    t0 = time.perf_counter()
    traj, order, report = pose_cycle_plan(
        robot,
        spec,
        catalogue,
        PtpDynamics.from_parameters(fitted, params, kinematics=robot),
        cycles,
        dwell_s,
        sample_s,
        encoder,
    )
    summary = motion_summary(traj.duration_s, time.perf_counter() - t0, report, traj.q[0], traj.q[-1])
    summary |= {
        "n_cycles": cycles,
        "dwell_s": dwell_s,
        "order": " ".join(order),
        "seconds": time.perf_counter() - t_all,
    }
    inputs = {"urdf": nominal.urdf_path, "drives": nominal.drives_path, "rectangle": rectangle}
    inputs |= {k: Path(v) for k, v in (("calibration", calibration), ("dynamics", dynamics)) if v is not None}
    settings = {
        "timing": "catalogue (cycloidal moves)",
        "catalogue": catalogue.as_dict(),
        "calibrated": calibration is not None,
        "compliance_compensated_rad_per_nm": compliance,
        "dynamics_model": "identified" if dynamics is not None else "prior",
        "sample_s": sample_s,
    }
    output.parent.mkdir(parents=True, exist_ok=True)
    save_trajectory_mcap(output, traj, TrajectorySummary.envelope(inputs, settings, summary))
    console.summary_table(f"plan-poses → {output}", {k: v for k, v in summary.items() if k != "order"})
    return summary


def _commanded(fitted, calibration: Path | None, params):
    """With a calibration that found joint compliance: the encoder angles that hold each link at its
    IK pose (`calibration.compliance`), and the compliances used; else none."""
    from rxcomm.calibration.compensation import compliance_command

    if calibration is None:
        return None, None
    return compliance_command(fitted, read_yaml_artefact(calibration, Calibration), params)
