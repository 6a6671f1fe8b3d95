"""Observations of a match, in two documented modes.

``paper`` -- the paper's global vector, identical for every agent:

    torso_position   (n_agents * 3)   torso centres, roster order
    torso_velocity   (n_agents * 3)   torso linear velocities, world frame
    contact_force    (n_agent_geoms * 3)  world-frame force on every agent geom, summed
                                       over all its contacts, clipped to +-contact_force_clip
    qpos             (nq)             all generalised positions
    qvel             (nv)             all generalised velocities

``egocentric`` -- for agent ``i``, in its heading frame (rotated by minus its yaw about z,
origin at its torso):

    self_height (1), self_orientation (4, quaternion w x y z), self_joint_position (8),
    self_velocity (3), self_angular_velocity (3, torso frame), self_joint_velocity (8),
    edge_distance (1, half_size - max(|x|, |y|), negative once out),
    <other>_position (3) and <other>_velocity (3) relative to the agent, for each partner
    then each opponent in roster order,
    contact_force (13 * 3, the agent's own geoms, heading frame, clipped).

``observation_structure(mode)`` gives the ordered block sizes.
"""

from __future__ import annotations

import numpy as np

from triplesumo.rules.teams import Teams
from triplesumo.sim.physics import Simulation


def yaw_of(quat: np.ndarray) -> np.ndarray:
    """Heading angle about z of ``(..., 4)`` quaternions (w, x, y, z)."""
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class ObservationBuilder:
    """Builds every agent's observation from a :class:`Simulation`."""

    def __init__(self, sim: Simulation, teams: Teams, mode: str, half_size: float, force_clip: float) -> None:
        self.sim, self.teams, self.mode = sim, teams, mode
        self.half_size, self.force_clip = half_size, force_clip
        names = sim.agent_names
        self.others = tuple(
            np.concatenate([teams.partners[i], teams.opponents[i]]).astype(int) for i in range(sim.n_agents)
        )
        self.structure: dict[str, dict[str, int]] = {}
        for i, name in enumerate(names):
            if mode == "paper":
                n, g = sim.n_agents, len(sim.agent_geoms)
                s = {"torso_position": 3 * n, "torso_velocity": 3 * n, "contact_force": 3 * g,
                     "qpos": sim.model.nq, "qvel": sim.model.nv}
            else:
                s = {"self_height": 1, "self_orientation": 4, "self_joint_position": 8, "self_velocity": 3,
                     "self_angular_velocity": 3, "self_joint_velocity": 8, "edge_distance": 1}
                for j in self.others[i]:
                    s[f"{names[j]}_position"] = 3
                    s[f"{names[j]}_velocity"] = 3
                s["contact_force"] = 3 * sim.geoms_per_agent
            self.structure[name] = s
        self.sizes = {name: sum(s.values()) for name, s in self.structure.items()}

    def global_state(self) -> np.ndarray:
        """The ``paper`` vector (float32): the match's global state."""
        sim, data = self.sim, self.sim.data
        forces = sim.contact_forces()
        np.clip(forces, -self.force_clip, self.force_clip, out=forces)
        return np.concatenate([sim.torso_positions().ravel(), sim.torso_velocities().ravel(), forces.ravel(),
                               data.qpos, data.qvel], dtype=np.float32)

    def build(self) -> list[np.ndarray]:
        """float32 observation of every agent, roster order."""
        sim = self.sim
        if self.mode == "paper":
            obs = self.global_state()
            return [obs] + [obs.copy() for _ in range(sim.n_agents - 1)]
        forces = np.clip(sim.contact_forces(), -self.force_clip, self.force_clip)
        pos, vel = sim.torso_positions(), sim.torso_velocities()
        quat = sim.torso_quaternions()
        yaw = yaw_of(quat)
        angvel = sim.torso_angular_velocities()
        g = sim.geoms_per_agent
        out = []
        for i, a in enumerate(sim.agents):
            c, s_ = np.cos(yaw[i]), np.sin(yaw[i])
            rot = np.array([[c, s_, 0.0], [-s_, c, 0.0], [0.0, 0.0, 1.0]])  # world -> heading frame
            o = self.others[i]
            rel_pos = (pos[o] - pos[i]) @ rot.T
            rel_vel = (vel[o] - vel[i]) @ rot.T
            others = np.concatenate([rel_pos, rel_vel], axis=1).ravel()
            edge = self.half_size - np.max(np.abs(pos[i, :2]))
            out.append(np.concatenate([
                pos[i, 2:3], quat[i], sim.data.qpos[a.joint_qpos], rot @ vel[i], angvel[i],
                sim.data.qvel[a.joint_qvel], [edge], others, (forces[i * g:(i + 1) * g] @ rot.T).ravel(),
            ]).astype(np.float32))
        return out
