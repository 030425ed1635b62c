"""Write (or ``--check``) the JSON Schema files of the models in ``rxcomm.schemas.ARTEFACT_MODELS``.

python -m rxcomm.schemas.generate            # rewrite rxcomm/schemas/*.schema.json
python -m rxcomm.schemas.generate --check    # exit 1 and list drifted files
"""

from __future__ import annotations

import argparse
import importlib
import json
import re
import sys
from pathlib import Path

from pydantic import BaseModel

from rxcomm.schemas import ARTEFACT_MODELS

SCHEMA_DIR = Path(__file__).resolve().parent
SUFFIX = ".schema.json"
DIALECT = "https://json-schema.org/draft/2020-12/schema"


def load_model(ref: str) -> type[BaseModel]:
    """``"module:Class"`` -> the class."""
    module, _, name = ref.partition(":")
    cls = getattr(importlib.import_module(module), name)
    if not (isinstance(cls, type) and issubclass(cls, BaseModel)):
        raise TypeError(f"{ref} is not a pydantic model")
    return cls


def file_name(cls: type[BaseModel]) -> str:
    """``rxcomm/RunLog`` (or class ``RunLog`` without KIND) -> ``run-log.schema.json``."""
    kind = getattr(cls, "KIND", None)
    base = kind.rsplit("/", 1)[-1] if isinstance(kind, str) else cls.__name__
    return re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "-", base).lower() + SUFFIX


def render(cls: type[BaseModel]) -> str:
    """Stable JSON text of the model's validation schema (sorted keys, 2-space indent, final newline)."""
    schema = {"$schema": DIALECT, **cls.model_json_schema()}
    return json.dumps(schema, indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def expected_files() -> dict[str, str]:
    """File name -> content for every registered model; refuses two models mapping to one file."""
    out: dict[str, str] = {}
    for ref in ARTEFACT_MODELS:
        cls = load_model(ref)
        name = file_name(cls)
        if name in out:
            raise ValueError(f"two registered models map to {name}")
        out[name] = render(cls)
    return out


def drift(directory: Path = SCHEMA_DIR) -> list[str]:
    """Files that differ from the models: missing, changed, or stale (no model any more)."""
    expected = expected_files()
    found = {p.name for p in directory.glob("*" + SUFFIX)}
    bad = [
        n
        for n, text in expected.items()
        if not (directory / n).is_file() or (directory / n).read_text() != text
    ]
    return sorted(bad + [n for n in found - expected.keys()])


def write(directory: Path = SCHEMA_DIR) -> list[str]:
    """Rewrite changed files and delete stale ones; returns the names touched."""
    expected = expected_files()
    touched = drift(directory)
    for name in touched:
        path = directory / name
        if name in expected:
            path.write_text(expected[name])
        else:
            path.unlink()
    return touched


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m rxcomm.schemas.generate", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--check", action="store_true", help="only check; exit 1 if any file drifted")
    parser.add_argument(
        "--dir", type=Path, default=SCHEMA_DIR, help="schema directory (default: rxcomm/schemas/)"
    )
    args = parser.parse_args(argv)
    if args.check:
        bad = drift(args.dir)
        for name in bad:
            print(f"drifted: {args.dir / name}", file=sys.stderr)
        if bad:
            print("regenerate with: .venv/bin/python -m rxcomm.schemas.generate", file=sys.stderr)
        return 1 if bad else 0
    for name in write(args.dir):
        print(f"wrote {args.dir / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
