"""Candidate error models (base + tool frames; + joint offsets; the full identifiable set; + joint
compliance), each fitted with the priors of `priors` and scored by k-fold cross-validation over the
fit poses. With `model: auto` the estimate is the full geometric model, regularised: the priors, not a
choice between candidates, decide how far the data move it from the frames-only answer, so the
estimate does not flip between models when the noise estimate moves. Joint compliance is added when
the cross-validation prefers it by more than one standard error (a structural term, not a
manufacturing tolerance: it has to earn its place). The cross-validated figures
are a report of each candidate (the chosen one's among them), not a switch; `choose` (the one
standard-error rule) is kept for unregularised fits (`regularise: false`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from rxcomm.calibration.compliance import compliant_joints
from rxcomm.calibration.lm import FitResult, Fitter
from rxcomm.calibration.measurements import MeasurementSet
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.model.geometric_errors import (
    IdentifiableSet,
    identification_jacobians,
    joint_offset_names,
    measurement_scaling,
    parameter_names,
)
from rxcomm.model.robot import Robot


@dataclass(frozen=True)
class Candidate:
    """One error model of the model selection and its k-fold cross-validation over the fit poses.

    `cv_misfit`: mean over poses of ‖r‖² (weighted residual) when the pose was held out; `cv_se` its
    standard error relative to the best candidate (paired); None when the folds cannot identify it."""

    name: str
    idx: tuple[int, ...]
    comp: tuple[int, ...]
    fit: FitResult | None
    cv_misfit: float | None
    cv_se: float | None
    cv_rms_position_m: float | None
    cv_rms_orientation_rad: float | None
    note: str | None = None

    @property
    def n_parameters(self) -> int:
        return len(self.idx) + len(self.comp)


def independent(robot: Robot, ms: MeasurementSet, ordered: list[int], point: np.ndarray | None) -> np.ndarray:
    """The parameters of `ordered` (preference order) that `ms` identifies: greedy Gram–Schmidt on the
    scaled Jacobian columns, keeping a column with more than 1e-6 of its norm outside the kept ones."""
    po = ms.position_only
    jac = identification_jacobians(robot, ms.q, None, None, po, point)
    row_w, col_s = measurement_scaling(robot, po)
    a = (jac * row_w[None, :, None]).reshape(-1, len(parameter_names(robot))) * col_s
    norms = np.linalg.norm(a, axis=0)
    basis = np.zeros((a.shape[0], 0))
    keep = []
    for i in ordered:
        if norms[i] <= 1e-9 * norms.max():
            continue
        c = a[:, i] / norms[i]
        for _ in range(2):
            c = c - basis @ (basis.T @ c)
        if np.linalg.norm(c) > 1e-6:
            keep.append(i)
            basis = np.column_stack([basis, c / np.linalg.norm(c)])
    return np.array(sorted(keep), dtype=int)


def frames_only_indices(robot: Robot, ms: MeasurementSet, point: np.ndarray | None) -> np.ndarray:
    names = parameter_names(robot)
    return independent(robot, ms, [i for i, n in enumerate(names) if n.startswith(("base.", "tool."))], point)


def candidate_models(
    robot: Robot, ms_fit: MeasurementSet, ident: IdentifiableSet, tau: np.ndarray, point, want
):
    """(name, geometric indices, compliant joints) from the simplest to the richest model."""
    names = parameter_names(robot)
    frames = frames_only_indices(robot, ms_fit, point)
    offsets = [names.index(n) for n in joint_offset_names(robot)]
    with_offsets = independent(robot, ms_fit, [*frames, *[i for i in offsets if i in ident.indices]], point)
    full = np.array(ident.indices)
    out = [("frames", frames, ()), ("offsets", with_offsets, ()), ("full", full, ())]
    comp = compliant_joints(tau) if want else ()
    if comp:
        out.append(("full+compliance", full, comp))
    return out


def choose(cands: list[Candidate]) -> Candidate:
    """The simplest candidate whose cross-validated misfit is within one paired standard error of
    the best's (the one-standard-error rule: a richer model must earn its parameters)."""
    scored = [c for c in cands if c.cv_misfit is not None]
    best = min(scored, key=lambda c: c.cv_misfit)
    for c in sorted(scored, key=lambda c: c.n_parameters):
        if c.cv_misfit - best.cv_misfit <= (c.cv_se or 0.0):
            return c
    return best


def score_candidates(
    specs: list[tuple[str, np.ndarray, tuple[int, ...]]],
    fitter_for: Callable[[np.ndarray, tuple[int, ...]], Fitter],
    poses: np.ndarray,
    folds: np.ndarray,
    only: str,
) -> list[Candidate]:
    """Each candidate (name, geometric indices, compliant joints) fitted to all `poses` and scored by
    the k-fold cross-validation `folds`; `only` ≠ "auto": that model and the frames-only fit alone.
    A candidate that cannot be fitted or cross-validated is kept with its reason (`note`)."""
    cands: list[Candidate] = []
    per_pose: dict[str, np.ndarray] = {}
    for name, idx, comp in specs:
        if only != "auto" and name not in (only, "frames"):
            continue
        f = fitter_for(idx, comp)
        idx_t = tuple(int(i) for i in idx)
        try:
            whole = f.fit(poses)
        except (InputError, InfeasibleError) as e:
            cands.append(Candidate(name, idx_t, comp, None, None, None, None, None, note=str(e)))
            continue
        try:
            mis, e_p, e_o = f.cross_validate(poses, whole, folds)
        except (InputError, InfeasibleError) as e:
            note = f"not cross-validated: {e}"
            cands.append(Candidate(name, idx_t, comp, whole, None, None, None, None, note=note))
            continue
        per_pose[name] = mis
        rms_o = None if np.all(np.isnan(e_o)) else float(np.sqrt(np.mean(e_o)))
        cands.append(
            Candidate(
                name, idx_t, comp, whole, float(np.mean(mis)), None, float(np.sqrt(np.mean(e_p))), rms_o
            )
        )
    if not per_pose:
        return cands
    best = min((c for c in cands if c.cv_misfit is not None), key=lambda c: c.cv_misfit)
    n = math.sqrt(poses.size)
    return [
        c
        if c.cv_misfit is None
        else replace(c, cv_se=float(np.std(per_pose[c.name] - per_pose[best.name], ddof=1) / n))
        for c in cands
    ]


def chosen_model(
    cands: list[Candidate], model: str, n_poses: int, regularised: bool = True
) -> tuple[Candidate, str | None]:
    """(the given model; else, regularised, the richest candidate that could be fitted; else the
    one-standard-error choice, else — too few poses to cross-validate, nothing scored — the full
    rigid model; a note saying so or None)."""
    if model != "auto":
        return next(c for c in cands if c.name == model), None
    if regularised:
        rigid = [c for c in cands if c.name in ("full", "full+compliance") and c.fit is not None]
        if len(rigid) == 2 and all(c.cv_misfit is not None for c in rigid):
            return choose(rigid), None  # compliance is a structural term, not a tolerance: it must earn it
        return next(c for c in reversed(cands) if c.fit is not None or c.name == "frames"), None
    if any(c.cv_misfit is not None for c in cands):
        return choose(cands), None
    note = f"{n_poses} fit poses are too few to cross-validate the models: the full model is used"
    return next(c for c in cands if c.name == "full"), note
