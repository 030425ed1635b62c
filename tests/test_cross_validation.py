"""Blocked cross-validation of the identification, the cut-off chosen from the data (`--cutoff-hz
auto`) and the parameter CSV export (truth read here only, to make the logs)."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.errors import InputError
from rxcomm.identification.cross_validation import choose_cutoff, cross_validate, fold_of
from rxcomm.identification.estimation import JointGrams, estimate, estimate_from_grams
from rxcomm.identification.excitation_problem import ExcitationProblem
from rxcomm.identification.export import export_dynamics_csv
from rxcomm.identification.fit import identify, score
from rxcomm.identification.logs import JointLog, check_log
from rxcomm.identification.processing import preprocess, regressor
from rxcomm.identification.settings import IdentifySettings
from rxcomm.io.yaml_io import read_yaml_artefact, read_yaml_model
from rxcomm.model.base_parameters import base_parameters
from rxcomm.model.dynamics import truth_parameters
from rxcomm.schemas.cell import Cell
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.schemas.excitation import ExcitationSettings
from rxcomm.schemas.truth import CellTruth

from .conftest import SAMPLES
from .test_identification import measured, sampled, write_run_log


@pytest.fixture(scope="module")
def truth_rx():
    return read_yaml_model(SAMPLES / "rx130l" / "truth.yaml", CellTruth)


@pytest.fixture(scope="module")
def bset_rx(rx130l):
    return base_parameters(rx130l)


@pytest.fixture(scope="module")
def noisy_log(rx130l, bset_rx, truth_rx):
    """Three periods of a random feasible excitation, the cell's true torques + its noise."""
    cell = read_yaml_model(SAMPLES / "rx130l" / "cell.yaml", Cell)
    prob = ExcitationProblem(rx130l, cell.allowed_region, ExcitationSettings(check_samples=400), bset_rx)
    traj = prob.trajectory(prob.random_feasible(np.random.default_rng(11)))
    t, q, qd, qdd = sampled(rx130l, traj, periods=3)
    truth = truth_parameters(rx130l, truth_rx)
    q_m, tau_m = measured(rx130l, truth, t, q, qd, qdd, truth_rx.noise.torque_noise_nm, 1e-6, seed=5)
    return JointLog(t, q_m, tau_m, "excite-log.mcap")


def test_folds_are_contiguous_equal_blocks_in_time():
    t = np.linspace(0.0, 10.0, 1001)
    k = fold_of(t, 5, 0.0, 10.0)
    assert np.all(np.diff(k) >= 0) and set(k) == set(range(5))  # contiguous, in time order
    assert np.bincount(k).tolist() == [200, 200, 200, 200, 201]  # the last block holds t1
    assert fold_of(np.array([-0.1, 10.1]), 5, 0.0, 10.0).tolist() == [-1, -1]


def test_held_out_error_is_the_fit_error_when_the_model_is_right(rx130l, bset_rx, noisy_log):
    """The model has the truth's form, so the held-out folds are predicted as well as the fitted rows,
    within the noise: held-out RMS ≥ in-sample RMS (in total), at most 30 % above it per joint."""
    s = IdentifySettings()
    data = preprocess(check_log(noisy_log, rx130l, s), s, rx130l)
    cv = cross_validate(rx130l, bset_rx, data, s)
    assert cv.folds == cv.folds_scored == 5
    assert np.all(np.isfinite(cv.rms_nm)) and cv.n_rows == int((~data.near_stick).sum())  # all rows, once
    assert cv.rms_nm.sum() >= cv.fit_rms_nm.sum()
    assert np.all(cv.rms_nm <= 1.3 * cv.fit_rms_nm), (cv.rms_nm, cv.fit_rms_nm)
    assert np.all(cv.r2 > 0.999)


@pytest.mark.parametrize("method", ["wls", "ols"])
def test_the_folds_estimate_from_gram_matrices_is_estimate_on_those_rows(rx130l, bset_rx, noisy_log, method):
    s = IdentifySettings(method=method)
    data = preprocess(check_log(noisy_log, rx130l, s), s, rx130l)
    w = bset_rx.base_regressor(regressor(rx130l, data))
    train = (data.t < 5.0) | (data.t > 9.0)
    rows = np.repeat(train, 6) & ~data.near_stick.ravel()
    grams = JointGrams.of_rows(w[rows], data.tau.ravel()[rows], np.tile(np.arange(6), len(data.t))[rows], 6)
    direct = estimate(rx130l, bset_rx, data.select(train), s)
    std = np.sqrt(np.diag(direct.cov))
    assert np.all(np.abs(estimate_from_grams(grams, s) - direct.p_b) < 1e-5 * std)  # equal within rounding
    few = JointGrams.of_rows(w[:30], data.tau.ravel()[:30], np.tile(np.arange(6), 5), 6)
    assert estimate_from_grams(few, s) is None  # fewer rows than parameters: refused, as estimate does


def test_held_out_error_exposes_a_missing_friction_model(rx130l, noisy_log):
    """The cell's wrist motor has its own friction: without those columns (joint friction only) the
    held-out folds of J5 and J6 are predicted measurably worse than with them."""
    both = identify(rx130l, noisy_log, IdentifySettings(friction="both")).cross_validation
    joint = identify(rx130l, noisy_log, IdentifySettings(friction="joint")).cross_validation
    assert np.all(joint.rms_nm[4:] > 1.05 * both.rms_nm[4:]), (joint.rms_nm, both.rms_nm)


def test_every_identification_states_its_held_out_error(rx130l, noisy_log):
    res = identify(rx130l, noisy_log)
    summary = res.summary()
    assert summary["cv_folds"] == summary["cv_folds_scored"] == 5
    assert len(summary["cv_rms_nm"]) == 6 and all(v > 0 for v in summary["cv_rms_nm"])
    assert summary["cutoff_choice"] == "given (--cutoff-hz)"
    off = identify(rx130l, noisy_log, IdentifySettings(folds=0))
    assert off.cross_validation is None and off.summary()["cv_folds"] == 0
    assert "cv_rms_nm" not in off.summary()  # not measured: no figure, never 0


@pytest.mark.slow
def test_cutoff_auto_picks_the_cutoff_that_predicts_held_out_torque(rx130l, bset_rx, noisy_log):
    """A 2 Hz cut-off smears the excitation's friction reversals and rejects the rows near them (the
    stick guard is 1/cutoff); 10 Hz predicts the same held-out rows better and is chosen. At 20 and
    40 Hz this log does not separate the wrist motor's friction from J6's: not scored, not chosen."""
    s = IdentifySettings(cutoff_hz="auto", cutoff_grid_hz=(2.0, 10.0))
    clean = check_log(noisy_log, rx130l, s)
    choice = choose_cutoff(rx130l, bset_rx, clean, s)
    assert choice.cutoff_hz == 10.0 and choice.reference_hz == 10.0
    assert choice.mean_nrmse[0] > 1.05 * choice.mean_nrmse[1]
    wide = choose_cutoff(rx130l, bset_rx, clean, IdentifySettings(cutoff_hz="auto"))
    assert wide.cutoff_hz in (5.0, 10.0) and "20 Hz: not scored, 40 Hz: not scored" in wide.reason
    res = identify(rx130l, noisy_log, s, bset=bset_rx)
    summary = res.summary()
    assert summary["cutoff_hz"] == 10.0 and summary["sample_hz"] == pytest.approx(20.0, rel=0.01)
    assert summary["cutoff_choice"].startswith("auto: least mean cross-validated held-out NRMSE")
    assert summary["cutoff_grid_hz"] == [2.0, 10.0] and len(summary["cutoff_grid_cv_nrmse"]) == 2
    # the same as identifying at the chosen cut-off directly
    given = identify(rx130l, noisy_log, IdentifySettings(cutoff_hz=10.0), bset=bset_rx)
    np.testing.assert_allclose(res.p_b, given.p_b, rtol=1e-12)
    with pytest.raises(InputError, match="below 0.4"):
        choose_cutoff(rx130l, bset_rx, clean, IdentifySettings(cutoff_grid_hz=(5.0, 1100.0)))
    with pytest.raises(InputError, match="own cut-off"):
        score(rx130l, res.params, noisy_log, s)


@pytest.mark.slow  # 1.4 s CPU (make test-fast: the unit tier within 60 s)
def test_params_out_csv_and_scoring_an_auto_model(tmp_path, rx130l, noisy_log):
    log = write_run_log(tmp_path / "excite-log.mcap", noisy_log.t, noisy_log.q, noisy_log.tau)
    out, table = tmp_path / "dynamics.yaml", tmp_path / "params.csv"
    rx = str(SAMPLES / "rx130l")
    args = ["identify", "--robot", rx, "--log", str(log), "-o", str(out)]
    res = CliRunner().invoke(app, [*args, "--cutoff-hz", "auto", "--params-out", str(table)])
    assert res.exit_code == 0, res.output
    assert "cv_rms_nm (5 of 5 held-out folds)" in res.output and "cutoff_choice" in res.output
    art = read_yaml_artefact(out, Dynamics)
    assert art.settings.cutoff_hz == "auto" and art.summary.cutoff_hz in (5.0, 10.0, 20.0, 40.0)
    with open(table, encoding="utf-8") as f:
        assert f.readline().startswith("# base dynamic parameters ± 1 sigma of rx130l (dynamics.yaml); wls")
        rows = list(csv.DictReader(f))
    assert [r["name"] for r in rows] == [b.name for b in art.base_parameters]
    for r, b in zip(rows, art.base_parameters, strict=True):
        assert float(r["value"]) == b.value  # 17 digits: exact
        assert float(r["std"]) == pytest.approx(b.relative_std * abs(b.value), rel=1e-6)
        assert r["definition"] == b.label
    assert export_dynamics_csv(out, tmp_path / "again.csv").read_text() == table.read_text()
    units = {r["name"]: r["unit"] for r in rows}
    assert units["joint_2.mcx"] == "kg·m" and units["spring.kL0"] == "N"
    assert units["joint_6.fc_motor"] == "N·m (motor side)"
    # a model identified with auto is scored at the cut-off it chose
    from rxcomm.stages.identify import score_run

    val = score_run(SAMPLES / "rx130l", out, log)  # rows 1/(2·cutoff) apart: decimated at 2 × cutoff
    assert np.median(np.diff(val.t)) == pytest.approx(0.5 / art.summary.cutoff_hz, rel=0.02)
    res = CliRunner().invoke(app, [*args[:-2], "-o", str(tmp_path / "d2.yaml"), "--cutoff-hz", "ten"])
    assert res.exit_code == 2 and "cutoff-hz" in res.output


@pytest.mark.slow  # 1.1 s CPU (make test-fast: the unit tier within 60 s)
def test_friction_option_overrides_drives_yaml_through_the_stage(tmp_path, noisy_log):
    """`--friction joint` on the RX130L (drives.yaml: both) identifies and writes the joint-friction
    model (59 base parameters, no motor columns); it used to exit 2 on its own artefact."""
    log = write_run_log(tmp_path / "excite-log.mcap", noisy_log.t, noisy_log.q, noisy_log.tau)
    out = tmp_path / "dynamics-joint.yaml"
    args = ["identify", "--robot", str(SAMPLES / "rx130l"), "--log", str(log), "--friction", "joint"]
    res = CliRunner().invoke(app, [*args, "-o", str(out)])
    assert res.exit_code == 0, res.output
    art = read_yaml_artefact(out, Dynamics)
    assert art.summary.n_base_params == 59
    assert not any("motor" in b.name for b in art.base_parameters)
