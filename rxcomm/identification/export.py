"""Identification results as CSV for other tools (`identify --params-out`, `--torques-out`).

Comma-separated tables: a `#` comment line (what, from where, units), one header line, one row per
item. The parameter table is written from the dynamics.yaml artefact itself (`export_dynamics_csv`
has the `(source, out) -> out` form of an `rxcomm export` entry), so an old model exports as a new one.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rxcomm.identification.validation import Validation
from rxcomm.io.files import atomic_write_text
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.schemas.dynamics import Dynamics

# SI unit of each full parameter kind (the last part of its name; `rxcomm.model.dynamics`)
PARAMETER_UNITS = {
    "m": "kg",
    "mcx": "kg·m",
    "mcy": "kg·m",
    "mcz": "kg·m",
    **{k: "kg·m²" for k in ("Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz", "rotor_inertia")},
    "fc": "N·m",
    "fv": "N·m·s/rad",
    "offset": "N·m",
    "k": "N/m",
    "kL0": "N",
    "fc_motor": "N·m (motor side)",
    "fv_motor": "N·m·s/rad (motor side)",
}


def parameter_unit(full_name: str) -> str:
    """The SI unit of a full parameter (`joint_2.mcz` → kg·m); "" for an unknown kind."""
    return PARAMETER_UNITS.get(full_name.rsplit(".", 1)[-1], "")


def write_parameters_csv(art: Dynamics, path: str | Path, source: str = "") -> Path:
    """The base parameters of a dynamics.yaml as CSV: name, value, std (1σ, same unit; empty where
    not measured), relative_std (σ/|value|), unit (that of the full parameter it is kept as) and its
    definition (the regrouping). 17 significant digits: a float64 reads back exactly."""
    lines = [
        f"# base dynamic parameters ± 1 sigma of {art.robot}{f' ({source})' if source else ''}; "
        f"{art.summary.method or ''}; units SI, joint side unless noted"
        + (
            "; on the calibrated link frames of the YAML's kinematics_errors" if art.kinematics_errors else ""
        ),
        "name,value,std,relative_std,unit,definition",
    ]
    for b in art.base_parameters:
        rel = b.relative_std
        known = rel is not None and math.isfinite(rel)
        sigma = b.std if b.std is not None else (rel * abs(b.value) if known else None)
        std = "" if sigma is None else f"{sigma:.17g}"
        label = b.label.replace('"', "'")
        lines.append(
            f"{b.name},{b.value:.17g},{std},{f'{rel:.17g}' if known else ''},{parameter_unit(b.independent)},"
            f'"{label}"'
        )
    return atomic_write_text(path, "\n".join(lines) + "\n")


def export_dynamics_csv(source: Path, out: Path) -> Path:
    """`rxcomm export dynamics.yaml`'s library call (source, out) → out: `write_parameters_csv`."""
    return write_parameters_csv(read_yaml_artefact(source, Dynamics), out, Path(source).name)


def write_torques_csv(path: str | Path, joint_names: tuple[str, ...], val: Validation) -> Path:
    """The validation rows as CSV: time_s, then per joint the measured and predicted torque (N·m, both
    through the same low-pass) and whether the joint moved (scored) on that row."""
    path = Path(path)
    n = len(joint_names)
    header = ["time_s"]
    header += [f"tau{i + 1}_measured_nm" for i in range(n)] + [f"tau{i + 1}_predicted_nm" for i in range(n)]
    header += [f"moving{i + 1}" for i in range(n)]
    table = np.column_stack([val.t, val.measured, val.predicted, val.moving.astype(float)])
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"# {val.source}; joints {', '.join(joint_names)}\n" + ",".join(header) + "\n")
        np.savetxt(f, table, delimiter=",", fmt="%.10g")
    return path
