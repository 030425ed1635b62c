"""The naive reference pose sets the selection is judged against (paper §3.3).

The naive baseline is the paper's "linear scan of the workspace" (`linear_scan`):
from one centre configuration each joint is swept alone along its grid line, as many poses as
the selection, spread evenly over the sweeps; the centre is the candidate with the widest
feasible sweeps, so it is the best such scan. Beside it, as many evenly spaced candidates in
grid order (`evenly_spaced`): not a naive set at all, since a stride through a uniform random
subset of the grid is as diverse as a random draw. RX130L at the defaults, expected rms position
error after calibration: selected 0.039 mm, evenly spaced candidates 0.042 mm (within the
spread of one campaign), linear scan 0.16 mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rxcomm.calibration.workspace import CandidateSet
from rxcomm.errors import InputError


def evenly_spaced(n_candidates: int, n: int) -> np.ndarray:
    """Indices of n evenly spaced candidates in grid order (the reference set "evenly spaced
    candidates": as diverse as a random draw of the candidates)."""
    return np.unique(np.round(np.linspace(0, n_candidates - 1, n)).astype(int))


@dataclass(frozen=True)
class LinearScan:
    """The paper's naive baseline: one joint moved at a time through its grid values."""

    q: np.ndarray  # [m, dof]: the centre, then the sweep of joint 1, joint 2, …
    centre: np.ndarray  # [dof]
    per_joint: tuple[int, ...]  # poses of each joint's sweep besides the centre


def linear_scan(candidates: CandidateSet, n: int, centres: np.ndarray | None = None) -> LinearScan:
    """A linear scan of the joint grid (the paper's baseline for its ×18.5): from one centre
    configuration each joint is swept alone over the grid values that passed the cell checks, and
    n poses (the centre once) are spread evenly along the six sweeps.

    The centre is the candidate (of `centres`, indices into the candidates; default all) whose six
    grid lines keep the most poses feasible: the widest sweeps the cell allows (most of the
    shortest sweep, then most in all), so the baseline is the best linear scan there is, not a
    strawman. Feasibility is read from the streamed grid's mask, not checked again. Shares are
    equal per joint, capped by a sweep's feasible count; fewer than n poses only when all six
    sweeps together have fewer.
    """
    cand = candidates
    pool = cand.grid_index if centres is None else cand.grid_index[np.asarray(centres, dtype=int)]
    if pool.size == 0 or n < 1:
        raise InputError("a linear scan needs at least one centre and one pose", field="n")
    shape = tuple(a.size for a in cand.axes)
    dof, width = len(shape), max(shape)
    sub = np.array(np.unravel_index(pool, shape))  # [dof, C]: each centre's grid indices
    # sweep[c, j, k]: centre c with joint j at its k-th grid value is feasible and not the centre.
    sweep = np.zeros((pool.size, dof, width), dtype=bool)
    for j, size in enumerate(shape):
        line = np.repeat(sub[:, :, None], size, axis=2)
        line[j] = np.arange(size)
        ok = cand.feasible[np.ravel_multi_index(tuple(line), shape)]
        ok[np.arange(pool.size), sub[j]] = False
        sweep[:, j, :size] = ok
    count = sweep.sum(axis=2)
    c = int(np.argmax(count.min(axis=1) * (dof * width + 1) + count.sum(axis=1)))
    share = np.zeros(dof, dtype=int)
    for _ in range(n - 1):  # one pose at a time to the joint with the smallest share that has room
        room = np.flatnonzero(share < count[c])
        if room.size == 0:
            break
        share[room[np.argmin(share[room])]] += 1
    centre = np.array([cand.axes[j][sub[j, c]] for j in range(dof)])
    qs = [centre]
    for j in range(dof):
        along = np.flatnonzero(sweep[c, j])
        for k in along[evenly_spaced(along.size, share[j])] if share[j] else []:
            q = centre.copy()
            q[j] = cand.axes[j][k]
            qs.append(q)
    return LinearScan(q=np.array(qs), centre=centre, per_joint=tuple(int(v) for v in share))
