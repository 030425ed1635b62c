"""report.html renders in a real browser: headless Chromium (Debian's `chromium`, .ci/run installs it)
opens a report built from a real plan and a real run on the simulated cell, every figure decodes and the
verdict table is there; a screenshot of the first page is written beside the report. file:// only."""

from __future__ import annotations

import shutil
import struct
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.stages import run as run_stage

from .conftest import SAMPLES

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium not installed (apt-get install chromium)"),
]

# Run after load, in a copy of the page: count the images that decoded, the verdict rows, the sections.
PROBE = """<script>
window.addEventListener("load", () => {
  const imgs = [...document.images];
  const ok = imgs.filter((i) => i.complete && i.naturalWidth > 0 && i.naturalHeight > 0);
  const b = document.body;
  b.setAttribute("data-images", imgs.length);
  b.setAttribute("data-images-loaded", ok.length);
  b.setAttribute("data-verdict-rows", document.querySelectorAll("#checks tr").length - 1);
  b.setAttribute("data-first-h2", document.querySelector("h2").textContent);
  b.setAttribute("data-headline", document.querySelector("h1").nextElementSibling.textContent);
});
</script>"""


def _chromium(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--hide-scrollbars"]
    cmd += [f"--user-data-dir={tmp / 'chromium-profile'}", "--virtual-time-budget=5000", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def _attr(dom: str, name: str) -> str:
    start = dom.index(f'{name}="') + len(name) + 2
    return dom[start : dom.index('"', start)]


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", path
    return struct.unpack(">II", head[16:24])


@pytest.fixture(scope="module")
def build(tmp_path_factory) -> Path:
    """A build with a real PtP plan and its run on the embedded cell (with their figures); every other
    stage missing, so the report must say "not measured" for them."""
    robot = SAMPLES / "m900"
    build = tmp_path_factory.mktemp("report-browser") / "build"
    build.mkdir()
    r = CliRunner().invoke(
        app,
        [
            "plan-ptp", "--robot", str(robot), "--start", "-0.5,0.3,-0.4,0.2,0.6,0.0",
            "--goal", "0.6,0.1,-0.1,-0.4,0.9,1.0", "-N", "12", "--plot", "-o", str(build / "ptp.mcap"),
        ],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    run_stage.execute(
        build / "ptp.mcap", robot, build / "run-ptp.mcap", approach=True, plot=True, show_progress=False
    )
    r = CliRunner().invoke(app, ["report", str(build), "-o", str(build / "report.md")])
    assert r.exit_code == 0, r.output
    return build


def test_every_figure_loads_in_chromium_and_the_verdict_opens_the_report(build, tmp_path):
    page = (build / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 2  # ptp.png and run-ptp.png, embedded
    probe = tmp_path / "probe.html"
    probe.write_text(page.replace("</body>", PROBE + "</body>"))
    res = _chromium(tmp_path, "--dump-dom", probe.as_uri())
    assert res.returncode == 0, res.stderr[-2000:]
    dom = res.stdout
    assert _attr(dom, "data-images") == "2"
    assert _attr(dom, "data-images-loaded") == "2"  # decoded: a broken data URL has naturalWidth 0
    # as many check rows as the Markdown rendering of the same report has (a new target adds one to both)
    md = (build / "report.md").read_text().split("## Commissioning checks", 1)[1].split("\n## ", 1)[0]
    md_rows = [ln for ln in md.splitlines() if ln.startswith("| ")][1:]  # less the header
    assert int(_attr(dom, "data-verdict-rows")) == len(md_rows) >= 8
    # the verdict line right under the title (no verdict.yaml here: not accepted, and why), then the
    # acceptance table
    assert _attr(dom, "data-headline").startswith("NOT ACCEPTED — not measured: no verdict.yaml")
    assert _attr(dom, "data-first-h2") == "Acceptance: factory vs commissioned"
    assert "point-to-point plan: max limit ratio" in dom and "not measured" in dom
    assert "run-ptp.yaml" in dom  # the PtP run is shown


def test_a_screenshot_of_the_first_page_is_written_to_the_build(build, tmp_path):
    shot = build / "report-first-page.png"
    res = _chromium(
        tmp_path, f"--screenshot={shot}", "--window-size=1280,1600", (build / "report.html").as_uri()
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert _png_size(shot) == (1280, 1600)
    assert shot.stat().st_size > 20_000  # a rendered page, not a blank one
