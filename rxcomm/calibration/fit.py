"""Geometric calibration from tracker measurements (paper §3.2; architecture §7 calibrate).

Model and parameters: `rxcomm.model.geometric_errors` (48 error twists; the identifiable subset by QR).
Problem: minimise Σᵢ ‖rᵢ‖² over the identifiable parameters p₁ (the others fixed at 0), with the
weighted residual of pose i

    rᵢ = [ (p_pred − p_meas) / σ_p ;  log3(R_pred·R_measᵀ) / σ_o ]     (tracker frame)

σ_p, σ_o the tracker's position and orientation noise (so rᵢ is ~N(0, I) when the model is right
and position and orientation are weighed by their precision). Levenberg–Marquardt
(`scipy.optimize.least_squares`, `method="lm"`; `trf` when a robust loss is asked) with the
analytic Jacobian of `geometric_errors` (orientation rows through the exact derivative of log3),
started at the closed-form base and tool frames, the joint errors at 0 (the paper starts at
p_e = 0). Standard deviations from the covariance s²·(JᵀJ)⁻¹ with s² the
residual variance per degree of freedom.

Around the fit (docs/calibrate-csv.md): the base and tool frames estimated from the data in closed
form (`estimate_frames`), so no guess is needed; a `tracker_to_base` from the measurements file or
the cell is the reference when it agrees with the data's, else replaced by it with a note; the
tracker noise given (settings, file) or estimated from the residuals (variance components,
`_Fitter.noise_from_residuals`); poses with a component beyond `outlier_sigma` robust σ after a first
fit are flagged (and dropped, by default, before the final fit); held-out poses (`validation` role,
or a seeded `holdout_fraction`) are never fitted; candidate models (base + tool frames; + joint
offsets; the full identifiable set; + joint compliance δq_j = c_j·τ_j with τ the prior model's
holding torque) compared by k-fold cross-validation over the fit poses, the simplest within one
standard error of the best chosen; the paper's Table 2 (`error_table`) before/after on fitted and
held-out poses, with the frames-only fit beside it; and, when the file has `baseline` poses (a naive
pose set measured for comparison), the chosen calibration fitted to those instead and judged on the
same held-out poses (`BaselineComparison`).

Input checks raise `InputError` (exit 2) with file and field: NaN rows, too few poses (says how
many are needed), a pose set that cannot identify some parameters (names them), positions that look
like millimetres, joint angles that look like degrees, orientations that do not fit a rigid tool
(angle convention), measurements that do not fit the robot even after the fit — named as a swapped
joint pair or a flipped joint sign when one fits far better (`diagnosis`). A calibration worse
than the nominal model on the held-out poses raises `InfeasibleError` (exit 3); held-out poses
beyond the noise are a warning naming them.

This module runs the steps; each concept lives in its own module of the package: `measurements`
(reading and checking), `frames` (closed-form base and tool), `residuals` (weighted residual,
Table 2), `lm` (the fit, covariance, outliers, noise, cross-validation), `selection` (candidate
models), `compliance` (holding torques), `plausibility` (the checks and notes), `urdf` and
`exports` (calibrated URDF with the TCP frame, MDH and zero offsets), `loading` (back from the artefact).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from rxcomm.calibration.compliance import compliant_joints, holding_torques
from rxcomm.calibration.diagnosis import heldout_disagreement, joint_mixup
from rxcomm.calibration.frames import DataFrames, estimate_frames, reference_base
from rxcomm.calibration.lm import BaselineComparison, FitResult, Fitter, at_links, rank_check
from rxcomm.calibration.measurements import ROLES, MeasurementSet
from rxcomm.calibration.plausibility import (
    check_beats_nominal,
    check_fits_robot,
    check_rigid_tool,
    fit_notes,
    undetermined_parameters,
)
from rxcomm.calibration.priors import effective_priors
from rxcomm.calibration.residuals import ErrorStats, error_table
from rxcomm.calibration.selection import Candidate, candidate_models, chosen_model, score_candidates
from rxcomm.calibration.settings import CalibrateSettings
from rxcomm.errors import InputError
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.geometric_errors import (
    IdentifiableSet,
    identifiable_parameters,
    parameter_names,
    random_poses,
)
from rxcomm.model.robot import Robot


@dataclass(frozen=True)
class TrackerNoise:
    position_sigma_m: float
    orientation_sigma_rad: float | None  # None: position-only measurements
    source: str  # "settings", "measurements" or "estimated"


@dataclass(frozen=True)
class CalibrationResult:
    fit: FitResult
    frames_only: FitResult
    identifiable: IdentifiableSet
    tracker_to_base: pin.SE3
    tracker_to_base_source: str
    fit_idx: np.ndarray
    heldout_idx: np.ndarray
    outlier_idx: np.ndarray
    tables: dict[tuple[str, str], ErrorStats]  # (pose set, model) → stats
    baseline: BaselineComparison | None  # the same calibration from the 'baseline' poses, if measured
    measurement: str
    settings: CalibrateSettings
    seconds: float
    noise: TrackerNoise
    candidates: tuple[Candidate, ...]
    model: str  # the chosen candidate's name
    data_frames: DataFrames
    undetermined: tuple[str, ...] = ()  # parameters the data cannot determine (σ above the threshold)
    notes: tuple[str, ...] = ()  # what the user should know (frames far from the guess, tool offset…)
    prior_scale: float = 1.0  # on the geometric priors' σ, from the data (`Fitter.noise_from_residuals`)
    unread: dict[str, int] = field(default_factory=dict)  # role → its poses without a tracker reading
    # [fit poses, 3]: each position component's minimal detectable blunder (`Fitter.detectable_blunders_m`)
    detectable_blunder_m: np.ndarray | None = None


# The prior scales beyond which the widening or narrowing is worth a note (the sample truths, drawn
# on the classes' scale, read 0.57–1.3 at camera grade).
WIDENED_PRIOR_NOTE = 2.0
NARROWED_PRIOR_NOTE = 0.3


# A pose set that lets a blunder this many σ_p hide in one of its components is worth a note: the
# blunder test is shown to catch 10σ (issue 30), and 10σ would then pass unflagged 1 time in 5 or more.
HIDDEN_BLUNDER_NOTE_SIGMA = 10.0


def hidden_blunder_note(detectable_m: np.ndarray, fit: np.ndarray, sigma_p: float) -> str | None:
    """Where the fit leans on one pose so much that a blunder of `HIDDEN_BLUNDER_NOTE_SIGMA` σ_p in
    one of its position components could go unflagged (`Fitter.detectable_blunders_m`), say which."""
    k, axis = np.unravel_index(int(np.argmax(detectable_m)), detectable_m.shape)
    worst = float(detectable_m[k, axis])
    if worst <= HIDDEN_BLUNDER_NOTE_SIGMA * sigma_p:
        return None
    return (
        f"the fit leans on pose {int(fit[k])} so much that a blunder of up to {worst * 1e3:.3g} mm "
        f"({worst / sigma_p:.1f}σ) in its {'xyz'[axis]} could go unflagged (one that size is caught 4 "
        "times in 5): no other pose checks it; a few more poses around it make it checkable"
    )


def unread_note(ms: MeasurementSet) -> str | None:
    """What the campaign could not measure (no tracker reading: a pose out of sight, or an arm that did
    not come to rest), and where that makes the selected poses' comparison with the naive ones unfair."""
    counts = {role: ms.unread(role) for role in ROLES}
    lost = [f"{k} of {n} {role}" for role, (k, n) in counts.items() if k]
    if not lost:
        return None
    text = f"poses without a tracker reading, left out: {', '.join(lost)}"
    (kf, nf), (kb, nb) = counts["fit"], counts["baseline"]
    if nb and nf and kf / nf > kb / nb:
        text += (
            f"; the selected poses ({nf - kf} measured) are compared with {nb - kb} naive ones, which is "
            "not like for like"
        )
    return text


def split_poses(ms: MeasurementSet, settings: CalibrateSettings) -> tuple[np.ndarray, np.ndarray, float]:
    """(fit poses, held-out poses, the hold-out fraction used): valid `validation` poses are held out,
    and a seeded `holdout_fraction` of the `fit` poses (default 0 with validation poses, else 0.25)."""
    valid = np.flatnonzero(ms.valid)
    roles = np.array(ms.role)
    heldout = valid[roles[valid] == "validation"]
    fit = valid[roles[valid] == "fit"]
    frac = settings.holdout_fraction
    if frac is None:
        frac = 0.0 if heldout.size else 0.25
    if frac > 0 and fit.size:
        rng = np.random.default_rng(settings.seed)
        held = np.sort(rng.choice(fit, size=int(round(frac * fit.size)), replace=False))
        heldout = np.union1d(heldout, held)
        fit = np.setdiff1d(fit, held)
    return fit, heldout, frac


def _identifiable(robot: Robot, ms: MeasurementSet, n_fit: int, point) -> tuple[IdentifiableSet, int]:
    """(the identifiable parameters of this measurement, the fewest fit poses they need)."""
    po = ms.position_only
    rows = 3 if po else 6
    ident = identifiable_parameters(robot, random_poses(robot, 60, np.random.default_rng(0)), po, point)
    p = len(ident)
    need = p // rows + 1
    if n_fit < need:
        raise InputError(
            f"{n_fit} valid fit poses give {n_fit * rows} equations for {p} identifiable parameters "
            f"({'position' if po else 'full pose'} measurement): need at least {need} fit poses "
            f"(≥ {2 * need} for a reliable fit; the paper uses 32)",
            file=ms.source,
            field="poses",
        )
    return ident, need


def _with_noise(full_f: Fitter, fit: np.ndarray, given_p: float | None, estimate: bool) -> Fitter:
    """The fitter with σ_p, σ_o estimated from the residuals when not given, and its priors' scale
    (`Fitter.noise_from_residuals`): robust first (blunders), outliers out, then efficient on the
    clean poses, and the poses tested again against that σ until the clean set stays (the robust
    scale, a median, is the noisier estimate: its flags are provisional; at 24 poses it read 0.77 mm
    for 1.5 mm of noise and dropped a clean pose, which took the efficient estimate from 1.23 to
    1.03 mm, architecture §11). Position noise given, orientation not: the given σ_p is kept and the
    ratio taken from the residuals."""
    if not estimate and full_f.prior is None:
        return full_f
    f = full_f.noise_from_residuals(fit, robust=True) if estimate else full_f
    clean = None
    for _ in range(4):
        _, kept, _ = f.fit_dropping_outliers(fit)
        if clean is not None and np.array_equal(kept, clean):
            break
        clean = kept
        f = f.noise_from_residuals(clean, robust=False, noise=estimate)
    if given_p is not None and estimate:
        f = replace(f, sigma_o=f.sigma_o * given_p / f.sigma_p, sigma_p=given_p)
    return f


def _tables(
    robot: Robot,
    ms: MeasurementSet,
    sets: dict[str, np.ndarray],
    models: dict[str, FitResult | None],
    tau: np.ndarray,
    t2b: pin.SE3,
    point,
) -> dict[tuple[str, str], ErrorStats]:
    """Table 2 of each model (None: nominal) on each non-empty pose set, the links where each
    model puts them."""
    out = {}
    for set_name, sel in sets.items():
        if sel.size == 0:
            continue
        sub = ms.subset(sel)
        for model_name, fr in models.items():
            at = sub if fr is None else at_links(sub, fr, tau[sel])
            out[(set_name, model_name)] = error_table(
                robot, at, None if fr is None else fr.errors, t2b, point
            )
    return out


def calibrate(
    robot: Robot,
    ms: MeasurementSet,
    settings: CalibrateSettings | None = None,
    tracker_to_base: pin.SE3 | None = None,
    dynamics: DynamicParameters | None = None,
) -> CalibrationResult:
    """Identify the geometric errors from `ms` (see the module docstring). `tracker_to_base` (e.g.
    from the cell) overrides the measurement file's as the guessed base; without either, or when the
    guess is far from the base the data give, the data's base (closed form) is the reference.
    `dynamics`: the model whose holding torques bend the joints (default the prior; an identified
    one makes the stiffness the true one rather than scaled by the prior's torque error)."""
    t0 = time.perf_counter()
    settings = settings or CalibrateSettings()
    point = None if settings.point_in_tcp_m is None else np.array(settings.point_in_tcp_m)
    po = ms.position_only
    fit, heldout, frac = split_poses(ms, settings)
    settings = settings.model_copy(update={"holdout_fraction": frac})
    ident, need = _identifiable(robot, ms, fit.size, point)
    ms_fit = ms.subset(fit)
    rank_check(robot, ms_fit, ident, point)
    # An exporter's joint order or signs first (closed-form frames for 21 alternatives, ~0.05 s): every
    # later check would blame something else (the angle convention, blunders, the fit's convergence).
    mixup = joint_mixup(robot, ms_fit, point)
    if mixup is not None:
        raise InputError(mixup, file=ms.source, field="q")
    # The frames from the data; a guess is a reference when it agrees, never a refusal.
    data = estimate_frames(robot, ms_fit, point)
    check_rigid_tool(data, ms)
    guess, source = (
        (tracker_to_base, "cell") if tracker_to_base is not None else (ms.tracker_to_base, "measurements")
    )
    t2b, source, note = reference_base(robot, ms_fit, data, guess, source, point)
    notes = [] if note is None else [note]
    start = np.zeros(len(parameter_names(robot)))
    start[:6] = np.asarray(pin.log6(t2b.inverse() * data.tracker_to_base).vector)
    start[-6:] = np.asarray(pin.log6(data.tool).vector)
    # Noise: given (settings, file) or estimated from the residuals.
    sp = settings.position_sigma_m or ms.position_sigma_m
    so = settings.orientation_sigma_rad or ms.orientation_sigma_rad
    noise_source = "settings" if settings.position_sigma_m else "measurements" if sp else "estimated"
    tau = holding_torques(robot, ms.q, dynamics)
    poses = random_poses(robot, 60, np.random.default_rng(0))  # as `_identifiable`'s
    sig, corr = effective_priors(robot, np.array(ident.indices), poses, po, point)

    def fitter_for(idx: np.ndarray, comp: tuple[int, ...], base: Fitter | None = None) -> Fitter:
        x0 = np.concatenate([start[idx], np.zeros(len(comp))])
        if base is not None:
            return replace(base, idx=np.asarray(idx), comp=comp, x0=x0)
        return Fitter(
            robot,
            ms,
            t2b,
            np.asarray(idx),
            sp or 1e-3,
            so or 1e-2,
            point,
            settings,
            need,
            tau,
            comp,
            x0,
            sig,
            geometric_corr=corr,
        )

    estimate = noise_source == "estimated" or (not po and so is None)
    # Noise and blunders against the richest model offered (joint compliance included), so that what
    # the model can explain is not taken for noise or blunders.
    comp = (
        compliant_joints(tau[fit])
        if settings.compliance and settings.model in ("auto", "full+compliance")
        else ()
    )
    full_f = _with_noise(fitter_for(np.array(ident.indices), comp), fit, sp, estimate)
    full_fit, fit, flagged = full_f.fit_dropping_outliers(fit)
    detectable = full_f.detectable_blunders_m(fit, full_fit)
    ms_fit = ms.subset(fit)
    noise = TrackerNoise(full_f.sigma_p, None if po else full_f.sigma_o, noise_source)
    # The model chosen by the data: k-fold cross-validation over the fit poses.
    folds = np.random.default_rng(settings.seed + 1).permutation(fit.size) % min(settings.cv_folds, fit.size)
    specs = candidate_models(robot, ms_fit, ident, tau[fit], point, settings.compliance)
    cands = score_candidates(specs, lambda i, c: fitter_for(i, c, full_f), fit, folds, settings.model)
    chosen, note = chosen_model(cands, settings.model, fit.size, settings.regularise)
    notes += [] if note is None else [note]
    frames_c = next(c for c in cands if c.name == "frames")
    if chosen.fit is None:
        raise InputError(
            f"model {chosen.name!r} cannot be fitted: {chosen.note}", file=ms.source, field="model"
        )
    result, frames = chosen.fit, frames_c.fit
    if frames is None:
        raise InputError(f"the base + tool frames cannot be fitted: {frames_c.note}", file=ms.source)
    fitter = fitter_for(np.array(chosen.idx), chosen.comp, full_f)
    # Plausibility after the fit: what the frames and errors cannot explain is the wrong robot.
    check_fits_robot(robot, ms_fit, result, tau[fit], t2b, point)
    notes += fit_notes(result, po, noise_source != "estimated")
    if full_f.prior_scale >= WIDENED_PRIOR_NOTE:
        notes.append(
            f"the joint errors are about {full_f.prior_scale:.1f}× the manufacturing classes' σ, so the "
            "priors were widened to match: the nominal model is further off than this class's tolerances "
            "(a catalogue model, a reworked or damaged arm)"
        )
    elif full_f.prior_scale <= NARROWED_PRIOR_NOTE:
        notes.append(
            f"the data put the joint errors at about {full_f.prior_scale:.2g}× the manufacturing classes' "
            "σ (or below what this noise resolves), so the priors were narrowed to match: the estimate "
            "stays close to the frames-only one"
        )
    limit = settings.undetermined_std_ratio * noise.position_sigma_m
    prior = sig * full_f.prior_scale if settings.regularise else None
    undetermined = undetermined_parameters(robot, chosen.idx, chosen.comp, result, limit, prior)
    sets = {"fit": fit, "heldout": heldout}
    tables = _tables(
        robot, ms, sets, {"nominal": None, "calibrated": result, "frames_only": frames}, tau, t2b, point
    )
    # Sanity: the calibration must beat the nominal model on the held-out poses, or miss them
    # within the noise (those that agree with it, when most do: one mistyped pose must not decide).
    disagreeing, warning = heldout_disagreement(fitter, result, fit, heldout)
    notes += [] if warning is None else [warning]
    agree = np.setdiff1d(heldout, disagreeing)
    scored = agree if 2 * agree.size > heldout.size else heldout
    notes += [] if (note := check_beats_nominal(fitter, result, fit, scored, tables)) is None else [note]
    rigid = next((c for c in cands if c.name == "full"), None)
    if chosen.comp and rigid is not None and rigid.fit is not None:
        tables |= _tables(robot, ms, {"heldout": heldout}, {"rigid": rigid.fit}, tau, t2b, point)
    valid = np.flatnonzero(ms.valid)
    baseline_poses = valid[np.array(ms.role)[valid] == "baseline"]
    notes += [] if (note := unread_note(ms)) is None else [note]
    notes += [] if (note := hidden_blunder_note(detectable, fit, full_f.sigma_p)) is None else [note]
    comparison = None
    if baseline_poses.size:
        comparison = fitter.compare_baseline(baseline_poses, heldout, result)
        if comparison.fit is not None:
            models = {"baseline_poses": comparison.fit}
            tables |= _tables(robot, ms, {"heldout": heldout}, models, tau, t2b, point)
    return CalibrationResult(
        fit=result,
        frames_only=frames,
        identifiable=ident,
        tracker_to_base=t2b,
        tracker_to_base_source=source,
        fit_idx=fit,
        heldout_idx=heldout,
        outlier_idx=flagged,
        tables=tables,
        baseline=comparison,
        measurement="position" if po else "pose",
        settings=settings,
        seconds=time.perf_counter() - t0,
        noise=noise,
        candidates=tuple(cands),
        model=chosen.name,
        data_frames=data,
        undetermined=tuple(undetermined),
        notes=tuple(notes),
        prior_scale=full_f.prior_scale,
        unread={role: ms.unread(role)[0] for role in ROLES},
        detectable_blunder_m=detectable,
    )
