"""The architecture the layout promises: packages all installed, dependencies pointing one way."""

import ast
import functools
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

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


@functools.cache
def _imports() -> dict[Path, list[ast.Import | ast.ImportFrom]]:
    """Every import statement of every rxcomm module (lazy ones inside functions too), parsed once for
    the tests that follow the imports."""
    return {
        path: [n for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.Import | ast.ImportFrom)]
        for path in sorted((ROOT / "rxcomm").rglob("*.py"))
    }


def test_library_never_imports_stages():
    offenders = []
    for path, nodes in _imports().items():
        if (path.name == "cli.py" and path.parent == ROOT / "rxcomm") or "stages" in path.parts:
            continue  # the composition root and the stages themselves
        for node in nodes:
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


def _lint_imports(tree: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("lint-imports")
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run(
        [str(exe), "--no-cache", "--config", str(tree / "pyproject.toml")],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.process  # lint-imports
def test_layer_contract_holds_and_catches_a_violation(tmp_path):
    """`make lint` runs this contract (pyproject [tool.importlinter]); a model module importing the
    planner above it must break it, so the contract is not vacuous."""
    for name in ("rxcomm", "bench"):
        shutil.copytree(ROOT / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    kept = _lint_imports(tmp_path)
    assert kept.returncode == 0, kept.stdout + kept.stderr
    robot = tmp_path / "rxcomm" / "model" / "robot.py"
    robot.write_text(robot.read_text() + "\nimport rxcomm.planning.paths  # noqa\n")
    bench = tmp_path / "bench" / "table.py"
    bench.write_text(bench.read_text() + "\nimport rxcomm.stages.run  # noqa\n")
    broken = _lint_imports(tmp_path)
    assert broken.returncode != 0
    assert "rxcomm.model.robot -> rxcomm.planning.paths" in broken.stdout
    assert "bench.table -> rxcomm.stages.run" in broken.stdout


def _module_imports() -> dict[str, set[str]]:
    """Every rxcomm module and the rxcomm modules it imports (lazy imports inside functions included)."""
    modules = {}
    for path in _imports():
        parts = path.relative_to(ROOT).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps = set()
        for node in _imports()[path]:
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            deps |= {t for t in targets if t in modules and t != name and not name.startswith(t + ".")}
        graph[name] = deps
    return graph


def test_no_import_cycle_between_modules():
    graph = _module_imports()
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                cycles.append(" -> ".join([*stack[stack.index(dep) :], dep]))
            elif dep not in state:
                visit(dep, [*stack, dep])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    # a package's __init__ importing nothing keeps "package -> submodule -> package" out of this list
    assert not cycles, cycles


# ---- size rules (docs/architecture.md §2): long modules say why, stage functions stay short ----------

MODULE_MAX_LINES = 500
STAGE_FUNCTION_MAX_LINES = 80
WHY_LONG = re.compile(r"\bLong because\b\W*\w+")  # the phrase and at least one word of reason


def says_why_long(source: str, max_lines: int = MODULE_MAX_LINES) -> bool:
    """A module within ``max_lines`` needs no reason; a longer one's docstring must give one."""
    if len(source.splitlines()) <= max_lines:
        return True
    doc = ast.get_docstring(ast.parse(source), clean=False)
    return doc is not None and WHY_LONG.search(doc) is not None


def long_functions(source: str, max_lines: int = STAGE_FUNCTION_MAX_LINES) -> list[tuple[str, int]]:
    """(name, lines) of every function, nested ones and methods included, longer than ``max_lines``;
    a function's lines run from its ``def`` to its last line (decorators not counted)."""
    return [
        (node.name, node.end_lineno - node.lineno + 1)
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and node.end_lineno - node.lineno + 1 > max_lines
    ]


def _lines(n: int) -> str:
    return "".join(f"x{i} = {i}\n" for i in range(n))


def test_long_module_check_catches_a_violation():
    doc = '"""A module.\n\nIt does one thing.\n"""\n'
    why = '"""A module.\n\nLong because its table is one unit.\n"""\n'
    assert says_why_long(doc + _lines(MODULE_MAX_LINES - 4))  # exactly at the limit: fine
    assert not says_why_long(doc + _lines(MODULE_MAX_LINES - 3))  # one line over, no reason
    assert not says_why_long(_lines(MODULE_MAX_LINES + 1))  # no docstring at all
    assert not says_why_long('"""Long because"""\n' + _lines(MODULE_MAX_LINES))  # the phrase, no reason
    assert not says_why_long('x = 0\n"""Long because it is."""\n' + _lines(MODULE_MAX_LINES))  # not first
    assert says_why_long(why + _lines(MODULE_MAX_LINES))


def test_long_modules_say_why():
    """Every module of rxcomm/ and bench/ over 500 lines says in its first docstring why it is
    long, with the phrase "Long because" and the reason (the convention of docs/architecture.md §2)."""
    offenders = [
        f"{path.relative_to(ROOT)} ({len(path.read_text().splitlines())} lines)"
        for name in ("rxcomm", "bench")
        for path in sorted((ROOT / name).rglob("*.py"))
        if not says_why_long(path.read_text())
    ]
    assert not offenders, f"over {MODULE_MAX_LINES} lines without 'Long because …': {offenders}"


def test_stage_function_check_catches_a_violation():
    def function(name: str, body_lines: int, indent: str = "") -> str:
        return f"{indent}def {name}():\n" + "".join(f"{indent}    x{i} = {i}\n" for i in range(body_lines))

    ok = function("short", STAGE_FUNCTION_MAX_LINES - 1)  # def line + 79 = 80 lines
    assert long_functions(ok) == []
    assert long_functions(function("long", STAGE_FUNCTION_MAX_LINES)) == [("long", 81)]
    nested = "class Stage:\n" + function("outer", 2, "    ") + function("inner", 81, "        ")
    nested += "async def coro():\n    pass\n"
    assert sorted(long_functions(nested)) == [("inner", 82), ("outer", 85)]
    decorated = "@decorator\n" + ok  # decorators do not count
    assert long_functions(decorated) == []


def test_stage_functions_are_short():
    """No function in rxcomm/stages (nested ones included) spans more than 80 lines: a stage parses
    options, builds settings, makes one library call and writes; longer is library code."""
    offenders = [
        f"{path.relative_to(ROOT)}: {name} ({n} lines)"
        for path in sorted((ROOT / "rxcomm" / "stages").glob("*.py"))
        for name, n in long_functions(path.read_text())
    ]
    assert not offenders, f"stage functions over {STAGE_FUNCTION_MAX_LINES} lines: {offenders}"
