"""`rxcomm report BUILD_DIR`: the commissioning report (Markdown + the stages' PNG figures).

Reads the artefacts `make commission` writes under their conventional names and puts each stage's
headline figures beside the paper's. A missing artefact is a missing section, said so in the report.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated

import typer

from rxcomm import __version__, console
from rxcomm import report as rep
from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_text, check_outputs
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.schemas.acceptance import Acceptance
from rxcomm.schemas.calibration import Calibration
from rxcomm.schemas.configs import Configs
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.excitation import Excitation
from rxcomm.schemas.run_log import RunLog
from rxcomm.schemas.trajectory import TrajectorySummary


def _load(path: Path, model: type[Artefact]) -> dict | None:
    """The artefact as plain data, validated by its schema (InputError names file and field)."""
    if not path.exists():
        return None
    return read_yaml_artefact(path, model).model_dump(mode="json")


def _img(build: Path, name: str) -> str | None:
    return name if (build / name).exists() else None


def build_report(build: Path) -> tuple[str, list[str]]:
    """(Markdown, names of the missing artefacts)."""
    missing: list[str] = []

    def need(name: str, model: type[Artefact]) -> dict | None:
        d = _load(build / name, model)
        if d is None:
            missing.append(name)
        return d

    sections: list[rep.Section] = []
    verdict = need("verdict.yaml", Acceptance)
    configs = need("configs.yaml", Configs)
    if configs:
        sections.append(
            rep.configs_section(configs["summary"], _img(build, "configs.png"), configs["criterion"])
        )
    cal = need("calibration.yaml", Calibration)
    if cal:
        sections.append(rep.calibration_section(cal["summary"], cal["error_tables"]))
    exc = need("excitation.yaml", Excitation)
    if exc:
        sections.append(rep.excitation_section(exc["summary"], _img(build, "excitation.png")))
    dyn = need("dynamics.yaml", Dynamics)
    if dyn:
        sections.append(rep.dynamics_section(dyn["summary"], _img(build, "dynamics.png")))
    cp = need("cp.yaml", TrajectorySummary)
    if cp:
        sections.append(
            rep.trajectory_section(
                "Time-optimal continuous path (paper §5.1–5.3, Figs. 7–8)",
                cp["summary"],
                _img(build, "cp.png"),
                "1.04 s (straight line passing near a singularity)",
            )
        )
    ptp = need("ptp.yaml", TrajectorySummary)
    if ptp:
        sec = rep.trajectory_section(
            "Time-optimal point-to-point (paper §5.4–5.5, Fig. 9)",
            ptp["summary"],
            _img(build, "ptp.png"),
            "0.67 s",
        )
        if cp:
            sec = rep.Section(
                sec.title, [*sec.figures, rep.ptp_vs_cp_figure(cp["summary"], ptp["summary"])], sec.image
            )
        sections.append(sec)
    ff = need("run-ff.yaml", RunLog)
    noff = need("run-noff.yaml", RunLog)
    if ff:
        sections.append(
            rep.execution_section(ff["summary"], noff["summary"] if noff else None, _img(build, "run-ff.png"))
        )
    robot = (cal or dyn or configs or {}).get("robot", "?")
    preamble = (
        f"Robot `{robot}` commissioned against the simulated cell by rxcomm {__version__} on "
        f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC. Every figure is read from the artefacts in this directory "
        "(their envelopes hold the sha256 of every input); the paper's numbers are the Stäubli RX130L's."
    )
    if missing:
        preamble += f"\n\nNot produced in this build: {', '.join(missing)}."
    lead = rep.verdict_table(verdict) if verdict else ""
    return rep.render("rxcomm commissioning report", preamble, sections, lead), missing


def command(
    build_dir: Annotated[
        Path, typer.Argument(help="Directory holding the chain's artefacts (make commission: build/).")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="Markdown file to write.")] = Path(
        "build/report.md"
    ),
) -> None:
    """Write the commissioning report: each stage's figures beside the paper's, with the stages' plots."""
    run(build_dir, output)


@console.stage_command
def run(build_dir: Path, output: Path) -> list[str]:
    if not build_dir.is_dir():
        raise InputError("not a directory", file=build_dir)
    # the report reads the build's artefacts and links its figures: none of them may be the output
    artefacts = {p.name: p for p in sorted(build_dir.iterdir()) if p.suffix in (".yaml", ".mcap", ".png")}
    check_outputs({"output": output}, artefacts)
    text, missing = build_report(build_dir)
    atomic_write_text(output, text)
    console.out.print(f"report → {output}" + (f" (missing: {', '.join(missing)})" if missing else ""))
    return missing
