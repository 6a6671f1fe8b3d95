"""Observations of a match, in two documented modes.

``paper`` -- the paper's global vector, identical for every agent:

    torso_position   (n_agents * 3)   torso centres, roster order
    torso_velocity   (n_agents * 3)   torso linear velocities, world frame
    contact_force    (n_agent_geoms * 3)  world-frame force on every agent geom, summed
                                       over all its contacts, clipped to +-contact_force_clip
    qpos             (nq)             all generalised positions
    qvel             (nv)             all generalised velocities

``egocentric`` -- for agent ``i``, in its heading frame (rotated by minus its yaw about z,
origin at its torso centre):

    self_height (1), self_orientation (4, quaternion w x y z of the torso in the heading
    frame: its roll and pitch only, w >= 0; an upright torso reads 1 0 0 0 whatever its
    yaw), self_joint_position (one per
    motor: 8 for an ant, 12 for a bug, 16 for a spider), self_velocity (3),
    self_angular_velocity (3, torso frame), self_joint_velocity (one per motor),
    edge_distance (1, half_size - max(|x|, |y|), negative once out),
    <other>_position (3) and <other>_velocity (3) relative to the agent, for each partner
    then each opponent in roster order,
    contact_force (3 per own geom: 13, 19 or 25 geoms; summed over the geom's contacts,
    rotated into the heading frame, then clipped to +-contact_force_clip).

``observation_structure(mode)`` gives the ordered block sizes.

Both modes are written once, over arrays of ``E`` matches in an array namespace ``xp``
(:func:`paper_observation`, :func:`egocentric_observation`): :class:`ObservationBuilder` calls them
for one match (``E = 1``, numpy), the CPU vector env for many, the MuJoCo Warp backend with torch.

Pursuit's "probabilistic observations": with an evader and ``sigma > 0``,
:meth:`ObservationBuilder.add_evader_noise` adds Gaussian noise to every entry of an
opponent's observation that holds the evader's torso position or velocity (``paper``: its
torso blocks and its free joint's first three qpos and qvel entries; ``egocentric``:
``<evader>_position`` and ``<evader>_velocity``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from triplesumo.rules.teams import Teams
from triplesumo.sim.physics import Simulation


def yaw_of(quat: Any, xp: Any) -> Any:
    """Heading angle about z of ``(..., 4)`` quaternions (w, x, y, z), in the namespace ``xp``
    (numpy for one match or many, torch on the MuJoCo Warp backend's device)."""
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    return xp.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def heading_quaternion(quat: Any, yaw: Any, xp: Any) -> Any:
    """``(..., 4)`` orientations ``quat`` (w, x, y, z, world frame) seen from the heading
    frame that is rotated by ``yaw`` about z: ``conj(q_yaw) * quat``, sign chosen so w >= 0.
    In the namespace ``xp``, as :func:`yaw_of`."""
    c, s = xp.cos(yaw / 2.0), xp.sin(yaw / 2.0)
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    q = xp.stack([c * w + s * z, c * x + s * y, c * y - s * x, c * z - s * w], axis=-1)
    return xp.where(q[..., :1] < 0.0, -q, q)


def clip(values: Any, limit: float, xp: Any) -> Any:
    """``values`` clipped to ``[-limit, limit]`` (a new array)."""
    if xp is np:  # np.clip's dispatch costs several times more than the two ufuncs, on every step of a match
        clipped = np.maximum(values, -limit)
        return np.minimum(clipped, limit, out=clipped)
    return xp.clip(values, -limit, limit)


def paper_observation(pos: Any, vel: Any, forces: Any, qpos: Any, qvel: Any, rules: Any, xp: Any) -> Any:
    """``(E, D)`` ``paper`` vector per match (the same for every agent): torso positions ``pos`` and velocities
    ``vel`` ``(E, n, 3)``, contact forces ``forces`` ``(E, n_agent_geoms, 3)`` clipped to
    ``+-rules.force_clip``, then ``qpos`` ``(E, nq)`` and ``qvel`` ``(E, nv)``; in the dtype of the inputs."""
    e = pos.shape[0]
    parts = [pos.reshape(e, -1), vel.reshape(e, -1), clip(forces, rules.force_clip, xp).reshape(e, -1), qpos, qvel]
    return xp.concat(parts, axis=1)


def heading_blocks(pos: Any, vel: Any, quat: Any, rules: Any, xp: Any) -> tuple[Any, Any, Any, Any, Any]:
    """The ``egocentric`` blocks every body shares, ``(E, n, ...)``: ``self_orientation``, ``self_velocity``,
    ``edge_distance``, the ``<other>_position``/``<other>_velocity`` pairs (``rules.others``' order), and
    ``rot_t`` ``(E, n, 3, 3)``, which turns a row vector of the world frame into each agent's heading frame."""
    e, n = pos.shape[0], pos.shape[1]
    yaw = yaw_of(quat, xp)
    c, s = xp.cos(yaw), xp.sin(yaw)
    zero, one = xp.zeros_like(c), xp.ones_like(c)
    rot = xp.stack([xp.stack([c, s, zero], axis=-1), xp.stack([-s, c, zero], axis=-1),
                    xp.stack([zero, zero, one], axis=-1)], axis=-2)  # (E, n, 3, 3): world -> heading
    rot_t = rot.swapaxes(-1, -2)
    others = rules.others
    rel_pos = (pos[:, others] - pos[:, :, None, :]) @ rot_t  # (E, n, n-1, 3)
    rel_vel = (vel[:, others] - vel[:, :, None, :]) @ rot_t
    edge = rules.half_size - xp.maximum(xp.abs(pos[..., 0]), xp.abs(pos[..., 1]))
    own_vel = (rot @ vel[..., None])[..., 0]
    rel = xp.concat([rel_pos, rel_vel], axis=-1).reshape(e, n, -1)
    return heading_quaternion(quat, yaw, xp), own_vel, edge[..., None], rel, rot_t


def egocentric_observation(pos: Any, vel: Any, quat: Any, angvel: Any, joint_pos: Any, joint_vel: Any,
                           forces: Any, rules: Any, xp: Any) -> Any:
    """``(E, n, D)`` ``egocentric`` observation of every agent, for rosters of one body kind.

    ``pos``, ``vel``, ``angvel``: ``(E, n, 3)``; ``quat``: ``(E, n, 4)``; ``joint_pos``,
    ``joint_vel``: ``(E, n, joints)``; ``forces``: ``(E, n, geoms_per_agent, 3)`` world frame, rotated
    into each agent's heading frame and then clipped. ``rules`` gives ``half_size``, ``force_clip`` and
    ``others`` (:class:`~triplesumo.rules.batched.BatchedRules`).
    """
    e, n = pos.shape[0], pos.shape[1]
    orientation, own_vel, edge, rel, rot_t = heading_blocks(pos, vel, quat, rules, xp)
    local_forces = clip(forces @ rot_t, rules.force_clip, xp)  # rotate, then clip
    parts = [pos[..., 2:3], orientation, joint_pos, own_vel, angvel, joint_vel, edge, rel,
             local_forces.reshape(e, n, -1)]
    return xp.concat(parts, axis=-1)


class ObservationBuilder:
    """Builds every agent's observation from a :class:`Simulation`."""

    def __init__(self, sim: Simulation, teams: Teams, mode: str, half_size: float, force_clip: float) -> None:
        self.sim, self.teams, self.mode = sim, teams, mode
        self.half_size, self.force_clip = half_size, force_clip
        names = sim.agent_names
        self.others = np.stack([np.concatenate([teams.partners[i], teams.opponents[i]]).astype(int)
                                for i in range(sim.n_agents)])
        """``(n, n - 1)``: for each agent, every other agent, partners first, then opponents."""
        self._others = self.others
        self._uniform = len(set(sim.action_sizes)) == 1 and len(set(sim.geom_counts)) == 1
        """Every agent has the same body size: one array op per block instead of one per agent."""
        self._joint_qpos = np.concatenate([a.joint_qpos for a in sim.agents])
        self._joint_qvel = np.concatenate([a.joint_qvel for a in sim.agents])
        self._joint_split = np.cumsum([len(a.joint_qpos) for a in sim.agents])[:-1]
        self._geom_split = np.cumsum(sim.geom_counts)[:-1]
        self.structure: dict[str, dict[str, int]] = {}
        for i, name in enumerate(names):
            if mode == "paper":
                n, g = sim.n_agents, len(sim.agent_geoms)
                s = {"torso_position": 3 * n, "torso_velocity": 3 * n, "contact_force": 3 * g,
                     "qpos": sim.model.nq, "qvel": sim.model.nv}
            else:
                joints = len(sim.agents[i].joint_qpos)
                s = {"self_height": 1, "self_orientation": 4, "self_joint_position": joints, "self_velocity": 3,
                     "self_angular_velocity": 3, "self_joint_velocity": joints, "edge_distance": 1}
                for j in self._others[i]:
                    s[f"{names[j]}_position"] = 3
                    s[f"{names[j]}_velocity"] = 3
                s["contact_force"] = 3 * sim.geom_counts[i]
            self.structure[name] = s
        self.sizes = {name: sum(s.values()) for name, s in self.structure.items()}
        self.evader_entries: dict[int, np.ndarray] = {}
        """Per opponent of the evader (set by :meth:`set_evader`): its observation's entries
        that hold the evader's torso position and velocity."""

    def set_evader(self, evader: int) -> None:
        """Mark agent ``evader``: :meth:`add_evader_noise` perturbs what its opponents see of it."""
        sim = self.sim
        self.evader_entries = {}
        for i in (int(o) for o in self.teams.opponents[evader]):
            s = self.structure[sim.agent_names[i]]
            if self.mode == "paper":
                n, g, a = sim.n_agents, len(sim.agent_geoms), sim.agents[evader]
                q0, v0 = 6 * n + 3 * g, 6 * n + 3 * g + sim.model.nq
                idx = [*range(3 * evader, 3 * evader + 3), *range(3 * n + 3 * evader, 3 * n + 3 * evader + 3),
                       *range(q0 + a.root_qpos, q0 + a.root_qpos + 3), *range(v0 + a.root_qvel, v0 + a.root_qvel + 3)]
            else:
                offsets, start = {}, 0
                for block, size in s.items():
                    offsets[block] = start
                    start += size
                evader_name = sim.agent_names[evader]
                p0, v0 = offsets[f"{evader_name}_position"], offsets[f"{evader_name}_velocity"]
                idx = [*range(p0, p0 + 3), *range(v0, v0 + 3)]
            self.evader_entries[i] = np.array(idx)

    def add_evader_noise(self, obs: list[np.ndarray], rng: np.random.Generator, sigma: float) -> None:
        """Add ``N(0, sigma)`` noise, drawn from ``rng``, in place to what each opponent sees of the evader."""
        for i, idx in self.evader_entries.items():
            obs[i][idx] += rng.normal(0.0, sigma, len(idx)).astype(np.float32)

    def global_state(self) -> np.ndarray:
        """The ``paper`` vector (float32): the match's global state."""
        sim, data = self.sim, self.sim.data
        return paper_observation(sim.torso_positions()[None], sim.torso_velocities()[None],
                                 sim.contact_forces()[None], data.qpos[None], data.qvel[None], self,
                                 np)[0].astype(np.float32)

    def build(self) -> list[np.ndarray]:
        """float32 observation of every agent, roster order."""
        sim = self.sim
        if self.mode == "paper":
            obs = self.global_state()
            return [obs] + [obs.copy() for _ in range(sim.n_agents - 1)]
        n, data = sim.n_agents, sim.data
        forces = sim.contact_forces()
        pos, vel, quat = sim.torso_positions()[None], sim.torso_velocities()[None], sim.torso_quaternions()[None]
        ang_vel = sim.torso_angular_velocities()
        if self._uniform:
            return list(egocentric_observation(
                pos, vel, quat, ang_vel[None], data.qpos[self._joint_qpos].reshape(1, n, -1),
                data.qvel[self._joint_qvel].reshape(1, n, -1), forces.reshape(1, n, -1, 3), self, np,
            )[0].astype(np.float32))
        # bodies of several kinds: the same blocks, joints and forces joined per agent
        orientation, own_vel, edge, rel, rot_t = (b[0] for b in heading_blocks(pos, vel, quat, self, np))
        qpos = np.split(data.qpos[self._joint_qpos], self._joint_split)
        qvel = np.split(data.qvel[self._joint_qvel], self._joint_split)
        own = [clip(f @ rot_t[i], self.force_clip, np) for i, f in enumerate(np.split(forces, self._geom_split))]
        return [np.concatenate([pos[0, i, 2:3], orientation[i], qpos[i], own_vel[i], ang_vel[i], qvel[i],
                                edge[i], rel[i], own[i].ravel()], dtype=np.float32) for i in range(n)]
