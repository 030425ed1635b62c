"""The command line as a user meets it (issue 18): an OS error is one line and exit 2 in every stage,
`report BUILD` works from any directory, degree options convert, long phases report in plain lines
when stderr is not a terminal."""

from __future__ import annotations

import io
import math
import re
import time

import pytest
from typer.testing import CliRunner

from rxcomm import console
from rxcomm.cli import app
from rxcomm.errors import InputError
from rxcomm.options import radians_text, radians_value

from .conftest import SAMPLES

ROBOT = SAMPLES / "rx130l"
LINE = ROBOT / "paths" / "iso9283-line.yaml"


def one_line_exit_2(res, *named: str) -> None:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and isinstance(res.exception, SystemExit), res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    for name in named:
        assert name in lines[0], f"{name!r} not in {lines[0]!r}"


def stage_reading(d) -> dict[str, list[str]]:
    """Each stage with its input file `d` (a directory: reading it is an OS error, EISDIR)."""
    r, out = str(ROBOT), str(d.parent / "out")
    return {
        "select-configs": ["select-configs", "--robot", r, "--cell", str(d), "-o", out + ".yaml"],
        "calibrate": ["calibrate", "--robot", r, "--measurements", str(d), "-o", out + ".yaml"],
        "cell-sim": ["cell-sim", "--truth", str(d), "--port", "0"],
        "excite": ["excite", "--robot", r, "--cell", str(d), "-o", out + ".yaml"],
        "plan-cp": ["plan-cp", "--robot", r, "--path", str(d), "-o", out + ".mcap"],
        "plan-cp --calibration": ["plan-cp", "--robot", r, "--path", str(LINE), "--calibration", str(d)]
        + ["-o", out + ".mcap"],
        "plan-ptp --dynamics": ["plan-ptp", "--robot", r, "--start", "0,0,1,0,0.5,0", "--goal", "0,0,1,0,1,0"]
        + ["--dynamics", str(d), "-o", out + ".mcap"],
        "recover-log": ["recover-log", str(d)],
        "identify --dynamics": ["identify", "--robot", r, "--dynamics", str(d), "--validate", str(d)],
        "score": ["score", "--robot", r, "--dynamics", str(d), "--log", str(d)],
    }


@pytest.mark.parametrize(
    "case",
    ["select-configs", "calibrate", "cell-sim", "excite", "plan-cp", "plan-cp --calibration"]
    + ["plan-ptp --dynamics", "recover-log", "identify --dynamics", "score"],
)
def test_an_input_that_cannot_be_read_is_one_line_exit_2_naming_it(tmp_path, case):
    d = tmp_path / "a-directory"
    d.mkdir()
    res = CliRunner().invoke(app, stage_reading(d)[case])
    one_line_exit_2(res, str(d))
    assert not list(tmp_path.glob("out*"))


def test_robot_info_of_a_directory_without_a_robot_is_exit_2(tmp_path):
    one_line_exit_2(CliRunner().invoke(app, ["robot-info", "--robot", str(tmp_path)]), "drives.yaml")


def test_report_without_output_from_another_directory_writes_into_build(tmp_path, monkeypatch):
    build, elsewhere = tmp_path / "build", tmp_path / "elsewhere"
    build.mkdir()
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    res = CliRunner().invoke(app, ["report", str(build)])
    assert res.exit_code == 0, res.output
    assert (build / "report.md").is_file() and not list(elsewhere.iterdir())
    assert "not produced in this build" in (build / "report.md").read_text().lower()


def test_degree_options_convert_joint_vectors_and_pose_angles_only():
    assert [float(v) for v in radians_text(None, "0,90,-180", "start").split(",")] == [
        0,
        math.pi / 2,
        -math.pi,
    ]
    pose = radians_text(None, "pose:1,0.5,0.2,180,0,90", "goal")
    assert pose.startswith("pose:")
    values = [float(v) for v in pose[5:].split(",")]
    assert values[:3] == [1, 0.5, 0.2]  # metres stay metres
    assert values[3:] == pytest.approx([math.pi, 0, math.pi / 2], abs=1e-15)
    assert radians_text("0,1", None, "start") == "0,1"
    assert radians_value(None, 3.0, "position-margin", 0.05) == pytest.approx(math.radians(3.0))
    assert radians_value(None, None, "position-margin", 0.05) == 0.05
    with pytest.raises(InputError, match="not both"):
        radians_text("0,1", "0,1", "start")
    with pytest.raises(InputError, match="deg"):
        radians_text(None, "0,ninety", "start")


def test_both_or_neither_of_a_degree_pair_is_one_line_exit_2(tmp_path):
    base = ["plan-ptp", "--robot", str(ROBOT), "--goal", "0,0,1,0,1,0", "-o", str(tmp_path / "p.mcap")]
    both = CliRunner().invoke(app, [*base, "--start", "0,0,1,0,0.5,0", "--start-deg", "0,0,57,0,28,0"])
    one_line_exit_2(both, "start-deg", "not both")
    one_line_exit_2(CliRunner().invoke(app, base), "start")
    cell = CliRunner().invoke(app, ["cell-sim", "--truth", str(ROBOT / "truth.yaml"), "--start-deg", "0,0"])
    one_line_exit_2(cell, "--start", "6 finite")


@pytest.mark.slow
def test_plain_progress_prints_a_line_per_period_and_a_last_one():
    stream = io.StringIO()
    bar = console.PlainProgress(period_s=0.2, stream=stream)
    with bar:
        task = bar.add_task("grid", total=10)
        bar.update(task, completed=4)
        phase = bar.add_task("selecting", total=None)
        time.sleep(0.5)
        bar.update(task, completed=10)
        time.sleep(0.3)
    lines = stream.getvalue().splitlines()
    assert any(re.fullmatch(r"grid: 40 % \d+ s", ln) for ln in lines)  # the fraction while it ran
    assert sum(bool(re.fullmatch(r"grid: 100 % \d+ s \(done\)", ln)) for ln in lines) == 1  # once at the end
    ticks = [ln for ln in lines if ln.startswith("selecting: ")]
    assert len(ticks) >= 3 and ticks[-1].endswith("(done)")  # a phase without a total: elapsed only
    assert all("%" not in ln for ln in ticks)
    assert bar._tasks[phase]["done"]


def test_plain_progress_says_stopped_for_a_task_cut_short():
    """A campaign that fails at 57 % must not read "(done)" on the console."""
    stream = io.StringIO()
    bar = console.PlainProgress(period_s=0.1, stream=stream)
    with bar:
        task = bar.add_task("poses", total=100)
        bar.update(task, completed=57)
        time.sleep(0.25)
    last = stream.getvalue().splitlines()[-1]
    assert re.fullmatch(r"poses: 57 % \d+ s \(stopped\)", last), last


def test_plain_progress_is_silent_for_short_tasks():
    stream = io.StringIO()
    with console.PlainProgress(period_s=5.0, stream=stream) as bar:
        bar.update(bar.add_task("quick", total=2), completed=2)
    assert stream.getvalue() == ""


def test_progress_without_a_terminal_is_plain(monkeypatch):
    monkeypatch.setattr("sys.stderr.isatty", lambda: False, raising=False)
    assert isinstance(console.progress(), console.PlainProgress)
