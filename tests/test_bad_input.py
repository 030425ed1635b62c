"""Bad input and bad outputs, case by case as a careful user tries them (issue 14, items 1, 2, 5, 6).

Each case runs the CLI and asserts the exit code, that the message names what it should (file,
field, reason), that no input was overwritten and that nothing new is left behind (no output, no
``.part``). The refusals come before any work, so every case here is fast; none needs the cell
(a ``run`` is pointed at a closed port: a refusal that came after contacting it would be exit 4).
"""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.io.files import atomic_write_text
from rxcomm.io.mcap_io import McapWriter
from rxcomm.io.yaml_io import write_yaml_artefact
from rxcomm.model.geometric_errors import random_poses
from rxcomm.model.kinematics import tcp_placement
from rxcomm.schemas.measurements import MeasuredPose, Measurements

from .conftest import SAMPLES
from .runs import Q0, cosine_plan, save_plan, write_configs

ROBOT = SAMPLES / "rx130l"
LINE = ROBOT / "paths" / "iso9283-line.yaml"
CP_FAST = (
    "--method",
    "toppra",
    "--no-torque-rate-limits",
    "--path-intervals",
    40,
)  # seconds, where a refusal is not first
CLOSED_PORT = "127.0.0.1:9"  # nothing listens: contacting the gateway would end in exit 4


# --- helpers ----------------------------------------------------------------------------------------
def invoke(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under `root` with its bytes (inputs must come out unchanged, nothing new in)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def assert_refused(res, code: int, *named: str) -> None:
    assert res.exit_code == code, res.output
    assert "Traceback" not in res.output and isinstance(res.exception, SystemExit), res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output  # one line, rxcomm's own
    for name in named:
        assert name in lines[0], f"{name!r} not in {lines[0]!r}"


def assert_untouched(before: dict[str, bytes], root: Path) -> None:
    after = snapshot(root)
    changed = sorted(k for k in before if after.get(k) != before[k])
    assert after == before, f"changed: {changed}, new: {sorted(set(after) - set(before))}"


def write_measurements(path: Path, robot, n: int = 40) -> Path:
    """A valid campaign on the nominal robot (tracker frame = base frame), as `run` writes it."""
    poses = []
    for q in random_poses(robot, n, np.random.default_rng(4)):
        m = tcp_placement(robot, q)
        qt = pin.Quaternion(m.rotation)
        poses.append(
            MeasuredPose(
                q_rad=q.tolist(), position_m=tuple(m.translation), quaternion_wxyz=(qt.w, qt.x, qt.y, qt.z)
            )
        )
    art = Measurements(
        **Measurements.envelope({}, {}, {"n_poses": n, "n_valid": n}),
        robot=robot.name,
        joint_names=list(robot.joint_names),
        tracker_to_base={"xyz_m": (0.0, 0.0, 0.0), "rpy_rad": (0.0, 0.0, 0.0)},
        position_sigma_m=5e-5,
        orientation_sigma_rad=1e-4,
        poses=poses,
    )
    write_yaml_artefact(path, art)
    return path


def path_file(path: Path, edit) -> Path:
    """The sample ISO 9283 line with `edit(data)` applied."""
    data = yaml.safe_load(LINE.read_text())
    edit(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def weak_robot(d: Path) -> Path:
    """The RX130L with a J2 peak torque (120 N·m) below what gravity needs with the arm stretched."""
    d.mkdir()
    shutil.copy(ROBOT / "rx130l.urdf", d / "rx130l.urdf")
    drives = yaml.safe_load((ROBOT / "drives.yaml").read_text())
    drives["joints"][1]["peak_torque_nm"] = 120
    drives["joints"][1]["continuous_torque_nm"] = 100
    (d / "drives.yaml").write_text(yaml.safe_dump(drives))
    return d


@pytest.fixture
def meas(tmp_path, rx130l) -> Path:
    return write_measurements(tmp_path / "m.yaml", rx130l)


@pytest.fixture
def plan(tmp_path) -> Path:
    return save_plan(tmp_path / "cp.mcap", cosine_plan(Q0, 0.1 * np.ones(6), 0.5, dt=0.01))


@pytest.fixture
def configs(tmp_path, rx130l) -> Path:
    return write_configs(tmp_path / "configs.yaml", rx130l, [Q0, Q0 + 0.1], ["fit", "fit"])


# --- item 1: an output that is an input -------------------------------------------------------------
def test_calibrate_onto_its_measurements_is_refused(tmp_path, meas):
    before = snapshot(tmp_path)
    res = invoke("calibrate", "--robot", ROBOT, "--measurements", meas, "-o", meas)
    assert_refused(res, 2, str(meas), "output", "also the input measurements")
    assert_untouched(before, tmp_path)


def test_calibrate_through_a_symlink_onto_its_measurements_is_refused(tmp_path, meas):
    (tmp_path / "link.yaml").symlink_to(meas)
    before = snapshot(tmp_path)
    res = invoke("calibrate", "--robot", ROBOT, "--measurements", meas, "-o", tmp_path / "link.yaml")
    assert_refused(res, 2, "link.yaml", "also the input measurements")
    assert_untouched(before, tmp_path)


def test_two_outputs_on_one_file_are_refused(tmp_path, meas):
    before = snapshot(tmp_path)
    out = tmp_path / "c.yaml"
    res = invoke("calibrate", "--robot", ROBOT, "--measurements", meas, "-o", out, "--urdf-out", out)
    assert_refused(res, 2, str(out), "urdf-out", "also the output output")
    assert_untouched(before, tmp_path)


def test_plan_cp_whose_summary_would_overwrite_the_path_is_refused(tmp_path):
    path = tmp_path / "line.yaml"
    shutil.copy(LINE, path)
    before = snapshot(tmp_path)
    res = invoke(
        "plan-cp",
        "--robot",
        ROBOT,
        "--path",
        path,
        "-o",
        tmp_path / "line.mcap",
        *CP_FAST,
    )
    assert_refused(res, 2, "line.mcap", "its summary", str(path), "input path")
    assert_untouched(before, tmp_path)


def test_run_onto_its_trajectory_is_refused(tmp_path, plan):
    before = snapshot(tmp_path)
    res = invoke("run", plan, "--robot", ROBOT, "--gateway", CLOSED_PORT, "-o", plan)
    assert_refused(res, 2, str(plan), "also the input plan")
    assert_untouched(before, tmp_path)


def test_run_onto_its_pose_list_is_refused(tmp_path, configs):
    before = snapshot(tmp_path)
    res = invoke("run", configs, "--robot", ROBOT, "--gateway", CLOSED_PORT, "-o", configs)
    assert_refused(res, 2, str(configs), "also the input plan")
    assert_untouched(before, tmp_path)


def test_identify_onto_the_summary_of_its_log_is_refused(tmp_path, plan):
    before = snapshot(tmp_path)
    res = invoke("identify", "--robot", ROBOT, "--log", plan, "-o", tmp_path / "cp.yaml")
    assert_refused(res, 2, "cp.yaml", "the summary of", "input log")
    assert_untouched(before, tmp_path)


# --- item 2: an output that cannot be written, found before the work ---------------------------------
def _bad_place(kind: str, tmp_path: Path, name: str) -> tuple[Path, str]:
    """(an output path of the given kind of bad place, what the message must say)."""
    if kind == "directory":
        (tmp_path / name).mkdir()
        return tmp_path / name, "is a directory"
    if kind == "under a file":
        (tmp_path / "notes.txt").write_text("a file\n")
        return tmp_path / "notes.txt" / name, "it is a file"
    # unwritable: root writes into a read-only mode directory, so use a place not even root can
    if os.geteuid() != 0:
        d = tmp_path / "ro"
        d.mkdir()
        d.chmod(0o500)
        return d / name, "cannot write in"
    if not Path("/sys/kernel").is_dir() or os.access("/sys", os.W_OK) and _can_create("/sys"):
        pytest.skip("no place here that root cannot write to")
    return Path("/sys") / "rxcomm-test" / name, "cannot write in /sys"


def _can_create(d: str) -> bool:
    try:
        Path(d, ".rxcomm-probe").touch()
    except OSError:
        return False
    Path(d, ".rxcomm-probe").unlink()
    return True


PLACES = ["directory", "under a file", "unwritable"]


@pytest.fixture
def restore_modes(tmp_path):
    yield
    for p in tmp_path.rglob("*"):
        if p.is_dir():
            p.chmod(0o700)


@pytest.mark.parametrize("place", PLACES)
def test_calibrate_into_a_bad_place_is_refused_before_the_fit(tmp_path, meas, place, restore_modes):
    out, reason = _bad_place(place, tmp_path, "c.yaml")
    before = snapshot(tmp_path)
    res = invoke("calibrate", "--robot", ROBOT, "--measurements", meas, "-o", out)
    assert_refused(res, 2, str(out), reason)
    assert_untouched(before, tmp_path)


@pytest.mark.parametrize("place", PLACES)
def test_campaign_into_a_bad_place_is_refused_before_contacting_the_gateway(
    tmp_path, configs, place, restore_modes
):
    out, reason = _bad_place(place, tmp_path, "meas.yaml")
    before = snapshot(tmp_path)
    res = invoke("run", configs, "--robot", ROBOT, "--gateway", CLOSED_PORT, "-o", out)
    assert_refused(res, 2, str(out), reason)
    assert_untouched(before, tmp_path)


@pytest.mark.parametrize("place", PLACES)
def test_plan_ptp_into_a_bad_place_is_refused_before_the_solve(tmp_path, place, restore_modes):
    out, reason = _bad_place(place, tmp_path, "ptp.mcap")
    before = snapshot(tmp_path)
    res = invoke(
        "plan-ptp", "--robot", ROBOT, "--start", "0,-0.5,1,0,0.5,0", "--goal", "0.5,-0.3,1.2,0,0.8,0.5",
        "--time-intervals", 12, "-o", out,
    )  # fmt: skip
    assert_refused(res, 2, str(out), reason)
    assert_untouched(before, tmp_path)


@pytest.mark.parametrize("place", PLACES)
def test_plan_cp_into_a_bad_place_is_refused_before_planning(tmp_path, place, restore_modes):
    out, reason = _bad_place(place, tmp_path, "cp.mcap")
    before = snapshot(tmp_path)
    res = invoke("plan-cp", "--robot", ROBOT, "--path", LINE, "-o", out, *CP_FAST)
    assert_refused(res, 2, str(out), reason)
    assert_untouched(before, tmp_path)


@pytest.mark.parametrize("place", PLACES)
def test_report_into_a_bad_place_is_refused(tmp_path, place, restore_modes):
    (tmp_path / "build").mkdir()
    out, reason = _bad_place(place, tmp_path, "report.md")
    before = snapshot(tmp_path)
    res = invoke("report", tmp_path / "build", "-o", out)
    assert_refused(res, 2, str(out), reason)
    assert_untouched(before, tmp_path)


def _stage_args(stage: str, tmp_path: Path, out: Path) -> list[object]:
    """The stage's command line with cheap settings (what the old code ran before failing)."""
    cell = ROBOT / "cell.yaml"
    return {
        "select-configs": ["select-configs", "--robot", ROBOT, "--cell", cell, "--poses", 6,
                           "--grid-intervals", 3, "--max-candidates", 60, "--restarts", 1,
                           "--validation-poses", 0, "-o", out],
        "excite": ["excite", "--robot", ROBOT, "--cell", cell, "--harmonics", 2, "--starts", 1,
                   "--samples", 50, "-o", out],
        "identify": ["identify", "--robot", ROBOT, "--log", tmp_path / "log.mcap", "-o", out],
    }[stage]  # fmt: skip


@pytest.mark.parametrize("stage", ["select-configs", "excite", "identify"])
def test_every_other_stage_refuses_a_directory_as_output(tmp_path, stage):
    out, reason = _bad_place("directory", tmp_path, "out.yaml")
    (tmp_path / "log.mcap").write_bytes(b"not read: the output is refused first")
    before = snapshot(tmp_path)
    res = invoke(*_stage_args(stage, tmp_path, out))
    assert_refused(res, 2, str(out), reason)
    assert_untouched(before, tmp_path)


def test_a_failing_cleanup_does_not_hide_the_first_error(tmp_path):
    (tmp_path / "notes.txt").write_text("a file\n")
    with pytest.raises(NotADirectoryError) as e:
        atomic_write_text(tmp_path / "notes.txt" / "x.yaml", "data")
    assert e.value.__context__ is None  # the open's error, not the unlink's raised while handling it
    assert "x.yaml.part" in str(e.value.filename)


def test_a_full_disk_mid_write_is_one_line_exit_2_and_leaves_no_part(tmp_path, monkeypatch):
    (tmp_path / "build").mkdir()
    out = tmp_path / "build" / "report.md"

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr("rxcomm.io.files.os.fsync", full)
    before = snapshot(tmp_path)
    res = invoke("report", tmp_path / "build", "-o", out)
    assert_refused(res, 2, "report.md.part", "No space left on device", "ENOSPC")
    assert isinstance(res.exception.__context__.__cause__, OSError)  # the OS error is kept as the cause
    assert_untouched(before, tmp_path)


# --- item 5: path files with NaN, inf or millimetres -------------------------------------------------
def _set(where: str, value):
    def edit(data):
        *keys, last = where.split(".")
        d = data
        for k in keys:
            d = d[k]
        d[last] = value

    return edit


@pytest.mark.parametrize(
    ("where", "value", "field"),
    [
        ("geometry.start_m", [float("nan"), -0.304, 0.306], "geometry.line.start_m.0"),
        ("geometry.end_m", [1.18, float("inf"), 0.91], "geometry.line.end_m.1"),
        ("orientation.rpy_rad", [3.14159, float("nan"), 0.0], "orientation.rpy_rad.1"),
    ],
)
def test_path_with_nan_or_inf_is_bad_input_naming_file_and_field(tmp_path, where, value, field):
    path = path_file(tmp_path / "p.yaml", _set(where, value))
    before = snapshot(tmp_path)
    res = invoke("plan-cp", "--robot", ROBOT, "--path", path, "-o", tmp_path / "cp.mcap", *CP_FAST)
    assert_refused(res, 2, str(path), field, "finite")
    assert_untouched(before, tmp_path)


def test_path_in_millimetres_is_bad_input_naming_file_field_and_unit(tmp_path):
    def to_mm(data):
        g = data["geometry"]
        g["start_m"], g["end_m"] = ([1000 * v for v in g[k]] for k in ("start_m", "end_m"))

    path = path_file(tmp_path / "p.yaml", to_mm)
    before = snapshot(tmp_path)
    res = invoke("plan-cp", "--robot", ROBOT, "--path", path, "-o", tmp_path / "cp.mcap", *CP_FAST)
    assert_refused(res, 2, str(path), "geometry.start_m", "millimetres")
    assert_untouched(before, tmp_path)


def test_circle_radius_in_millimetres_is_bad_input(tmp_path):
    path = tmp_path / "c.yaml"
    data = yaml.safe_load((ROBOT / "paths" / "iso9283-circle-large.yaml").read_text())
    data["geometry"]["radius_m"] = 304.0
    path.write_text(yaml.safe_dump(data))
    before = snapshot(tmp_path)
    res = invoke("plan-cp", "--robot", ROBOT, "--path", path, "-o", tmp_path / "cp.mcap", *CP_FAST)
    assert_refused(res, 2, str(path), "geometry.radius_m", "millimetres")
    assert_untouched(before, tmp_path)


def test_path_just_beyond_reach_in_metres_stays_unreachable_exit_3(tmp_path):
    """The bound is the robot's longest possible reach (RX130L: 2.36 m from the base origin): a
    metre-scale path beyond what this arm reaches on its branch is still an infeasible plan (3)."""
    r = 2.1  # m: beyond the arm (1.81 m shoulder → TCP stretched), within the bound
    path = path_file(tmp_path / "p.yaml", _set("geometry.end_m", [r, 0.0, 0.3]))
    res = invoke("plan-cp", "--robot", ROBOT, "--path", path, "-o", tmp_path / "cp.mcap", *CP_FAST)
    assert_refused(res, 3, "unreachable")
    assert not list(tmp_path.glob("cp.*"))


# --- item 6: one exit code per condition; run checks the plan first ----------------------------------
STRETCHED = "0,-1.5,0,0,0,0"  # arm stretched forward: J2 holds ~180 N·m (test_plan_ptp)


def test_plan_ptp_statics_above_the_peak_torque_is_exit_3_naming_drives_yaml(tmp_path):
    robot = weak_robot(tmp_path / "weak")
    before = snapshot(tmp_path)
    res = invoke("plan-ptp", "--robot", robot, "--start", STRETCHED, "--goal", "0,-0.2,1,0,0.5,0",
                 "-o", tmp_path / "ptp.mcap")  # fmt: skip
    assert_refused(res, 3, str(robot / "drives.yaml"), "peak_torque_nm", "joint_2", "holding torque")
    assert_untouched(before, tmp_path)


def test_plan_cp_statics_above_the_peak_torque_is_exit_3_naming_drives_yaml(tmp_path):
    robot = weak_robot(tmp_path / "weak")
    before = snapshot(tmp_path)
    res = invoke(
        "plan-cp", "--robot", robot, "--path", ROBOT / "paths" / "line-near-singularity.yaml",
        "-o", tmp_path / "cp.mcap", *CP_FAST,
    )  # fmt: skip
    assert_refused(res, 3, str(robot / "drives.yaml"), "peak_torque_nm", "joint_2")
    assert_untouched(before, tmp_path)


def test_run_names_a_wrong_kind_yaml_plan_before_the_output(tmp_path):
    wrong = tmp_path / "line.yaml"
    shutil.copy(LINE, wrong)
    before = snapshot(tmp_path)
    res = invoke("run", wrong, "--robot", ROBOT, "--gateway", CLOSED_PORT, "-o", tmp_path / "log.mcap")
    assert_refused(res, 2, str(wrong), "kind", "rxcomm/Path", "rxcomm/Configs")
    assert_untouched(before, tmp_path)


def test_run_names_a_wrong_kind_mcap_plan_before_the_output(tmp_path):
    wrong = tmp_path / "meas.mcap"  # an MCAP of another kind (here: measurements)
    with McapWriter(wrong, Measurements.envelope({}, {}, {"n_poses": 0, "n_valid": 0})):
        pass
    before = snapshot(tmp_path)
    res = invoke("run", wrong, "--robot", ROBOT, "--gateway", CLOSED_PORT, "-o", tmp_path / "m.yaml")
    assert_refused(res, 2, str(wrong), "envelope.kind", "rxcomm/Measurements", "rxcomm/Trajectory")
    assert_untouched(before, tmp_path)


# --- cases that already behave (kept so they stay so) ------------------------------------------------
def test_missing_measurements_file_is_named(tmp_path):
    res = invoke(
        "calibrate", "--robot", ROBOT, "--measurements", tmp_path / "nope.yaml", "-o", tmp_path / "c.yaml"
    )
    assert_refused(res, 2, "nope.yaml", "file not found")
    assert snapshot(tmp_path) == {}


def test_path_with_an_unknown_key_names_the_field(tmp_path):
    path = path_file(tmp_path / "p.yaml", _set("geometry.speed", 1.0))
    before = snapshot(tmp_path)
    res = invoke("plan-cp", "--robot", ROBOT, "--path", path, "-o", tmp_path / "cp.mcap")
    assert_refused(res, 2, str(path), "geometry.line.speed", "unknown key")
    assert_untouched(before, tmp_path)


def test_yaml_syntax_error_names_line_and_column(tmp_path, meas):
    meas.write_text(meas.read_text().replace("poses:", "poses: [", 1))
    before = snapshot(tmp_path)
    res = invoke("calibrate", "--robot", ROBOT, "--measurements", meas, "-o", tmp_path / "c.yaml")
    assert_refused(res, 2, str(meas), "YAML syntax error at line")
    assert_untouched(before, tmp_path)


def test_non_loopback_gateway_is_refused_and_nothing_written(tmp_path, plan):
    before = snapshot(tmp_path)
    res = invoke("run", plan, "--robot", ROBOT, "--gateway", "10.1.2.3:502", "-o", tmp_path / "log.mcap")
    assert_refused(res, 2, "gateway", "--allow-remote")
    assert_untouched(before, tmp_path)


def test_ptp_start_outside_the_joint_limits_is_bad_input(tmp_path):
    res = invoke("plan-ptp", "--robot", ROBOT, "--start", "0,3,0,0,0,0", "--goal", "0,0,1,0,0,0",
                 "-o", tmp_path / "ptp.mcap")  # fmt: skip
    assert_refused(res, 2, "start[joint_2]", "outside the joint limits")
    assert snapshot(tmp_path) == {}


def test_pose_list_into_an_mcap_names_the_output(tmp_path, configs):
    before = snapshot(tmp_path)
    res = invoke("run", configs, "--robot", ROBOT, "--gateway", CLOSED_PORT, "-o", tmp_path / "m.mcap")
    assert_refused(res, 2, "m.mcap", "output", "measurements NAME.yaml")
    assert_untouched(before, tmp_path)
