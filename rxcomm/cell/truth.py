"""Loading the simulated cell's hidden truth (`truth.yaml`, architecture §6) into what the simulator needs.

The only reader of truth files in the library (stages never read them; recovery-scoring tests may).
`truth.robot` names the robot directory relative to the truth file; the nominal robot is loaded from
there. The cell file (`cell.yaml`, for the tracker's visibility cone) is optional: by default the one
beside the truth file is used when it exists. A payload on the flange (the truth's `payload`, or a
`rxcomm/CellPayload` file given per run that replaces it) is added to the last link's inertials of the
true dynamics (`rxcomm.model.payload`): the own plant, the MuJoCo plant and the tracker's sag carry it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rxcomm.errors import InputError
from rxcomm.io.yaml_io import read_yaml_model
from rxcomm.model.dynamics import DynamicParameters, truth_parameters
from rxcomm.model.payload import FlangeInertia, with_payload
from rxcomm.model.robot import Robot, load_robot
from rxcomm.schemas.cell import Cell
from rxcomm.schemas.payload import CellPayload
from rxcomm.schemas.truth import CellTruth

DEFAULT_CELL_NAME = "cell.yaml"


@dataclass(frozen=True, eq=False)
class SimTruth:
    """A truth file resolved: the nominal robot, its true dynamic parameters, the cell (optional)."""

    path: Path
    truth: CellTruth
    robot: Robot  # the NOMINAL robot (URDF + drives.yaml): drives are tuned on it
    params: DynamicParameters  # the true dynamics the plant integrates (with the payload)
    cell: Cell | None
    cell_path: Path | None


def loaded_parameters(robot: Robot, truth: CellTruth) -> DynamicParameters:
    """The true dynamics with the truth's payload (if any) on the last link."""
    params = truth_parameters(robot, truth)
    if truth.payload is None:
        return params
    try:
        return with_payload(robot, params, FlangeInertia.of_mount(truth.payload))
    except InputError as e:
        raise InputError(e.reason, field="payload") from e


def load_truth(
    path: str | Path, cell_path: str | Path | None = None, payload_path: str | Path | None = None
) -> SimTruth:
    """Read and check `truth.yaml` (InputError naming file and field on any problem).

    `cell_path`: the cell file whose tracker spec gives visibility; None looks for `cell.yaml` beside
    the truth file (absent: every pose is visible). `payload_path`: a `rxcomm/CellPayload` file whose
    payload replaces the truth's for this cell.
    """
    path = Path(path)
    truth = read_yaml_model(path, CellTruth)
    if payload_path is not None:
        mounted = read_yaml_model(payload_path, CellPayload)
        truth = truth.model_copy(update={"payload": mounted.payload})
    robot_dir = (path.parent / truth.robot).resolve()
    if not (robot_dir / "drives.yaml").exists():
        raise InputError(f"robot directory {robot_dir} has no drives.yaml", file=path, field="robot")
    robot = load_robot(robot_dir)
    try:
        params = loaded_parameters(robot, truth)
    except InputError as e:
        where = payload_path if payload_path is not None and e.field == "payload" else path
        raise InputError(e.reason, file=where, field=e.field) from e
    noise = truth.noise
    if len(noise.torque_noise_nm) != robot.n:
        raise InputError(f"expected {robot.n} values", file=path, field="noise.torque_noise_nm")
    if cell_path is None and (path.parent / DEFAULT_CELL_NAME).exists():
        cell_path = path.parent / DEFAULT_CELL_NAME
    cell = None if cell_path is None else read_yaml_model(cell_path, Cell)
    return SimTruth(
        path=path,
        truth=truth,
        robot=robot,
        params=params,
        cell=cell,
        cell_path=None if cell_path is None else Path(cell_path),
    )
