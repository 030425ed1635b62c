"""`rxcomm report BUILD_DIR`: the commissioning report, report.md and a self-contained report.html.

Reads the artefacts `make commission` writes under their conventional names, and every run log of the
build; opens with the verdict line (``ACCEPTED`` / ``NOT ACCEPTED — …``, from verdict.yaml), the
acceptance table (factory vs commissioned) and the ISO 9283 tables, then rxcomm's commissioning checks
(never part of the verdict), each stage's figures, parameter tables and plots, every executed run,
and the comparison with the paper. A missing artefact is a section "not measured".
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import BaseModel

from rxcomm import __version__, console
from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_text
from rxcomm.io.yaml_io import load_yaml, read_yaml_artefact
from rxcomm.reporting import html, markdown
from rxcomm.reporting.calibration import calibration_section, configs_section
from rxcomm.reporting.document import (
    DEFAULT_TOLERANCE,
    Report,
    Section,
    Tolerance,
    VerdictRow,
    missing_section,
)
from rxcomm.reporting.exports import exports_section
from rxcomm.reporting.identification import dynamics_section, excitation_section
from rxcomm.reporting.iso9283 import TestSet, iso9283_sections
from rxcomm.reporting.runs import (
    energy_section,
    execution_section,
    ptp_vs_cp_figure,
    ran_on,
    runs_section,
    trajectory_section,
)
from rxcomm.reporting.targets import acceptance_verdict, headline, stage_verdicts, verdict_note
from rxcomm.schemas.acceptance import Acceptance
from rxcomm.schemas.calibration import Calibration
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.iso9283 import Iso9283
from rxcomm.schemas.payload import Payload
from rxcomm.schemas.run_log import RunLog
from rxcomm.stages.declarations import DECLARATIONS

# The artefacts read by name: the command that writes each in the chain (tests/test_stage_declarations.py
# holds the Makefile's rules to it) and the section a missing one leaves "not measured".
SECTIONS: dict[str, tuple[str, str]] = {
    "configs.yaml": ("select-configs", "Optimal measurement poses (paper §3.3)"),
    "calibration.yaml": ("calibrate", "Geometric calibration (paper §3.1–3.4, Table 2)"),
    "excitation.yaml": ("excite", "Optimal exciting trajectory (paper §4.2)"),
    "dynamics.yaml": ("identify", "Dynamic identification (paper §4.1, §4.3, Fig. 5b)"),
    "cp.yaml": ("plan-cp", "Time-optimal continuous path (paper §5.1–5.3, Figs. 7–8)"),
    "ptp.yaml": ("plan-ptp", "Time-optimal point-to-point (paper §5.4–5.5, Fig. 9)"),
    "run-ff.yaml": ("run", "Execution with model-based feed-forward (paper §2.3, Fig. 2)"),
}
# Each artefact's schema: its command's declared output.
ARTEFACTS: dict[str, tuple[type[Artefact], str]] = {
    name: (DECLARATIONS[command].kinds[0], title) for name, (command, title) in SECTIONS.items()
}
# Which run log executed which plan: the limit tolerance `run` checked that plan against (the test
# above holds these to the Makefile's rules too).
EXECUTED_BY = {"cp": "run-ff.yaml", "ptp": "run-ptp.yaml", "excitation": "excite-log.yaml"}


def _load(path: Path, model: type[Artefact]) -> Any:
    """The artefact validated by its schema (InputError names file and field: a renamed summary
    field fails here, never reads as "not measured"), or None if the build has none."""
    if not path.exists():
        return None
    return read_yaml_artefact(path, model)


def _dump(items: Sequence[BaseModel]) -> list[dict]:
    """A table's rows as plain data for the section builders."""
    return [i.model_dump(mode="json") for i in items]


def _img(build: Path, name: str) -> str | None:
    return name if (build / name).exists() else None


def _plot(build: Path, artefact: str, command: str | None = None) -> str | None:
    """The plot `command` (default: the artefact's, `SECTIONS`) writes beside `artefact`, if the build
    has it (the declaration's `--plot` file)."""
    stage = DECLARATIONS[command or SECTIONS[artefact][0]]
    plot = next((b for b in stage.beside if b.when == "plot"), None)
    return None if plot is None else _img(build, plot.path(artefact).name)


def run_logs(build: Path) -> dict[str, RunLog]:
    """Every run log of the build (kind rxcomm/RunLog), by file name, validated."""
    out = {}
    for path in sorted(build.glob("*.yaml")):
        data = load_yaml(path)
        if isinstance(data, dict) and data.get("kind") == RunLog.KIND:
            out[path.name] = read_yaml_artefact(path, RunLog)
    return out


def _tolerances(runs: dict[str, RunLog]) -> dict[str, Tolerance]:
    out = {}
    for key, log in EXECUTED_BY.items():
        tol = runs[log].settings.limit_tolerance if log in runs else None
        if tol is not None:
            out[key] = (float(tol), f"`run`'s limit_tolerance in {log}")
    return out


def _stage_sections(build: Path, a: dict[str, Any], tol: dict) -> list[Section]:
    """One section per stage artefact present, in chain order."""
    s = {k: None if v is None else v.summary for k, v in a.items()}
    cfg, cal, dyn = a["configs.yaml"], a["calibration.yaml"], a["dynamics.yaml"]
    out: dict[str, Section] = {}
    if cfg:
        out["configs.yaml"] = configs_section(s["configs.yaml"], _plot(build, "configs.yaml"), cfg.criterion)
    if cal:
        # The prior-torque pass of the same measurements (optional: not every chain makes it).
        prior = _load(build / "calibration-prior.yaml", Calibration)
        out["calibration.yaml"] = calibration_section(
            cal.summary,
            _dump(cal.error_tables),
            _dump(cal.parameters),
            _dump(cal.compliance),
            None if prior is None else prior.summary,
            cal.notes,
        )
    if s["excitation.yaml"]:
        exc_tol = tol.get("excitation", DEFAULT_TOLERANCE)
        out["excitation.yaml"] = excitation_section(
            s["excitation.yaml"], _plot(build, "excitation.yaml"), exc_tol
        )
    if dyn:
        out["dynamics.yaml"] = dynamics_section(
            dyn.summary, _plot(build, "dynamics.yaml"), _dump(dyn.base_parameters), _dump(dyn.friction)
        )
    for key, paper in (("cp", "1.04 s (straight line passing near a singularity)"), ("ptp", "0.67 s")):
        if s[f"{key}.yaml"]:
            name = f"{key}.yaml"
            sec = trajectory_section(
                ARTEFACTS[name][1],
                s[name],
                _plot(build, name),
                paper,
                tol.get(key, DEFAULT_TOLERANCE),
            )
            if key == "ptp" and s["cp.yaml"]:
                sec = Section(sec.title, [*sec.figures, ptp_vs_cp_figure(s["cp.yaml"], s[name])], sec.image)
            out[name] = sec
    if s["run-ff.yaml"]:
        out["run-ff.yaml"] = execution_section(
            s["run-ff.yaml"], s["run-noff.yaml"], _plot(build, "run-ff.yaml")
        )
    return [out.get(name) or missing_section(title, [name]) for name, (_, title) in ARTEFACTS.items()]


def build_report(
    build: Path, acceptance: Sequence[VerdictRow] = (), headline_text: str = ""
) -> tuple[Report, list[str]]:
    """(the report, names of the missing artefacts). `acceptance`: criteria measured on the robot as a
    whole (factory vs commissioned, issue 17) that make the verdict `headline_text`, detailed by the
    ISO 9283 tables of both states; the stage targets are the commissioning checks, apart from it."""
    a = {name: _load(build / name, model) for name, (model, _) in ARTEFACTS.items()}
    missing = [name for name, v in a.items() if v is None]
    runs = run_logs(build)
    a["run-noff.yaml"] = runs.get("run-noff.yaml")
    tol = _tolerances(runs)
    sections = _stage_sections(build, a, tol)
    run_images = [png for n in runs if n != "run-ff.yaml" and (png := _plot(build, n, "run"))]
    sections.append(runs_section(runs, run_images))
    parity = build / "exports" / "parity.yaml"
    sections.append(exports_section(load_yaml(parity) if parity.is_file() else None))
    keys = {"calibration": "calibration.yaml", "dynamics": "dynamics.yaml", "excitation": "excitation.yaml"}
    keys |= {"cp": "cp.yaml", "ptp": "ptp.yaml", "run-ff": "run-ff.yaml", "run-noff": "run-noff.yaml"}
    summaries = {k: None if a.get(name) is None else a[name].summary for k, name in keys.items()}
    checks = stage_verdicts(summaries, runs, tol)
    iso = iso9283_sections(iso_sets(build), runs, summaries["calibration"])
    named = a["calibration.yaml"] or a["dynamics.yaml"] or a["configs.yaml"]
    robot = None if named is None else named.robot
    preamble = (
        ("The robot (named by no artefact here)" if robot is None else f"Robot `{robot}`")
        + f" commissioned against {ran_on(runs)} by rxcomm {__version__} on "
        f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC. The verdict above is `rxcomm accept`'s against "
        "acceptance.yaml: the robot as a whole, factory state vs commissioned state (factory: nominal "
        "kinematics, no feed-forward, a generic controller's timing from the catalogue limits), every "
        "criterion in the acceptance table counting. rxcomm's own commissioning checks follow apart "
        "and never count toward it; then each stage, every run, and the paper comparison last. Every "
        "figure is read from the artefacts in this directory (their envelopes hold the sha256 of every "
        "input)."
    )
    if missing:
        preamble += f"\n\nNot produced in this build: {', '.join(missing)}."
    if stale := stale_artefacts(build):
        preamble += "\n\n**Built on replaced inputs** (re-run `make commission`): " + "; ".join(stale) + "."
    report = Report(
        "rxcomm commissioning report",
        preamble,
        checks,
        sections,
        verdict_note(checks, "checks"),
        headline=headline_text,
        acceptance=acceptance,
        acceptance_note="" if not acceptance else verdict_note(acceptance, "acceptance criteria"),
        acceptance_sections=[*iso, energy_section(runs)],
    )
    return report, missing


def iso_sets(build: Path) -> list[TestSet]:
    """The build's ISO 9283 test sets: iso9283(-factory).yaml, then iso9283(-factory)-load-L.yaml (make
    acceptance's further loads, heaviest first), each with the build's identified payloads."""
    from rxcomm.schemas.plain import sha256_file

    payloads = {}
    for path in sorted(build.glob("payload-*.yaml")):
        if (art := _load(path, Payload)) is not None:
            payloads[path.name] = (sha256_file(path), art)
    names = [("iso9283-factory.yaml", "iso9283.yaml")]
    loads = [p for p in build.glob("iso9283-load-*.yaml") if p.stem.rsplit("-", 1)[1].isdigit()]
    loads.sort(key=lambda p: -int(p.stem.rsplit("-", 1)[1]))
    names += [(p.name.replace("iso9283-", "iso9283-factory-"), p.name) for p in loads]
    return [TestSet(_load(build / f, Iso9283), _load(build / c, Iso9283), payloads) for f, c in names]


def stale_artefacts(build: Path) -> list[str]:
    """Artefacts of ``build`` made from a file of ``build`` that has been replaced since: an input
    named NAME in the envelope whose NAME.yaml here has another sha256 (and no other YAML here has
    the recorded one: the envelope names an input by its role, and `make commission PLANT=mujoco`
    gives identify calibration-prior.yaml as its `calibration`), and a summary whose MCAP is not the
    one it was written for."""
    from rxcomm.schemas.plain import sha256_file

    hashes: dict[str, str] = {}

    def sha(path: Path) -> str:
        if path.name not in hashes:
            hashes[path.name] = sha256_file(path)
        return hashes[path.name]

    yamls = sorted(build.glob("*.yaml"))
    out = []
    for path in yamls:
        try:
            doc = load_yaml(path)
        except InputError:
            continue
        if not isinstance(doc, dict):
            continue
        for name, made in (doc.get("inputs") or {}).items():
            source = build / f"{name}.yaml"
            if not (isinstance(made, str) and source.is_file() and source != path and sha(source) != made):
                continue
            if not any(sha(other) == made for other in yamls if other != path):
                out.append(f"{path.name} was made from an older {source.name}")
        mcap = doc.get("mcap_file")
        if isinstance(mcap, str) and (build / mcap).is_file() and sha(build / mcap) != doc.get("mcap_sha256"):
            out.append(f"{mcap} is not the MCAP its summary {path.name} was written for")
    return out


def _image_loader(build: Path):
    def load(name: str) -> bytes | None:
        path = build / name
        return path.read_bytes() if path.is_file() else None

    return load


@console.stage_command
def command(
    build_dir: Annotated[
        Path, typer.Argument(help="Directory holding the chain's artefacts (make commission: build/).")
    ],
    output: Annotated[
        Path | None,
        typer.Option(
            "-o", "--output", help="Markdown file to write (default: BUILD/report.md); NAME.html beside it."
        ),
    ] = None,
) -> list[str]:
    """Write the commissioning report (Markdown + self-contained HTML): the verdict, each stage's figures,
    parameter tables and plots, every run, the comparison with the paper."""
    build_dir = Path(build_dir)
    output = build_dir / "report.md" if output is None else Path(output)
    if not build_dir.is_dir():
        raise InputError("not a directory", file=build_dir)
    if output.suffix == ".html":
        raise InputError("give the Markdown file (NAME.md): NAME.html is written beside it", field="output")
    page = output.with_suffix(".html")
    # the report reads the build's artefacts and embeds its figures: none of them may be an output
    artefacts = {p.name: p for p in sorted(build_dir.iterdir()) if p.suffix in (".yaml", ".mcap", ".png")}
    DECLARATIONS["report"].check(output=output, build_dir=list(artefacts.values()))
    verdict = _load(build_dir / "verdict.yaml", Acceptance)  # factory vs commissioned (`rxcomm accept`)
    report, missing = build_report(build_dir, acceptance_verdict(verdict), headline(verdict))
    output.parent.mkdir(parents=True, exist_ok=True)
    # Markdown links the figures where they are, relative to the report's own directory
    prefix = Path(os.path.relpath(build_dir.resolve(), output.resolve().parent))
    atomic_write_text(output, markdown.render(report, "" if prefix == Path(".") else f"{prefix.as_posix()}/"))
    atomic_write_text(page, html.render(report, _image_loader(build_dir)))
    console.out.print(
        f"report → {output}, {page.name}" + (f" (missing: {', '.join(missing)})" if missing else "")
    )
    return missing
