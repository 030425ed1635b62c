"""Identification results as CSV for other tools (`identify --params-out`, `--torques-out`).

Plain comma-separated tables with one header line after a `#` comment line that says what and from
where; numbers to 10 significant digits; NaN where nothing was measured.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rxcomm.identification.validation import Validation
from rxcomm.model.base_parameters import BaseParameterSet

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


def write_parameters_csv(
    path: str | Path, bset: BaseParameterSet, p_b: np.ndarray, std: np.ndarray, source: str
) -> Path:
    """The base parameters as CSV: name, value, std (1σ, same unit), relative_std (σ/|value|), unit
    (that of the independent parameter it is kept as) and its definition (the regrouping)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"# base dynamic parameters ± 1 sigma; {source}\n")
        f.write("name,value,std,relative_std,unit,definition\n")
        for i, name in enumerate(bset.names):
            v, s = float(p_b[i]), float(std[i])
            rel = s / abs(v) if v != 0 else float("inf")
            unit = parameter_unit(bset.full_names[int(bset.independent[i])])
            label = bset.labels[i].replace('"', "'")
            f.write(f'{name},{v:.10g},{s:.10g},{rel:.6g},{unit},"{label}"\n')
    return path


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
