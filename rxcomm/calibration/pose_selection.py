"""Optimal measurement poses for geometric calibration (paper §3.3; architecture §7 select-configs).

1. **Candidates.** A joint grid (default 13 equal intervals per axis, their midpoints: 13⁶ ≈ 4.8 M
   configurations) is streamed in blocks with bounded memory: FK is split into the arm (q1..q3, one
   4×4 per grid point of the first three axes) and the wrist (q4..q6, relative 4×4s computed once),
   so a block of configurations costs one batched product. Each configuration is checked against
   the cell (`feasibility` gives the same checks for arbitrary poses): TCP, wrist centre and elbow
   in the workspace box and above the floor; TCP and wrist centre clear of the base capsule and the
   TCP clear of the upper-arm capsule (`schemas.cell.SelfCollision`); the probe visible to the
   tracker (range, view cone, probe facing the tracker; both cones narrowed by the cell's
   `visibility_margin_rad` so that the real robot's errors keep the chosen poses in view). The
   feasible ones are sub-sampled on the fly to `max_candidates` by priority sampling (the k smallest
   of a seeded uniform key per candidate, i.e. a uniform random subset, as a reservoir), then sorted
   in grid order.

   About q6: with the TCP on the flange axis (RX130L) q6 does not move the TCP, only turns the probe
   about it; it matters for full-pose measurement (it excites the tool/joint-6 orientation terms)
   and for the visibility only if the probe axis is off the flange axis. So it stays in the grid;
   with `position` measurement of an on-axis TCP use `intervals` with 1 for q6.

2. **Observation index.** Per candidate the identification Jacobian over the identifiable
   parameters (nominal model), scaled Θ̃ = W·Θ·S·T. Rows W: position in m, orientation in rad × σ_p/σ_o
   (the tracker's noise ratio from `cell.yaml`), so Λ = Σ Θ̃ᵢᵀΘ̃ᵢ over the chosen poses is the fit's
   Fisher information up to σ_p². Columns S·T: translations m, rotations rad × L, then whitened by the
   candidates' mean information (TᵀF̄T = I, F̄ = mean ΘᵢᵀΘᵢ), so Λ is counted in "average candidate
   poses": a set of n poses as informative as the average candidate in every direction has Λ = n·I,
   and the index does not depend on the tracker frame, on unit choices or on how the parameters are
   scaled. Criteria (all maximised): `det-root` det(Λ)^(1/p) (the default), `min-eig`
   B = λ_min(Λ) = σ_min(ΘᵀΘ) (the paper's), `cond` reported as cond(Λ) = λ_max/λ_min (minimised).

   Why det-root is the default: what the user gets from the poses is the prediction error after
   calibration, σ_p²·trace(Θ_c Λ⁻¹ Θ_cᵀ) at a pose c. With 6-D measurements and 32 poses for 30
   parameters every diverse set is within ~10 % of the best possible (I-optimal) set; maximising
   λ_min alone pushes the one weakest combination (J5 offset vs J6 misalignment) at the expense of
   the others (in a plain metre scaling its sets predicted worse than evenly spaced candidates);
   det-root predicts best (see `expected_errors`, reported for the chosen set and both baselines).

3. **Exchange algorithm** (paper steps 1–4). Random nonsingular start of `n_start` poses; remove-and-
   replace while it improves; add the best pose until `n`; final remove-and-replace; `restarts`
   times with a seeded generator, keeping the best. Each move changes Λ by ±Θ̃ᵢᵀΘ̃ᵢ (rank ≤ 6, a sum
   of rank-one updates), so Λ is never rebuilt. The search over all candidates for the best addition
   costs one batched product: in Λ's eigenbasis a second-order perturbation estimate of the new
   λ_min (weakest direction's gain minus its coupling to the others) ranks every candidate, and the
   best `n_exact` (32) by that estimate are evaluated exactly (30×30 eigenvalues); the exact best of
   those is taken (tests check it equals the brute-force best). For `det-root` the matrix
   determinant lemma gives a candidate's exact value from a 6×6 determinant, and the trace of that
   6×6 bounds it from both sides, so only the few candidates whose bound can still win are evaluated.
   Removal is evaluated exactly for every chosen pose.

   Cost (RX130L, 4,000 candidates, 30 parameters, one BLAS thread): ≈0.1 s per restart (det-root),
   ≈0.25 s (min-eig).

4. **Baselines** (`rxcomm.calibration.baselines`): the paper's linear scan and evenly spaced
   candidates, scored like the selection (`BaselineSet`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from rxcomm.calibration.baselines import LinearScan, evenly_spaced, linear_scan
from rxcomm.calibration.workspace import CandidateSet, Progress, stream_candidates
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.model.geometric_errors import (
    IdentifiableSet,
    characteristic_length_m,
    identifiable_parameters,
    identification_jacobians,
    measurement_scaling,
    random_poses,
)
from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import Cell


class Criterion(StrEnum):
    MIN_EIG = "min-eig"
    DET_ROOT = "det-root"
    COND = "cond"


# ---------------------------------------------------------------------------------------------------
# Cell checks (shared by the grid stream and arbitrary poses)


# ---------------------------------------------------------------------------------------------------
# The candidate grid, streamed


# ---------------------------------------------------------------------------------------------------
# Information blocks and the observation index


def information_blocks(
    robot: Robot,
    qs: np.ndarray,
    ident: IdentifiableSet,
    position_only: bool = False,
    point: np.ndarray | None = None,
    orientation_weight_m: float | None = None,
) -> np.ndarray:
    """Θ̃ per pose, [N, rows, p]: the scaled identification Jacobian over the identifiable parameters.

    Rows: position (first 3) in m, orientation in rad × `orientation_weight_m` (default L; the
    tracker's σ_p/σ_o makes Λ the fit's Fisher information up to σ_p²). Columns: translations m,
    rotations rad × L.
    """
    jac = identification_jacobians(robot, qs, None, None, position_only, point)
    row_w, col_s = measurement_scaling(robot, position_only)
    if orientation_weight_m is not None and not position_only:
        row_w = np.array([1.0, 1.0, 1.0] + [orientation_weight_m] * 3)
    idx = list(ident.indices)
    return jac[:, :, idx] * row_w[None, :, None] * col_s[idx][None, None, :]


def normalise_to_candidates(blocks: np.ndarray, n_candidates: int | None = None) -> np.ndarray:
    """Blocks in parameter coordinates where the mean candidate's information is the identity.

    Θ̃ → Θ̃·T with TᵀF̄T = I, F̄ = mean Θ̃ᵢᵀΘ̃ᵢ over the first `n_candidates` blocks (default all; any
    further blocks are other poses, e.g. a baseline, put in the same coordinates): Λ of a set is then
    counted in average candidate poses, and `min-eig`/`cond` no longer depend on how the parameters
    are scaled (det-root changes by a constant factor only). Raises InfeasibleError when the
    candidates cannot identify the set.
    """
    cand = blocks[:n_candidates]
    mean_info = np.einsum("nri,nrj->ij", cand, cand) / cand.shape[0]
    d, v = np.linalg.eigh(mean_info)
    if d[0] <= 1e-12 * d[-1]:
        raise InfeasibleError(
            f"the {cand.shape[0]} candidates leave a parameter combination unobservable "
            f"(λ_min/λ_max of their mean information {d[0] / d[-1]:.1e}): widen the grid or the cell"
        )
    return blocks @ (v / np.sqrt(d))


def expected_errors(
    chosen: np.ndarray, targets: np.ndarray, position_sigma_m: float, orientation_weight_m: float | None
) -> tuple[float, float | None]:
    """Expected rms (position m, orientation rad) prediction error over the `targets` poses (blocks,
    e.g. all candidates) after a fit to the `chosen` poses' blocks: σ_p·sqrt(mean_c trace(Θ̃_c Λ⁻¹
    Θ̃_cᵀ)) for the position rows, the orientation rows divided by their weight. Needs blocks with
    Fisher row weights (orientation σ_p/σ_o)."""
    lam = np.einsum("nri,nrj->ij", chosen, chosen)
    ev = np.linalg.eigvalsh(lam)
    if ev[0] <= 1e-12 * ev[-1]:
        return math.inf, (math.inf if orientation_weight_m else None)
    inv = np.linalg.inv(lam)

    def rms(rows: np.ndarray) -> float:
        mean_info = np.einsum("nri,nrj->ij", rows, rows) / rows.shape[0]
        return math.sqrt(max(float(np.trace(mean_info @ inv)), 0.0))

    pos = position_sigma_m * rms(targets[:, :3])
    if targets.shape[1] == 3 or not orientation_weight_m:
        return pos, None
    return pos, position_sigma_m * rms(targets[:, 3:]) / orientation_weight_m


def selection_blocks(
    robot: Robot,
    cell: Cell,
    qs: np.ndarray,
    ident: IdentifiableSet,
    point: np.ndarray | None = None,
    n_candidates: int | None = None,
) -> tuple[np.ndarray, float]:
    """(blocks, orientation row weight): the Fisher-weighted, candidate-whitened Θ̃ that selection
    and `expected_errors` use (module docstring, 2.); the first `n_candidates` poses (default all)
    are the candidates that define the whitening."""
    tracker = cell.tracker
    weight = tracker.position_sigma_m / tracker.orientation_sigma_rad
    position_only = tracker.measures == "position"
    raw = information_blocks(robot, qs, ident, position_only, point, weight)
    return normalise_to_candidates(raw, n_candidates), weight


def _score(lam: np.ndarray, criterion: Criterion) -> np.ndarray:
    """Criterion value to MAXIMISE for [..., p, p] information matrices."""
    if criterion is Criterion.DET_ROOT:
        sign, logdet = np.linalg.slogdet(lam)
        return np.where(sign > 0, np.exp(logdet / lam.shape[-1]), 0.0)
    ev = np.linalg.eigvalsh(lam)
    if criterion is Criterion.MIN_EIG:
        return np.maximum(ev[..., 0], 0.0)
    return np.maximum(ev[..., 0], 0.0) / ev[..., -1]


def observation_index(blocks: np.ndarray, criterion: Criterion | str = Criterion.DET_ROOT) -> float:
    """The index of a pose set given its blocks [n, rows, p] (cond reported as λ_max/λ_min)."""
    criterion = Criterion(criterion)
    lam = np.einsum("nri,nrj->ij", blocks, blocks)
    s = float(_score(lam, criterion))
    if criterion is Criterion.COND:
        return math.inf if s <= 0 else 1.0 / s
    return s


@dataclass
class _Search:
    """Exchange-algorithm state over a fixed candidate set (blocks [N, r, p])."""

    blocks: np.ndarray
    criterion: Criterion
    n_exact: int = 32
    evaluations: int = field(default=0)

    def _estimate(self, a: np.ndarray, d: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Second-order perturbation estimate of the criterion after adding each candidate.

        In Λ's eigenbasis (B = A·V, G = BᵀB): λ_min ≈ d₀ + G₀₀ − Σⱼ G₀ⱼ² / (dⱼ + Gⱼⱼ − d₀ − G₀₀), the
        last term the coupling to the other directions; λ_max likewise (for `cond`).
        """
        b = a @ v  # [N, r, p]
        g_diag = np.einsum("nrj,nrj->nj", b, b)
        lo = d[0] + g_diag[:, 0]
        c0 = np.einsum("nr,nrj->nj", b[:, :, 0], b[:, :, 1:])
        gap = np.maximum(d[1:] + g_diag[:, 1:] - lo[:, None], 1e-12 * max(d[-1], 1e-300))
        lo = lo - np.sum(c0**2 / gap, axis=1)
        if self.criterion is Criterion.COND:
            hi = d[-1] + g_diag[:, -1]
            return np.maximum(lo, 0.0) / hi
        return lo

    def gram(self, i: int | np.ndarray) -> np.ndarray:
        a = self.blocks[i]
        return np.einsum("...ri,...rj->...ij", a, a)

    def best_add(self, lam: np.ndarray, exclude: np.ndarray) -> tuple[int, float]:
        """argmax over candidates not excluded of score(Λ + Θ̃ᵢᵀΘ̃ᵢ), exact (branch and bound)."""
        a = self.blocks
        allowed = ~exclude
        if self.criterion is Criterion.DET_ROOT:
            sign, logdet = np.linalg.slogdet(lam)
            if sign <= 0:
                lam = lam + np.eye(lam.shape[0]) * 1e-12 * np.trace(lam)
                sign, logdet = np.linalg.slogdet(lam)
            # det(Λ + AᵀA) = det Λ · det(I + X), X = A Λ⁻¹ Aᵀ = WWᵀ (W = A L⁻ᵀ, Λ = LLᵀ): a 6×6 per
            # candidate. Branch and bound on t = tr X = ‖W‖²: 1 + t ≤ det(I + X) ≤ (1 + t/r)^r, so
            # candidates are evaluated exactly in order of t until no bound can beat the best.
            n_cand, r, p = a.shape
            w = (a.reshape(-1, p) @ np.linalg.inv(np.linalg.cholesky(lam)).T).reshape(n_cand, r, p)
            t = np.einsum("nrp,nrp->n", w, w)
            t[~allowed] = -np.inf
            order = np.argsort(-t)
            order = order[np.isfinite(t[order])]
            best_i, best_ld = -1, -np.inf
            for start in range(0, order.size, self.n_exact):
                chunk = order[start : start + self.n_exact]
                if r * math.log1p(t[chunk[0]] / r) <= best_ld:
                    break
                wc = w[chunk]
                _, ld = np.linalg.slogdet(np.eye(r) + wc @ wc.transpose(0, 2, 1))
                self.evaluations += chunk.size
                j = int(np.argmax(ld))
                if ld[j] > best_ld:
                    best_i, best_ld = int(chunk[j]), float(ld[j])
            if best_i < 0:
                return -1, -np.inf
            return best_i, float(np.exp((logdet + best_ld) / p))
        d, v = np.linalg.eigh(lam)
        est = self._estimate(a, d, v)
        est[~allowed] = -np.inf
        top = np.argsort(-est)[: self.n_exact]
        top = top[np.isfinite(est[top])]
        if top.size == 0:
            return -1, -np.inf
        vals = _score(lam + self.gram(top), self.criterion)
        self.evaluations += top.size
        j = int(np.argmax(vals))
        best_i, best_v = int(top[j]), float(vals[j])
        return best_i, best_v

    def best_remove(self, lam: np.ndarray, chosen: list[int]) -> tuple[int, float]:
        """Position in `chosen` whose removal keeps the score highest, and that score."""
        vals = _score(lam[None] - self.gram(np.array(chosen)), self.criterion)
        self.evaluations += len(chosen)
        j = int(np.argmax(vals))
        return j, float(vals[j])


def _exchange(
    search: _Search, chosen: list[int], lam: np.ndarray, max_moves: int
) -> tuple[list[int], np.ndarray, int]:
    """Remove-and-replace while it improves (paper steps 2 and 4). Returns (chosen, Λ, moves)."""
    n_cand = search.blocks.shape[0]
    score = float(_score(lam, search.criterion))
    moves = 0
    while moves < max_moves:
        j, _ = search.best_remove(lam, chosen)
        out = chosen[j]
        lam_minus = lam - search.gram(out)
        exclude = np.zeros(n_cand, dtype=bool)
        exclude[chosen] = True
        exclude[out] = False
        i, val = search.best_add(lam_minus, exclude)
        if i < 0 or i == out or val <= score * (1 + 1e-9):
            break
        chosen = chosen[:j] + chosen[j + 1 :] + [i]
        lam = lam_minus + search.gram(i)
        score = val
        moves += 1
    return chosen, lam, moves


@dataclass(frozen=True)
class SelectionResult:
    indices: np.ndarray  # into the candidate blocks, in the order chosen
    observation_index: float  # as reported (cond: λ_max/λ_min)
    score: float  # maximised value
    restart_indices: tuple[float, ...]  # the index each restart reached
    moves: int
    evaluations: int
    seconds: float


def select_poses(
    blocks: np.ndarray,
    n: int,
    criterion: Criterion | str = Criterion.DET_ROOT,
    restarts: int = 5,
    seed: int = 0,
    n_start: int | None = None,
) -> SelectionResult:
    """The paper's exchange algorithm over candidate blocks [N, rows, p] (see the module docstring).

    Raises InfeasibleError when the candidates cannot make Λ nonsingular (too few or too similar).
    """
    t0 = time.perf_counter()
    criterion = Criterion(criterion)
    n_cand, rows, p = blocks.shape
    n_min = math.ceil(p / rows)
    if n < n_min:
        raise InputError(
            f"{n} poses of {rows} rows cannot identify {p} parameters: need at least {n_min}", field="n"
        )
    if n > n_cand:
        raise InfeasibleError(
            f"only {n_cand} feasible candidates for {n} poses: relax the cell or refine the grid"
        )
    n0 = min(n, max(n_min + 2, n // 2)) if n_start is None else max(min(n_start, n), n_min)
    rng = np.random.default_rng(seed)
    search = _Search(blocks, criterion)
    best: tuple[float, list[int]] | None = None
    reached: list[float] = []
    moves = 0
    for _ in range(max(restarts, 1)):
        for _attempt in range(200):
            chosen = [int(i) for i in rng.choice(n_cand, size=n0, replace=False)]
            lam = np.einsum("nri,nrj->ij", blocks[chosen], blocks[chosen])
            ev = np.linalg.eigvalsh(lam)
            if ev[0] > 1e-10 * ev[-1]:
                break
        else:
            raise InfeasibleError(
                f"no nonsingular start among {n_cand} candidates after 200 random draws of {n0}: "
                "the candidates cannot identify all parameters (too few, or all alike)"
            )
        chosen, lam, m1 = _exchange(search, chosen, lam, 10 * n)
        while len(chosen) < n:
            exclude = np.zeros(n_cand, dtype=bool)
            exclude[chosen] = True
            i, _ = search.best_add(lam, exclude)
            if i < 0:
                break
            chosen.append(i)
            lam = lam + search.gram(i)
        chosen, lam, m2 = _exchange(search, chosen, lam, 10 * n)
        moves += m1 + m2
        s = float(_score(lam, criterion))
        reached.append(s)
        if best is None or s > best[0]:
            best = (s, chosen)
    assert best is not None
    score, chosen = best
    report = (lambda s: math.inf if s <= 0 else 1.0 / s) if criterion is Criterion.COND else (lambda s: s)
    return SelectionResult(
        indices=np.array(chosen),
        observation_index=report(score),
        score=score,
        restart_indices=tuple(report(s) for s in reached),
        moves=moves,
        evaluations=search.evaluations,
        seconds=time.perf_counter() - t0,
    )


@dataclass(frozen=True)
class BaselineSet:
    """A reference pose set scored like the selection: its index, the selection's ratio over it
    (`None` when it is singular), and the rms prediction error calibrating from it should leave
    over the candidates (position m, orientation rad or None) at the tracker noise of cell.yaml."""

    q: np.ndarray
    observation_index: float
    improvement_ratio: float | None
    expected_error: tuple[float, float | None]


@dataclass(frozen=True)
class PoseSelection:
    candidates: CandidateSet
    identifiable: IdentifiableSet
    measurement: str  # "pose" | "position"
    characteristic_length_m: float
    criterion: Criterion
    selection: SelectionResult
    q_selected: np.ndarray
    q_validation: np.ndarray
    expected_error: tuple[float, float | None]  # of the selected set, as BaselineSet.expected_error
    # The naive baseline, the paper's linear scan of the joint grid (`linear_scan`).
    baseline: BaselineSet
    scan: LinearScan
    # σ_min(Λ) of the selected set over the linear scan's: the paper's ×18.5 figure, whatever the criterion.
    min_eig_improvement_ratio: float | None
    # The stronger reference: as many evenly spaced candidates (`evenly_spaced`).
    evenly_spaced: BaselineSet


def _improvement(selected: float, other: float, criterion: Criterion) -> float | None:
    if criterion is Criterion.COND:  # reported as λ_max/λ_min: smaller is better
        return other / selected if math.isfinite(other) else None
    return selected / other if other > 0 else None


def select_measurement_poses(
    robot: Robot,
    cell: Cell,
    n: int = 32,
    *,
    intervals: int | tuple[int, ...] = 13,
    max_candidates: int | None = 4000,
    criterion: Criterion | str = Criterion.DET_ROOT,
    restarts: int = 5,
    seed: int = 0,
    n_validation: int = 32,
    point: np.ndarray | None = None,
    progress: Progress | None = None,
) -> PoseSelection:
    """Candidates from the grid, identifiable set, exchange selection, the linear-scan baseline and
    evenly spaced candidates beside it, validation poses."""
    criterion = Criterion(criterion)
    cand = stream_candidates(robot, cell, intervals, max_candidates, seed, progress)
    n_cand = cand.q.shape[0]
    if n_cand < n:
        raise InfeasibleError(
            f"only {n_cand} of {cand.n_grid} grid configurations pass the cell checks "
            f"(rejected: {cand.rejected}); {n} poses requested: relax the cell or refine the grid"
        )
    position_only = cell.tracker.measures == "position"
    rng = np.random.default_rng(seed)
    ident = identifiable_parameters(robot, random_poses(robot, 60, rng), position_only, point)
    scan = linear_scan(cand, n)
    stacked, weight = selection_blocks(robot, cell, np.vstack([cand.q, scan.q]), ident, point, n_cand)
    blocks, scan_blocks = stacked[:n_cand], stacked[n_cand:]
    sigma_p = cell.tracker.position_sigma_m
    sel = select_poses(blocks, n, criterion, restarts, seed)

    def reference(q: np.ndarray, b: np.ndarray) -> BaselineSet:
        index = observation_index(b, criterion)
        return BaselineSet(
            q=q,
            observation_index=index,
            improvement_ratio=_improvement(sel.observation_index, index, criterion),
            expected_error=expected_errors(b, blocks, sigma_p, weight),
        )

    even = evenly_spaced(n_cand, n)
    rest = np.setdiff1d(np.arange(n_cand), sel.indices)
    val_idx = np.sort(rng.choice(rest, size=min(n_validation, rest.size), replace=False))
    return PoseSelection(
        candidates=cand,
        identifiable=ident,
        measurement="position" if position_only else "pose",
        characteristic_length_m=characteristic_length_m(robot),
        criterion=criterion,
        selection=sel,
        q_selected=cand.q[sel.indices],
        q_validation=cand.q[val_idx],
        expected_error=expected_errors(blocks[sel.indices], blocks, sigma_p, weight),
        baseline=reference(scan.q, scan_blocks),
        scan=scan,
        min_eig_improvement_ratio=_improvement(
            observation_index(blocks[sel.indices], Criterion.MIN_EIG),
            observation_index(scan_blocks, Criterion.MIN_EIG),
            Criterion.MIN_EIG,
        ),
        evenly_spaced=reference(cand.q[even], blocks[even]),
    )
