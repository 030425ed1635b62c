"""Which code made an artefact (architecture §3): the version, the git revision and a hash of the sources.

``code_identity()`` is ``"0.1.0 git a600d80c1f2e-dirty sources 3f2a9c1b7e4d5a6b"``: the package version,
``git describe --always --dirty`` of the checkout rxcomm runs from (left out where rxcomm is not run
from a git checkout, e.g. an installed wheel) and the sha256 of every source file of the package (its
``.py`` and packaged ``.json``), hashed from the files that run. Two trees that differ in any source
byte differ in the hash, whatever git says (two uncommitted edits on one commit are both "-dirty").
Every artefact envelope carries it (``code_identity``) and ``rxcomm --version`` prints it.

The Makefile asks ``python -m rxcomm.code_identity --make`` for one hash a command: the hash of the
sources that command imports (its stage module, ``rxcomm.cli`` and everything they import, found in
the source text: lazily imported modules included, and the ``"rxcomm.a.b:name"`` strings of modules
imported by name with importlib), so editing a module rebuilds the rules whose command imports it and
nothing else. Standard library only: make runs it with the system Python.
"""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
from functools import cache
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
PACKAGE = PACKAGE_DIR.name  # "rxcomm"
HASH_CHARS = 16


def source_files(root: Path = PACKAGE_DIR) -> list[Path]:
    """The package's source files (``.py`` and ``.json``, caches excluded), sorted."""
    return sorted(p for p in root.rglob("*") if p.suffix in (".py", ".json") and "__pycache__" not in p.parts)


def sources_hash(files: list[Path], root: Path = PACKAGE_DIR) -> str:
    """sha256 over each file's path below ``root`` and bytes (so a renamed or moved file counts)."""
    h = hashlib.sha256()
    for p in sorted(files):
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()[:HASH_CHARS]


def git_describe(root: Path = PACKAGE_DIR) -> str | None:
    """``git describe --always --dirty`` of the checkout holding the package, or None (no checkout,
    no git)."""
    if not (root.parent / ".git").exists():  # a directory, or a file in a git worktree
        return None
    try:
        out = subprocess.run(
            ["git", "-C", str(root.parent), "describe", "--always", "--dirty", "--abbrev=12"],
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def _version(root: Path) -> str:
    # Read from the text so the Makefile's system Python never imports the package.
    for line in (root / "__init__.py").read_text().splitlines():
        if line.startswith("__version__"):
            return line.split("=", 1)[1].strip().strip("\"'")
    return "unknown"


@cache
def code_identity(root: Path = PACKAGE_DIR) -> str:
    """``"VERSION [git DESCRIBE] sources HASH"`` of the code running now (computed once a process)."""
    git = git_describe(root)
    sources = sources_hash(source_files(root), root)
    return " ".join([_version(root), *(["git", git] if git else []), "sources", sources])


# ---- what a command imports ------------------------------------------------------------------------------


def _module_file(name: str, root: Path) -> Path | None:
    """The file of module ``name`` (``rxcomm.a.b``) below ``root``, or None (not a module of ours)."""
    parts = name.split(".")
    if parts[0] != PACKAGE:
        return None
    base = root.joinpath(*parts[1:])
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.is_file():
            return p
    return None


_FROM = re.compile(r"^[ \t]*from[ \t]+(\.*[\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*)", re.M)
_IMPORT = re.compile(r"^[ \t]*import[ \t]+([^\n]*)", re.M)
# "rxcomm.a.b:name": a module imported by name at run time (importlib; stages.export's exporters)
_BY_NAME = re.compile(r"[\"'](rxcomm(?:\.\w+)+):\w+[\"']")


def _names(text: str) -> list[str]:
    """``a as b, c`` (or a parenthesised, multi-line list with comments) -> ``["a", "c"]``."""
    text = re.sub(r"#[^\n]*", "", text).strip("() \n")
    return [n.split()[0] for n in text.replace("\n", " ").split(",") if n.strip()]


@cache
def _imported(path: Path, root: Path) -> frozenset[str]:
    """Names of the package's modules ``path`` imports anywhere (top level or inside a function).
    Read from the text by line patterns (an AST walk of every module costs make ~1 s a run); an import
    shown in a docstring counts too, which at worst rebuilds more."""
    package = (PACKAGE, *path.relative_to(root).parts[:-1])  # a module's or an __init__.py's package
    text = path.read_text(encoding="utf-8")
    names: set[str] = set()
    for m in _IMPORT.finditer(text):
        names |= set(_names(m.group(1)))
    names |= set(_BY_NAME.findall(text))
    for m in _FROM.finditer(text):
        spec = m.group(1)
        level = len(spec) - len(spec.lstrip("."))
        base = package[: len(package) - level + 1] if level else ()
        mod = ".".join((*base, *([spec.lstrip(".")] if spec.lstrip(".") else [])))
        names.add(mod)
        names |= {f"{mod}.{n}" for n in _names(m.group(2))}  # `from rxcomm.io import files`
    return frozenset(n for n in names if n.split(".")[0] == PACKAGE)


def import_closure(modules: list[str], root: Path = PACKAGE_DIR) -> list[Path]:
    """The files of ``modules`` and of every package module they import, transitively, with the
    ``__init__.py`` of each package on the way (importing ``a.b.c`` runs ``a`` and ``a.b``)."""
    todo, seen = list(modules), set()
    files: set[Path] = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]
        if (p := _module_file(name, root)) is not None and p not in files:
            files.add(p)
            todo += sorted(_imported(p, root))
    return sorted(files)


def command_modules(root: Path = PACKAGE_DIR) -> dict[str, str]:
    """Command name -> its stage module: every ``rxcomm/stages/NAME.py`` that defines ``command`` is the
    command ``NAME`` with ``-`` for ``_`` (the convention ``rxcomm.cli.STAGES`` follows; a test checks)."""
    out = {}
    for p in sorted((root / "stages").glob("*.py")):
        if "\ndef command(" in p.read_text():
            out[p.stem.replace("_", "-")] = f"{PACKAGE}.stages.{p.stem}"
    return out


def command_hashes(root: Path = PACKAGE_DIR) -> dict[str, str]:
    """Command name -> hash of the sources it imports (``rxcomm.cli`` and its stage module, closed)."""
    return {
        cmd: sources_hash(import_closure([f"{PACKAGE}.cli", mod], root), root)
        for cmd, mod in command_modules(root).items()
    }


def main(argv: list[str]) -> int:
    if argv == ["--make"]:  # one line `command=hash ...`: make's $(shell) turns newlines into spaces
        print(" ".join(f"{c}={h}" for c, h in command_hashes().items()))
        return 0
    if not argv:
        print(code_identity())
        return 0
    print("usage: python -m rxcomm.code_identity [--make]", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
