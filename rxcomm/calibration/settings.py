"""`calibrate`'s settings (recorded in the Calibration artefact; the model lives with it in
`rxcomm.schemas.calibration`)."""

from __future__ import annotations

from rxcomm.schemas.calibration import CalibrateSettings

__all__ = ["CalibrateSettings"]
