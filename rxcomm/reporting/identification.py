"""The report's sections for the exciting trajectory and dynamic identification (paper §4):
cond(W), the validation figures per joint, base parameters and friction ± σ.

Pure functions over the summaries of excitation and dynamics.yaml (plain mappings).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from rxcomm.reporting.document import (
    DEFAULT_TOLERANCE,
    NOT_MEASURED,
    Figure,
    Section,
    Table,
    Tolerance,
    ratio_note,
)
from rxcomm.reporting.values import fmt, plus_minus
from rxcomm.schemas.dynamics import DynamicsSummary
from rxcomm.schemas.excitation import ExcitationSummary


def excitation_section(
    s: ExcitationSummary, image: str | None, tol: Tolerance = DEFAULT_TOLERANCE
) -> Section:
    return Section(
        "Optimal exciting trajectory (paper §4.2)",
        [
            Figure("cond(W), unit-norm columns", fmt(s.cond), "N = 5, ω_f = 0.8 rad/s, k = 80"),
            Figure("random feasible Fourier trajectory (median)", fmt(s.baseline_cond)),
            Figure("cond(W) unnormalised", fmt(s.cond_raw)),
            Figure("densely sampled max limit ratio", ratio_note(s.max_limit_ratio, *tol)),
            Figure("binding limit", fmt(s.worst_limit)),
            Figure("duration", fmt(s.duration_s, unit="s")),
            Figure("compute time", fmt(s.seconds, unit="s")),
        ],
        image,
    )


def in_band_labels(
    fraction: Sequence[float | None],
    below_noise: Sequence[bool] | None,
    rows: Sequence[int] | None = None,
) -> list[str]:
    """Per joint, the standstill in-band share as written on the console and in the report: "k of n"
    rows where the counts are known (a share of 2 rows is not one of 2000), else 3 significant
    digits; "no standstill" where the joint never stood still, "band < noise" where its static
    friction is narrower than its torque noise (nothing to score against)."""
    below = list(below_noise) if below_noise is not None else [False] * len(fraction)
    counts = list(rows) if rows is not None else [None] * len(fraction)

    def label(v: float | None, b: bool, n: int | None) -> str:
        if v is None:
            return "band < noise" if b else "no standstill"
        return f"{v:.3g}" if n is None else f"{round(v * n)} of {n}"

    return [label(v, b, n) for v, b, n in zip(fraction, below, counts, strict=True)]


def _in_band(s: DynamicsSummary) -> str:
    if s.validation_standstill_in_band_fraction is None:
        return NOT_MEASURED
    labels = in_band_labels(
        s.validation_standstill_in_band_fraction,
        s.validation_stiction_band_below_noise,
        s.validation_standstill_rows,
    )
    return "[" + ", ".join(labels) + "]"


def _per_joint(
    values: Sequence[float | None] | None,
    scale: float = 1.0,
    unit: str = "",
    none: str = "not scored",
    decimals: int | None = None,
) -> str:
    """Per-joint figures (3 significant digits, or `decimals` fixed); None (a joint that did not move
    on the validation data) is "not scored"."""
    if values is None:
        return NOT_MEASURED

    def one(v: float) -> str:
        return fmt(v, scale) if decimals is None else f"{float(v) * scale:.{decimals}f}"

    text = ", ".join(none if v is None else one(v) for v in values)
    return f"[{text}]" + (f" {unit}" if unit else "")


def _cutoff_choice(s: DynamicsSummary) -> str:
    """ " (auto: why)" for a cut-off chosen from the data; nothing for one given."""
    choice = str(s.cutoff_choice or "")
    return f" ({choice})" if choice.startswith("auto") else ""


_UNITS = {"m": "kg", "mcx": "kg·m", "mcy": "kg·m", "mcz": "kg·m", "fc": "N·m", "fv": "N·m·s/rad"}
_UNITS |= {"offset": "N·m", "rotor_inertia": "kg·m²", "kL0": "N"}


def dynamics_parameter_table(params: Sequence[Mapping]) -> Table | None:
    """The identified base parameters ± 1σ (σ = |value| · relative σ), in the independent parameter's
    SI unit; σ not available (a parameter fixed by the fit) is said so."""
    if not params:
        return None
    rows = []
    for p in params:
        kind = p["independent"].rsplit(".", 1)[-1]
        unit = "kg·m²" if kind.startswith("I") else _UNITS.get(kind, "SI")
        rel = p.get("relative_std")
        std = p.get("std")
        if std is None and rel is not None and math.isfinite(rel):
            std = abs(p["value"]) * rel  # artefacts before `std`
        if rel is None:
            rel_text = NOT_MEASURED
        else:
            rel_text = f"{rel * 100:.2g} %" if math.isfinite(rel) else "none (value 0)"
        rows.append(
            [
                p["name"],
                plus_minus(p["value"], std, 1.0).replace("(fixed)", "(σ not measured)"),
                unit,
                rel_text,
            ]
        )
    return Table("Identified base parameters ± 1σ", ["base parameter", "value", "unit", "relative σ"], rows)


def friction_table(friction: Sequence[Mapping]) -> Table | None:
    if not friction:
        return None
    rows = [
        [f["joint"], f"{f['coulomb_nm']:.4g}", f"{f['viscous_nm_s_per_rad']:.4g}", f"{f['offset_nm']:.4g}"]
        for f in friction
    ]
    return Table(
        "Identified friction per joint",
        ["joint", "Coulomb [N·m]", "viscous [N·m·s/rad]", "offset [N·m]"],
        rows,
    )


def dynamics_section(
    s: DynamicsSummary,
    image: str | None,
    parameters: Sequence[Mapping] = (),
    friction: Sequence[Mapping] = (),
) -> Section:
    tables = [t for t in (dynamics_parameter_table(parameters), friction_table(friction)) if t]
    cutoff = s.cutoff_hz
    rows = s.rows_per_parameter
    return Section(
        "Dynamic identification (paper §4.1, §4.3, Fig. 5b)",
        [
            Figure("base parameters (friction model)", f"{s.n_base_params} ({s.friction or 'joint'})"),
            *(
                [
                    Figure(
                        "fitted regrouped: the calibrated axis tilt separates them, this log could not "
                        "(their effect sits in J1's friction offset; a wider J1 swing separates them)",
                        s.kinematics_regrouped,
                    )
                ]
                if s.kinematics_regrouped
                else []
            ),
            Figure(
                "validation RMS prediction error per joint, moving rows (headline)",
                _per_joint(s.validation_rms_nm, unit="N·m"),
            ),
            Figure(
                "validation NRMSE per joint",
                _per_joint(s.validation_nrmse, 100, "%"),
                "Fig. 5b: close match",
            ),
            Figure("validation R² per joint", _per_joint(s.validation_r2, decimals=4)),
            Figure(
                "standstill rows inside the stiction band, per joint",
                _in_band(s),
            ),
            Figure(
                "fit RMS error per joint beside the cross-validated held-out RMS (contiguous folds)",
                f"{_per_joint(s.fit_rms_nm, unit='N·m')} / "
                f"{_per_joint(s.cv_rms_nm if s.cv_folds_scored else None, unit='N·m')}",
            ),
            Figure(
                "low-pass cut-off; fit rows per base parameter",
                f"{fmt(cutoff, unit='Hz')}{_cutoff_choice(s)}; {fmt(rows)}",
            ),
            Figure("compute time", fmt(s.seconds, unit="s")),
        ],
        image,
        note=f"validated on {s.validation or '?'}; a joint that did not move there is not scored.",
        tables=tables,
    )
