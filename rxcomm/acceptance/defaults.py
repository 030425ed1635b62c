"""Stated acceptance thresholds for a robot that comes without a customer's (`import-robot`).

Every row is a ratio to the factory state measured the same way, so nothing here depends on the
robot's size or class: commissioning must halve the ISO 9283 pose accuracy and the path accuracy on
the ISO line, not worsen pose repeatability by more than 10 %, make the reference task no slower than
the factory's, and at equal time (and at equal energy) spend no more energy. A customer's absolute
thresholds (the samples': AP_p ≤ 0.3 mm, AT_p ≤ 0.5 mm at 1 m/s) replace these.
"""

from __future__ import annotations

from rxcomm.schemas.acceptance import AcceptanceThresholds, Threshold


def default_thresholds() -> AcceptanceThresholds:
    rows = [
        Threshold(criterion="AP_p", unit="m", max_ratio=0.5),
        Threshold(criterion="AT_p", unit="m", target="iso9283-line", max_ratio=0.5),
        Threshold(criterion="RP_l", unit="m", max_ratio=1.1),
        Threshold(criterion="cycle_time", unit="s", max_ratio=1.0),
        Threshold(criterion="electrical_energy_at_factory_time", unit="J", max_ratio=1.0),
        Threshold(criterion="cycle_time_at_factory_energy", unit="s", max_ratio=1.0),
    ]
    return AcceptanceThresholds(kind="rxcomm/AcceptanceThresholds", schema_version=1, criteria=rows)
