"""calibrate on thin and noisy data (issue 30): the regularised estimate never worse than its own
frames-only baseline, tracker-grade accuracy kept, blunders flagged at both noise grades with a noise
estimate they do not inflate (truth read here only to score)."""

import shutil

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rxcomm.calibration.artefact import detectable_blunder_figures
from rxcomm.calibration.fit import calibrate
from rxcomm.calibration.loading import load_calibration
from rxcomm.calibration.measurements import MeasurementSet
from rxcomm.calibration.priors import effective_prior_sigmas, effective_priors, parameter_prior_sigmas
from rxcomm.calibration.settings import CalibrateSettings
from rxcomm.cell.tracker import SimulatedTracker
from rxcomm.cli import app
from rxcomm.errors import InputError
from rxcomm.io.yaml_io import read_yaml_artefact, write_yaml_artefact
from rxcomm.model.geometric_errors import (
    identifiable_parameters,
    identification_jacobians,
    parameter_names,
    predict_poses,
    random_poses,
)
from rxcomm.model.kinematics import tcp_placement
from rxcomm.model.robot import load_robot
from rxcomm.schemas.calibration import Calibration

from .conftest import SAMPLES
from .test_calibration import _artefact, _load, _measure


@pytest.fixture(scope="module")
def rx():
    robot = load_robot(SAMPLES / "rx130l")
    _, truth, t2b = _load("rx130l")
    return robot, truth, t2b


def _campaign(rx, seed, grade):
    """(measurements, σ_p): camera grade 17–25 fit poses at 1–2 mm / 3 mrad, 6 held out; tracker
    grade 32 + 32 poses at 50 µm / 0.1 mrad."""
    robot, truth, _ = rx
    if grade == "camera":
        n_fit, n_val, sp, so = 17 + seed % 9, 6, 1e-3 + 0.5e-3 * (seed % 3), 3e-3
    else:
        n_fit, n_val, sp, so = 32, 32, 50e-6, 1e-4
    noise = truth.noise.model_copy(
        update={"tracker_position_sigma_m": sp, "tracker_orientation_sigma_rad": so}
    )
    tracker = SimulatedTracker(
        robot, truth.model_copy(update={"noise": noise}), np.random.default_rng(200 + seed)
    )
    qs = random_poses(robot, n_fit + n_val, np.random.default_rng(300 + seed))
    return _measure(tracker, qs, ["fit"] * n_fit + ["validation"] * n_val), sp


def _heldout(res, model="calibrated"):
    return res.tables[("heldout", model)].rms_position_error_m


@pytest.mark.slow
def test_camera_grade_never_worse_than_frames_only(rx):
    """20 seeded camera-grade campaigns: the default (regularised) calibration's held-out rms position
    is ≤ frames-only's on 19 of 20 (seed 14 the exception, below), and its mean within 5 % of the
    better mean of frames-only and the unregularised full model. Scored on the truth instead (the
    held-out poses without their tracker noise) it is below frames-only on 20 of 20."""
    robot, truth, t2b = rx
    plain = CalibrateSettings(model="full", regularise=False)
    true_poses = SimulatedTracker(robot, truth, np.random.default_rng(0)).true_poses
    cal, frames, full, exact = [], [], [], []
    for seed in range(20):
        ms, _ = _campaign(rx, seed, "camera")
        res = calibrate(robot, ms, tracker_to_base=t2b)
        cal.append(_heldout(res))
        frames.append(_heldout(res, "frames_only"))
        full.append(_heldout(calibrate(robot, ms, plain, tracker_to_base=t2b)))
        q = ms.q[res.heldout_idx]
        p, _ = true_poses(q)
        exact.append(
            [
                np.sqrt(np.mean(np.sum((predict_poses(robot, q, f.errors, t2b)[0] - p) ** 2, axis=1)))
                for f in (res.fit, res.frames_only)
            ]
        )
    cal, frames, full, exact = map(np.array, (cal, frames, full, exact))
    # 19 of 20 on the six held-out measurements: seed 14 (22 poses at 2 mm) reads 3.652 mm against
    # frames-only's 3.600, 1.4 % above, while against the truth (500 random poses) it is 0.59 of it.
    # The score's noise, not the estimate: 0cc3a74's diagonal prior read 3.579 there (0.6 % below),
    # and against the truth the correlated prior is closer on the mean (1.653 against 1.676 mm over
    # 500 poses per campaign, the plain fit 1.692). Fresh noise on the six put even the truth above
    # frames-only about 1 time in 5 (architecture §11).
    above = np.flatnonzero(cal > frames)
    assert above.tolist() in ([], [14]), np.c_[cal, frames]
    assert np.all(exact[:, 0] < exact[:, 1]), exact  # measured: worst 0.83 of frames-only
    # the mean over the campaigns within 5 % of the better of the two models' means (measured: 2.994
    # mm, below both: frames-only 4.353, the plain full model 3.014; per campaign within 5 % of the
    # better of the two on 18 of 20, seeds 2 and 19 6.5 % and 8.9 % above the plain full model)
    assert np.mean(cal) <= 1.05 * min(np.mean(frames), np.mean(full)), (
        cal.mean(),
        frames.mean(),
        full.mean(),
    )


@pytest.mark.slow
def test_tracker_grade_accuracy_is_kept(rx):
    """32 poses at 50 µm: the priors (1 mm, 1–2 mrad) leave the held-out error where the plain fit has
    it (measured over 5 seeds: 0.1014 mm before the priors and with them), and all 30 identifiable
    parameters are determined by the data."""
    robot, _, t2b = rx
    ms, _ = _campaign(rx, 0, "tracker")
    res = calibrate(robot, ms, tracker_to_base=t2b)
    plain = calibrate(robot, ms, CalibrateSettings(regularise=False), tracker_to_base=t2b)
    assert res.model == plain.model == "full" and not res.undetermined
    assert abs(_heldout(res) - _heldout(plain)) < 0.05 * _heldout(plain)
    assert _heldout(res) < 0.15e-3


@pytest.mark.slow
@pytest.mark.parametrize("grade", ["camera", "tracker"])
def test_ten_sigma_blunder_is_flagged_and_dropped(rx, grade):
    """One fit pose 10 σ off along z (10–20 mm on the camera, 0.5 mm on the tracker): flagged and
    dropped, and the noise estimate stays within 25 % of the one without the blunder (on main the
    blunder was missed on exactly these three camera-grade seeds, 17 of the 20 of the test above, and
    the noise estimate inflated by 54–79 %)."""
    robot, _, t2b = rx
    for seed in (1, 9, 18) if grade == "camera" else (0,):
        ms, sp = _campaign(rx, seed, grade)
        clean = calibrate(robot, ms, tracker_to_base=t2b)
        assert clean.outlier_idx.size == 0
        p = ms.position_m.copy()
        p[3] += [0.0, 0.0, 10 * sp]
        res = calibrate(robot, MeasurementSet(ms.q, p, ms.rotation, ms.valid, ms.role), tracker_to_base=t2b)
        assert res.outlier_idx.tolist() == [3] and 3 not in res.fit_idx
        ratio = res.noise.position_sigma_m / clean.noise.position_sigma_m
        assert 0.8 < ratio < 1.25, (seed, ratio)


@pytest.mark.slow
def test_a_blunder_is_judged_against_its_own_quantitys_noise(rx):
    """Camera-grade seed 12 (21 fit poses at 1 mm), fit pose 0 10σ off along y, a component the fit
    leans on (its standardised residual 5.6σ at the robust noise): flagged and dropped, the noise
    estimate within 25 % of the clean one's. On 0cc3a74 the orientation residuals' median scale
    (1.35σ at the efficient noise) raised the pooled threshold to 6.1σ, the pose came back into the
    fit, and the position noise read 1.60 mm for 1.26 without it: not flagged."""
    robot, _, t2b = rx
    ms, sp = _campaign(rx, 12, "camera")
    clean = calibrate(robot, ms, tracker_to_base=t2b)
    p = ms.position_m.copy()
    p[0] += [0.0, 10 * sp, 0.0]
    res = calibrate(robot, MeasurementSet(ms.q, p, ms.rotation, ms.valid, ms.role), tracker_to_base=t2b)
    assert res.outlier_idx.tolist() == [0]
    ratio = res.noise.position_sigma_m / clean.noise.position_sigma_m
    assert 0.8 < ratio < 1.25, ratio


@pytest.mark.slow
def test_the_minimal_detectable_blunder_is_what_the_blunder_test_catches(rx):
    """12 camera-grade fit poses (seed 0, 1 mm) measured in position only: the fit leans on pose 7,
    whose x no other pose checks. The summary names it with its minimal detectable blunder (measured
    8.53 mm, 14.7σ; the median component 10.1σ), and a note says a blunder that size could hide
    there. A blunder of 1.3× that in pose 7's x is flagged, either sign; one of 0.5× is not: the
    figure is where the test starts to catch. (On 0cc3a74 nothing said a 10σ blunder could pass.)"""
    robot, _, t2b = rx
    ms, _ = _campaign(rx, 0, "camera")
    keep = list(range(12)) + [i for i, r in enumerate(ms.role) if r == "validation"]
    ms = MeasurementSet(
        ms.q[keep], ms.position_m[keep], None, ms.valid[keep], tuple(ms.role[i] for i in keep)
    )
    res = calibrate(robot, ms, tracker_to_base=t2b)
    figures = detectable_blunder_figures(res)
    worst, sigma = figures["minimal_detectable_blunder_m"], res.noise.position_sigma_m
    assert figures["minimal_detectable_blunder_pose"] == 7 and worst / sigma > 10
    assert figures["median_minimal_detectable_blunder_m"] < worst
    (note,) = [n for n in res.notes if "leans on pose" in n]
    assert "pose 7 " in note and f"{worst * 1e3:.3g} mm" in note and "in its x" in note
    for factor, flagged in ((1.3, [7]), (0.5, [])):
        for sign in (1.0, -1.0):
            p = ms.position_m.copy()
            p[7, 0] += sign * factor * worst
            bad = calibrate(robot, MeasurementSet(ms.q, p, None, ms.valid, ms.role), tracker_to_base=t2b)
            assert bad.outlier_idx.tolist() == flagged, (factor, sign)


@pytest.mark.slow
def test_clean_pose_with_a_large_draw_is_not_flagged(rx):
    """Clean camera-grade seed 16 (24 fit poses at 1.5 mm; the draws' rms 1.38 mm, fit pose 2 has
    −2.34σ along y): nothing flagged and the noise estimate within 25 % of the draws' rms. Before,
    the robust fit's residuals were standardised by 1/√(1 − h) although the fit gives pose 2 little
    weight (its residual is a prediction error, variance 1 + h'), so pose 2 read 8.3σ against the
    robust (median) scale of 0.74 mm, was dropped before the efficient estimate (1.03 mm, 0.75 of
    the draws' rms; 1.23 mm with it) and flagged at 5.3σ in the end. Measured now: 1.229 mm, no
    flag; clean seeds 0–39 flag nothing (before: this one), tracker-grade seeds 0–4 nothing."""
    robot, _, t2b = rx
    ms, _ = _campaign(rx, 16, "camera")
    res = calibrate(robot, ms, tracker_to_base=t2b)
    assert res.outlier_idx.size == 0 and 2 in res.fit_idx
    draws_rms = 1.38e-3  # the tracker's noise draws on the 24 fit poses (replayed from its seed)
    assert abs(res.noise.position_sigma_m / draws_rms - 1) < 0.25, res.noise.position_sigma_m


def test_the_prior_is_the_distribution_of_the_errors_folded_into_the_identifiable_set(rx):
    """`effective_priors`: draws of all 48 errors at their classes' σ (the frames held at 0: flat),
    mapped onto the identifiable set as the data see them (least squares of its Jacobian columns on
    the draws' effect), have the prior's σ and correlation (20 000 draws: σ within 3 %, correlation
    within 0.03). On 0cc3a74 the prior was diagonal: on MuJoCo Menagerie's i2rt YAM (not shipped)
    an error folded into joint_3.rz and joint_4.rz was held back along their common direction as if
    each moved alone, and the regularised calibration missed the truth by 2.26 mm against the plain
    fit's 1.49 over 20 camera-grade campaigns (now 1.63)."""
    robot = rx[0]
    q = random_poses(robot, 60, np.random.default_rng(0))
    ident = np.array(identifiable_parameters(robot, q, False).indices)
    sig, corr = effective_priors(robot, ident, q, False, None)
    cls = parameter_prior_sigmas(robot)
    draws = np.random.default_rng(1).standard_normal((20000, cls.size)) * np.where(np.isfinite(cls), cls, 0.0)
    jac = identification_jacobians(robot, q, None, None, False, None).reshape(-1, cls.size)
    seen, *_ = np.linalg.lstsq(jac[:, ident], jac @ draws.T, rcond=None)
    keep = np.isfinite(sig[ident])
    sample = np.cov(seen[keep])
    sd = np.sqrt(np.diag(sample))
    assert np.allclose(sd, sig[ident][keep], rtol=0.03)
    assert np.max(np.abs(sample / np.outer(sd, sd) - corr[np.ix_(ident[keep], ident[keep])])) < 0.03
    assert np.max(np.abs(corr - np.diag(np.diag(corr)))) > 0.1  # the RX130L's folds correlate too


def test_a_frame_folded_into_a_joint_error_keeps_the_frame_flat_prior(rx):
    """The tool's tz and rz are joint_6's tz and rz to the data (6R): those two carry the tool
    frame's flat prior, every other joint error its tolerance (the base is identifiable itself)."""
    robot = rx[0]
    names = parameter_names(robot)
    q = random_poses(robot, 60, np.random.default_rng(0))
    for po in (False, True):
        ident = np.array(identifiable_parameters(robot, q, po, None).indices)
        sig = effective_prior_sigmas(robot, ident, q, po, None)
        joints = [i for i in ident if not names[i].startswith(("base", "tool"))]
        flat = {names[i] for i in joints if not np.isfinite(sig[i])}
        assert flat == ({"joint_6.tz"} if po else {"joint_6.tz", "joint_6.rz"}), flat


@pytest.mark.slow
def test_tool_length_error_moves_as_freely_as_in_frames_only(rx):
    """The tool 20 mm longer than drives.yaml's TCP (the cell's set-up, not a joint tolerance): at
    camera grade the regularised calibration finds it as the frames-only fit does and beats it on
    the held-out poses (before, joint_6.tz kept its 1 mm prior for the tool's tz: seed 0 missed them
    by 11.9 mm rms against frames-only's 3.1, seeds 1 and 2 were refused, 'still 15 / 12 mm (median)
    from the robot's'; 10 mm longer: 20 % above frames-only on one of the three)."""
    robot, truth, t2b = rx
    g = truth.geometry
    ep = dict(g.error_parameters) | {"tool.tz": g.error_parameters["tool.tz"] + 0.02}
    long_tool = truth.model_copy(update={"geometry": g.model_copy(update={"error_parameters": ep})})
    i = parameter_names(robot).index("joint_6.tz")
    for seed in range(3):
        ms, _ = _campaign((robot, long_tool, t2b), seed, "camera")
        res = calibrate(robot, ms, tracker_to_base=t2b)
        assert _heldout(res) <= _heldout(res, "frames_only"), seed
        tz = res.fit.errors.values[i]  # the data's joint_6.tz is joint_6's and the tool's
        assert abs(tz - ep["joint_6.tz"] - ep["tool.tz"]) < 3 * res.fit.std[i], (seed, tz)


def _scaled_truth(rx, factor):
    """The sample truth with every joint error × `factor` (the base and tool frames as they are)."""
    robot, truth, t2b = rx
    g = truth.geometry
    ep = {k: v * (1.0 if k.startswith(("base.", "tool.")) else factor) for k, v in g.error_parameters.items()}
    return robot, truth.model_copy(update={"geometry": g.model_copy(update={"error_parameters": ep})}), t2b


def _truth_rms(rx, fit):
    """rms position error of `fit` against the truth over 300 random poses (no tracker noise)."""
    robot, truth, t2b = rx
    q = random_poses(robot, 300, np.random.default_rng(9))
    p, _ = SimulatedTracker(robot, truth, np.random.default_rng(0)).true_poses(q)
    return float(np.sqrt(np.mean(np.sum((predict_poses(robot, q, fit.errors, t2b)[0] - p) ** 2, axis=1))))


@pytest.mark.slow
def test_a_robot_further_off_than_its_class_widens_the_priors(rx):
    """Joint errors 4× the manufacturing classes (4 mm / 4 mrad: a nominal model from a catalogue
    rather than this robot's drawings) at camera grade: the data widen the priors (their factor
    measured 3.3–3.6 on seeds 0–4), the noise estimate is the noise, not the misfit (0.84–1.17×;
    the class priors read 1.4–2.0×), and the calibration comes within 15 % of the unregularised
    full model against the truth (1.04–2.32 mm over 300 poses, ≤ 1.08×; the class priors held it at
    2.20–5.60 mm, 1.5–2.9×, and on a UR5e with 4× errors refused 4 of 20 campaigns as the wrong
    robot). A 10σ blunder is caught (the class priors missed it on 4 of seeds 0, 1, 5, 9, 18, the
    noise read 2.4–3.7×; seeds 1 and 18 also while only the efficient stage widened them). The
    sample truth, on the classes' scale, keeps them near 1 (0.57–1.07 on the 20 camera-grade seeds,
    0.84 on seed 0), with no note."""
    far = _scaled_truth(rx, 4.0)
    robot, _, t2b = rx
    plain = CalibrateSettings(model="full", regularise=False)
    for seed in range(5):
        ms, sp = _campaign(far, seed, "camera")
        res = calibrate(robot, ms, tracker_to_base=t2b)
        assert 2.0 < res.prior_scale < 8.0, (seed, res.prior_scale)
        assert 0.75 < res.noise.position_sigma_m / sp < 1.3, (seed, res.noise.position_sigma_m)
        assert any("manufacturing classes" in n for n in res.notes)
        full = calibrate(robot, ms, plain, tracker_to_base=t2b)
        assert _truth_rms(far, res.fit) < 1.15 * _truth_rms(far, full.fit), seed
    for seed in (1, 18):
        ms, sp = _campaign(far, seed, "camera")
        p = ms.position_m.copy()
        p[3] += [0.0, 0.0, 10 * sp]
        res = calibrate(robot, MeasurementSet(ms.q, p, ms.rotation, ms.valid, ms.role), tracker_to_base=t2b)
        assert res.outlier_idx.tolist() == [3], seed
    ms, _ = _campaign(rx, 0, "camera")
    res = calibrate(robot, ms, tracker_to_base=t2b)
    assert 0.5 < res.prior_scale < 2.0 and not any("manufacturing classes" in n for n in res.notes)


@pytest.mark.slow
def test_a_robot_better_than_its_class_narrows_the_priors(rx):
    """Joint errors ¼ of the manufacturing classes (a well-built arm, or one whose controller already
    carries a factory calibration) at camera grade: the data narrow the priors (measured 0.02–0.10 on
    seeds 0–4), so the calibration is no worse than frames-only against the truth (300 poses;
    measured 0.88–1.02×). With the priors held at the classes (on main) it fitted their freedom to the
    noise: 1.07–1.97× frames-only on these seeds, worse on 17 of 20, 1.25× on the mean; with no joint
    errors at all 1.29–3.42× on 20 of 20."""
    good = _scaled_truth(rx, 0.25)
    robot, _, t2b = rx
    for seed in range(5):
        ms, _ = _campaign(good, seed, "camera")
        res = calibrate(robot, ms, tracker_to_base=t2b)
        assert res.prior_scale < 0.3 and any("narrowed" in n for n in res.notes), (seed, res.prior_scale)
        assert _truth_rms(good, res.fit) <= 1.05 * _truth_rms(good, res.frames_only), seed


@pytest.mark.slow
def test_tcp_on_the_last_link_works_with_urdf_out(tmp_path, rx):
    """drives.yaml's TCP on `link_6` (the last revolute joint's child, as `wrist_3_link` on a UR):
    `calibrate --urdf-out` writes a URDF whose TCP, with drives.yaml's TCP still valid, is the
    calibrated one to 1e-9 (on main: refused, asking for a fixed flange link)."""

    _, truth, t2b = rx
    rdir = tmp_path / "robot"
    shutil.copytree(SAMPLES / "rx130l", rdir)
    drives = yaml.safe_load((rdir / "drives.yaml").read_text())
    drives["tcp"]["parent_frame"] = "link_6"  # tool0 sits on link_6 at the identity
    (rdir / "drives.yaml").write_text(yaml.safe_dump(drives))
    robot = load_robot(rdir)
    tracker = SimulatedTracker(robot, truth, np.random.default_rng(3))
    ms = _measure(
        tracker, random_poses(robot, 40, np.random.default_rng(4)), ["fit"] * 30 + ["validation"] * 10
    )
    meas, out, urdf = tmp_path / "meas.yaml", tmp_path / "cal.yaml", tmp_path / "cal.urdf"
    write_yaml_artefact(meas, _artefact(robot, ms, t2b))
    args = ["calibrate", "--robot", str(rdir), "--measurements", str(meas), "-o", str(out)]
    r = CliRunner().invoke(app, [*args, "--urdf-out", str(urdf)])
    assert r.exit_code == 0, r.output
    assert read_yaml_artefact(out, Calibration).summary.model.startswith("full")
    errors, _ = load_calibration(out)
    assert np.linalg.norm(errors.twist("tool")) > 1e-4  # the truth's tool error is in it
    calibrated = load_robot(rdir, urdf=urdf)
    for q in random_poses(robot, 20, np.random.default_rng(0)):
        a, b = tcp_placement(calibrated, q), tcp_placement(robot, q, errors)
        assert np.max(np.abs(a.homogeneous - b.homogeneous)) < 1e-9


@pytest.fixture(scope="module")
def good(rx):
    """30 fit + 10 validation poses on the tracker (rigid truth)."""
    robot, truth, _ = rx
    tracker = SimulatedTracker(robot, truth, np.random.default_rng(21))
    qs = random_poses(robot, 40, np.random.default_rng(22))
    return _measure(tracker, qs, ["fit"] * 30 + ["validation"] * 10)


@pytest.mark.slow
def test_shifted_validation_pose_is_a_warning_naming_it(rx, good):
    """Validation pose 34 shifted by 100 mm: the calibration still beats nominal and is written, but a
    warning names pose 34 (on main: exit 0 and no word); the clean set warns of nothing."""
    robot, _, t2b = rx
    clean = calibrate(robot, good, tracker_to_base=t2b)
    assert not any("held-out poses disagree" in n for n in clean.notes)
    p = good.position_m.copy()
    p[34] += [0.1, 0.0, 0.0]
    res = calibrate(
        robot, MeasurementSet(good.q, p, good.rotation, good.valid, good.role), tracker_to_base=t2b
    )
    (warn,) = [n for n in res.notes if "held-out poses disagree" in n]
    assert "34 (100." in warn and warn.count("mm,") == 1


@pytest.mark.slow
@pytest.mark.parametrize(
    ("change", "named"),
    [
        ("swap", "joint_2 and joint_3 are swapped"),
        ("flip", "joint_2's sign is flipped"),
        ("flip J1", "joint_1's sign is flipped"),
    ],
)
def test_joint_mixup_is_named(rx, good, change, named):
    """Joint columns 2 and 3 swapped, or J2's or J1's sign flipped, in the export: the error names
    that (on main: 'check the angle convention'), position-only measurements too. The mix-up is
    looked for before the fit: on 0cc3a74 only a failed plausibility check asked, and a J1 flip
    measured position-only was refused as '7 outlier poses … do not fit the model' first (on the M900
    two swaps as 'calibration did not converge'). Every swapped pair and flipped sign, with and
    without orientations (42 cases), is now named on the M900 and on MuJoCo Menagerie's Z1 and lite6
    as here, but for J6's flip in positions alone on three of the four: a tool point near J6's axis
    hides it."""
    robot, _, t2b = rx
    q = good.q.copy()
    if change == "swap":
        q[:, [1, 2]] = q[:, [2, 1]]
    else:
        j = 0 if change == "flip J1" else 1
        q[:, j] = -q[:, j]
    for rot in (good.rotation, None):
        bad = MeasurementSet(q, good.position_m, rot, good.valid, good.role)
        with pytest.raises(InputError, match=named):
            calibrate(robot, bad, tracker_to_base=t2b)


@pytest.mark.slow
def test_a_robot_already_as_good_as_its_model_is_not_refused(rx):
    """No joint or frame errors at all (a robot calibrated before, checked again): the calibration
    cannot beat the nominal model, and on six held-out poses at camera grade it misses them a little
    more often than not. That is the noise, not a robot the measurements fail to describe: a note,
    the calibration written. On main `calibrate` refused (exit 3, "the measurements do not describe
    this robot") 18 of camera-grade seeds 0–19, and 5 of 5 tracker-grade ones: a robot checked with
    a laser tracker after its calibration was loaded. A held-out misfit beyond the noise still
    refuses (tests/test_calibration_data.py::test_worse_than_nominal_exits_3)."""
    robot, truth, t2b = rx
    g = truth.geometry
    zero = {k: 0.0 for k in g.error_parameters}
    perfect = (
        robot,
        truth.model_copy(update={"geometry": g.model_copy(update={"error_parameters": zero})}),
        t2b,
    )
    noted = 0
    for seed, grade in [(0, "camera"), (1, "camera"), (3, "camera"), (4, "camera"), (0, "tracker")]:
        ms, _ = _campaign(perfect, seed, grade)
        res = calibrate(robot, ms, tracker_to_base=t2b)
        noted += any("does not beat the nominal model" in n for n in res.notes)
    assert noted >= 4  # measured: all five (in the fit's position + orientation metric)
