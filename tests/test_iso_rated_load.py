"""ISO 9283 at rated load in the report (issue 29): each test set states its load, the identified payload
its commissioned runs fed forward (matched by sha256 to the build's payload-L.yaml: L % of the rated
load); a build without one says none was mounted and that the set is reduced by it."""

from __future__ import annotations

from pathlib import Path

import yaml
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.io.yaml_io import write_yaml_artefact
from rxcomm.schemas.plain import sha256_file

from .conftest import ROOT
from .test_acceptance import _run_log
from .test_payload import _payload_artefact
from .test_verdict_first import _iso

runner = CliRunner()


def _set(build: Path, suffix: str, payload: Path | None, ap: float) -> None:
    """Both states' ISO artefacts of one set; the commissioned runs name `payload` as their input."""
    factory, commissioned = _iso(4e-3, 1e-4, 3e-3), _iso(ap, 1e-4, 3e-4)
    logs = {"run-poses.mcap": f"run-poses{suffix}.mcap", "run-iso.mcap": f"run-iso-line{suffix}.mcap"}
    data = commissioned.model_dump(mode="json")
    for c in data["criteria"]:
        c["log"] = logs[c["log"]]
    commissioned = type(commissioned).model_validate(data)
    for name in logs.values():
        log = _run_log(build / name.replace(".mcap", ".yaml"), 10.0, 1.0, None)
        doc = yaml.safe_load(log.read_text())
        doc["inputs"] = {} if payload is None else {"payload": sha256_file(payload)}
        log.write_text(yaml.safe_dump(doc))
    write_yaml_artefact(build / f"iso9283-factory{suffix}.yaml", factory)
    write_yaml_artefact(build / f"iso9283{suffix}.yaml", commissioned)


def _report(build: Path) -> str:
    res = runner.invoke(app, ["report", str(build)])
    assert res.exit_code == 0, res.output
    return (build / "report.md").read_text()


def _payload(robot, path: Path, mass: float) -> Path:
    _payload_artefact(robot, path)
    doc = yaml.safe_load(path.read_text())
    path.write_text(yaml.safe_dump(doc | {"mass_kg": mass}))
    return path


def test_each_test_set_states_its_identified_load(tmp_path, rx130l):
    build = tmp_path / "build"
    build.mkdir()
    full = _payload(rx130l, build / "payload-100.yaml", 5.0)
    tenth = _payload(rx130l, build / "payload-10.yaml", 0.5)
    _set(build, "", full, 2e-4)
    _set(build, "-load-10", tenth, 1e-4)
    md = _report(build)
    # one conditions block per set, the rated load first (the set the acceptance criteria read)
    first = md.index("test conditions (ISO 9283 §6), at 100 % of the rated load")
    assert first < md.index("test conditions (ISO 9283 §6), at 10 % of the rated load")
    assert "| load | 100 % of the rated load: payload-100.yaml, identified 5.000 ± 0.010 kg" in md
    assert "| load | 10 % of the rated load: payload-10.yaml, identified 0.500 ± 0.010 kg" in md
    # the pose tables per set and state: P3 commissioned at 100 %: 0.3 mm, at 10 %: 0.15 mm
    assert md.count("| pose | AP_p |") == 4
    assert "| P3 | 0.3 mm |" in md and "| P3 | 0.15 mm |" in md
    assert "test loads identified by `identify-payload`" in md
    assert (
        "| payload-100.yaml | 100 % | 5.0000 ± 0.0100 kg | (15.00 ± 0.10, -10.00 ± 0.10, 100.00 ± 0.10) mm"
        in md
    )
    assert "The acceptance criteria read the set at 100 % of the rated load." in md
    assert "no payload" not in md
    assert "not at 100 % of the rated load" not in md and "not at 10 % of the rated load" not in md


def test_a_set_without_a_payload_or_with_one_not_in_the_build_says_so(tmp_path, rx130l):
    build = tmp_path / "build"
    build.mkdir()
    _set(build, "", None, 2e-4)
    md = _report(build)
    assert "| load | none mounted: 0 % of the rated load" in md
    assert "no payload (ISO 9283: 100 % and 10 % of the rated load" in md
    assert "test loads identified" not in md
    # the runs fed forward a payload the build does not hold: not stated, never "none"
    elsewhere = _payload(rx130l, tmp_path / "payload-100.yaml", 5.0)
    _set(build, "", elsewhere, 2e-4)
    md = _report(build)
    assert "| load | not stated: the runs' payload file is not in this build |" in md
    # only the rated load: the 10 % set is named missing
    _payload(rx130l, build / "payload-100.yaml", 5.0)
    _set(build, "", build / "payload-100.yaml", 2e-4)
    md = _report(build)
    assert "not at 10 % of the rated load" in md and "no payload" not in md


def test_the_report_shows_the_time_energy_curve_accept_plots(tmp_path):
    """`accept --plot` with the curve's runs draws time-energy.png; the report's energy section embeds it
    (Markdown link, HTML data URL); a build without the curve's runs has no such figure."""
    import base64

    build = tmp_path / "build"
    build.mkdir()
    for name, t, tau2, e in (
        ("run-factory-cp", 4.0, 2e5, 900.0),
        ("run-factory-ptp", 3.0, 1.5e5, 600.0),
        ("run-ff", 1.2, 1.8e5, 800.0),
        ("run-ptp", 0.9, 1.2e5, 500.0),
        ("run-cp-at-factory-time", 4.0, 0.9e5, 700.0),
        ("run-ptp-at-factory-time", 3.0, 0.6e5, 450.0),
    ):
        _run_log(build / f"{name}.yaml", t, tau2, e)
    _run_log(build / "run-cp-curve-0.5.yaml", 2.6, 1.2e5, 740.0)
    _run_log(build / "run-ptp-curve-0.5.yaml", 1.9, 0.8e5, 470.0)
    args = [
        "accept",
        "--thresholds",
        str(ROOT / "samples/rx130l/acceptance.yaml"),
        "-o",
        str(build / "verdict.yaml"),
    ]
    for flag, names in (
        ("--factory-log", ("run-factory-cp", "run-factory-ptp")),
        ("--commissioned-log", ("run-ff", "run-ptp")),
        ("--commissioned-equal-time-log", ("run-cp-at-factory-time", "run-ptp-at-factory-time")),
        ("--commissioned-curve-log", ("run-cp-curve-0.5", "run-ptp-curve-0.5")),
    ):
        for n in names:
            args += [flag, str(build / f"{n}.mcap")]
    res = runner.invoke(app, [*args, "--plot"])
    assert res.exit_code == 0, res.output
    png = build / "time-energy.png"
    assert png.is_file() and png.read_bytes()[:4] == b"\x89PNG"
    md = _report(build)
    energy = md.split("Energy of the reference task at equal cycle time", 1)[1]
    assert "](time-energy.png)" in energy.split("\n## ", 1)[0]
    html = (build / "report.html").read_text()
    assert base64.b64encode(png.read_bytes()).decode() in html
    # without the curve's runs: no figure claimed
    for n in ("run-cp-curve-0.5.yaml", "run-ptp-curve-0.5.yaml", "time-energy.png"):
        (build / n).unlink()
    assert "time-energy.png" not in _report(build)
