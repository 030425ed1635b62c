"""Code identity (rxcomm/code_identity.py): every artefact names the code that wrote it, a source edit
changes that name, and the Makefile's per-command hashes follow what each command imports."""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from rxcomm import code_identity as ci
from rxcomm.cli import STAGES
from rxcomm.schemas.trajectory import TrajectorySummary

from .conftest import ROOT


def _copy(dest: Path) -> Path:
    """A copy of the rxcomm package outside any git checkout."""
    shutil.copytree(ROOT / "rxcomm", dest / "rxcomm", ignore=shutil.ignore_patterns("__pycache__"))
    return dest / "rxcomm"


def _edit(path: Path) -> None:
    path.write_text(path.read_text() + "\n# an edit\n")


def test_a_source_edit_changes_the_identity_and_a_touch_does_not(tmp_path):
    a, b = _copy(tmp_path / "a"), _copy(tmp_path / "b")
    # outside a git checkout: the version and the sources' hash, no "git" part
    ident = ci.code_identity(a)
    assert ident.split()[0] == "0.1.0" and ident.split()[1] == "sources" and "git" not in ident
    assert ci.code_identity.__wrapped__(b) == ident  # the same bytes: the same identity
    (b / "planning/paths.py").touch()
    assert ci.code_identity.__wrapped__(b) == ident
    _edit(b / "planning/paths.py")
    assert ci.code_identity.__wrapped__(b) != ident
    # a moved file changes it too, though no byte changed
    (a / "planning/paths.py").rename(a / "planning/paths2.py")
    assert ci.code_identity.__wrapped__(a) != ident


@pytest.mark.process
def test_this_checkout_names_its_git_revision():
    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not run from a git checkout")
    ident = ci.code_identity()
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    assert ident.split()[1] == "git" and head.stdout.startswith(ident.split()[2][:12])


def test_the_envelope_carries_it_and_an_older_artefact_without_it_still_reads():
    env = TrajectorySummary.envelope({}, {}, {})
    assert env["code_identity"] == ci.code_identity() and env["rxcomm_version"] == "0.1.0"
    summary = dict(duration_s=1.0, solve_seconds=0.0, max_limit_ratio=0.0, active_fraction=0.0)
    summary |= dict(q_start=[0.0], q_goal=[0.0])
    old = dict(TrajectorySummary.envelope({}, {}, summary), mcap_file="x.mcap", mcap_sha256="0" * 64)
    old |= dict(topic="/t", n_samples=1, fields=["q"])
    del old["code_identity"]
    assert TrajectorySummary.model_validate(old).code_identity is None


def test_version_prints_the_code_identity():
    from typer.testing import CliRunner

    from rxcomm.cli import app

    res = CliRunner().invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output == f"rxcomm {ci.code_identity()}\n"
    assert " sources " in res.output


def test_commands_are_their_stage_modules():
    # the convention command_modules() reads from the file names, against the CLI's own table
    expected = {name: f"rxcomm.stages.{s.module}" for name, s in STAGES.items()}
    assert ci.command_modules() == expected


def test_a_command_hash_covers_what_it_imports_and_only_that(tmp_path):
    root = _copy(tmp_path)
    files = ci.import_closure(["rxcomm.cli", "rxcomm.stages.report"], root)
    names = {p.relative_to(root).as_posix() for p in files}
    # the stage, the CLI, the packages on the way, a function-level import, what the report renders with
    assert {"stages/report.py", "cli.py", "__init__.py", "reporting/__init__.py"} <= names
    assert "reporting/html.py" in names
    assert "planning/topp.py" not in names and "cell/server.py" not in names  # the report plans nothing
    before = ci.command_hashes(root)
    _edit(root / "reporting/html.py")
    ci._imported.cache_clear()
    after = ci.command_hashes(root)
    assert {c for c in before if before[c] != after[c]} == {"report"}


def test_relative_and_parenthesised_imports_are_read(tmp_path):
    pkg = tmp_path / "rxcomm"
    (pkg / "sub").mkdir(parents=True)
    for f in ("__init__.py", "sub/__init__.py", "sub/b.py", "sub/c.py", "d.py", "e.py", "f.py"):
        (pkg / f).write_text("")
    (pkg / "sub/a.py").write_text(
        textwrap.dedent(
            """\
            from . import b
            from .c import x  # c is a module
            from .. import d


            def f():
                from rxcomm import (
                    e,  # a comment
                )


            EXPORTERS = {"kind": "rxcomm.f:export"}  # imported by name (importlib)
            """
        )
    )
    files = ci.import_closure(["rxcomm.sub.a"], pkg)
    got = {p.relative_to(pkg).as_posix() for p in files}
    assert got == {
        "__init__.py",
        "sub/__init__.py",
        "sub/a.py",
        "sub/b.py",
        "sub/c.py",
        "d.py",
        "e.py",
        "f.py",
    }


@pytest.mark.process
def test_two_artefacts_from_different_code_name_different_code(tmp_path):
    """The same script writes a trajectory (MCAP + summary YAML) with two copies of rxcomm that differ
    by one comment: the envelopes (in the YAML and in the MCAP) name two codes."""
    script = textwrap.dedent(
        """\
        import sys
        from pathlib import Path

        import numpy as np

        import rxcomm
        from rxcomm.io.trajectory import Trajectory, save_trajectory_mcap
        from rxcomm.schemas.trajectory import TrajectorySummary

        assert Path(rxcomm.__file__).parent == Path.cwd() / "rxcomm", rxcomm.__file__
        t, q = np.linspace(0.0, 1.0, 11), np.zeros((11, 6))
        s = dict(duration_s=1.0, solve_seconds=0.0, max_limit_ratio=0.0, active_fraction=0.0)
        s |= dict(q_start=[0.0] * 6, q_goal=[0.0] * 6)
        save_trajectory_mcap(Path(sys.argv[1]), Trajectory(t, q, q, q), TrajectorySummary.envelope({}, {}, s))
        """
    )
    from rxcomm.io.mcap_io import read_mcap_envelope

    idents = []
    for name, edit in (("a", False), ("b", True)):
        root = _copy(tmp_path / name)
        if edit:
            _edit(root / "io/trajectory.py")
        out = tmp_path / f"{name}.mcap"
        run = subprocess.run([sys.executable, "-c", script, str(out)], cwd=root.parent, capture_output=True)
        assert run.returncode == 0, run.stderr.decode()
        printed = subprocess.run(
            [sys.executable, "-m", "rxcomm.code_identity"], cwd=root.parent, capture_output=True, text=True
        ).stdout.strip()
        doc = yaml.safe_load(out.with_suffix(".yaml").read_text())
        assert doc["code_identity"] == printed == read_mcap_envelope(out)["code_identity"]
        idents.append(printed)
    assert idents[0] != idents[1]
    assert idents[0].rsplit(" ", 1)[0] == idents[1].rsplit(" ", 1)[0]  # same version, only the sources differ
