"""Stated acceptance thresholds for a robot that comes without a customer's (`import-robot`).

Ratios to the factory state measured the same way, so nothing depends on the robot's size or class:
commissioning must halve the ISO 9283 pose accuracy and the path accuracy on the ISO line, make the
reference task no slower than the factory's, and at equal time (and at equal energy) spend no more
energy. Pose repeatability is bounded absolutely, by the assumed cell's tracker σ (50 µm): the
chain's 5 pose cycles measure a few µm on both states, and their ratio is noise (1.24 on a
hand-made arm, 5.06 → 6.29 µm). A customer's thresholds (the samples': AP_p ≤ 0.3 mm, AT_p ≤ 0.5 mm
at 1 m/s, RP_l ≤ 1.1 × the factory's) replace these.
"""

from __future__ import annotations

from rxcomm.schemas.acceptance import AcceptanceThresholds, Threshold


def default_thresholds() -> AcceptanceThresholds:
    rows = [
        Threshold(criterion="AP_p", unit="m", max_ratio=0.5),
        Threshold(criterion="AT_p", unit="m", target="iso9283-line", max_ratio=0.5),
        Threshold(criterion="RP_l", unit="m", max_commissioned=5e-5),
        Threshold(criterion="cycle_time", unit="s", max_ratio=1.0),
        Threshold(criterion="electrical_energy_at_factory_time", unit="J", max_ratio=1.0),
        Threshold(criterion="cycle_time_at_factory_energy", unit="s", max_ratio=1.0),
    ]
    return AcceptanceThresholds(kind="rxcomm/AcceptanceThresholds", schema_version=1, criteria=rows)
