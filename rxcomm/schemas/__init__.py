"""Artefact contracts: one pydantic module per artefact, plus the JSON Schema generated from them.

``ARTEFACT_MODELS`` lists every model whose JSON Schema is committed here as
``<name>.schema.json`` (``rxcomm/Calibration`` -> ``calibration.schema.json``; a config model without
``KIND`` is named after its class, ``CellConfig`` -> ``cell-config.schema.json``). When you add an
artefact model, append ``"rxcomm.schemas.<module>:<Class>"`` here and run
``.venv/bin/python -m rxcomm.schemas.generate``; ``tests/test_schemas.py`` fails on drift.
"""

ARTEFACT_MODELS: list[str] = [
    "rxcomm.schemas.trajectory:TrajectorySummary",
    "rxcomm.schemas.drives:Drives",
    "rxcomm.schemas.truth:CellTruth",
    "rxcomm.schemas.dynamics:Dynamics",
    "rxcomm.schemas.cell:Cell",
    "rxcomm.schemas.configs:Configs",
    "rxcomm.schemas.measurements:Measurements",
    "rxcomm.schemas.calibration:Calibration",
    "rxcomm.schemas.kinematics:Kinematics",
    "rxcomm.schemas.run_log:RunLog",
    "rxcomm.schemas.excitation:Excitation",
    "rxcomm.schemas.path:PathSpec",
    "rxcomm.schemas.iso9283:Iso9283",
    "rxcomm.schemas.acceptance:AcceptanceThresholds",
    "rxcomm.schemas.acceptance:Acceptance",
    "rxcomm.schemas.payload:Payload",
    "rxcomm.schemas.payload:CellPayload",
]
