"""Figures are files: matplotlib on its file-only Agg backend (no display on a CI machine or over ssh),
imported on first use so that commands that draw nothing start fast."""

from __future__ import annotations

from types import ModuleType


def pyplot() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
