"""The committed JSON Schemas match the pydantic models, and every registered model is a strict contract."""

from __future__ import annotations

import json

import pytest
from pydantic import BaseModel

from rxcomm.schemas import ARTEFACT_MODELS
from rxcomm.schemas.envelope import ENVELOPE_FIELDS, Artefact
from rxcomm.schemas.generate import SCHEMA_DIR, drift, file_name, load_model, main, render
from rxcomm.schemas.strict import Strict

REGEN = ".venv/bin/python -m rxcomm.schemas.generate"


def test_committed_json_schemas_match_models() -> None:
    bad = drift()
    assert not bad, f"JSON Schema files drifted from the models: {bad}; regenerate with `{REGEN}` and commit"


@pytest.mark.parametrize("ref", ARTEFACT_MODELS)
def test_registered_model_is_strict_and_pinned(ref: str) -> None:
    cls = load_model(ref)
    assert cls.model_config.get("extra") == "forbid", f"{ref}: needs ConfigDict(extra='forbid')"
    schema = json.loads((SCHEMA_DIR / file_name(cls)).read_text())
    assert schema["additionalProperties"] is False
    if issubclass(cls, Artefact):
        assert cls.KIND.startswith("rxcomm/") and cls.SCHEMA_VERSION >= 1
        assert schema["properties"]["kind"]["const"] == cls.KIND
        assert schema["properties"]["schema_version"]["const"] == cls.SCHEMA_VERSION
        # code_identity is optional: artefacts written before it still read
        assert set(ENVELOPE_FIELDS) - {"code_identity"} <= set(schema["required"])
        assert set(ENVELOPE_FIELDS) <= set(schema["properties"])
        # summary and settings are models of their own (issue 28): a $ref, never an open mapping
        typed = ("summary",) if cls.SETTINGS_UNTYPED else ("summary", "settings")
        for name in typed:
            prop = schema["properties"][name]
            assert "additionalProperties" not in prop, f"{ref}: {name} is an untyped mapping"


def test_kinds_and_file_names_are_unique() -> None:
    models = [load_model(ref) for ref in ARTEFACT_MODELS]
    names = [file_name(m) for m in models]
    kinds = [m.KIND for m in models if issubclass(m, Artefact)]
    assert len(set(names)) == len(names) and len(set(kinds)) == len(kinds)


def test_file_names() -> None:
    class RunLog(Artefact):
        KIND = "rxcomm/RunLog"
        SCHEMA_VERSION = 1
        settings: Strict
        summary: Strict

    class CellConfig(BaseModel):
        pass

    assert file_name(RunLog) == "run-log.schema.json"
    assert file_name(CellConfig) == "cell-config.schema.json"


def test_check_mode_reports_drift(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--dir", str(tmp_path)]) == 0  # generate into an empty directory
    assert main(["--check", "--dir", str(tmp_path)]) == 0
    first = next(iter(sorted(tmp_path.glob("*.schema.json"))))
    first.write_text(first.read_text().replace('"type"', '"typ"', 1))
    (tmp_path / "stale.schema.json").write_text("{}\n")
    capsys.readouterr()
    assert main(["--check", "--dir", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert first.name in err and "stale.schema.json" in err and "python -m rxcomm.schemas.generate" in err
    assert render(load_model(ARTEFACT_MODELS[0])) == render(load_model(ARTEFACT_MODELS[0]))


def test_a_kind_with_an_untyped_summary_or_settings_is_refused() -> None:
    """Issue 28: every kind narrows summary and settings to models; a dict fails when it is defined."""
    with pytest.raises(TypeError, match="Loose.summary must be a pydantic model"):

        class Loose(Artefact):
            KIND = "rxcomm/Loose"
            SCHEMA_VERSION = 1
            settings: Strict

    with pytest.raises(TypeError, match="Loose2.settings must be a pydantic model"):

        class Loose2(Artefact):
            KIND = "rxcomm/Loose2"
            SCHEMA_VERSION = 1
            summary: Strict
