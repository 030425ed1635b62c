"""A tracker's samples on the joint log's time axis (docs/tracker-csv.md).

The tracker stamps its samples on its own clock, a latency after the instant it measured. Joint log
time t relates to tracker time by one offset: t = t_tracker − offset.

- **trigger**: the tracker latched the controller's stream-start trigger at ``trigger_s`` (its clock);
  joint record k is the state at the end of setpoint k + 1, so offset = trigger_s + sample_s. This
  leaves the tracker's latency in the offset.
- **cross-correlation**: the TCP velocity the tracker saw against the velocity of FK(q_actual)
  (nominal kinematics), FK's turned into the tracker frame by the rotation that best maps its
  positions onto the tracker's (Kabsch). Velocity vectors, not speeds: |v + noise| is biased where
  the robot is slow, at the starts and stops that place the motion in time. Both are central
  differences over ±`half_window_s` (the tracker's noise) on the joint log's grid; outside its
  samples each side is held (a plan runs rest to rest), and the tracker's side is evaluated ±`search_s`
  wider so that every lag correlates whole windows (a cut would be an edge that pulls the peak to
  itself). The peak of the normalised correlation, refined by a parabola through the three samples
  around it, gives the offset; a second pass about it (±10 samples) puts the held ends where they
  belong. What is left is the nominal model's velocity error (compliance, geometric errors): about
  0.3 ms on a 1.5 s joint move of the RX130L (tests/test_tracker_motion.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rxcomm.errors import InputError
from rxcomm.io.tracker_csv import TrackerExport
from rxcomm.model.kinematics import frame_placement
from rxcomm.model.robot import Robot
from rxcomm.schemas.run_log import TrackerChannel


@dataclass(frozen=True)
class Alignment:
    offset_s: float  # joint-log time = t_tracker − offset_s
    method: str  # "trigger" | "cross-correlation" | "trigger+cross-correlation"
    trigger_offset_s: float | None
    correlation: float | None


def trigger_offset(trigger_s: float, sample_s: float) -> float:
    """The offset from the stream-start trigger stamp (joint record k ends setpoint k + 1)."""
    return float(trigger_s) + float(sample_s)


def speed_on_grid(t: np.ndarray, p: np.ndarray, grid: np.ndarray, half_window_s: float) -> np.ndarray:
    """|dp/dt| on `grid` (m/s): p linearly interpolated, central difference over ±`half_window_s`."""
    lo = np.column_stack([np.interp(grid - half_window_s, t, p[:, i]) for i in range(3)])
    hi = np.column_stack([np.interp(grid + half_window_s, t, p[:, i]) for i in range(3)])
    return np.linalg.norm(hi - lo, axis=1) / (2 * half_window_s)


def velocity_on_grid(t: np.ndarray, p: np.ndarray, grid: np.ndarray, half_window_s: float) -> np.ndarray:
    """dp/dt [len(grid), 3] (m/s): p linearly interpolated (held outside t), central difference over
    ±`half_window_s`."""
    lo = np.column_stack([np.interp(grid - half_window_s, t, p[:, i]) for i in range(3)])
    hi = np.column_stack([np.interp(grid + half_window_s, t, p[:, i]) for i in range(3)])
    return (hi - lo) / (2 * half_window_s)


def kabsch_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R minimising Σ |R (a_i − ā) − (b_i − b̄)|² (a, b [k, 3])."""
    h = (a - a.mean(axis=0)).T @ (b - b.mean(axis=0))
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def _correlate(
    t_tr: np.ndarray, p_tracker: np.ndarray, grid: np.ndarray, p_fk: np.ndarray, m: int, half_window_s: float
) -> tuple[float, float]:
    """(lag in samples, peak) of the tracker's velocity (times `t_tr`) against FK's on `grid`."""
    dt = float(np.median(np.diff(grid)))
    p_tr_grid = np.column_stack([np.interp(grid, t_tr, p_tracker[:, i]) for i in range(3)])
    rot = kabsch_rotation(p_fk, p_tr_grid)
    a = velocity_on_grid(grid, p_fk, grid, half_window_s) @ rot.T
    wide = np.concatenate([grid[0] - dt * np.arange(m, 0, -1), grid, grid[-1] + dt * np.arange(1, m + 1)])
    b = velocity_on_grid(t_tr, p_tracker, wide, half_window_s)  # ±m more: each lag sees a whole window
    n = len(grid)
    size = 1 << int(np.ceil(np.log2(2 * n + 2 * m)))
    fb, fa = np.fft.rfft(b, size, axis=0), np.fft.rfft(a, size, axis=0)
    full = np.fft.irfft(np.sum(fb * np.conj(fa), axis=1), size)[: 2 * m + 1]  # [j] = Σ_i b[i + j]·a[i]
    cum = np.concatenate([[0.0], np.cumsum(np.sum(b * b, axis=1))])
    window = cum[n : n + 2 * m + 1] - cum[: 2 * m + 1]
    # the peak of the raw correlation (a matched filter: normalising per lag would favour lags where
    # the tracker's window holds little but noise); its normalised value says how well they match
    best = int(np.argmax(full))
    lag = float(best - m)
    if 0 < best < 2 * m:
        cm, c0, cp = full[best - 1], full[best], full[best + 1]
        if (denom := cm - 2 * c0 + cp) < 0:
            lag += 0.5 * (cm - cp) / denom  # the parabola's vertex through the three around the peak
    return lag, float(full[best] / np.sqrt(np.sum(a * a) * max(window[best], 1e-300)))


def cross_correlation_offset(
    t_tracker: np.ndarray,
    p_tracker: np.ndarray,
    t_joint: np.ndarray,
    p_fk: np.ndarray,
    *,
    offset0_s: float = 0.0,
    search_s: float = 0.05,
    half_window_s: float = 0.01,
) -> tuple[float, float]:
    """(offset s, peak normalised correlation) of the tracker's TCP velocity against FK's.

    `p_fk` [k, 3]: TCP positions of the encoders through the kinematics at `t_joint` (uniform grid).
    The search runs ±`search_s` about `offset0_s`, then once more about what it found (±10 samples),
    so the held ends sit where they belong. Raises InputError when the TCP does not move."""
    t_joint = np.asarray(t_joint, dtype=float)
    dt = float(np.median(np.diff(t_joint)))
    if np.max(np.ptp(p_fk, axis=0)) < 1e-4:
        raise InputError("the TCP does not move: no velocity profile to cross-correlate", field="tracker")
    offset, peak = offset0_s, 0.0
    for m in (int(np.ceil(search_s / dt)), 10):
        lag, peak = _correlate(np.asarray(t_tracker) - offset, p_tracker, t_joint, p_fk, m, half_window_s)
        offset += lag * dt  # the tracker's velocity at grid + lag·dt matches FK's at grid: lag·dt late
    return float(offset), peak


def align(
    t_tracker: np.ndarray,
    p_tracker: np.ndarray,
    t_joint: np.ndarray,
    p_fk: np.ndarray,
    *,
    trigger_s: float | None,
    sample_s: float,
    method: str = "auto",
    search_s: float = 0.05,
) -> Alignment:
    """The offset by `method`: "trigger", "cross-correlation" (a search of ±1 s about the trigger's;
    without a trigger, wherever the two records overlap) or "auto" (the trigger refined by the
    cross-correlation within ±`search_s`; the cross-correlation alone without a trigger). The
    cross-correlation is kept only when the tracker covers `MIN_COVERAGE` of the joint log and the
    velocities correlate to `MIN_CORRELATION`: held values over a lost beam are no motion to match
    ("auto" then keeps the trigger's offset; otherwise InputError)."""
    trig = None if trigger_s is None else trigger_offset(trigger_s, sample_s)
    if method == "trigger":
        if trig is None:
            raise InputError(
                "alignment by trigger, but the tracker data have no trigger_s", field="trigger_s"
            )
        return Alignment(trig, "trigger", trig, None)
    if method not in ("auto", "cross-correlation"):
        raise InputError(f"unknown alignment {method!r}", field="alignment")
    if trig is not None:
        start, search = trig, 1.0 if method == "cross-correlation" else search_s
    else:  # no trigger: anywhere the two records overlap
        start = float(t_tracker[0] - t_joint[0])
        search = float(np.ptp(t_tracker) + np.ptp(t_joint))
    reason = ""
    try:
        offset, peak = cross_correlation_offset(
            t_tracker, p_tracker, t_joint, p_fk, offset0_s=start, search_s=search
        )
        cover = coverage(t_tracker - offset, t_joint)
        if cover < MIN_COVERAGE or peak < MIN_CORRELATION:
            reason = (
                f"the tracker covers {cover:.0%} of the joint log (gaps: the beam was lost) and the "
                f"velocities correlate to {peak:.2f}; need ≥ {MIN_COVERAGE:.0%} and ≥ {MIN_CORRELATION}"
            )
    except InputError as e:
        reason = str(e)
    if reason:
        if method == "auto" and trig is not None:  # the trigger alone
            return Alignment(trig, "trigger", trig, None)
        raise InputError(f"no alignment by cross-correlation: {reason}", field="tracker")
    name = (
        "cross-correlation" if trig is None or method == "cross-correlation" else "trigger+cross-correlation"
    )
    return Alignment(offset, name, trig, peak)


MIN_COVERAGE = 0.95  # share of the joint log's instants with a tracker sample within 2 ms
MIN_CORRELATION = 0.9


def coverage(t_tracker_aligned: np.ndarray, t_joint: np.ndarray, within_s: float = 0.002) -> float:
    """Share of the joint log's instants with a tracker sample within `within_s`."""
    i = np.clip(np.searchsorted(t_tracker_aligned, t_joint), 1, len(t_tracker_aligned) - 1)
    near = np.minimum(np.abs(t_tracker_aligned[i] - t_joint), np.abs(t_tracker_aligned[i - 1] - t_joint))
    return float(np.mean(near <= within_s))


CORRELATE_S = 30.0  # the log's first seconds the cross-correlation looks at (the latency is constant)


def tracker_channel(
    robot: Robot,
    export: TrackerExport,
    q_actual: np.ndarray,
    sample_s: float,
    *,
    method: str = "auto",
    source_file: str | None = None,
    correlate_s: float = CORRELATE_S,
) -> TrackerChannel:
    """How `export` sits on a joint log with encoder rows `q_actual` [k, n] every `sample_s`: the
    `TrackerChannel` record (`rxcomm.schemas.run_log`) with the offset. The cross-correlation uses
    the first `correlate_s` of the log (the latency is constant; FK of every row of a long log is not
    needed)."""
    if export.n < 2:
        raise InputError("the tracker export has fewer than two samples", field="tracker")
    m = min(len(q_actual), int(correlate_s / sample_s) + 1)
    ok = np.all(np.isfinite(q_actual[:m]), axis=1)
    data = robot.create_data()
    p_fk = np.array(
        [frame_placement(robot, data, q, robot.tcp_frame_id).translation for q in q_actual[:m][ok]]
    )
    t_joint = (np.arange(m) * sample_s)[ok]
    a = align(
        export.t_s,
        export.position_m,
        t_joint,
        p_fk,
        trigger_s=export.trigger_s,
        sample_s=sample_s,
        method=method,
    )
    return TrackerChannel(
        source="simulated-cell" if export.source == "simulated-cell" else "csv",
        source_file=source_file,
        rate_hz=export.rate_hz,
        n_samples=export.n,
        alignment=a.method,
        offset_s=a.offset_s,
        trigger_offset_s=a.trigger_offset_s,
        correlation=a.correlation,
    )
