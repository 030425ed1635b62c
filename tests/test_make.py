"""Honest make: editing the robot, the truth, a path, an option or the code rebuilds exactly what depends
on it.

Each test works on a temporary copy of the Makefile and the sample robot whose chain was "built" with
`make -t` (touch: every artefact and option stamp up to date, no stage run), then asks GNU make what it
would remake (`make -n --debug=b`: its "Must remake target" lines). Nothing of the chain runs.
"""

import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from .conftest import ROOT

pytestmark = [
    pytest.mark.make,
    pytest.mark.skipif(shutil.which("make") is None, reason="GNU make not installed"),
]

ROBOT = Path("samples/rx130l")

# Every rule of `make commission`, by the file it writes in BUILD.
ALL = {
    "robot-info.txt",
    "configs.yaml",
    "calib-meas.yaml",
    "calibration-prior.yaml",
    "calibration.yaml",
    "excitation.yaml",
    "excite-log.mcap",
    "validation-plan.mcap",
    "validation-log.mcap",
    "dynamics.yaml",
    "cp.mcap",
    "ptp.mcap",
    "run-noff.mcap",
    "run-ff.mcap",
    "run-ptp.mcap",
    "factory-cp.mcap",
    "factory-ptp.mcap",
    "run-factory-cp.mcap",
    "run-factory-ptp.mcap",
    "factory-poses.mcap",
    "factory-iso-line.mcap",
    "poses.mcap",
    "iso-line.mcap",
    "factory-iso-line-cycles.mcap",
    "iso-line-cycles.mcap",
    "run-factory-poses.mcap",
    "run-factory-iso-line.mcap",
    "run-poses.mcap",
    "run-iso-line.mcap",
    "factory-iso-circle.mcap",
    "iso-circle.mcap",
    "factory-iso-circle-cycles.mcap",
    "iso-circle-cycles.mcap",
    "run-factory-iso-circle.mcap",
    "run-iso-circle.mcap",
    "iso9283-factory.yaml",
    "iso9283.yaml",
    "verdict.yaml",
    "exports/parity.yaml",
    "report.md",
    "cp-at-factory-time.mcap",
    "ptp-at-factory-time.mcap",
    "run-cp-at-factory-time.mcap",
    "run-ptp-at-factory-time.mcap",
}
# The commissioned reference task slowed to the factory's cycle time and its runs (issue 29).
EQ_PLANS = {"cp-at-factory-time.mcap", "ptp-at-factory-time.mcap"}
EQ_RUNS = {"run-cp-at-factory-time.mcap", "run-ptp-at-factory-time.mcap"}
# The factory state (issue 17): catalogue timing of the CP path and the PtP move, run without feed-forward.
FACTORY_PLANS = {"factory-cp.mcap", "factory-ptp.mcap"}
FACTORY_RUNS = {"run-factory-cp.mcap", "run-factory-ptp.mcap"}
# ISO 9283 in both states: the pose cycle, the ISO line and the large circle, their runs with the
# tracker, the criteria.
ISO_RUNS = {"run-factory-poses.mcap", "run-factory-iso-line.mcap", "run-poses.mcap", "run-iso-line.mcap"}
ISO_RUNS |= {"run-factory-iso-circle.mcap", "run-iso-circle.mcap"}
# what the identified dynamics (and the calibration) feed of it
ISO_ON_MODEL = {"poses.mcap", "iso-line.mcap", "iso-line-cycles.mcap", "run-poses.mcap", "run-iso-line.mcap"}
ISO_ON_MODEL |= {"iso-circle.mcap", "iso-circle-cycles.mcap", "run-iso-circle.mcap", "iso9283.yaml"}
# The rules whose command talks to the simulated cell (`run`: it reads truth.yaml) ...
ON_CELL = {
    "calib-meas.yaml",
    "excite-log.mcap",
    "validation-log.mcap",
    "run-noff.mcap",
    "run-ff.mcap",
    "run-ptp.mcap",
    *FACTORY_RUNS,
    *ISO_RUNS,
    *EQ_RUNS,
}
# ... and those downstream of their outputs. select-configs, excite, the validation plan and robot-info
# never see the cell.
AFTER_CELL = {
    "calibration-prior.yaml",
    "calibration.yaml",
    "dynamics.yaml",
    "cp.mcap",
    "ptp.mcap",
    "verdict.yaml",
    "exports/parity.yaml",
    "report.md",
}
AFTER_CELL |= {"poses.mcap", "iso-line.mcap", "iso-line-cycles.mcap", "iso9283-factory.yaml", "iso9283.yaml"}
AFTER_CELL |= {"iso-circle.mcap", "iso-circle-cycles.mcap", *EQ_PLANS}
# select-configs and what follows the pose set: measurement, calibration, identification (on the
# prior calibration's kinematics), the planners on the calibrated robot, their runs, the report.
# Excitation, identification's logs and robot-info do not.
AFTER_POSES = {
    "configs.yaml",
    "calib-meas.yaml",
    "calibration-prior.yaml",
    "dynamics.yaml",
    "calibration.yaml",
    "cp.mcap",
    "ptp.mcap",
    "run-noff.mcap",
    "run-ff.mcap",
    "run-ptp.mcap",
    "verdict.yaml",
    "exports/parity.yaml",
    "report.md",
    *ISO_ON_MODEL,
    "iso9283-factory.yaml",  # the tracker's base frame is the calibration's
    *EQ_PLANS,
    *EQ_RUNS,
}
# The commissioned plans on the identified, calibrated model and their runs, the verdict, the report.
AFTER_MODEL = {
    "cp.mcap",
    "ptp.mcap",
    "run-noff.mcap",
    "run-ff.mcap",
    "run-ptp.mcap",
    "verdict.yaml",
    "exports/parity.yaml",  # the controller files of the calibration, the plans and the FF run
    "report.md",
    *ISO_ON_MODEL,
    *EQ_PLANS,
    *EQ_RUNS,
}
# The CP path feeds plan-cp (both states); plan-ptp starts from its end states.
AFTER_CP_PATH = AFTER_MODEL - ISO_ON_MODEL | FACTORY_PLANS | FACTORY_RUNS
# What `make commission` builds, the files `make -q` can vouch for (phony targets are never "up to date").
PRODUCTS = ["robot-info.txt", "report.md", "run-ptp.mcap"]


def _env() -> dict[str, str]:
    # Under `make test` the outer make's flags (and jobserver) would leak into these makes.
    drop = {"MAKEFLAGS", "MFLAGS", "MAKELEVEL", "MAKEOVERRIDES", "MAKEFILES"}
    return {k: v for k, v in os.environ.items() if k not in drop}


def _make(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["make", "--no-print-directory", *args], cwd=cwd, env=_env(), capture_output=True, text=True
    )


def _remade(cwd: Path, *args: str, goal: str = "commission", build: str = "build") -> tuple[set, set]:
    """(artefacts, option stamps) in `build` that `make -n GOAL ARGS` would remake."""
    out = _make(cwd, "-n", "--debug=b", goal, *args)
    assert out.returncode == 0, out.stderr
    targets = set(re.findall(r"Must remake target '([^']+)'", out.stdout))
    prefix = build + "/"
    artefacts = {t[len(prefix) :] for t in targets if t.startswith(prefix) and "/.params/" not in t}
    stamps = {t.rsplit("/", 1)[1] for t in targets if t.startswith(prefix + ".params/")}
    return artefacts, stamps


def _newer(path: Path) -> None:
    """An edit: the file's mtime a minute ahead of everything built."""
    t = time.time() + 60
    os.utime(path, (t, t))


def _copy_sources(dest: Path) -> None:
    """The Makefile, pyproject.toml and the rxcomm sources (the code stamps hash them)."""
    shutil.copy(ROOT / "Makefile", dest / "Makefile")
    shutil.copy(ROOT / "pyproject.toml", dest / "pyproject.toml")
    shutil.copytree(ROOT / "rxcomm", dest / "rxcomm", ignore=shutil.ignore_patterns("__pycache__"))


@pytest.fixture
def built(tmp_path: Path) -> Path:
    """A copy of the Makefile and the sample robot with `make commission` and `make commission-ci`
    touched up to date."""
    _copy_sources(tmp_path)
    shutil.copytree(ROOT / ROBOT, tmp_path / ROBOT)
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / ".installed").touch()  # after pyproject.toml: the install is current
    for build in ("build", "build-ci"):
        (tmp_path / build).mkdir()
    for goal in ("commission", "commission-ci"):
        out = _make(tmp_path, "-t", goal)
        assert out.returncode == 0, out.stderr
    return tmp_path


def test_a_built_chain_is_up_to_date_and_a_dry_run_changes_nothing(built):
    assert _remade(built) == (set(), set())
    assert _make(built, "-q", *(f"build/{p}" for p in PRODUCTS)).returncode == 0
    # A dry run with other options must not write their stamps: the build stays up to date.
    assert _remade(built, "N_POSES=24")[0]
    assert _make(built, "-q", *(f"build/{p}" for p in PRODUCTS)).returncode == 0
    assert _make(built, "-q", *(f"build/{p}" for p in PRODUCTS)).returncode == 0
    assert _make(built, "-q", "N_POSES=24", "build/report.md").returncode == 1


def test_the_report_reads_the_ptp_run(built):
    # `report` shows every run of the build; the PtP run feeds the verdict (the reference task) and the
    # report, nothing else; a factory run likewise.
    assert _remade(built, "-W", "build/run-ptp.mcap") == ({"verdict.yaml", "report.md"}, set())
    # a factory run also sets the cycle time the commissioned task is slowed to (energy at equal time)
    eq_ptp = {"ptp-at-factory-time.mcap", "run-ptp-at-factory-time.mcap"}
    assert _remade(built, "-W", "build/run-factory-ptp.mcap") == (
        {"verdict.yaml", "report.md"} | eq_ptp,
        set(),
    )


def test_touching_the_urdf_or_drives_rebuilds_every_rule(built):
    # Every command reads the robot (report through the artefacts); drives.yaml names the URDF.
    assert (built / ROBOT / "drives.yaml").read_text().count("urdf: rx130l.urdf") == 1
    assert _remade(built, "-W", str(ROBOT / "rx130l.urdf")) == (ALL, set())
    assert _remade(built, "-W", str(ROBOT / "drives.yaml")) == (ALL, set())


def test_editing_the_truth_rebuilds_the_cell_runs_and_their_dependents_only(built):
    _newer(built / ROBOT / "truth.yaml")
    artefacts, stamps = _remade(built)
    assert artefacts == ON_CELL | AFTER_CELL
    assert not artefacts & {"configs.yaml", "excitation.yaml", "validation-plan.mcap", "robot-info.txt"}
    assert stamps == set()


def test_n_poses_on_the_command_line_rebuilds_select_configs_and_what_follows(built):
    assert _remade(built, "N_POSES=24") == (AFTER_POSES, {"select-configs"})
    assert _remade(built, "N_POSES=32") == (set(), set())  # the default: what was built


def test_other_inputs_rebuild_what_reads_them(built):
    assert _remade(built, "-W", str(ROBOT / "paths/line-near-singularity.yaml"))[0] == AFTER_CP_PATH
    # cell.yaml: select-configs, calibrate, excite and the simulated cell (its tracker's field of view).
    not_cell = {
        "robot-info.txt",
        "validation-plan.mcap",
        *FACTORY_PLANS,
        "factory-poses.mcap",
        "factory-iso-line.mcap",
        "factory-iso-line-cycles.mcap",
        "factory-iso-circle.mcap",
        "factory-iso-circle-cycles.mcap",
    }
    assert _remade(built, "-W", str(ROBOT / "cell.yaml"))[0] == ALL - not_cell
    # The planners' calibration bends the joints with the identified torques: it follows identify.
    excite = {"excitation.yaml", "excite-log.mcap", "dynamics.yaml", "calibration.yaml"} | AFTER_MODEL
    excite.add("iso9283-factory.yaml")  # both states are measured in the calibrated base frame
    assert _remade(built, "EXCITE_OPTS=--starts 3") == (excite, {"excite"})
    # the ISO line: its plans in both states, their runs, the criteria, the verdict, the report
    line = {"factory-iso-line.mcap", "iso-line.mcap", "run-factory-iso-line.mcap", "run-iso-line.mcap"}
    line |= {"factory-iso-line-cycles.mcap", "iso-line-cycles.mcap"}
    after = {"iso9283-factory.yaml", "iso9283.yaml", "verdict.yaml", "report.md"}
    assert _remade(built, "-W", str(ROBOT / "paths/iso9283-line.yaml"))[0] == line | after
    # the pose cycle's length: its two plans, their runs and what follows
    poses = {"factory-poses.mcap", "poses.mcap", "run-factory-poses.mcap", "run-poses.mcap"}
    assert _remade(built, "POSE_CYCLES=3") == (
        poses | after,
        {"factory-poses", "poses", "iso9283"} - {"iso9283"},
    )
    # the circle's speed: its plans in both states, their cycles and runs, and what follows
    circle = {"factory-iso-circle.mcap", "iso-circle.mcap", "factory-iso-circle-cycles.mcap"}
    circle |= {"iso-circle-cycles.mcap", "run-factory-iso-circle.mcap", "run-iso-circle.mcap"}
    assert _remade(built, "CIRCLE_SPEED=0.3") == (circle | after, {"factory-iso-circle", "iso-circle"})
    # the acceptance thresholds: the verdict and the report only
    assert _remade(built, "-W", str(ROBOT / "acceptance.yaml"))[0] == {"verdict.yaml", "report.md"}


def test_a_stamp_is_rewritten_only_when_its_text_changes(built):
    stamp = built / "build/.params/select-configs"
    assert "--poses 32 " in stamp.read_text()
    before = stamp.stat().st_mtime_ns
    assert _make(built, "build/.params/select-configs").returncode == 0
    assert stamp.stat().st_mtime_ns == before  # same options: untouched, nothing downstream rebuilds
    assert _make(built, "N_POSES=24", "build/.params/select-configs").returncode == 0
    assert "--poses 24 " in stamp.read_text()
    assert _make(built, "-q", "N_POSES=24", "build/report.md").returncode == 1  # now stale under 24
    assert _remade(built)[1] == {"select-configs"}  # and back to 32 rebuilds again


def test_commission_ci_reuses_the_same_rules_in_its_own_dir(built):
    assert "--poses 16 " in (built / "build-ci/.params/select-configs").read_text()
    assert _remade(built, goal="commission-ci", build="build-ci") == (set(), set())
    _newer(built / ROBOT / "truth.yaml")
    assert _remade(built, goal="commission-ci", build="build-ci")[0] == ON_CELL | AFTER_CELL


def test_identification_reads_the_prior_calibration_so_recalibrating_is_no_loop(built):
    # The planners' calibration follows identify (its torques bend the joints); identify reads the
    # prior-torque calibration (its kinematics), which reads no dynamics: no loop.
    after_cal = {"cp.mcap", "ptp.mcap", "run-noff.mcap", "run-ff.mcap", "run-ptp.mcap", "report.md"}
    # the commissioned ISO plans and runs, and both states' criteria (measured in the calibrated base frame)
    after_cal |= {
        "poses.mcap",
        "iso-line.mcap",
        "iso-line-cycles.mcap",
        "run-poses.mcap",
        "run-iso-line.mcap",
        "iso-circle.mcap",
        "iso-circle-cycles.mcap",
        "run-iso-circle.mcap",
    }
    after_cal |= {"iso9283-factory.yaml", "iso9283.yaml", "verdict.yaml", "exports/parity.yaml"}
    after_cal |= {*EQ_PLANS, *EQ_RUNS}
    assert _remade(built, "-W", "build/calibration.yaml")[0] == after_cal
    after_prior = after_cal | {"dynamics.yaml", "calibration.yaml"}
    assert _remade(built, "-W", "build/calibration-prior.yaml")[0] == after_prior
    assert _remade(built, "-W", "build/dynamics.yaml")[0] == after_cal | {"calibration.yaml"}


def test_a_robot_without_the_singular_line_runs_its_iso_line_and_a_missing_path_is_one_clear_error(tmp_path):
    """A robot directory the project does not ship: its CP path is its ISO 9283 line; a path file it
    lacks stops make with the file and how to write it (exit 2), not "No rule to make target"."""
    _copy_sources(tmp_path)
    robot = tmp_path / "newbot"
    shutil.copytree(ROOT / "samples/m900", robot)
    assert not (robot / "paths/line-near-singularity.yaml").exists()
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / ".installed").touch()
    out = _make(tmp_path, "-n", "commission", "ROBOT=newbot")
    assert out.returncode == 0, out.stderr
    plan_cp = [ln for ln in out.stdout.splitlines() if " plan-cp " in ln and "build/cp.mcap" in ln]
    assert plan_cp and "--path newbot/paths/iso9283-line.yaml" in plan_cp[0]
    (robot / "paths/iso9283-line.yaml").unlink()
    out = _make(tmp_path, "build/factory-cp.mcap", "ROBOT=newbot")  # the path is its first input
    assert out.returncode == 2
    assert "newbot/paths/iso9283-line.yaml: no such path file" in out.stderr
    assert "--iso9283 newbot/paths" in out.stderr
    assert not (tmp_path / "build" / "factory-cp.mcap").exists()


# ---- the code: each rule lists the stamp of its command's sources (rxcomm/code_identity.py) ----------

# The commands the chain runs.
CHAIN_COMMANDS = {"robot-info", "select-configs", "run", "calibrate", "excite", "identify", "plan-cp"}
CHAIN_COMMANDS |= {"plan-ptp", "plan-poses", "plan-cycles", "iso9283", "accept", "export", "report"}


def _edit(path: Path) -> None:
    path.write_text(path.read_text() + "\n# an edit\n")


def test_every_rule_lists_the_code_stamp_of_the_command_its_recipe_runs(built):
    """From make's own database: each chain rule's recipe runs `$(RX) COMMAND`, and the rule lists
    build/.params/code-COMMAND."""
    db = _make(built, "-pn", "commission").stdout
    seen = {}
    for block in db.split("\n\n"):
        head = block.lstrip("\n").split("\n", 1)[0]
        target, colon, prereqs = head.partition(":")
        if not colon or not target.startswith("build/") or "/.params/" in target:
            continue
        recipe = re.search(r"^\t\$\(RX\) ([\w-]+)", block, re.M)
        if recipe is None:
            continue
        seen[target[len("build/") :]] = recipe.group(1)
        assert f"build/.params/code-{recipe.group(1)} " in prereqs + " ", (target, prereqs)
    assert set(seen) == ALL and set(seen.values()) == CHAIN_COMMANDS


def test_editing_a_module_rebuilds_the_rules_whose_command_imports_it(built):
    html = built / "rxcomm/reporting/html.py"  # imported by `report` only
    _newer(html)  # touched, not edited: the same code, nothing to rebuild
    assert _remade(built) == (set(), set())
    _edit(html)
    assert _remade(built) == ({"report.md"}, {"code-report"})


def test_editing_identification_rebuilds_identify_and_what_follows_it(built):
    _edit(built / "rxcomm/identification/fit.py")  # imported by `identify` only
    artefacts, stamps = _remade(built)
    assert stamps == {"code-identify"}
    # the same set as a newer dynamics.yaml (test above), and dynamics.yaml itself
    assert artefacts == _remade(built, "-W", "build/dynamics.yaml")[0] | {"dynamics.yaml"}
    assert {"excitation.yaml", "excite-log.mcap", "configs.yaml"}.isdisjoint(artefacts)


def test_editing_the_cli_rebuilds_every_rule(built):
    _edit(built / "rxcomm/cli.py")  # every command runs through it
    assert _remade(built) == (ALL, {f"code-{c}" for c in CHAIN_COMMANDS})
