"""The command line: docs/cli.md is the option vocabulary, `rxcomm --help` answers without importing the
stages, deprecated spellings still work, every command's help shows an example."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from rxcomm import cli

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "cli.md"
HEAVY = ("toppra", "matplotlib", "scipy", "casadi", "pinocchio")


def documented() -> dict[str, tuple[set[str], set[str], set[str]]]:
    """command -> (option spellings, deprecated spellings, hidden options) from the tables of docs/cli.md
    (a hidden option's meaning starts with "hidden:")."""
    tables: dict[str, tuple[set[str], set[str], set[str]]] = {}
    name = None
    for line in DOC.read_text(encoding="utf-8").splitlines():
        if m := re.match(r"### `rxcomm ([a-z0-9-]+)`", line):
            name = m.group(1)
            tables[name] = (set(), set(), set())
        elif name and line.startswith("| `-"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            names = re.findall(r"`(-[^`]+)`", cells[0])
            if cells[1] == "switch":  # rule 7: a switch --X is also --no-X
                names += [f"--no-{o[2:]}" for o in names if not o.startswith("--no-")]
            tables[name][2 if cells[2].startswith("hidden") else 0].update(names)
            tables[name][1].update(re.findall(r"`(-[^`]+)`", cells[-1]))
    return tables


def command_tree() -> dict:
    group = typer.main.get_command(cli.app)
    ctx = typer.Context(group)
    return {name: group.get_command(ctx, name) for name in group.list_commands(ctx)}


def spellings(cmd, hidden: bool | None = False) -> set[str]:
    """The options' spellings: visible ones (hidden=False), hidden ones (True) or all (None)."""
    return {
        o
        for p in cmd.params
        if p.param_type_name == "option" and (hidden is None or p.hidden == hidden)
        for o in (*p.opts, *p.secondary_opts)
        if o != "--help"
    }


def test_every_option_is_spelled_as_docs_cli_md_says():
    docs, tree = documented(), command_tree()
    assert set(docs) == set(tree), "docs/cli.md must have one table per command"
    for name, cmd in tree.items():
        assert spellings(cmd) == docs[name][0], name
        assert spellings(cmd, hidden=True) == docs[name][2], name
        old = {o for o, _ in cli.STAGES[name].deprecated}
        assert old == docs[name][1] - {"positional"}, name  # the table's deprecated column
        assert not old & spellings(cmd), f"{name}: a deprecated spelling is still a visible option"
        for _, new in cli.STAGES[name].deprecated:
            assert new in spellings(cmd, hidden=None), f"{name}: alias to unknown {new}"


def test_units_are_the_last_word_and_no_single_letter_option_but_o():
    unitless = re.compile(r"--(max-gap|torque-lag|min-speed|max-wall|margin|position-margin|omega|speed)$")
    for name, cmd in command_tree().items():
        for o in spellings(cmd):
            assert not unitless.match(o), f"{name} {o}: unit missing from the name"
            assert o.startswith("--") or o == "-o", f"{name} {o}"


def test_short_help_is_the_start_of_the_commands_help_and_every_help_has_an_example():
    tree = command_tree()
    for name, stage in cli.STAGES.items():
        cmd = tree[name]
        assert " ".join(cmd.help.split()).startswith(stage.short_help), name
        res = CliRunner().invoke(cli.app, [name, "--help"], terminal_width=200)
        assert res.exit_code == 0, res.output
        assert "Example:" in res.output and f"rxcomm {name}" in res.output, name
        # the example itself parses: its options are the command's
        args = stage.example.split()[2:]
        assert {a.partition("=")[0] for a in args if a.startswith("-")} <= spellings(cmd), name


@pytest.mark.process
@pytest.mark.parametrize("args", [[], ["--help"], ["--version"]])
def test_import_of_the_cli_and_top_level_help_load_no_heavy_library(args):
    code = (
        "import sys; import rxcomm.cli as c\n"
        f"try:\n    c.app({args!r}, prog_name='rxcomm')\nexcept SystemExit:\n    pass\n"
        f"print([m for m in {HEAVY + ('rxcomm.stages',)!r} if m in sys.modules])"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip().splitlines()[-1] == "[]", res.stdout
    if args == ["--help"]:
        assert "plan-ptp" in res.stdout  # the listing still names every command


@pytest.mark.process
def test_every_commands_help_loads_no_heavy_library():
    """`rxcomm STAGE --help` answers from the options alone: a stage imports the library inside the
    functions that run it (rxcomm/stages/__init__.py), so its help costs no toppra, scipy, pinocchio."""
    code = (
        "import sys; import rxcomm.cli as c\n"
        "for name in c.STAGES:\n"
        "    try:\n        c.app([name, '--help'], prog_name='rxcomm')\n"
        "    except SystemExit:\n        pass\n"
        f"    loaded = [m for m in {HEAVY!r} if m in sys.modules]\n"
        "    if loaded:\n        print('HEAVY', name, loaded); break\n"
        "else:\n    print('done')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip().splitlines()[-1] == "done", res.stdout.strip().splitlines()[-1]


@pytest.mark.process
def test_completion_is_on_and_completes_commands_and_options():
    res = CliRunner().invoke(cli.app, ["--help"], terminal_width=200)
    assert "--install-completion" in res.output and "--show-completion" in res.output
    exe = Path(sys.executable).with_name("rxcomm")
    if not exe.exists():
        pytest.skip("no rxcomm console script beside the interpreter")

    def complete(words: str, cword: int) -> list[str]:
        env = {"_RXCOMM_COMPLETE": "complete_bash", "COMP_WORDS": words, "COMP_CWORD": str(cword)}
        done = subprocess.run([str(exe)], env={**os.environ, **env}, capture_output=True, text=True)
        return done.stdout.split()

    assert complete("rxcomm pl", 1) == ["plan-cp", "plan-ptp", "plan-poses", "plan-cycles"]
    assert complete("rxcomm select-configs --va", 2) == [
        "--validation-poses"
    ]  # hidden aliases are not offered


@pytest.mark.parametrize(
    ("name", "old", "new"),
    [
        ("select-configs", ["-n", "12", "--intervals=7"], ["--poses", "12", "--grid-intervals=7"]),
        ("robot-info", ["samples/rx130l"], ["--robot", "samples/rx130l"]),
        ("plan-ptp", ["-N", "8", "--max-wall", "1"], ["--time-intervals", "8", "--max-wall-s", "1"]),
        ("identify", ["--model", "d.yaml", "--", "--model"], ["--dynamics", "d.yaml", "--", "--model"]),
    ],
)
def test_deprecated_spellings_are_rewritten(name, old, new, capsys):
    assert cli.rewrite_deprecated(name, old) == new
    assert "deprecated" in capsys.readouterr().err


@pytest.mark.slow
def test_deprecated_spelling_still_runs_the_command():
    res = CliRunner().invoke(cli.app, ["robot-info", str(ROOT / "samples" / "rx130l")])
    assert res.exit_code == 0, res.output
    assert "deprecated" in res.output and "rx130l" in res.output


@pytest.mark.make
@pytest.mark.parametrize("goal", ["commission", "commission-ci"])
def test_the_makefile_spells_every_option_as_docs_cli_md(tmp_path, goal):
    """`make -n -B GOAL` prints every rxcomm command of the chain: each option must be its command's."""
    if shutil.which("make") is None:
        pytest.skip("no make")
    printed = subprocess.run(
        ["make", "-n", "-B", goal, f"BUILD={tmp_path / 'b'}"], cwd=ROOT, capture_output=True, text=True
    ).stdout
    printed = re.sub(r'\$\(\S*python -c "[^"]*"\)', "VALUE", printed)  # plan-ptp's states from cp.yaml
    tree = command_tree()
    commands = re.findall(r"bin/rxcomm ([a-z0-9-]+)((?: (?!&&|>)\S+)*)", printed)
    assert {name for name, _ in commands} >= {"select-configs", "calibrate", "identify", "plan-ptp", "run"}
    for name, args in commands:
        used = {a.partition("=")[0] for a in args.split() if a.startswith("-")}
        assert used <= spellings(tree[name]), f"{name}: {used - spellings(tree[name])}"


# Option names that still carry several help texts across commands: each a name whose meaning differs by
# command or whose texts say what that command does with it. One meaning a name is the rule (issue 28):
# this list only shrinks; a new name with a second help text fails below.
SEVERAL_HELP_TEXTS = {
    "--allow-remote",  # run: a real gateway; cell-sim: listening beyond loopback
    "--calibration",  # what each command takes from the calibration
    "--cycles",  # pose cycles / path cycles
    "--duration-s",  # cell-sim: stop after; plan-cycles: time-scale to
    "--dwell-s",  # at each pose / at each path end
    "--k2",
    "--method",  # identify: least squares; plan-cp: planner
    "--output",  # what each command writes
    "--plot",  # what each figure shows
    "--realtime",
    "--seed",  # of what each command draws
    "--start",  # cell-sim: initial; excite: rest pose; plan-ptp: start of the move
    "--start-deg",
    "--timing",
    "--truth",
}


def help_texts() -> dict[str, set[str]]:
    """option name -> its help texts over every command (visible options)."""
    out: dict[str, set[str]] = {}
    for cmd in command_tree().values():
        for p in cmd.params:
            if p.param_type_name == "option" and not p.hidden:
                out.setdefault(max(p.opts, key=len), set()).add(" ".join((p.help or "").split()))
    return out


def test_every_option_name_has_one_help_text_across_commands():
    texts = help_texts()
    several = {name for name, t in texts.items() if len(t) > 1}
    assert several == SEVERAL_HELP_TEXTS, (several - SEVERAL_HELP_TEXTS, SEVERAL_HELP_TEXTS - several)
    for name in ("--dynamics", "--cell", "--log", "--robot"):  # the ones issue 28 named, and the robot
        assert len(texts[name]) == 1, (name, texts[name])
    # the check fails on a name given a second text
    texts["--dynamics"].add("Score this dynamics.yaml instead of identifying.")
    assert {name for name, t in texts.items() if len(t) > 1} != SEVERAL_HELP_TEXTS


@pytest.mark.slow
def test_iso9283_paths_writes_the_sample_paths_and_the_old_spelling_still_works(tmp_path):
    robot = ROOT / "samples" / "rx130l"
    res = CliRunner().invoke(
        cli.app,
        [
            "iso9283-paths",
            "--robot",
            str(robot),
            "--cell",
            str(robot / "cell.yaml"),
            "-o",
            str(tmp_path / "a"),
        ],
    )
    assert res.exit_code == 0, res.output
    for f in sorted(robot.glob("paths/iso9283-*.yaml")):  # the samples were written this way
        body = [ln for ln in (tmp_path / "a" / f.name).read_text().splitlines() if not ln.startswith("#")]
        assert body == [ln for ln in f.read_text().splitlines() if not ln.startswith("#")], f.name
    res = CliRunner().invoke(
        cli.app,
        [
            "plan-cp",
            "--robot",
            str(robot),
            "--cell",
            str(robot / "cell.yaml"),
            "--iso9283",
            str(tmp_path / "b"),
        ],
    )
    assert res.exit_code == 0 and "deprecated: use rxcomm iso9283-paths" in res.output, res.output
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == sorted(
        p.name for p in (tmp_path / "a").iterdir()
    )
