"""The run log's resolution per ``/run/joints`` field: each value is rounded to an absolute grid of
2^-e in its unit before it is stored as float32 (docs/logs.md §2, issue 32).

float32 keeps 24 significant bits of every value whatever its size, so the low mantissa bits of a
joint angle near 0 or of a following error hold digits no encoder resolved; they are noise to the
chunk compressor, which then keeps ~80 % of the bytes. On a grid at or below what the gateway's
registers resolve (position and velocity counts of 1 µrad and 1 µrad/s, torque counts of 0.1 % of the
rated torque, ≥ 15 mN·m for a drive rated ≥ 15 N·m), those bits are zeros and zstd shrinks the joint
messages by ~30 %. A grid value is exact in float32 while |value| < 2^(24-e) (8 rad for the angles);
beyond it float32's own rounding applies, as before.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

# field -> e: the grid step is 2^-e in the field's unit (rad, rad/s, rad/s², N·m, m, m/s)
JOINT_GRID_EXPONENTS = {
    "q_demand": 21,  # 0.48 µrad: half the position count (1 µrad)
    "qd_demand": 21,  # 0.48 µrad/s: half the velocity count (1 µrad/s)
    "qdd_demand": 12,  # 0.24 mrad/s²: the plan's acceleration, on no register
    "q_actual": 21,
    "tau_actual": 10,  # 0.98 mN·m: ≤ 1/15 of a torque count (drives rated ≥ 15 N·m)
    "tau_ff": 10,
    "following_error": 21,
    "tcp_error_m": 30,  # 0.93 nm
    "tcp_speed_m_s": 24,  # 60 nm/s
}


def joint_grid_steps() -> dict[str, float]:
    """field -> grid step in its unit (the ``rxcomm/grid`` channel metadata)."""
    return {k: 2.0**-e for k, e in JOINT_GRID_EXPONENTS.items()}


def on_grid(cols: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``cols`` rounded to their fields' grids (half to even); NaN (a lost record) stays NaN."""
    out = {}
    for k, c in cols.items():
        e = JOINT_GRID_EXPONENTS.get(k)
        out[k] = c if e is None else np.round(np.asarray(c, dtype=float) * 2.0**e) * 2.0**-e
    return out
