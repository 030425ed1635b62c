"""Before a run without feed-forward on drives just powered on, the model's static torque is handed
over to the drives' integrators (rxcomm.execution.handover): the arm does not sag when the plan starts.

On drives whose integrators start empty the arm sags until they build its holding torque; MuJoCo
Menagerie's i2rt YAM (J4: 1.1 N·m on 0.016 kg·m² at q = 0) reached the 35 mrad following-error window
in 70 ms and tripped every run without feed-forward. Shown here on the hand-made arm, whose J2
sags 8 mrad from power-on without it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.execution.handover import HANDOVER_S, hand_over, handover_ramp, rest_plan
from rxcomm.execution.plan import model_torque
from rxcomm.execution.session import Session, StreamSettings
from rxcomm.model.dynamics import prior_parameters
from rxcomm.model.robot import load_robot

ARM = Path(__file__).parent / "data" / "handmade_arm.xml"


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("arm")
    for args in (["import-robot", str(ARM), "-o", str(out)], ["truth", "--robot", str(out), "--seed", "3"]):
        r = CliRunner().invoke(app, [*args, *(["-o", str(out / "truth.yaml")] if args[0] == "truth" else [])])
        assert r.exit_code == 0, r.output
    return out


def _hold_after_power_on(arm: Path, handover: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Max |actual − held| per joint over 0.5 s of standing still with zero feed-forward, right after
    the first enable (with or without the hand-over first), the last torque actual, the model's
    static torque."""
    from rxcomm.cell.sim import start_embedded_cell
    from rxcomm.gateway.client import GatewayClient

    robot = load_robot(arm)
    params = prior_parameters(robot)
    server = start_embedded_cell(arm / "truth.yaml", port=0)
    try:
        client = GatewayClient(server.host, server.port).connect()
        ses = Session(client, robot, StreamSettings(interpolation_ratio=1))
        ses.check_identity()
        ses.configure()
        client.enable_all()
        q = ses.demand()
        if handover:
            hand_over(ses, robot, params, q)
        log = ses.stream(rest_plan(q, np.zeros((1251, robot.n)), ses.cycle_s))
        client.disable_all()
        client.close()
    finally:
        server.stop()
    zeros = np.zeros((1, robot.n))
    return (
        np.abs(log.q_actual - q).max(axis=0),
        log.tau_actual[-1],
        model_torque(robot, params, q[None], zeros, zeros)[0],
    )


@pytest.mark.slow  # serves a simulated cell on 127.0.0.1 (the hand-over is a stream)
def test_the_static_torque_is_handed_to_the_integrators_and_the_arm_does_not_sag(arm):
    sag, _, static = _hold_after_power_on(arm, handover=False)
    assert sag[1] > 5e-3  # J2 sags from power-on while its integrator builds the holding torque
    held, tau, _ = _hold_after_power_on(arm, handover=True)
    assert held.max() < 0.05 * sag[1]
    # the loops alone hold the arm now: their torque is the model's static torque up to the truth's
    # difference from the model (its torque offsets and inertials, a few % of J2's)
    assert abs(tau[1] - static[1]) < 0.1 * abs(static[1])


def test_the_ramp_has_no_step():
    ramp = handover_ramp(np.array([10.0, -4.0]), 0.0004)
    assert len(ramp) == round(HANDOVER_S / 0.0004) + 1
    np.testing.assert_allclose(ramp[0], [10.0, -4.0])
    np.testing.assert_allclose(ramp[-1], 0.0, atol=1e-12)
    assert (
        np.abs(np.diff(ramp, axis=0)).max() < 10.0 * 1.5 * 0.0004 / HANDOVER_S + 1e-12
    )  # smoothstep slope ≤ 1.5
