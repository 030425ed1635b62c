"""The simulated cell behind the gateway: drives + true plant + tracker from a truth file (architecture §6).

`SimulatedCell` implements `rxcomm.cell.backend.CellBackend`: each `cycle` quantises the encoders,
runs the drives' cascaded loops (`rxcomm.cell.drives`, tuned on the NOMINAL robot), integrates the
TRUE dynamics over one drive cycle (`rxcomm.cell.plant`) and reports what a drive reports: the
quantised position, the filtered velocity estimate, the commanded torque (after saturation) plus the
truth's torque-measurement noise, and the following error demand − actual. The gateway quantises
torque to 0.1 % of the rated (continuous) torque.

The tracker (`rxcomm.cell.tracker.SimulatedTracker`, the cell's visibility cone when a cell file is
given) answers only when every axis stands still: |velocity estimate| ≤ `standstill_rad_s` on all
axes, the drives' own standstill, which needs ≈ 8 filter time constants without any encoder count
change (≈ 4 ms at the default filter; a joint creeping slower than one count per that time is at
most ≈ 0.25 mrad/s). The same standstill ends the gateway's settling in virtual time, so the tracker
never waits for cycles that will not come; a reading is the pose at that instant, taken together
with the encoder positions the gateway reports. While a stream runs, the same tracker also samples
the moving TCP (`rxcomm.cell.tracker.MotionTracker`, the cell file's `tracker.sample_rate_hz`, the
truth's `noise.tracker_latency_s`), triggered by the stream start; `CellServer.tracker_export()`
hands those samples over like a real tracker's export file.

`start_embedded_cell` builds one from a truth file and serves it on loopback: `run` uses it when no
gateway is given.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pydantic import Field

from rxcomm.cell.backend import AxisFeedback, BackendState, TrackerReading
from rxcomm.cell.drives import CascadedDrives, DriveGains, DriveTuning, drive_gains
from rxcomm.cell.plant import Plant
from rxcomm.cell.server import CellServer, ServerConfig, TimeMode
from rxcomm.cell.tracker import MotionTracker, SimulatedTracker
from rxcomm.cell.truth import SimTruth, load_truth
from rxcomm.errors import InputError
from rxcomm.schemas.cell import TrackerSpec
from rxcomm.schemas.strict import Strict

NOISE_BLOCK = 1024
PLANTS = ("own", "mujoco")


class SimSettings(Strict):
    """How the simulated cell runs (the physics itself comes from the truth file)."""

    q0_rad: tuple[float, ...] | None = Field(None, description="initial joint angles; None: all zero")
    seed: int | None = Field(None, description="noise seed; None: the truth file's seed")
    substeps: int = Field(1, ge=1, le=64, description="plant integration steps per drive cycle")
    standstill_rad_s: float = Field(
        1e-6, gt=0, description="tracker: every |velocity estimate| at most this (≤ the gateway's 1e-6)"
    )
    tracker_max_samples: int = Field(
        1_000_000, ge=1, description="tracker samples kept during one stream (1 kHz: ≈ 17 min)"
    )
    tuning: DriveTuning = DriveTuning()


class SimulatedCell(BackendState):
    """The real backend of the simulated cell (`CellBackend`)."""

    def __init__(self, truth: SimTruth, settings: SimSettings | None = None):
        s = settings or SimSettings()
        robot = truth.robot
        self.truth = truth
        self.settings = s
        n = robot.n
        q0 = np.zeros(n) if s.q0_rad is None else np.array(s.q0_rad, dtype=float)
        if q0.shape != (n,):
            raise InputError(f"q0 needs {n} joint angles, got {len(q0)}", field="q0")
        bad = (q0 < robot.q_min) | (q0 > robot.q_max)
        if bad.any():
            j = int(np.flatnonzero(bad)[0])
            raise InputError(
                f"q0 of {robot.joint_names[j]} = {q0[j]:.4f} rad is outside "
                f"[{robot.q_min[j]:.4f}, {robot.q_max[j]:.4f}]",
                field="q0",
            )
        seed = truth.truth.seed if s.seed is None else s.seed
        torque_rng, tracker_rng, motion_rng = (
            np.random.default_rng(ss) for ss in np.random.SeedSequence(seed).spawn(3)
        )
        self._rng = torque_rng
        self._lsb = truth.truth.noise.encoder_lsb_rad
        self._torque_sigma = np.array(truth.truth.noise.torque_noise_nm, dtype=float)
        self._noise = np.empty((0, n))
        self._noise_next = 0
        self.gains: DriveGains = drive_gains(robot, s.tuning)
        self.plant = self._make_plant(q0)
        self.drives = CascadedDrives(self.gains, self._encoder())
        visibility = None if truth.cell is None else truth.cell.tracker
        self._tracker = self._make_tracker(tracker_rng, visibility)
        rate = 1000.0 if visibility is None else visibility.sample_rate_hz
        # Performance tests mount their target facing the tracker: its range and view cone hold,
        # the calibration probe's cone does not (a TCP pointing down would hide the whole ISO cube).
        facing = None if visibility is None else visibility.model_copy(update={"probe_half_angle_rad": np.pi})
        self.motion_tracker = MotionTracker(
            self._make_tracker(motion_rng, facing),
            rate,
            truth.truth.noise.tracker_latency_s,
            len(self.plant.tracker_state),
            max_samples=s.tracker_max_samples,
        )
        self._enabled = np.zeros(n, dtype=bool)
        g = self.gains
        super().__init__(
            self._encoder(),
            cycle_s=g.cycle_s,
            rated_torque_nm=np.array(robot.tau_cont, dtype=float),
            following_error_limit_rad=g.following_error_limit_rad,
            quick_stop_decel_rad_s2=g.quick_stop_decel_rad_s2,
        )

    # ---- the plant and what the tracker sees of it (`rxcomm.cell.mujoco_plant` swaps both) ----------

    plant_name = "own"
    plant_notes: tuple[str, ...] = ()

    def _make_plant(self, q0: np.ndarray) -> Plant:
        return Plant(self.truth.robot, self.truth.params, q0, substeps=self.settings.substeps)

    def _make_tracker(self, rng: np.random.Generator, visibility: TrackerSpec | None) -> SimulatedTracker:
        return SimulatedTracker(self.truth.robot, self.truth.truth, rng, visibility=visibility)

    # ---- CellBackend ---------------------------------------------------------------------------

    def cycle(
        self, position_demand_rad: np.ndarray, torque_ff_nm: np.ndarray, enabled: np.ndarray
    ) -> AxisFeedback:
        enabled = np.asarray(enabled, dtype=bool)
        tau = self.drives.control(position_demand_rad, torque_ff_nm, enabled)
        self.plant.step(tau, ~enabled)
        enc = self._encoder()
        self.drives.measure(enc)
        noise = self._torque_noise()
        self._enabled = enabled
        self._fb = AxisFeedback(
            position_rad=enc,
            velocity_rad_s=self.drives.velocity,
            torque_nm=(tau + noise) * enabled,  # torque off: no current, nothing measured
            following_error_rad=(position_demand_rad - enc) * enabled,
        )
        self.cycles += 1
        self.motion_tracker.step(self.cycles * self.cycle_s, self.plant.tracker_state)
        return self._fb

    def stream_started(self) -> None:
        """The gateway starts a stream (before its first cycle): the tracker's trigger input."""
        self.motion_tracker.trigger(self.cycles * self.cycle_s)

    def tracker(self) -> TrackerReading | None:
        if not self.standing_still():
            return None
        reading = self._tracker.measure(self.plant.tracker_state)
        if not reading.valid:
            return None
        return TrackerReading(np.array(reading.position_m), np.array(reading.quaternion_wxyz))

    # ---- helpers -------------------------------------------------------------------------------

    def standing_still(self) -> bool:
        """Every axis' velocity estimate within the standstill window."""
        s = self.settings
        return bool((np.abs(self.drives.velocity) <= s.standstill_rad_s).all())

    def _encoder(self) -> np.ndarray:
        return np.rint(self.plant.q / self._lsb) * self._lsb

    def _torque_noise(self) -> np.ndarray:
        """One row of torque-measurement noise; drawn NOISE_BLOCK cycles at a time (one call, not 1000)."""
        if self._noise_next >= len(self._noise):
            self._noise = self._rng.standard_normal((NOISE_BLOCK, self._n)) * self._torque_sigma
            self._noise_next = 0
        self._noise_next += 1
        return self._noise[self._noise_next - 1]


def simulated_cell(
    truth_path: str | Path,
    *,
    cell_path: str | Path | None = None,
    q0: Sequence[float] | None = None,
    settings: SimSettings | None = None,
    plant: str = "own",
    payload_path: str | Path | None = None,
) -> SimulatedCell:
    """A `SimulatedCell` from a truth file (`q0` overrides `settings.q0_rad`) on `plant` (`PLANTS`);
    `payload_path`: a `rxcomm/CellPayload` file replacing the truth's payload."""
    s = settings or SimSettings()
    if q0 is not None:
        s = s.model_copy(update={"q0_rad": tuple(float(x) for x in q0)})
    return cell_class(plant)(load_truth(truth_path, cell_path, payload_path), s)


class MujocoCell(SimulatedCell):
    """The simulated cell on the MuJoCo plant (`rxcomm.cell.mujoco_plant`, imported only here): the same
    drives, noise and tracker, MuJoCo's physics, the tracker reading the model's TCP site."""

    plant_name = "mujoco"

    def _make_plant(self, q0: np.ndarray):  # type: ignore[override]
        from rxcomm.cell.mujoco_plant import MujocoPlant

        plant = MujocoPlant(self.truth, q0, substeps=self.settings.substeps)
        self.plant_notes = plant.built.notes
        return plant

    def _make_tracker(self, rng: np.random.Generator, visibility: TrackerSpec | None) -> SimulatedTracker:
        from rxcomm.cell.mujoco_plant import MujocoSiteTracker

        built = self.plant.built  # type: ignore[union-attr]
        return MujocoSiteTracker(built, self.truth, self.truth.truth, rng, visibility=visibility)


def cell_class(plant: str) -> type[SimulatedCell]:
    """The simulated cell on `plant`: "own" (`rxcomm.cell.plant`) or "mujoco" (`rxcomm.cell.mujoco_plant`)."""
    if plant == "own":
        return SimulatedCell
    if plant == "mujoco":
        return MujocoCell
    raise InputError(f"unknown plant {plant!r}: one of {list(PLANTS)}", field="--plant")


def start_embedded_cell(
    truth_path: str | Path,
    port: int = 0,
    realtime: bool = False,
    q0: Sequence[float] | None = None,
    *,
    cell_path: str | Path | None = None,
    settings: SimSettings | None = None,
    server_config: ServerConfig | None = None,
    plant: str = "own",
    payload_path: str | Path | None = None,
) -> CellServer:
    """Serve a simulated cell on 127.0.0.1 (port 0: ephemeral, see `.port`); returns the STARTED server.

    The caller stops it (`server.stop()`, or use it as a context manager). Virtual time unless
    `realtime`. `plant`: "own" or "mujoco" (`cell_class`). `server_config` overrides host/port/time
    mode and the gateway's sizes entirely. `payload_path`: the payload it carries instead of the truth's.
    """
    backend = simulated_cell(
        truth_path, cell_path=cell_path, q0=q0, settings=settings, plant=plant, payload_path=payload_path
    )
    cfg = server_config or ServerConfig(
        port=port, time_mode=TimeMode.REALTIME if realtime else TimeMode.VIRTUAL
    )
    return CellServer(backend, cfg).start()
