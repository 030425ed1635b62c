"""`rxcomm plan-cycles PLAN`: a test path's plan repeated for the ISO 9283 cycles (issue 17).

ISO 9283 measures a path over repeated cycles (10 for AT/RT). The simulated cell draws the same noise
in every fresh run, so the cycles go into one plan: PLAN (a trajectory MCAP, e.g. `plan-cp`'s ISO
line), then per further cycle a dwell, a return move to its start (cycloidal, at the catalogue
limits of `model.catalogue`) and a dwell (`planning.iso9283.repeat_cycles`). Writes ``NAME.mcap``
with ``NAME.yaml`` beside it for `run`; `rxcomm iso9283` splits the log into its cycles.

``--duration-s`` first slows (or speeds up) the one cycle uniformly in time to that duration
(`planning.iso9283.time_scaled`): with ``--cycles 1`` the commissioned reference task at the factory's
cycle time, whose electrical energy `accept` compares at equal time (issue 29).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from rxcomm import console
from rxcomm.io.files import trajectory_output
from rxcomm.options import PLAN_OUTPUT, RobotDir
from rxcomm.schemas.trajectory import TrajectorySummary
from rxcomm.stages.declarations import DECLARATIONS
from rxcomm.stages.stage_cli import stage
from rxcomm.stages.summary import motion_summary


@stage("plan-cycles")
def command(
    plan: Annotated[Path, typer.Argument(help="The trajectory of one cycle (NAME.mcap, e.g. from plan-cp).")],
    robot_dir: RobotDir,
    output: Annotated[Path, PLAN_OUTPUT],
    cycles: Annotated[int, typer.Option(help="Cycles of the path (ISO 9283: 10).")] = 10,
    dwell_s: Annotated[float, typer.Option(help="Hold at each end of the path, s.")] = 0.3,
    dynamics: Path | None = None,
    payload: Path | None = None,
    duration_s: Annotated[
        float | None,
        typer.Option(help="Time-scale the cycle uniformly to this duration first, s (default: as planned)."),
    ] = None,
) -> dict[str, object]:
    """Repeat a test path's plan for the ISO 9283 cycles, with return moves at the catalogue limits."""
    from rxcomm.io.trajectory import Trajectory, load_trajectory_mcap, save_trajectory_mcap
    from rxcomm.model.catalogue import catalogue_limits
    from rxcomm.model.limits import check_limits
    from rxcomm.model.payload import model_inputs, model_parameters
    from rxcomm.model.robot import load_robot
    from rxcomm.planning.iso9283 import cycloidal_move, repeat_cycles, time_scaled
    from rxcomm.planning.ptp_problem import PtpDynamics

    t_all, plan, output = time.perf_counter(), Path(plan), trajectory_output(output)
    DECLARATIONS["plan-cycles"].check(
        output=output, robot=robot_dir, plan=plan, dynamics=dynamics, payload=payload
    )
    one, env = load_trajectory_mcap(plan)
    robot = load_robot(robot_dir)
    catalogue = catalogue_limits(robot)
    sample_s = float(np.median(np.diff(one.t)))
    planned_s = one.duration_s
    one = one if duration_s is None else time_scaled(one, duration_s, sample_s)
    rep = repeat_cycles(
        one, cycles, dwell_s, cycloidal_move(catalogue.v_max, catalogue.a_max, sample_s), sample_s
    )
    params, fitted = model_parameters(robot, dynamics, payload)  # None: the prior
    tau = PtpDynamics.from_parameters(fitted, params).torque(rep.q, rep.qd, rep.qdd)
    traj = Trajectory(rep.t, rep.q, rep.qd, rep.qdd, tau)
    report = check_limits(robot, traj.t, traj.q, traj.qd, traj.qdd, tau)
    summary = motion_summary(traj.duration_s, time.perf_counter() - t_all, report, traj.q[0], traj.q[-1])
    summary |= {
        "n_cycles": cycles,
        "cycle_duration_s": one.duration_s,
        "time_scale": one.duration_s / planned_s,
        "seconds": time.perf_counter() - t_all,
    }
    inputs = {"plan": plan, "urdf": robot.urdf_path, "drives": robot.drives_path}
    inputs |= model_inputs(dynamics, payload)
    settings = {"cycles": cycles, "dwell_s": dwell_s, "duration_s": duration_s,
                "return_moves": "cycloidal at the catalogue limits",
                "plan_settings": env.get("settings", {})}  # fmt: skip
    output.parent.mkdir(parents=True, exist_ok=True)
    save_trajectory_mcap(output, traj, TrajectorySummary.envelope(inputs, settings, summary))
    console.summary_table(f"plan-cycles → {output}", summary)
    return summary
