"""The architecture the layout promises: packages all installed, dependencies pointing one way."""

import ast
import tomllib

from .conftest import ROOT


def test_every_package_directory_is_installed():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    on_disk = {
        "rxcomm." + ".".join(p.parent.relative_to(ROOT / "rxcomm").parts)
        if p.parent != ROOT / "rxcomm"
        else "rxcomm"
        for p in (ROOT / "rxcomm").rglob("__init__.py")
    }
    assert on_disk <= listed, f"add to pyproject [tool.setuptools] packages: {sorted(on_disk - listed)}"


def test_library_never_imports_stages():
    offenders = []
    for path in (ROOT / "rxcomm").rglob("*.py"):
        if (path.name == "cli.py" and path.parent == ROOT / "rxcomm") or "stages" in path.parts:
            continue  # the composition root and the stages themselves
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            offenders += [f"{path.relative_to(ROOT)}: {n}" for n in names if n.startswith("rxcomm.stages")]
    assert not offenders, offenders


def test_stages_never_read_the_hidden_truth():
    """Only the simulator (rxcomm.cell) and recovery-scoring tests may read truth.yaml."""
    offenders = []
    for path in (ROOT / "rxcomm").rglob("*.py"):
        rel = path.relative_to(ROOT)
        if rel.parts[:2] in (("rxcomm", "cell"), ("rxcomm", "schemas")) or rel.name in (
            "dynamics.py",
            "cli.py",
        ):
            continue
        text = path.read_text()
        if "schemas.truth" in text or "truth_parameters" in text:
            offenders.append(str(rel))
    assert not offenders, offenders
