"""The stage declarations (rxcomm/stages/declarations.py) are the one statement of what each command
reads and writes: the stages' output checks and the report's artefact list come from them, and here
the Makefile's chain rules are held to them (inputs and outputs match), from make's own database.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from pydantic import BaseModel

from rxcomm import cli
from rxcomm.stages import report
from rxcomm.stages.declarations import DECLARATIONS, Beside, Declaration

from .conftest import ROOT


def test_every_command_has_a_declaration_and_its_settings_model_exists():
    assert set(DECLARATIONS) == set(cli.STAGES)
    for name, decl in DECLARATIONS.items():
        model = decl.settings_model()
        assert model is None or issubclass(model, BaseModel), name
        assert set(decl.positional) <= set(decl.inputs), name


def test_a_stage_checks_exactly_its_declared_files(tmp_path):
    decl = DECLARATIONS["plan-cycles"]
    out, plan = tmp_path / "x.mcap", tmp_path / "plan.mcap"
    robot = ROOT / "samples/rx130l"
    with pytest.raises(TypeError, match="undeclared"):  # a file the declaration does not name
        decl.check(output=out, robot=robot, plan=plan, dynamics=None, calibration=None)
    with pytest.raises(TypeError, match="missing"):
        decl.check(output=out, robot=robot)
    # the output is refused where it is the plan's summary (the .mcap stands for its .yaml too)
    from rxcomm.errors import InputError

    with pytest.raises(InputError, match="is also the input plan"):
        decl.check(output=plan.with_suffix(".yaml"), robot=robot, plan=plan, dynamics=None, payload=None)


def test_a_command_takes_its_model_options_and_policy_from_the_declaration():
    def options(name: str) -> dict[str, list[str]]:
        return {p.name: p.opts for p in cli.stage_command(name).params}

    for name in ("plan-cp", "plan-ptp", "plan-cycles", "plan-poses", "run", "calibrate"):
        assert options(name)["dynamics"] == ["--dynamics"], name
    for name in ("plan-cp", "plan-ptp", "run"):  # declared with artefact_policy
        assert options(name)["payload"] == ["--payload"], name
        assert options(name)["other_robot"] == ["--other-robot"], name
        assert options(name)["allow_inconsistent"] == ["--allow-inconsistent"], name
    assert "other_robot" not in options("plan-cycles")
    assert "show_progress" not in options("run")  # run.execute's switch the command line does not set


def test_the_policy_options_set_the_policy_before_the_stage_runs():
    from rxcomm.model import artefact_checks
    from rxcomm.stages.stage_cli import stage

    seen = []

    @stage("run")
    def command() -> None:
        seen.append(artefact_checks._current())

    command(other_robot=True)
    command()
    assert seen == [artefact_checks.Policy(other_robot=True), artefact_checks.Policy()]


def test_checking_takes_the_declared_files_from_the_arguments(tmp_path):
    from rxcomm.errors import InputError
    from rxcomm.stages.stage_cli import checking

    def cycles(plan, robot_dir, output, dynamics=None, payload=None) -> str:
        return "ran"

    plan, robot = tmp_path / "plan.mcap", ROOT / "samples/rx130l"
    assert checking("plan-cycles")(cycles)(plan, robot, tmp_path / "x.mcap") == "ran"
    with pytest.raises(InputError, match="is also the input plan"):
        checking("plan-cycles")(cycles)(plan, robot, plan.with_suffix(".yaml"))
    with pytest.raises(TypeError, match="takes no"):  # a declared file it has no parameter for
        checking("plan-cp")(cycles)


def test_files_written_beside_come_from_the_declaration():
    calibrate = DECLARATIONS["calibrate"].written(output="b/c.yaml", urdf_out=None, mdh_out="b/mdh.yaml")
    assert calibrate == {
        "output": Path("b/c.yaml"),
        "urdf-out": None,
        "mdh-out": Path("b/mdh.yaml"),
        "mdh-out CSV": Path("b/mdh.csv"),
    }
    excite = DECLARATIONS["excite"].written(output="b/excitation.yaml", plot=True)
    assert excite["trajectory-out"] == Path("b/excitation-trajectory.mcap")
    assert excite["plot"] == Path("b/excitation.png")
    assert DECLARATIONS["excite"].written(output="b/e.yaml", plot=False)["plot"] is None


def test_the_reports_artefact_list_is_the_declared_outputs():
    for name, (command, _) in report.SECTIONS.items():
        decl = DECLARATIONS[command]
        assert report.ARTEFACTS[name][0] is decl.kinds[0], name
        assert Path(name).suffix == ".yaml"  # the artefact itself or the summary of its .mcap


# ---- the Makefile against the declarations --------------------------------------------------------------


@dataclass
class Rule:
    target: str
    command: str
    prereqs: set[str]
    text: str  # the recipe as make -n prints it (continuations joined)
    options: dict[str, list[str]] = field(default_factory=dict)  # option -> values
    args: list[str] = field(default_factory=list)  # positional arguments


def _env() -> dict[str, str]:
    drop = {"MAKEFLAGS", "MFLAGS", "MAKELEVEL", "MAKEOVERRIDES", "MAKEFILES"}
    return {k: v for k, v in os.environ.items() if k not in drop}


def _parse_args(text: str) -> tuple[dict[str, list[str]], list[str]]:
    text = re.sub(r'\$\(\S*python -c "[^"]*"\)', "VALUE", text)  # make helpers reading a summary
    words = text.split()
    options: dict[str, list[str]] = {}
    args: list[str] = []
    i = 0
    while i < len(words):
        w = words[i]
        if w in ("&&", ">", "|"):
            break
        if w.startswith("-"):
            key, eq, value = w.partition("=")
            if not eq and i + 1 < len(words) and not words[i + 1].startswith("-") and words[i + 1] != "&&":
                value, i = words[i + 1], i + 1
            options.setdefault(key, []).append(value)
        elif not options:
            args.append(w)
        i += 1
    return options, args


def chain_rules(makefile: Path, build: str, *variables: str) -> dict[str, Rule]:
    """Every rule of `make commission` (with make `variables`, NAME=VALUE) whose recipe runs rxcomm, by
    target, from `make -pn -B`."""
    out = subprocess.run(
        ["make", "--no-print-directory", "-f", str(makefile), "-pn", "-B", "commission", f"BUILD={build}"]
        + list(variables),
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    printed, _, database = out.stdout.partition("# Make data base")
    printed = printed.replace("\\\n", " ")
    prereqs: dict[str, set[str]] = {}
    for block in database.split("\n\n"):
        head = block.lstrip("\n").split("\n", 1)[0]
        target, colon, deps = head.partition(":")
        if colon and target.startswith(build + "/") and not block.lstrip().startswith("#"):
            prereqs[target] = set(deps.split())
    rules = {}
    for line in printed.splitlines():
        m = re.search(r"bin/rxcomm ([a-z0-9-]+) (.*)", line)
        if m is None:
            continue
        options, args = _parse_args(m.group(2))
        redirect = re.search(r"> (\S+)\.part", line)
        written = redirect.group(1) if redirect else options["-o"][0]
        target = written if written in prereqs else f"{written}/parity.yaml"  # export writes a directory
        text = re.split(r" > | && ", m.group(2))[0]
        rules[target] = Rule(target, m.group(1), prereqs[target], text, options, args)
    return rules


def _products(rule: Rule) -> set[str]:
    """The files a rule's command writes: the target, summaries of MCAPs, the declared files beside."""
    decl = DECLARATIONS[rule.command]
    files: dict[str, object] = {"output": rule.target}
    files |= {name: rule.options[f"--{name}"][0] for name in decl.outputs if f"--{name}" in rule.options}
    files |= {b.when: f"--{b.when}" in rule.options for b in decl.beside if b.when}
    out = {str(p) for p in decl.written(**files).values() if p is not None}
    return out | {p[: -len(".mcap")] + ".yaml" for p in out if p.endswith(".mcap")}


def _robot_files(robot_dir: str) -> set[str]:
    text = (ROOT / robot_dir / "drives.yaml").read_text()
    urdf = re.search(r"^urdf:\s*(\S+)", text, re.M).group(1).strip("'\"")
    return {f"{robot_dir}/drives.yaml", f"{robot_dir}/{urdf}"}


def check_rule(rule: Rule, rules: dict[str, Rule], build: str) -> list[str]:
    """What is wrong with one rule against its command's declaration ([] when it agrees)."""
    decl: Declaration = DECLARATIONS[rule.command]
    errors = []
    name = rule.target
    # the output: -o is the target (a directory output: the target's directory), of a declared suffix
    suffix = Path(name).suffix
    if "-o" in rule.options and rule.options["-o"][0] != name:
        if "/" not in decl.suffixes or rule.options["-o"][0] != str(Path(name).parent):
            errors.append(f"{name}: -o {rule.options['-o'][0]} is not the rule's target")
    elif "-o" not in rule.options and "" not in decl.suffixes:
        errors.append(f"{name}: {rule.command} declares an -o output")
    elif "-o" in rule.options and suffix not in decl.suffixes:
        errors.append(f"{name}: {rule.command} writes {decl.suffixes}, not {suffix}")
    # every option naming a file of the build is a declared input or output
    given: dict[str, list[str]] = {}
    for opt, values in rule.options.items():
        files = [v for v in values if v.startswith(build + "/")]
        if files and opt != "-o" and opt[2:] not in (*decl.inputs, *decl.outputs):
            errors.append(f"{name}: {rule.command} declares no file option {opt}")
        if opt.startswith("--") and opt[2:] in decl.inputs:
            given[opt[2:]] = values
    if decl.positional:
        given[decl.positional[0]] = rule.args
    # the source files it reads are its prerequisites: the robot's, a file, a directory's files (those of
    # the build: below)
    for inp, values in given.items():
        for v in (v for v in values if not v.startswith(build + "/")):
            if inp == "robot":
                missing = _robot_files(v) - rule.prereqs
            elif (ROOT / v).is_dir():
                missing = set() if any(p.startswith(v.rstrip("/") + "/") for p in rule.prereqs) else {v}
            else:
                missing = {v} - rule.prereqs
            for m in sorted(missing):
                errors.append(f"{name}: reads {m} (--{inp}) but the rule does not list it")
    # every artefact of the build it lists is one its recipe reads (through its command or a make helper
    # reading a summary), and every build file the recipe reads is a product of a listed rule
    producer = {p: r.target for r in rules.values() for p in _products(r)}
    mine = _products(rule)
    named = set(re.findall(re.escape(build) + r"/[\w.-]+(?:/[\w.-]+)?", rule.text))
    named -= mine | set(rule.options.get("-o", []))
    for f in sorted(named):
        if f not in producer:
            errors.append(f"{name}: reads {f}, which no rule of the chain writes")
        elif producer[f] not in rule.prereqs:
            errors.append(f"{name}: reads {f} but does not list {producer[f]}")
    if rule.command != "report":  # `report` reads the build directory (test below)
        for dep in sorted(p for p in rule.prereqs if p in rules and not _products(rules[p]) & named):
            errors.append(f"{name}: lists {dep}, which its recipe does not read")
    return errors


def check_makefile(makefile: Path, build: str, *variables: str) -> list[str]:
    rules = chain_rules(makefile, build, *variables)
    errors = [e for r in rules.values() for e in check_rule(r, rules, build)]
    # `report` reads its artefacts by name (report.SECTIONS, these), every run log of the build
    producer = {p: r.target for r in rules.values() for p in _products(r)}
    also = ["calibration-prior.yaml", "iso9283-factory.yaml", "iso9283.yaml", "verdict.yaml"]
    reads = {producer[f"{build}/{n}"] for n in [*report.SECTIONS, *also, "exports/parity.yaml"]}
    reads |= {r.target for r in rules.values() if r.command == "run" and r.target.endswith(".mcap")}
    # every ISO 9283 set (iso9283-load-L.yaml: make acceptance) and identified test load (payload-L.yaml)
    reads |= {r.target for r in rules.values() if r.command in ("iso9283", "identify-payload")}
    page = rules[f"{build}/report.md"]
    listed = {p for p in page.prereqs if p in rules}
    errors += [f"report.md: reads {f} but does not list it" for f in sorted(reads - listed)]
    errors += [f"report.md: lists {f}, which the report does not read" for f in sorted(listed - reads)]
    for key, log in report.EXECUTED_BY.items():  # which run executed which plan
        run = rules[producer[f"{build}/{log}"]]
        if producer.get(run.args[0]) != producer[f"{build}/{key}.yaml"]:
            errors.append(f"report.EXECUTED_BY: {log} does not run the {key} plan ({run.args})")
    return errors


needs_make = pytest.mark.skipif(shutil.which("make") is None, reason="GNU make not installed")


@pytest.mark.make
@needs_make
def test_the_makefile_rules_read_and_write_what_their_commands_declare(tmp_path):
    build = str(tmp_path / "build")  # `make -n` still runs the `+` lines (mkdir of exports/): not in ROOT
    rules = chain_rules(ROOT / "Makefile", build)
    assert {r.command for r in rules.values()} >= {"select-configs", "run", "identify", "plan-cp", "report"}
    assert len(rules) >= 40
    assert check_makefile(ROOT / "Makefile", build) == []


# `make acceptance`'s variables (the Makefile's acceptance rule): the rated-load rules are checked too.
ACCEPTANCE_VARS = (
    "POSE_CYCLES=30",
    "LINE_CYCLES=10",
    "LINE_SPEEDS_EXTRA=0.5 0.1",
    "LOAD=100",
    "LOADS_EXTRA=10",
)


@pytest.mark.make
@needs_make
def test_make_acceptance_rules_at_rated_load_read_and_write_what_they_declare(tmp_path):
    recipe = (ROOT / "Makefile").read_text().split("\nacceptance:\n", 1)[1].split("\n\n", 1)[0]
    for var in ACCEPTANCE_VARS:  # the variables `make acceptance` passes
        name, value = var.split("=", 1)
        assert re.search(rf"{name}=\"?{re.escape(value)}\"?(\s|$)", recipe), var
    build = str(tmp_path / "build")
    rules = chain_rules(ROOT / "Makefile", build, *ACCEPTANCE_VARS)
    assert check_makefile(ROOT / "Makefile", build, *ACCEPTANCE_VARS) == []
    # the load is identified on the cell carrying it, and the ISO tests carry and feed it forward
    ident = rules[f"{build}/payload-100.yaml"]
    assert ident.command == "identify-payload" and ident.options["--log"] == [
        f"{build}/excite-log-load-100.mcap"
    ]
    cell = rules[f"{build}/excite-log-load-100.mcap"].options["--truth-payload"]
    assert cell == ["samples/rx130l/truth-payload-100.yaml"]
    for name in ("run-poses", "run-iso-line", "run-iso-circle", "run-iso-line-0.1"):
        opts = rules[f"{build}/{name}.mcap"].options
        assert opts["--payload"] == [f"{build}/payload-100.yaml"], name
        assert opts["--truth-payload"] == ["samples/rx130l/truth-payload-100.yaml"], name
    assert rules[f"{build}/iso-line.mcap"].options["--payload"] == [f"{build}/payload-100.yaml"]
    factory = rules[f"{build}/run-factory-poses.mcap"].options
    assert "--payload" not in factory and factory["--truth-payload"] == [
        "samples/rx130l/truth-payload-100.yaml"
    ]
    assert factory["--speed-fraction"] == ["0.1"]  # the factory's slower approach with the load on
    for name in ("run-poses-load-10", "run-iso-line-load-10"):
        assert rules[f"{build}/{name}.mcap"].options["--payload"] == [f"{build}/payload-10.yaml"]
    assert {f"{build}/iso9283-load-10.yaml", f"{build}/iso9283-factory-load-10.yaml"} <= set(rules)
    # the verdict draws time-energy.png (accept --plot) from the curve's runs; the report embeds it
    verdict = rules[f"{build}/verdict.yaml"].options
    assert "--plot" in verdict and len(verdict["--commissioned-curve-log"]) >= 2
    # make commission's reduced set carries none
    plain = chain_rules(ROOT / "Makefile", build)
    assert not any("--payload" in r.options or "--truth-payload" in r.options for r in plain.values())


@pytest.mark.make
@needs_make
@pytest.mark.parametrize(
    ("edit", "error"),
    [
        # the feed-forward run without the dynamics it reads
        (
            ("$(B)/run-noff.mcap: $(B)/cp.mcap $(B)/dynamics.yaml", "$(B)/run-noff.mcap: $(B)/cp.mcap"),
            "build/run-noff.mcap: reads build/dynamics.yaml but does not list build/dynamics.yaml",
        ),
        # a plan listing an artefact its command never reads
        (
            ("$(B)/cp.mcap: $(CP_PATH) $(MODEL)", "$(B)/cp.mcap: $(CP_PATH) $(MODEL) $(B)/excitation.yaml"),
            "build/cp.mcap: lists build/excitation.yaml, which its recipe does not read",
        ),
        # a rule whose robot is not its prerequisite
        (
            ("$(B)/excitation.yaml: $(STAMP) $(ROBOT_FILES)", "$(B)/excitation.yaml: $(STAMP)"),
            "build/excitation.yaml: reads samples/rx130l/drives.yaml (--robot) but the rule does not list it",
        ),
        # the report without a run log of the chain
        (
            ("$(B)/run-iso-circle.mcap $(B)/run-cp-at-factory-time.mcap", "$(B)/run-cp-at-factory-time.mcap"),
            "report.md: reads build/run-iso-circle.mcap but does not list it",
        ),
    ],
)
def test_the_check_catches_a_rule_that_disagrees_with_its_declaration(tmp_path, edit, error):
    text = (ROOT / "Makefile").read_text()
    assert text.count(edit[0]) == 1
    (tmp_path / "Makefile").write_text(text.replace(edit[0], edit[1]))
    build = str(tmp_path / "build")
    assert error.replace("build/", build + "/") in check_makefile(tmp_path / "Makefile", build)


def test_a_declared_default_beside_output():
    d = Declaration(("robot",), defaults=(Beside("x-out", ".csv"),), outputs=("x-out",))
    assert d.written(output="a/b.yaml") == {"output": Path("a/b.yaml"), "x-out": Path("a/b.csv")}
