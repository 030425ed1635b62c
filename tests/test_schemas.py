"""The committed JSON Schemas match the pydantic models, and every registered model is a strict contract."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from pydantic import BaseModel

from rxcomm.schemas import ARTEFACT_MODELS
from rxcomm.schemas.envelope import ENVELOPE_FIELDS, Artefact
from rxcomm.schemas.generate import SCHEMA_DIR, drift, file_name, load_model, main, render
from rxcomm.schemas.strict import Strict

from .conftest import ROOT

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
        for name in ("summary", "settings"):
            prop = schema["properties"][name]
            assert "additionalProperties" not in prop, f"{ref}: {name} is an untyped mapping"


def test_kinds_and_file_names_are_unique() -> None:
    models = [load_model(ref) for ref in ARTEFACT_MODELS]
    names = [file_name(m) for m in models]
    kinds = [m.KIND for m in models if issubclass(m, Artefact)]
    assert len(set(names)) == len(names) and len(set(kinds)) == len(kinds)


def test_file_names() -> None:
    class RunLog(Artefact[Strict, Strict], kind="rxcomm/RunLog", schema_version=1):
        pass

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

        class Loose(Artefact[Strict, dict[str, float]], kind="rxcomm/Loose", schema_version=1):
            pass

    with pytest.raises(TypeError, match="Loose2.settings must be a pydantic model"):

        class Loose2(Artefact[dict[str, float], Strict], kind="rxcomm/Loose2", schema_version=1):
            pass

    with pytest.raises(TypeError, match="Bare.summary must be a pydantic model"):

        class Bare(Artefact, kind="rxcomm/Bare", schema_version=1):
            pass

    with pytest.raises(TypeError, match="Kindless must set kind="):

        class Kindless(Artefact[Strict, Strict]):
            pass


# ---- what `run` and the planners record (issue 28: no untyped settings) ---------------------------


def _record_pairs():
    """(the stage's own settings model, the model its artefact records it with)."""
    from rxcomm.execution.campaign import CampaignSettings
    from rxcomm.execution.session import RunSettings, StreamSettings
    from rxcomm.model.energy import BusPowerModel
    from rxcomm.planning.cp import CpSettings
    from rxcomm.planning.ptp_problem import PtpOptions
    from rxcomm.schemas.run_settings import MeasurementsSettings, RunLogSettings, StreamRecord
    from rxcomm.schemas.trajectory import BusPowerRecord, CpPlanSettings, PtpOptionsRecord

    return [
        (RunSettings, RunLogSettings),
        (StreamSettings, StreamRecord),
        (CampaignSettings, MeasurementsSettings),
        (CpSettings, CpPlanSettings),
        (PtpOptions, PtpOptionsRecord),
        (BusPowerModel, BusPowerRecord),
    ]


def test_recorded_settings_name_every_option_of_the_stage_models() -> None:
    """A new option of a stage must be recordable: the record model has every field of the stage's
    model, and what the stage dumps reads back field by field."""
    for stage_model, record in _record_pairs():
        missing = set(stage_model.model_fields) - set(record.model_fields)
        assert not missing, f"{record.__name__} does not record {stage_model.__name__}'s {missing}"
    from rxcomm.execution.session import RunSettings, StreamSettings
    from rxcomm.schemas.run_settings import RunLogSettings

    used = RunSettings(approach=True, stream=StreamSettings(interpolation_ratio=2, watchdog_ms=5000))
    back = RunLogSettings.model_validate(used.model_dump(mode="json") | {"model": "prior", "plant": "own"})
    assert back.approach is True and back.stream is not None and back.stream.watchdog_ms == 5000
    assert back.model == "prior" and back.realtime is None  # not recorded: None, not a default


def test_an_old_log_without_a_setting_reads_it_as_not_recorded_and_a_renamed_one_is_refused() -> None:
    from rxcomm.schemas.run_log import RunLog
    from rxcomm.schemas.trajectory import CpPlanSettings, CyclesPlanSettings, TrajectorySummary

    s = RunLog.model_fields["settings"].annotation.model_validate({"feedforward": False})
    assert s.feedforward is False and s.model is None and s.plant is None and s.stream is None
    with pytest.raises(ValueError, match="feed_forward"):
        RunLog.model_fields["settings"].annotation.model_validate({"feed_forward": False})
    summary = {"duration_s": 1.0, "solve_seconds": None, "max_limit_ratio": None, "active_fraction": None}
    summary |= {"q_start": [0.0], "q_goal": [0.0]}
    env = TrajectorySummary.envelope({}, {"k1": 1.0, "timing": "optimal"}, summary)
    plan = TrajectorySummary(
        **env, mcap_file="x.mcap", mcap_sha256="0" * 64, topic="/t", n_samples=1, fields=[]
    )
    assert isinstance(plan.settings, CpPlanSettings) and plan.settings.k2 is None
    cycles = {"cycles": 3, "plan_settings": {"start": "0,0", "options": {"n_intervals": 50}}}
    env = TrajectorySummary.envelope({}, cycles, summary)
    rep = TrajectorySummary(
        **env, mcap_file="x.mcap", mcap_sha256="0" * 64, topic="/t", n_samples=1, fields=[]
    )
    assert (
        isinstance(rep.settings, CyclesPlanSettings) and rep.settings.plan_settings.options.n_intervals == 50
    )
    with pytest.raises(ValueError, match="intervalls"):
        TrajectorySummary(
            **TrajectorySummary.envelope({}, {"intervalls": 200}, summary),
            mcap_file="x.mcap", mcap_sha256="0" * 64, topic="/t", n_samples=1, fields=[],
        )  # fmt: skip


def _kinds() -> dict[str, type[Artefact]]:
    models = [load_model(ref) for ref in ARTEFACT_MODELS]
    return {m.KIND: m for m in models if isinstance(m, type) and issubclass(m, Artefact)}


def validate_build(build: Path) -> tuple[dict[str, int], list[str]]:
    """Every artefact of a built chain read with its kind's model: the YAMLs whole, the settings in the
    MCAPs' (and .part logs') envelopes. Returns (files read per kind, the failures)."""
    import yaml
    from pydantic import TypeAdapter, ValidationError

    from rxcomm.io.mcap_io import read_mcap_envelope

    kinds, read, bad = _kinds(), {}, []
    for path in sorted(build.iterdir()):
        try:
            if path.suffix == ".yaml":
                data = yaml.safe_load(path.read_text())
                if not isinstance(data, dict) or data.get("kind") not in kinds:
                    continue
                kinds[data["kind"]].model_validate(data)
            elif path.name.endswith((".mcap", ".mcap.part")):
                data = read_mcap_envelope(path)
                cls = kinds[data["kind"]]
                # the settings; its summary may be the one written when a run log began (outcome running)
                TypeAdapter(cls.model_fields["settings"].annotation).validate_python(data["settings"])
            else:
                continue
        except (ValidationError, KeyError) as e:
            bad.append(f"{path.name}: {e}")
            continue
        read[data["kind"]] = read.get(data["kind"], 0) + 1
    return read, bad


@pytest.mark.slow  # reads a whole built chain (≈ 90 artefacts, the MCAPs' envelopes)
def test_every_artefact_of_a_built_chain_reads_with_its_model() -> None:
    """`make commission-ci` (or RXCOMM_CHECK_BUILD=DIR): the typed contents hold what the stages wrote."""
    build = Path(os.environ.get("RXCOMM_CHECK_BUILD", ROOT / "build-ci"))
    if not (build / "report.md").is_file():
        pytest.skip(f"no built chain in {build} (make commission-ci)")
    read, bad = validate_build(build)
    assert not bad, "\n".join(bad)
    for kind in ("rxcomm/RunLog", "rxcomm/Measurements", "rxcomm/Trajectory"):
        assert read.get(kind), f"{build} holds no {kind}"


def test_the_build_check_fails_on_a_renamed_setting(tmp_path: Path) -> None:
    import yaml

    from rxcomm.schemas.measurements import Measurements

    env = Measurements.envelope({}, {"feedforward": True, "model": "prior"}, {"n_poses": 0, "n_valid": 0})
    good = Measurements(**env, robot="rx130l", joint_names=[], poses=[]).model_dump(mode="json")
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(good))
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(good | {"settings": {"feed_forward": True}}))
    read, bad = validate_build(tmp_path)
    assert read == {"rxcomm/Measurements": 1} and len(bad) == 1
    assert bad[0].startswith("b.yaml") and "feed_forward" in bad[0]
