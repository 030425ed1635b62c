"""Figures are files: matplotlib on its file-only Agg backend (no display on a CI machine or over ssh),
imported on first use so that commands that draw nothing start fast."""

from __future__ import annotations

from types import ModuleType


def pyplot() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path, dpi: int = 110, rect: tuple[float, float, float, float] | None = None):
    """Lay the figure out (within `rect` of the canvas when a title needs room), write it cropped to
    what is drawn, and free it: a stage draws many figures in one process."""
    fig.tight_layout(rect=rect)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    pyplot().close(fig)
    return path


# A limit "binds" in a figure when its series reaches this fraction of the bound: drawn in colour and
# named in the legend; the others are drawn faded, so the eye finds what sets the timing.
BINDS = 0.9
# matplotlib's tab10 without its grey, which is the faded lines' colour; then tab20's light shades
BINDING_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22"]
BINDING_COLOURS += ["#17becf", "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5", "#c49c94", "#f7b6d2"]


def signed_ratios(ratios, raw):
    """Limit ratios |value|/limit (name → [n, cols]) given the sign of the value in `raw` (name →
    array of the same shape), so they read as value/limit within ±1; a limit without raw values keeps
    its magnitude."""
    import numpy as np

    out = {}
    for name, r in ratios.items():
        v = raw.get(name)
        out[name] = r * np.where(v < 0, -1.0, 1.0) if v is not None and np.shape(v) == np.shape(r) else r
    return out


def limit_panel(ax, t, ratios, columns, threshold: float = BINDS, what: str = "value / limit") -> list[str]:
    """Draw every limit series value/limit over `t` on `ax`: those reaching `threshold` in colour with
    their peak in the legend, the others faded; the bounds ±1 dashed; the legend outside the axes.
    `ratios`: name → [n, cols]; `columns`: the column labels (joint names), or name → labels for a
    limit with other columns (a TCP limit). Returns the labels of the binding series."""
    binding, faded = [], False
    for name, r in ratios.items():
        labels = columns.get(name, ()) if isinstance(columns, dict) else columns
        for j in range(r.shape[1]):
            col = labels[j] if j < len(labels) else str(j)
            peak = float(abs(r[:, j]).max())
            if peak >= threshold:
                label = f"{name.replace('_', ' ')} {col} (peak {peak:.3f})"
                colour = BINDING_COLOURS[len(binding) % len(BINDING_COLOURS)]
                ax.plot(t, r[:, j], lw=1.3, label=label, zorder=3, color=colour)
                binding.append(label)
            else:
                ax.plot(t, r[:, j], color="0.6", lw=0.6, alpha=0.45, zorder=1)
                faded = True
    if faded:
        ax.plot([], [], color="0.6", lw=0.6, alpha=0.6, label=f"other limits (peak < {threshold:g}), faded")
    signed = any(float(r.min()) < 0 for r in ratios.values())
    for y in (1.0, -1.0) if signed else (1.0,):
        ax.axhline(y, color="k", lw=0.7, ls="--", zorder=2)
    ax.set_ylim(-1.1 if signed else 0.0, 1.1)
    ax.set_ylabel(what)
    ax.grid(alpha=0.3)
    legend_outside(ax)
    return binding


def legend_outside(ax, **kwargs) -> None:
    """The legend to the right of the axes, never over the data (save with bbox_inches="tight")."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=7, **kwargs)


def joint_signs(t, q, qd, qdd, tau, q_centre) -> dict:
    """The joint-side values whose sign `signed_ratios` gives each limit of `rxcomm.model.limits`."""
    import numpy as np

    rate = np.gradient(tau, t, axis=0) if len(t) > 1 else np.zeros_like(tau)
    return {"position": q - q_centre, "velocity": qd, "acceleration": qdd, "torque": tau, "torque_rate": rate}
