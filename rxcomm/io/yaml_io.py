"""YAML artefacts and config files: human-readable writing, strict reading.

Reading maps every failure to ``InputError(reason, file=, field=)``: missing file, YAML syntax error
(with line and column), duplicate key, unknown ``kind``, unsupported ``schema_version``, unknown keys,
wrong types. Writing is atomic (``NAME.part`` then rename).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel

from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_text, mcap_summary_path
from rxcomm.io.validate import check_kind, validate_model
from rxcomm.schemas.envelope import Artefact, McapSummary
from rxcomm.schemas.plain import sha256_file, to_plain

A = TypeVar("A", bound=Artefact)
S = TypeVar("S", bound=McapSummary)
M = TypeVar("M", bound=BaseModel)


class _Dumper(yaml.SafeDumper):
    """Block mappings; lists of scalars in flow style (``q_start: [0.1, 0.2, ...]``) to stay readable."""


def _repr_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = bool(data) and all(isinstance(v, int | float | str | bool) or v is None for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _repr_list)


class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (PyYAML silently keeps the last one)."""


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict[Any, Any]:
    loader.flatten_mapping(node)
    out: dict[Any, Any] = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in out:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
        out[key] = loader.construct_object(value_node, deep=True)
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def dump_yaml(data: Any) -> str:
    """YAML text of plain data (numpy converted), keys in the given order, block style."""
    return yaml.dump(
        to_plain(data),
        Dumper=_Dumper,
        sort_keys=False,
        allow_unicode=True,
        width=100,
        default_flow_style=False,
    )


def load_yaml(path: str | Path) -> Any:
    """Parse a YAML file; missing file, unreadable file and syntax errors become InputError."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as e:
        raise InputError("file not found", file=path) from e
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read: {e}", file=path) from e
    try:
        return yaml.load(text, Loader=_Loader)  # _Loader derives from SafeLoader
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise InputError(f"YAML syntax error{where}: {e.problem or e.context}", file=path) from e
    except yaml.YAMLError as e:
        raise InputError(f"YAML error: {e}", file=path) from e


def write_yaml_artefact(path: str | Path, artefact: BaseModel) -> Path:
    """Write a model (an Artefact or a config model) as YAML, fields in model order, atomically."""
    return atomic_write_text(path, dump_yaml(artefact.model_dump(mode="json")))


def read_yaml_model(path: str | Path, cls: type[M]) -> M:
    """Read a non-enveloped YAML config (cell.yaml, drives.yaml, a path) into ``cls``."""
    data = load_yaml(path)
    if not isinstance(data, dict):
        raise InputError(f"expected a mapping at top level, got {type(data).__name__}", file=path)
    return validate_model(cls, data, file=path)


def read_yaml_artefact(path: str | Path, cls: type[A]) -> A:
    """Read an enveloped YAML artefact, refusing another kind or schema_version first."""
    data = load_yaml(path)
    check_kind(data, cls, file=path)
    return validate_model(cls, data, file=path)


def summary_yaml_path(mcap_path: str | Path) -> Path:
    """``cp.mcap`` -> ``cp.yaml``: the summary YAML written beside a trajectory or log MCAP."""
    mcap_path = Path(mcap_path)
    if mcap_path.suffix != ".mcap":
        raise InputError("an MCAP output must end in .mcap (its summary goes to NAME.yaml)", file=mcap_path)
    return mcap_summary_path(mcap_path)


def write_summary_yaml(mcap_path: str | Path, artefact: Artefact) -> Path:
    """Write ``artefact`` (envelope + summary + its data) as ``NAME.yaml`` beside ``NAME.mcap``."""
    return write_yaml_artefact(summary_yaml_path(mcap_path), artefact)


def mcap_summary(
    cls: type[S], data: Mapping[str, Any], mcap_path: str | Path, part: str | Path | None = None
) -> S:
    """``data`` as ``cls``, the summary of the MCAP at ``mcap_path``: its file name and the sha256 of
    ``part``, the MCAP's finished bytes (None: not written yet, a placeholder hash, to refuse bad data
    before anything is written)."""
    sha = "0" * 64 if part is None else sha256_file(part)
    return cls.model_validate({**data, "mcap_file": Path(mcap_path).name, "mcap_sha256": sha})


def write_mcap_summary(cls: type[S], data: Mapping[str, Any], mcap_path: str | Path, part: str | Path) -> S:
    """Write ``NAME.yaml`` beside ``NAME.mcap`` from its finished ``.part`` (``McapWriter.finish``'s
    ``before_rename`` step, so a visible ``NAME.mcap`` always has its YAML); returns the summary."""
    summary = mcap_summary(cls, data, mcap_path, part)
    write_summary_yaml(mcap_path, summary)
    return summary


def check_mcap_summary(mcap_path: str | Path) -> None:
    """The summary ``NAME.yaml`` beside ``NAME.mcap`` must name this MCAP's sha256: a replaced MCAP
    (or summary) is refused (InputError, exit 2) instead of read as the artefact the summary
    describes. Nothing to check without a summary (a stopped run's ``.part``, a recovered log)."""
    mcap_path = Path(mcap_path)
    summary = mcap_summary_path(mcap_path)
    if mcap_path.suffix != ".mcap" or not summary.is_file():
        return
    doc = load_yaml(summary)
    want = doc.get("mcap_sha256") if isinstance(doc, dict) else None
    if not isinstance(want, str) or doc.get("mcap_file") != mcap_path.name:
        return
    got = sha256_file(mcap_path)
    if got != want:
        raise InputError(
            f"its summary {summary.name} was written for an MCAP with sha256 {want[:12]}…, this one has "
            f"{got[:12]}…: the MCAP or its summary was replaced; re-run the stage that wrote them",
            file=mcap_path,
            field="mcap_sha256",
        )
