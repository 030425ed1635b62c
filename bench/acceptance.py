"""Factory state rows (issue 17): the catalogue limits' compute time and what they cost in cycle time.

The factory's CP timing (catalogue limits, toppra + setpoint filter) against toppra under the drives'
own limits and the prior model's torques on the same line: the planned share of time the commissioned
state can save (the run on the cell, in `make commission`, measures it).
"""

from __future__ import annotations

from pathlib import Path

from bench.table import Row, median_seconds
from rxcomm.io.yaml_io import load_yaml
from rxcomm.model.catalogue import catalogue_limits
from rxcomm.model.dynamics import prior_parameters
from rxcomm.model.robot import load_robot
from rxcomm.planning.catalogue_timing import plan_cp_catalogue
from rxcomm.planning.cp import CpSettings, plan_cp
from rxcomm.planning.paths import build_path
from rxcomm.planning.timing import PlanDynamics
from rxcomm.schemas.path import PathSpec

ROOT = Path(__file__).resolve().parent.parent
LINE = ROOT / "samples/rx130l/paths/line-near-singularity.yaml"


def rows(quick: bool) -> list[Row]:
    robot = load_robot(ROOT / "samples/rx130l")
    t_cat = median_seconds(lambda: catalogue_limits(robot), repeats=1 if quick else 3)
    cat = catalogue_limits(robot)
    path = build_path(PathSpec.model_validate(load_yaml(LINE)))
    dyn = PlanDynamics.from_parameters(robot, prior_parameters(robot), 0.02)
    factory = plan_cp_catalogue(robot, path, cat, dyn)
    optimal = plan_cp(robot, path, dyn, CpSettings(method="toppra", torque_rate=False))
    return [
        Row("factory", f"catalogue limits ({cat.n_poses} poses, RX130L)", "s", t_cat, "", "", None, ""),
        Row("factory", "catalogue speed scale k_v (v = k_v·v_rated)", "", float(cat.velocity_scale.min()),
            "", "", None, ""),
        Row("factory", "catalogue acceleration scale k_a (a = k_a·a_drive)", "",
            float(cat.acceleration_scale.min()), "", "", None, ""),
        Row("factory", "singular line: planned duration, catalogue vs toppra at the limits", "s",
            factory.duration_s, "", "toppra, prior model", optimal.duration_s, "ratio ≥ 1/0.7"),
    ]  # fmt: skip
