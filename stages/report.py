"""`rxcomm report BUILD_DIR`: the commissioning report (Markdown + the stages' PNG figures).

Reads the artefacts `make commission` writes under their conventional names and puts each stage's
headline figures beside the paper's. A missing artefact is a missing section, said so in the report.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated

import typer
import yaml

from rxcomm import __version__, console
from rxcomm import report as rep
from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_text


def _load(path: Path, kind: str) -> dict | None:
    if not path.exists():
        return None
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise InputError(f"not valid YAML: {e}", file=path) from e
    if not isinstance(data, dict) or data.get("kind") != kind:
        found = data.get("kind") if isinstance(data, dict) else None
        raise InputError(f"expected kind {kind!r}, found {found!r}", file=path, field="kind")
    return data


def _img(build: Path, name: str) -> str | None:
    return name if (build / name).exists() else None


def build_report(build: Path) -> tuple[str, list[str]]:
    """(Markdown, names of the missing artefacts)."""
    missing: list[str] = []

    def need(name: str, kind: str) -> dict | None:
        d = _load(build / name, kind)
        if d is None:
            missing.append(name)
        return d

    sections: list[rep.Section] = []
    configs = need("configs.yaml", "rxcomm/Configs")
    if configs:
        sections.append(rep.configs_section(configs["summary"], _img(build, "configs.png")))
    cal = need("calibration.yaml", "rxcomm/Calibration")
    if cal:
        sections.append(rep.calibration_section(cal["summary"], cal["error_tables"]))
    exc = need("excitation.yaml", "rxcomm/Excitation")
    if exc:
        sections.append(rep.excitation_section(exc["summary"], _img(build, "excitation.png")))
    dyn = need("dynamics.yaml", "rxcomm/Dynamics")
    if dyn:
        sections.append(rep.dynamics_section(dyn["summary"], _img(build, "dynamics.png")))
    cp = need("cp.yaml", "rxcomm/Trajectory")
    if cp:
        sections.append(
            rep.trajectory_section(
                "Time-optimal continuous path (paper §5.1–5.3, Figs. 7–8)",
                cp["summary"],
                _img(build, "cp.png"),
                "1.04 s (straight line passing near a singularity)",
            )
        )
    ptp = need("ptp.yaml", "rxcomm/Trajectory")
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
    ff = need("run-ff.yaml", "rxcomm/RunLog")
    noff = need("run-noff.yaml", "rxcomm/RunLog")
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
    return rep.render("rxcomm commissioning report", preamble, sections), missing


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
    text, missing = build_report(build_dir)
    atomic_write_text(output, text)
    console.out.print(f"report → {output}" + (f" (missing: {', '.join(missing)})" if missing else ""))
    return missing
