"""Step a compiled match model and read each agent's state.

:class:`Simulation` owns one ``MjData``. It resolves every name to ids once, at
construction, and gives array views per agent: torso position and velocity read from
the free joint (current after ``mj_step``, unlike the one-substep-stale ``xpos``),
joint state, and contact forces summed over every contact of each agent geom.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from triplesumo.model import names

WATCHED_WARNINGS: dict[str, int] = {
    "bad_qacc": int(mujoco.mjtWarning.mjWARN_BADQACC),
    "bad_qpos": int(mujoco.mjtWarning.mjWARN_BADQPOS),
    "bad_qvel": int(mujoco.mjtWarning.mjWARN_BADQVEL),
    "bad_ctrl": int(mujoco.mjtWarning.mjWARN_BADCTRL),
    "contact_full": int(mujoco.mjtWarning.mjWARN_CONTACTFULL),
    "constraint_full": int(mujoco.mjtWarning.mjWARN_CNSTRFULL),
}
"""MuJoCo warnings that mean the physics can no longer be trusted (auto-reset, overflow)."""


class PhysicsError(RuntimeError):
    """MuJoCo reported a warning that invalidates the simulation (see WATCHED_WARNINGS)."""


@dataclass(frozen=True)
class AgentIndex:
    """Ids and addresses of one agent's elements in the compiled model."""

    name: str
    torso_body: int
    root_qpos: int
    """Address of the free joint in qpos (x, y, z, qw, qx, qy, qz)."""
    root_qvel: int
    """Address of the free joint in qvel (vx, vy, vz world frame; wx, wy, wz body frame)."""
    joint_qpos: np.ndarray
    joint_qvel: np.ndarray
    actuators: np.ndarray
    geoms: np.ndarray


class Simulation:
    """One match's physics: ``MjData`` plus per-agent views of it."""

    def __init__(self, model: mujoco.MjModel, agent_names: tuple[str, ...], frame_skip: int) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.frame_skip = int(frame_skip)
        self.agent_names = tuple(agent_names)
        self.agents = tuple(self._index(model, a) for a in self.agent_names)
        self.n_agents = len(self.agents)
        self.torso_qpos = np.array([[a.root_qpos + k for k in range(3)] for a in self.agents])
        self.torso_qvel = np.array([[a.root_qvel + k for k in range(3)] for a in self.agents])
        self.quat_qpos = np.array([[a.root_qpos + 3 + k for k in range(4)] for a in self.agents])
        self.angvel_qvel = np.array([[a.root_qvel + 3 + k for k in range(3)] for a in self.agents])
        self.action_sizes = tuple(len(a.actuators) for a in self.agents)
        """Motors of each agent (8, 12 or 16 for an ant, bug or spider)."""
        self.action_width = max(self.action_sizes)
        """Columns of the ``(n_agents, action_width)`` control arrays: agents with fewer motors
        leave the columns past their own count unused (padding)."""
        self.actuator_ids = np.full((self.n_agents, self.action_width), -1, dtype=np.int64)
        """Actuator ids per agent in its action order, ``-1`` in padding."""
        for row, a in zip(self.actuator_ids, self.agents, strict=True):
            row[:len(a.actuators)] = a.actuators
        self.action_mask: np.ndarray | None = None
        """``(n_agents, action_width)`` True where a column is a motor; ``None`` when every agent has
        ``action_width`` motors (no padding)."""
        if len(set(self.action_sizes)) > 1:
            self.action_mask = self.actuator_ids >= 0
        self.agent_geoms = np.concatenate([a.geoms for a in self.agents])
        """All agent geom ids, agent by agent; rows of :meth:`contact_forces`."""
        self.geom_counts = tuple(len(a.geoms) for a in self.agents)
        """Geoms of each agent (13, 19 or 25 for an ant, bug or spider)."""
        self._geom_row = np.full(model.ngeom, -1, dtype=np.int64)
        self._geom_row[self.agent_geoms] = np.arange(len(self.agent_geoms))
        lo, hi = model.actuator_ctrlrange[self.actuator_ids].transpose(2, 0, 1)
        real = self.actuator_ids >= 0
        self.ctrl_low: np.ndarray = np.where(real, lo, 0.0)
        """``(n_agents, action_width)`` lower control limits read from the model (0 in padding)."""
        self.ctrl_high: np.ndarray = np.where(real, hi, 0.0)
        """``(n_agents, action_width)`` upper control limits read from the model (0 in padding)."""
        # Views into MjData, made once (each attribute access builds a new numpy view).
        data = self.data
        self._qpos, self._qvel, self._warn_number = data.qpos, data.qvel, data.warning.number
        bodies = model.geom_bodyid[self.agent_geoms]
        self._body_forces: tuple[np.ndarray, np.ndarray] | None = None
        """``cfrc_ext`` force and ``xfrc_applied`` force rows of the agent geoms' bodies, when each
        agent geom has a body of its own and those bodies are consecutive (every RoboSumo body's are)."""
        self.body_force_rows: slice | None = None
        """The rows of ``cfrc_ext`` and ``xfrc_applied`` that :meth:`contact_forces` reads (the agent
        geoms' bodies), or ``None`` when it has to sum contact by contact."""
        if np.array_equal(bodies, np.arange(bodies[0], bodies[0] + len(bodies))):
            rows = slice(int(bodies[0]), int(bodies[0]) + len(bodies))
            self.body_force_rows = rows
            self._body_forces = (data.cfrc_ext[rows, 3:], data.xfrc_applied[rows, :3])
        self._ctrl_index = self.actuator_ids[real]
        self._ctrl_flat = None if self.action_mask is None else self.action_mask.ravel()
        self._ctrl_view = data.ctrl if np.array_equal(self._ctrl_index, np.arange(model.nu)) else None
        self._fatal = ""
        self._warn_ids = np.array(list(WATCHED_WARNINGS.values()))
        self._warn_seen = np.zeros(len(WATCHED_WARNINGS), dtype=np.int64)
        """Counts of the watched warnings as of the last check (set by snapshots too)."""
        self._warn_all: list[int] | None = None
        """Every warning counter at the last check; ``None`` forces a full comparison."""

    @property
    def dt(self) -> float:
        """Seconds of simulated time per env step."""
        return float(self.model.opt.timestep) * self.frame_skip

    @staticmethod
    def _index(model: mujoco.MjModel, agent: str) -> AgentIndex:
        """The agent's hinges in model order (hip_1, ankle_1, hip_2, ...) and the motor of each."""
        root = model.joint(names.scoped(agent, names.ROOT_JOINT))
        torso = model.body(names.scoped(agent, names.TORSO_BODY)).id
        joints = [model.joint(j) for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
                  and _body_root(model, int(model.jnt_bodyid[j])) == torso]
        motor_of = {int(model.actuator_trnid[i, 0]): i for i in range(model.nu)
                    if model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT}
        missing = [j.name for j in joints if j.id not in motor_of]
        if missing:
            raise RuntimeError(f"joints {missing} of agent {agent!r} have no motor")
        acts = [motor_of[j.id] for j in joints]
        geoms = [g for g in range(model.ngeom) if _body_root(model, int(model.geom_bodyid[g])) == torso]
        return AgentIndex(
            name=agent,
            torso_body=torso,
            root_qpos=int(root.qposadr[0]),
            root_qvel=int(root.dofadr[0]),
            joint_qpos=np.array([int(j.qposadr[0]) for j in joints]),
            joint_qvel=np.array([int(j.dofadr[0]) for j in joints]),
            actuators=np.array(acts),
            geoms=np.array(geoms),
        )

    # ------------------------------------------------------------------ state
    def reset(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Set the state, clear controls and warnings, and recompute derived quantities."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_forward(self.model, self.data)
        self._warn_seen[:] = 0
        self._warn_all = None
        self._fatal = ""

    def step(self, ctrl: np.ndarray) -> None:
        """Apply ``ctrl`` (shape ``(n_agents, action_width)``, in control units; padding ignored) for one env step."""
        flat = ctrl.ravel() if self._ctrl_flat is None else ctrl.ravel()[self._ctrl_flat]
        if self._ctrl_view is not None:
            self._ctrl_view[:] = flat
        else:
            self.data.ctrl[self._ctrl_index] = flat
        try:
            mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        except mujoco.FatalError as exc:  # e.g. the arena stack overflows: reported by new_warnings()
            self._fatal = str(exc)

    @property
    def step_failed(self) -> bool:
        """``mj_step`` raised a MuJoCo fatal error since the last :meth:`new_warnings` (which reports it)."""
        return bool(self._fatal)

    def torso_positions(self) -> np.ndarray:
        """``(n_agents, 3)`` torso centres from the free joints' qpos (current after a step)."""
        return self.data.qpos[self.torso_qpos]

    def torso_velocities(self) -> np.ndarray:
        """``(n_agents, 3)`` torso linear velocities in the world frame."""
        return self.data.qvel[self.torso_qvel]

    def torso_quaternions(self) -> np.ndarray:
        """``(n_agents, 4)`` torso orientations (w, x, y, z)."""
        return self.data.qpos[self.quat_qpos]

    def torso_angular_velocities(self) -> np.ndarray:
        """``(n_agents, 3)`` torso angular velocities in the torso frame."""
        return self.data.qvel[self.angvel_qvel]

    def contact_forces(self) -> np.ndarray:
        """``(n_agent_geoms, 3)`` world-frame contact force on each agent geom.

        Summed over every contact the geom takes part in (the paper's code overwrote
        all but one), from the contacts and constraint forces now in ``data``. When every
        agent geom has a body of its own, in consecutive bodies (the quadruped's), this is one
        call to ``mj_rnePostConstraint``: the force half of ``cfrc_ext`` is exactly that sum
        (minus ``xfrc_applied``, e.g. a viewer perturbation, which is not a contact).
        Otherwise it is :meth:`contact_forces_reference`.
        """
        if self._body_forces is None:
            return self.contact_forces_reference()
        mujoco.mj_rnePostConstraint(self.model, self.data)
        return self._body_forces[0] - self._body_forces[1]

    def contact_forces_reference(self) -> np.ndarray:
        """:meth:`contact_forces` from ``mj_contactForce``, contact by contact.

        MuJoCo's contact normal points from geom1 to geom2; the force from
        ``mj_contactForce`` (contact frame, rows of ``contact.frame`` are its axes) acts
        on geom2 and its reaction on geom1.
        """
        out = np.zeros((len(self.agent_geoms), 3))
        data, rows = self.data, self._geom_row
        local = np.empty(6)
        for i in range(data.ncon):
            contact = data.contact[i]
            r1, r2 = rows[contact.geom1], rows[contact.geom2]
            if r1 < 0 and r2 < 0:
                continue
            mujoco.mj_contactForce(self.model, data, i, local)
            world = contact.frame.reshape(3, 3).T @ local[:3]
            if r2 >= 0:
                out[r2] += world
            if r1 >= 0:
                out[r1] -= world
        return out

    # ------------------------------------------------------------- warnings
    def warnings_seen(self) -> np.ndarray:
        """Counts of the :data:`WATCHED_WARNINGS` already reported (a copy, for snapshots)."""
        return self._warn_seen.copy()

    def set_warnings_seen(self, counts: np.ndarray) -> None:
        """Continue from a snapshot whose reported counts were ``counts``."""
        self._warn_seen[:] = counts
        self._warn_all = None

    def new_warnings(self) -> list[str]:
        """Names of watched MuJoCo warnings raised since the last call or reset.

        Also reports ``non_finite_state`` when qpos or qvel hold NaN or inf, and
        ``arena_overflow`` when ``mj_step`` failed with a MuJoCo fatal error (out of arena
        memory).
        """
        fired = []
        every = self._warn_number.tolist()
        if every != self._warn_all:  # rare: compare the watched counters one by one
            counts = self._warn_number[self._warn_ids]
            fired = [n for n, c, s in zip(WATCHED_WARNINGS, counts, self._warn_seen, strict=True) if c > s]
            self._warn_seen[:] = counts
            self._warn_all = every
        if self._fatal:
            fired.append("arena_overflow")
            self._fatal = ""
        if not (math.isfinite(self._qpos.sum()) and math.isfinite(self._qvel.sum())):
            fired.append("non_finite_state")
        return fired


def _body_root(model: mujoco.MjModel, body: int) -> int:
    """The child-of-world ancestor of ``body`` (the agent's torso for agent geoms)."""
    while model.body_parentid[body] != 0:
        body = int(model.body_parentid[body])
    return body
