"""The MuJoCo plant behind the gateway: the simulated cell with MuJoCo's physics (architecture §6).

`rxcomm.cell.sim.MujocoCell` is the simulated cell (`SimulatedCell`: the same CiA 402 drives and
their loops tuned on the nominal robot, encoder quantisation, torque noise, tracker noise, view
cone and latency, time modes) with its plant and its tracker's geometry swapped: the robot moves in
the MuJoCo model of `rxcomm.cell.mujoco_model` (MuJoCo's URDF parser, its integrator
`implicitfast`, its friction constraints, tendons and hinges), and the tracker reads the model's
TCP site.

`MujocoPlant` has the own plant's interface (`q`, `step(τ, braked)`, `tracker_state`): `q` are the
motor hinges' angles (what the encoders read), `tracker_state` the whole MuJoCo position vector
(link hinges of compliant joints included) from which the site is computed. Each drive cycle the
drives' torque minus the truth's torque offset is the generalised force on the motor hinges, and
MuJoCo steps `substeps` times. A braked joint is locked (a joint equality at its braked angle).
A compliant joint starts at its static deflection, so the arm does not ring at power-on.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin

from rxcomm.cell.mujoco_model import MujocoPlantModel, build_mujoco_model
from rxcomm.cell.tracker import SimulatedTracker
from rxcomm.cell.truth import SimTruth
from rxcomm.schemas.cell import TrackerSpec
from rxcomm.schemas.truth import CellTruth

SETTLE_ITERATIONS = 6


class MujocoPlant:
    """State of the MuJoCo model; `step(τ, braked)` advances one drive cycle."""

    def __init__(self, truth: SimTruth, q0_rad: np.ndarray, *, substeps: int = 1):
        robot = truth.robot
        self.n = robot.n
        self.substeps = substeps
        self.built: MujocoPlantModel = build_mujoco_model(
            truth, timestep_s=robot.drives.cycle_s / substeps, q0_rad=q0_rad
        )
        self.model = self.built.model
        self.data = mujoco.MjData(self.model)
        self._offset = np.array(truth.params.offset_nm, dtype=float)
        self._braked = np.zeros(self.n, dtype=bool)
        self.data.qpos[self.built.motor_qpos] = np.asarray(q0_rad, dtype=float)
        self._settle()

    def _settle(self) -> None:
        """Compliant joints to their static deflection at the initial motor angles (Newton on the
        link hinges' balance: stiffness, gravity and balancer spring, all from MuJoCo)."""
        m, d, b = self.model, self.data, self.built
        cd, cq = b.compliance_dof[b.compliance_dof >= 0], b.compliance_qpos[b.compliance_qpos >= 0]
        if not len(cd):
            mujoco.mj_forward(m, d)
            return
        k = np.array([m.jnt_stiffness[m.dof_jntid[i]] for i in cd])
        for _ in range(SETTLE_ITERATIONS):
            mujoco.mj_forward(m, d)
            d.qpos[cq] += (d.qfrc_passive[cd] - d.qfrc_bias[cd]) / k
        mujoco.mj_forward(m, d)

    @property
    def q(self) -> np.ndarray:
        """Motor-side joint angles (rad): what the encoders read."""
        return self.data.qpos[self.built.motor_qpos].copy()

    @property
    def tracker_state(self) -> np.ndarray:
        return self.data.qpos.copy()

    def link_angles(self) -> np.ndarray:
        """The links' angles (motor + compliance hinge), rad."""
        q = self.q
        rigid = self.built.compliance_qpos < 0
        return q + np.where(rigid, 0.0, self.data.qpos[np.where(rigid, 0, self.built.compliance_qpos)])

    def step(self, tau_nm: np.ndarray, braked: np.ndarray) -> None:
        """Advance one drive cycle with joint torques `tau_nm` held; `braked` joints are locked."""
        self._brakes(np.asarray(braked, dtype=bool))
        self.data.qfrc_applied[self.built.motor_dof] = np.asarray(tau_nm, dtype=float) - self._offset
        for _ in range(self.substeps):
            mujoco.mj_step(self.model, self.data)

    def _brakes(self, braked: np.ndarray) -> None:
        for j in np.flatnonzero(braked != self._braked):
            eq = self.built.brake_eq[j]
            if braked[j]:
                self.model.eq_data[eq, :5] = 0.0
                self.model.eq_data[eq, 0] = self.data.qpos[self.built.motor_qpos[j]]
            self.data.eq_active[eq] = bool(braked[j])
        self._braked = braked.copy()


class MujocoSiteTracker(SimulatedTracker):
    """The simulated tracker (noise, view cone) reading the TCP site of the MuJoCo model: a state is
    MuJoCo's position vector, the pose is `tracker_to_base` · the site's world pose."""

    def __init__(
        self,
        built: MujocoPlantModel,
        truth: SimTruth,
        cell_truth: CellTruth,
        rng: np.random.Generator,
        *,
        visibility: TrackerSpec | None = None,
    ) -> None:
        super().__init__(truth.robot, cell_truth, rng, visibility=visibility)
        self._built = built
        self._data = mujoco.MjData(built.model)

    def _site(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d, b = self._data, self._built
        d.qpos[:] = state
        mujoco.mj_kinematics(b.model, d)
        rot = d.site_xmat[b.tcp_site].reshape(3, 3)
        pos = d.site_xpos[b.tcp_site]
        if self._point is not None:
            pos = pos + rot @ self._point
        t = b.tracker_to_base
        return t.rotation @ pos + t.translation, t.rotation @ rot

    def true_pose(self, q: np.ndarray) -> pin.SE3:
        p, r = self._site(np.asarray(q, dtype=float))
        return pin.SE3(r, p)

    def true_poses(self, qs: np.ndarray, deflection_every: int = 25) -> tuple[np.ndarray, np.ndarray]:
        k = len(qs)
        pos, rot = np.empty((k, 3)), np.empty((k, 3, 3))
        for i, state in enumerate(np.asarray(qs, dtype=float)):
            pos[i], rot[i] = self._site(state)
        return pos, rot
