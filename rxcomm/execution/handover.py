"""Handing the arm's weight to the drives before a run without feed-forward.

At the first enable after power-on a drive's integrator is empty (`rxcomm.cell.drives`): without a
feed-forward the arm sags until the loops build its holding torque. On an arm whose static torque is
large against its inertia (the loops' gains scale with it) that sag trips the drive: MuJoCo
Menagerie's i2rt YAM (J4: 1.1 N·m on 0.016 kg·m² at q = 0) reached the 35 mrad following-error window
70 ms after the enable, in every run without feed-forward, before its approach had moved. So a run or
campaign without feed-forward on drives just powered on (the simulated cell `run` starts is) first
stands still for `HANDOVER_S` with the model's static torque as feed-forward, ramped to zero: the
integrators take it over, and the plan starts on an arm standing under its own loops, as a
controller's that has been holding it does. A gateway's drives may hold already (a drive re-enabled
keeps its integrator: its holding-torque memory, and the torque actual reads 0 until a cycle has run):
adding the static torque there would kick the arm by it, so they get no hand-over. With the
feed-forward on, the plan's own torque holds. On a realtime cell the drives run from the enable on,
and the hand-over begins only once its stream's prefill is written (tens of ms, not measured): the
sag before it is not prevented there.
"""

from __future__ import annotations

import numpy as np

from rxcomm.execution.plan import StreamPlan, model_torque
from rxcomm.execution.session import Session
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.robot import Robot

HANDOVER_S = 1.0  # 15 × the drives' integral time (67 ms): the integrators follow the ramp closely


def rest_plan(q: np.ndarray, tau_ff: np.ndarray, sample_s: float) -> StreamPlan:
    """Standing still at ``q`` with the feed-forward ``tau_ff`` [n, dof], one row per sample."""
    n = tau_ff.shape[0]
    zeros = np.zeros_like(tau_ff)
    return StreamPlan(sample_s, np.repeat(np.asarray(q, dtype=float)[None], n, axis=0), zeros, zeros, tau_ff)


def handover_ramp(missing_nm: np.ndarray, sample_s: float, seconds: float = HANDOVER_S) -> np.ndarray:
    """``missing_nm`` [dof] ramped to zero over ``seconds`` (a smoothstep: no torque step at either
    end), one row per ``sample_s``, ending at zero."""
    k = max(2, int(np.ceil(seconds / sample_s - 1e-9)) + 1)
    x = np.linspace(0.0, 1.0, k)
    return (1.0 - x * x * (3.0 - 2.0 * x))[:, None] * np.asarray(missing_nm, dtype=float)[None]


def hand_over(ses: Session, robot: Robot, params: DynamicParameters, q: np.ndarray) -> np.ndarray:
    """Stand still at ``q`` for `HANDOVER_S`, the model's static torque there as feed-forward ramped
    to zero (module docstring); returns that torque [dof]. A stop raises `StreamStopped` as any
    stream does."""
    zeros = np.zeros((1, robot.n))
    static = model_torque(robot, params, np.asarray(q, dtype=float)[None], zeros, zeros)[0]
    ses.stream(rest_plan(q, handover_ramp(static, ses.cycle_s), ses.cycle_s))  # at the drive cycle
    return static
