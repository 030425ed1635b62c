"""The MuJoCo plant against rxcomm's own models: checks that do not go through our dynamics.

MuJoCo parses the URDF itself and computes its own inverse dynamics (`mj_inverse`: rigid bodies,
armature, tendon armature of the coupled wrist motor, joint and tendon friction, the balancer as a
spatial tendon) and forward kinematics; a URDF read differently by either side, an inertia frame, a
coupling or a spring shape shows up here.
"""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest
import yaml

from rxcomm.cell.mujoco_model import build_mujoco_model
from rxcomm.cell.mujoco_plant import MujocoPlant, MujocoSiteTracker
from rxcomm.cell.sim import simulated_cell
from rxcomm.cell.tracker import SimulatedTracker
from rxcomm.cell.truth import load_truth
from rxcomm.model.dynamics import RobotDynamics, random_states
from rxcomm.model.geometric_errors import ErrorModel
from rxcomm.model.kinematics import tcp_pose

TRUTHS = ["samples/rx130l/truth.yaml", "samples/m900/truth.yaml"]


def _mj_inverse(built, offset: np.ndarray, q, qd, qdd) -> np.ndarray:
    m, d = built.model, mujoco.MjData(built.model)
    out = np.empty_like(q)
    for i in range(len(q)):
        d.qpos[built.motor_qpos], d.qvel[built.motor_dof], d.qacc[built.motor_dof] = q[i], qd[i], qdd[i]
        mujoco.mj_inverse(m, d)
        # qfrc_inverse is what the actuators must supply; the truth's offset is a constant load on top
        out[i] = d.qfrc_inverse[built.motor_dof] + offset
    return out


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_mujoco_dry_friction_is_the_truths_coulomb_wherever_identify_fits():
    """MuJoCo's dry friction is a soft constraint; measured per plant step on a drive-driven move of every
    joint (M900), its force is exactly F_c·sgn(q̇) from 0.01 rad/s up (below F_c only under 0.0085 rad/s
    on the chain's excitation, where identify keeps no row: it rejects |q̇| < 0.05 rad/s and 1/cut-off
    around), and the damping is F_v·q̇ at the step's start. So the soft constraint biases no base
    parameter: the M900's j1.fc / j1.fv miss was the tilted J1's gravity (architecture §6.1)."""
    cell = simulated_cell(TRUTHS[1], plant="mujoco", q0=[0.0, -0.3, 0.6, 0.0, 0.5, 0.0])
    plant, p = cell.plant, cell.truth.params
    d, b = plant.data, plant.built
    rows, step = [], plant.step

    def recorded(tau, braked):
        v = d.qvel[b.motor_dof].copy()
        step(tau, braked)
        rows.append((v, d.qfrc_constraint[b.motor_dof].copy(), d.qfrc_passive[b.motor_dof].copy()))

    plant.step = recorded
    start = cell.feedback().position_rad.copy()
    amplitude = np.array([0.4, 0.2, 0.2, 0.3, 0.3, 0.3])
    for k in range(int(2.0 / cell.cycle_s)):  # half a sine period: through rest at both ends
        s = np.sin(np.pi * k * cell.cycle_s / 2.0) ** 2
        cell.cycle(start + amplitude * s, np.zeros(6), np.ones(6, bool))
    v, friction, passive = (np.array(x) for x in zip(*rows, strict=True))
    sliding = np.abs(v) >= 0.01
    assert sliding.sum(axis=0).min() > 1000
    fc = np.broadcast_to(p.coulomb_nm, v.shape)
    np.testing.assert_allclose(friction[sliding], -(fc * np.sign(v))[sliding], rtol=1e-9, atol=0)
    np.testing.assert_allclose(passive, -p.viscous_nm_s_per_rad * v, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("truth_path", TRUTHS)
def test_mj_inverse_equals_rxcomm_inverse_dynamics(truth_path):
    truth = load_truth(truth_path)
    built = build_mujoco_model(truth, errors=False, compliance=False)
    q, qd, qdd = random_states(truth.robot, 200, seed=26)
    tau_rx = RobotDynamics(truth.robot, truth.params).inverse_dynamics(q, qd, qdd)
    tau_mj = _mj_inverse(built, np.array(truth.params.offset_nm), q, qd, qdd)
    assert _relative(tau_mj, tau_rx) <= 1e-6
    # every term is in play: friction, rotor and (RX130L) spring each move τ far beyond the tolerance
    for field, factor in (("coulomb_nm", 1.01), ("rotor_inertia_kgm2", 1.01), ("spring", 1.01)):
        value = getattr(truth.params, field)
        if value is None:
            continue
        other = RobotDynamics(truth.robot, replace(truth.params, **{field: np.asarray(value) * factor}))
        assert _relative(tau_mj, other.inverse_dynamics(q, qd, qdd)) > 1e-5, field


def test_coupled_wrist_rotor_is_a_tendon():
    """The RX130L's motor 6 (40·(q6 + 0.4·q5)) as a tendon: its inertia couples q5 and q6 (Rᵀ·J·R)."""
    truth = load_truth(TRUTHS[0])
    built = build_mujoco_model(truth, errors=False, compliance=False)
    m = built.model
    tendon = m.tendon("motor_6").id
    assert m.tendon_armature[tendon] == pytest.approx(truth.params.rotor_inertia_kgm2[5])
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    j5, j6 = built.motor_dof[4], built.motor_dof[5]
    unit, column = np.zeros(m.nv), np.zeros(m.nv)
    unit[j6] = 1.0
    mujoco.mj_mulM(m, d, column, unit)
    dyn = RobotDynamics(truth.robot, truth.params)
    links_only = dyn.mass_matrix(np.zeros(6))[4, 5] - dyn.rotor_matrix[4, 5]
    assert column[j5] == pytest.approx(dyn.mass_matrix(np.zeros(6))[4, 5], rel=1e-9)
    assert column[j5] - links_only == pytest.approx(16 * 40 * truth.params.rotor_inertia_kgm2[5], rel=1e-9)


@pytest.mark.parametrize("truth_path", TRUTHS)
@pytest.mark.parametrize("errors", [False, True])
def test_mujoco_fk_equals_rxcomm_fk(truth_path, errors):
    truth = load_truth(truth_path)
    built = build_mujoco_model(truth, errors=errors, compliance=False)
    m, d = built.model, mujoco.MjData(built.model)
    model_errors = ErrorModel.from_mapping(
        truth.robot, truth.truth.geometry.error_parameters if errors else {}
    )
    q, _, _ = random_states(truth.robot, 100, seed=3)
    worst_p = worst_r = 0.0
    for qi in q:
        d.qpos[built.motor_qpos] = qi
        mujoco.mj_kinematics(m, d)
        p, r = tcp_pose(truth.robot, qi, model_errors)
        worst_p = max(worst_p, float(np.linalg.norm(d.site_xpos[built.tcp_site] - p)))
        worst_r = max(worst_r, float(np.abs(d.site_xmat[built.tcp_site].reshape(3, 3) - r).max()))
    assert worst_p <= 1e-6 and worst_r <= 1e-9
    if errors:  # the errors are really on the MuJoCo side: the nominal TCP is mm away
        p0, _ = tcp_pose(truth.robot, q[0])
        d.qpos[built.motor_qpos] = q[0]
        mujoco.mj_kinematics(m, d)
        assert np.linalg.norm(d.site_xpos[built.tcp_site] - p0) > 1e-3


def test_static_deflection_equals_own_tracker():
    """A compliant joint (second hinge with stiffness) at rest sags as the own tracker computes it:
    MuJoCo's site and our compliance model agree on the TCP to well below a µm."""
    truth = load_truth(TRUTHS[0])
    rng = np.random.default_rng(0)
    own = SimulatedTracker(truth.robot, truth.truth, rng)
    for q0 in ([0.0, -0.5, 1.2, 0.0, 0.6, 0.0], [0.3, 0.4, 0.2, 1.0, -0.5, 0.3]):
        plant = MujocoPlant(truth, np.array(q0))
        site = MujocoSiteTracker(plant.built, truth, truth.truth, rng)
        sag = plant.link_angles() - q0
        assert np.abs(sag[1:3]).max() > 1e-5  # joints 2 and 3 do sag (≈ 0.1 mrad)
        gap = site.true_pose(plant.tracker_state).translation - own.true_pose(np.array(q0)).translation
        assert np.linalg.norm(gap) < 1e-7


def test_mujoco_cell_follows_like_the_own_cell():
    """The same drives on both plants: a 1 s move leaves following errors within 20 % of each other,
    a braked (disabled) arm stays where it is on MuJoCo too."""
    q0 = [0.0, -0.5, 1.2, 0.0, 0.6, 0.0]
    step = np.array([0.5, 0.3, -0.3, 0.5, 0.5, 0.5])
    peaks = {}
    for plant in ("own", "mujoco"):
        cell = simulated_cell(TRUTHS[0], plant=plant, q0=q0)
        start = cell.feedback().position_rad.copy()
        fe = []
        for k in range(2500):
            s = 0.5 * (1 - np.cos(min(k * cell.cycle_s, 1.0) * np.pi))
            fb = cell.cycle(start + s * step, np.zeros(6), np.ones(6, bool))
            fe.append(np.abs(fb.following_error_rad))
        peaks[plant] = np.max(fe, axis=0)
        if plant == "mujoco":
            held = cell.plant.q
            for _ in range(500):
                cell.cycle(held, np.zeros(6), np.zeros(6, bool))
            assert np.abs(cell.plant.q - held).max() < 1e-5
            assert "torque offset" in " ".join(cell.plant_notes)
    assert np.all(np.abs(peaks["mujoco"] - peaks["own"]) <= 0.2 * peaks["own"])


@pytest.mark.socket  # serves the gateway on 127.0.0.1
def test_cell_sim_on_mujoco_serves_and_says_what_is_not_faithful():
    """`cell-sim --plant mujoco`: the gateway answers on the MuJoCo plant, the tracker reads its site,
    and the start-up facts list what has no faithful MuJoCo form."""
    import threading

    from rxcomm.gateway.client import GatewayClient
    from rxcomm.stages import cell_sim

    q_visible = (-0.4, 0.2, 1.2, 0.0, 0.8, 0.0)
    facts: list[dict] = []
    ready, stop = threading.Event(), threading.Event()
    kwargs = {"port": 0, "q0": ",".join(map(str, q_visible)), "plant": "mujoco", "stop": stop}
    t = threading.Thread(
        target=lambda: cell_sim.run(TRUTHS[0], on_ready=lambda f: (facts.append(f), ready.set()), **kwargs),
        daemon=True,
    )
    t.start()
    try:
        assert ready.wait(30)
        port = int(facts[0]["address"].rsplit(":", 1)[1])
        with GatewayClient("127.0.0.1", port, timeout_s=2.0).connect() as c:
            np.testing.assert_allclose(c.positions_rad(), q_visible, atol=1e-6)
            assert c.read_tracker() is not None
    finally:
        stop.set()
        t.join(20)
    assert facts[0]["plant"] == "mujoco"
    notes = " ".join(facts[0]["plant_notes"])
    assert "torque offset" in notes and "compliance" in notes and "friction" in notes


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["cell-sim", "--truth", TRUTHS[0], "--port", "0", "--plant", "bullet"], "unknown plant"),
        (
            ["run", "configs.yaml", "--robot", "samples/rx130l", "-o", "x.yaml"]
            + ["--gateway", "127.0.0.1:1502", "--plant", "mujoco"],
            "--plant",
        ),
    ],
)
def test_bad_plant_options_exit_2(args, needle):
    from typer.testing import CliRunner

    from rxcomm.cli import app

    r = CliRunner().invoke(app, args)
    assert r.exit_code == 2, r.output
    assert needle in r.output


@pytest.fixture(scope="module")
def true_dynamics_rx(tmp_path_factory, rx130l):
    """dynamics.yaml holding the cell's TRUE parameters (scoring only, as tests/test_run_sim.py)."""
    from rxcomm.io.yaml_io import write_yaml_artefact
    from rxcomm.model.base_parameters import base_parameters, dynamics_artefact_fields
    from rxcomm.schemas.dynamics import Dynamics

    true = load_truth(TRUTHS[0]).params
    bset = base_parameters(rx130l)
    fields = dynamics_artefact_fields(rx130l, bset, bset.project(true), full=true, full_method="truth (test)")
    summary = {"n_base_params": bset.n_base, "validation_nrmse": [0.0] * 6, "validation_rms_nm": [0.0] * 6}
    art = Dynamics(**Dynamics.envelope({}, {}, {**summary, "seconds": 0.0}), **fields)
    return write_yaml_artefact(tmp_path_factory.mktemp("dyn") / "true-dynamics.yaml", art)


@pytest.mark.slow
def test_feedforward_cuts_the_lag_on_mujoco_too(tmp_path, rx130l, true_dynamics_rx):
    """`run --plant mujoco`: the same plan, the same drives, MuJoCo's physics; the true model's
    feed-forward cuts the joint lag ≥ 3× as on our plant, and the run says what is not faithful."""
    from typer.testing import CliRunner

    from rxcomm.cli import app

    from .test_run import save_plan
    from .test_run_sim import FAST, HOME, cosine_plan

    plan = save_plan(tmp_path / "fast.mcap", cosine_plan(HOME, FAST, 1.1))
    common = ["--robot", "samples/rx130l", "--dynamics", str(true_dynamics_rx), "--interpolation-ratio", "1"]
    common += ["--plant", "mujoco"]
    runs = {}
    for name, extra in (("off", ["--no-feedforward"]), ("on", [])):
        r = CliRunner().invoke(app, ["run", str(plan), *common, *extra, "-o", str(tmp_path / f"{name}.mcap")])
        assert r.exit_code == 0, r.output
        assert "mujoco" in r.output and "not faithful: torque offset" in r.output
        runs[name] = yaml.safe_load((tmp_path / f"{name}.yaml").read_text())["summary"]
    lag_on, lag_off = np.array(runs["on"]["max_lag_rad"]), np.array(runs["off"]["max_lag_rad"])
    assert np.all(lag_off[:3] >= 3.0 * lag_on[:3]), (lag_off, lag_on)
    assert runs["off"]["max_tcp_error_m"] >= 3.0 * runs["on"]["max_tcp_error_m"]
