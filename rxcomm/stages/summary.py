"""The summary head every trajectory-writing stage gives (`TrajectoryFigures`' required fields).

Not a subcommand: the plan stages (plan-ptp, plan-cycles, plan-poses) share it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from rxcomm.model.limits import LimitReport


def motion_summary(
    duration_s: float, solve_seconds: float, report: LimitReport, q_start, q_goal
) -> dict[str, object]:
    """The required summary keys of a motion checked against its limits in `report`."""
    return {
        "duration_s": duration_s,
        "solve_seconds": solve_seconds,
        "max_limit_ratio": report.max_ratio,
        "active_fraction": report.active_fraction(),
        "q_start": np.asarray(q_start).tolist(),
        "q_goal": np.asarray(q_goal).tolist(),
    }


def planned_energy(robot, traj, objective_j: float | None) -> dict[str, object]:
    """The plan's electrical energy on its drive-cycle samples with the planning model's torques
    (`model.energy.electrical_energy`, what `run` would measure with a perfect model; null without
    winding resistances) and, for an energy-objective plan, what the NLP's smooth objective said on
    its nodes (issue 29: the two differ by the smoothing and the node spacing)."""
    from rxcomm.model.energy import electrical_energy

    out: dict[str, object] = {
        "planned_electrical_energy_j": electrical_energy(robot, traj.t, traj.qd, traj.tau_ff)
    }
    if objective_j is not None:
        out["energy_objective_j"] = objective_j
    return out
