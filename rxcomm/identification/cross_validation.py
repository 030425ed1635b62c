"""Blocked cross-validation of an identification and the cut-off chosen by it (`identification.fit`).

**Folds in time.** Neighbouring rows are correlated (the low-pass spreads each sample over ~1/cutoff,
the excitation is periodic), so a random k-fold split would score a fit on rows it has all but seen.
The processed log is cut into `folds` contiguous blocks of equal duration; each block is predicted by
the base parameters fitted (same method, `estimation.estimate`) on the other blocks, less a gap of
`gap_s` (default 2/cutoff, the filter's reach) on each side of the held-out block. The held-out rows
scored are the ones the fit itself would use (moving, outside the stick guard), so the held-out
error beside the in-sample error of the fit on all rows (`fit_rms_nm`, same rows) says how much of
the fit is noise fitted: ≈ 1 means the model generalises within the log. A fold whose complement
does not excite every base parameter (where `estimate` would refuse the rows) is not scored.

**Cut-off from the data** (`choose_cutoff`, `--cutoff-hz auto`). Each cut-off of the grid processes
the log (decimation 2 × cutoff unless `decimate_hz` is set) and is cross-validated as above, but
every candidate is scored against the same targets: the held-out rows processed at the grid's
highest cut-off (its measured torque and states), on the time span all candidates keep after
trimming. Scoring each candidate on
its own filtered torque would favour the lowest cut-off (a smoother target is easier to hit). A
cut-off too low biases the parameters (friction jumps and fast inertial terms smeared, fewer rows);
too high lets noise into q̈ and the rows (errors in variables). The grid value with the least mean
held-out NRMSE over the joints wins; the record keeps every candidate's figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rxcomm.errors import InputError
from rxcomm.identification.estimation import JointGrams, estimate_from_grams
from rxcomm.identification.logs import JointLog
from rxcomm.identification.processing import Processed, preprocess, regressor
from rxcomm.identification.settings import IdentifySettings
from rxcomm.identification.validation import joint_scores, nan_list
from rxcomm.model.base_parameters import BaseParameterSet
from rxcomm.model.robot import Robot


@dataclass(frozen=True, eq=False)
class CrossValidation:
    """Held-out figures of a blocked k-fold cross-validation (module docstring), per joint: `rms_nm`,
    `nrmse`, `r2` pooled over the scored folds' rows (NaN: not scored), `fit_rms_nm` the in-sample
    RMS of the fit on all rows over the same row selection; `folds_scored` of `folds`."""

    folds: int
    folds_scored: int
    rms_nm: np.ndarray
    nrmse: np.ndarray
    r2: np.ndarray
    fit_rms_nm: np.ndarray
    gap_s: float
    n_rows: int

    @property
    def mean_nrmse(self) -> float:
        """Mean held-out NRMSE over the scored joints (NaN when none is)."""
        ok = np.isfinite(self.nrmse)
        return float(np.mean(self.nrmse[ok])) if ok.any() else math.nan

    def summary(self) -> dict[str, object]:
        return {
            "cv_folds": self.folds,
            "cv_folds_scored": self.folds_scored,
            "cv_rms_nm": nan_list(self.rms_nm),
            "cv_nrmse": nan_list(self.nrmse),
            "cv_r2": nan_list(self.r2),
            "cv_fit_rms_nm": nan_list(self.fit_rms_nm),
            "cv_gap_s": self.gap_s,
            "cv_scored_on": "contiguous time folds, each predicted by a fit on the others (gap on each "
            "side); the fit's rows (moving, outside the stick guard); fit = in-sample on the same rows",
        }


def fold_of(t: np.ndarray, folds: int, t0: float, t1: float) -> np.ndarray:
    """Fold number [M] of each time: `folds` equal contiguous blocks of [t0, t1] (−1 outside)."""
    k = np.floor((t - t0) / (t1 - t0) * folds).astype(int)
    k = np.where(t >= t1, folds - 1, k)
    return np.where((t < t0) | (t > t1), -1, k)


def cross_validate(
    robot: Robot,
    bset: BaseParameterSet,
    data: Processed,
    settings: IdentifySettings,
    *,
    w: np.ndarray | None = None,
    test: Processed | None = None,
    w_test: np.ndarray | None = None,
    span: tuple[float, float] | None = None,
) -> CrossValidation:
    """Blocked k-fold cross-validation of the identification of `data` (module docstring).

    `w`: the base regressor of `data` if computed already. `test` (with `w_test`): score the held-out
    folds on these rows instead of `data`'s own (the same log processed otherwise: `choose_cutoff`),
    folds cut on `span` (default: `test`'s time span). The rows are passed once: their Gram matrices
    per time segment (fold cores and the gaps beside each fold edge) and joint are summed per fold
    (`estimation.estimate_from_grams`, the same estimate as `estimate` on those rows)."""
    n, k = robot.n, settings.folds
    test = data if test is None else test
    if w is None:
        w = bset.base_regressor(regressor(robot, data))
    if w_test is None:
        w_test = w if test is data else bset.base_regressor(regressor(robot, test))
    t0, t1 = span if span is not None else (float(test.t[0]), float(test.t[-1]))
    gap = 2.0 / settings.cutoff
    scored = ~test.near_stick  # [M', n]: the rows the fit would use
    in_span = (test.t >= t0) & (test.t <= t1)
    pred = np.full(test.tau.shape, np.nan)
    folds_scored = 0
    edges = t0 + (t1 - t0) * np.arange(max(k, 1) + 1) / max(k, 1)
    # time segments between the fold edges and the edges ± gap: each fold's training set is a union
    breaks = np.unique(np.concatenate([edges, edges - gap, edges + gap]))
    seg = np.searchsorted(breaks, data.t, side="right")  # segment s spans [breaks[s-1], breaks[s])
    keep = ~data.near_stick.ravel()
    joint = np.tile(np.arange(n), len(data.t))
    seg_rows = np.repeat(seg, n)
    y = data.tau.ravel()
    grams = [
        JointGrams.of_rows(w[m], y[m], joint[m], n)
        for m in (keep & (seg_rows == s_) for s_ in range(len(breaks) + 1))
    ]
    lo_b = np.concatenate([[-np.inf], breaks])  # segment s's bounds
    hi_b = np.concatenate([breaks, [np.inf]])
    if k >= 2:
        fold_test = fold_of(test.t, k, t0, t1)
        for f in range(k):
            lo, hi = edges[f] - gap, edges[f + 1] + gap
            out = (lo_b >= lo - 1e-12) & (hi_b <= hi + 1e-12)  # segments inside the held-out block + gaps
            p_b = estimate_from_grams(
                JointGrams.total([g for g, o in zip(grams, out, strict=True) if not o]), settings
            )
            if p_b is None:  # the other folds do not excite every base parameter: not scored
                continue
            held = fold_test == f
            pred[held] = (w_test[np.repeat(held, n)] @ p_b).reshape(-1, n)
            folds_scored += 1
    rows = scored & in_span[:, None] & np.isfinite(pred)
    rms, nrmse, r2 = joint_scores(test.tau, np.nan_to_num(pred), rows)
    # The fit on all rows, scored in-sample on the same selection (test is data unless choosing)
    fit_rms = np.full(n, np.nan)
    p_all = estimate_from_grams(JointGrams.total(grams), settings) if test is data and folds_scored else None
    if p_all is not None:
        fit_rms = joint_scores(data.tau, (w @ p_all).reshape(-1, n), scored & in_span[:, None])[0]
    return CrossValidation(
        folds=k,
        folds_scored=folds_scored,
        rms_nm=rms,
        nrmse=nrmse,
        r2=r2,
        fit_rms_nm=fit_rms,
        gap_s=gap,
        n_rows=int(rows.sum()),
    )


@dataclass(frozen=True, eq=False)
class CutoffChoice:
    """`choose_cutoff`'s result: the cut-off chosen, the grid, each candidate's mean held-out NRMSE
    (NaN: no fold scored), the reference cut-off of the common targets, and the chosen processing."""

    cutoff_hz: float
    grid_hz: tuple[float, ...]
    mean_nrmse: tuple[float, ...]
    reference_hz: float
    data: Processed

    @property
    def reason(self) -> str:
        figs = ", ".join(
            f"{fc:g} Hz: {'not scored' if not math.isfinite(v) else f'{100 * v:.3g} %'}"
            for fc, v in zip(self.grid_hz, self.mean_nrmse, strict=True)
        )
        return (
            f"auto: least mean cross-validated held-out NRMSE over the joints ({figs}; targets processed "
            f"at {self.reference_hz:g} Hz)"
        )

    def summary(self) -> dict[str, object]:
        return {
            "cutoff_choice": self.reason,
            "cutoff_grid_hz": list(self.grid_hz),
            "cutoff_grid_cv_nrmse": nan_list(np.array(self.mean_nrmse)),
        }


def choose_cutoff(
    robot: Robot, bset: BaseParameterSet, log: JointLog, settings: IdentifySettings
) -> CutoffChoice:
    """The grid cut-off (`settings.cutoff_grid_hz`, those below 0.4 × the log's rate) whose fit
    predicts held-out rows best, all scored against the same targets (module docstring). `log` is
    checked already (`logs.check_log`)."""
    fs = 1.0 / float(np.median(np.diff(log.t)))
    grid = tuple(sorted(fc for fc in set(settings.cutoff_grid_hz) if fc < 0.4 * fs))
    if len(grid) < 2:
        raise InputError(
            f"cutoff_hz auto: fewer than two grid cut-offs {settings.cutoff_grid_hz} Hz lie below 0.4 × the "
            f"log's {fs:.0f} Hz",
            file=log.source or None,
            field="cutoff_grid_hz",
        )
    folds = max(settings.folds, 2)
    candidates = [settings.with_cutoff(fc).model_copy(update={"folds": folds}) for fc in grid]
    processed = [preprocess(log, s, robot) for s in candidates]
    test, ref = processed[-1], candidates[-1]
    w_test = bset.base_regressor(regressor(robot, test))
    span = (max(d.t[0] for d in processed), min(d.t[-1] for d in processed))
    scores = []
    for s, d in zip(candidates, processed, strict=True):
        w = w_test if d is test else None
        cv = cross_validate(robot, bset, d, s, w=w, test=test, w_test=w_test, span=span)
        scores.append(cv.mean_nrmse)
    finite = [i for i, v in enumerate(scores) if math.isfinite(v)]
    if not finite:
        raise InputError(
            "cutoff_hz auto: no cut-off of the grid could be cross-validated (every fold's complement "
            "leaves base parameters unexcited); give --cutoff-hz",
            file=log.source or None,
            field="cutoff_hz",
        )
    best = min(finite, key=lambda i: scores[i])
    return CutoffChoice(grid[best], grid, tuple(scores), ref.cutoff, processed[best])
