"""Options of identification (`rxcomm identify`), read by every step of `rxcomm.identification.fit`;
the model lives with the artefact that records it (`rxcomm.schemas.dynamics`)."""

from __future__ import annotations

from rxcomm.schemas.dynamics import IdentifySettings

__all__ = ["MODEL_SETTINGS", "IdentifySettings"]

# The identified model's own processing and friction model: what scoring it on another log, or fitting
# a payload's residual through it, takes from its dynamics.yaml.
MODEL_SETTINGS = ("cutoff_hz", "decimate_hz", "min_speed_rad_s", "friction", "filter_order", "torque_lag_s")
