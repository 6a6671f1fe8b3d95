"""The rules of :mod:`triplesumo.rules` over arrays of many matches at once.

Every function takes arrays shaped ``(num_envs, n_agents, ...)`` and an array namespace
``xp`` -- ``numpy`` or ``torch`` (this module never imports torch) -- and uses only what
both spell alike (``abs``, ``sign``, ``where``, ``maximum`` of two arrays, ``clip``, ``@``, and the
methods ``sum``, ``any``, ``all``, ``reshape``,
``swapaxes``; ``concat`` and ``stack`` with ``axis``). The batched backends (MuJoCo Warp on a GPU)
call them with ``torch`` on the device; ``tests/test_batched_rules.py`` holds them equal,
on numpy, to the per-match rules that :class:`~triplesumo.envs.match.Match` uses
(:mod:`.outcome`, :mod:`.rewards`, :mod:`.observations`), so the two never drift apart
unnoticed. Rules that need no roster matrices are written once, over ``xp``, in the per-match
modules and used from here: :func:`~.outcome.first_out_places`, :func:`~.observations.yaw_of`,
:func:`~.observations.heading_quaternion`.

Outcomes are integer codes per agent, :data:`~triplesumo.rules.outcome.OUTCOME_CODES`:
0 the match goes on, 1 win, 2 loss, 3 draw, 4 physics error.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from triplesumo.rules.config import MatchConfig
from triplesumo.rules.observations import heading_quaternion as heading_quaternion
from triplesumo.rules.observations import yaw_of as yaw_of
from triplesumo.rules.outcome import DRAW_CODE as DRAW_CODE
from triplesumo.rules.outcome import ERROR_CODE as ERROR_CODE
from triplesumo.rules.outcome import LOSS_CODE as LOSS_CODE
from triplesumo.rules.outcome import PLAYING
from triplesumo.rules.outcome import WIN_CODE as WIN_CODE
from triplesumo.rules.outcome import first_out_places as first_out_places
from triplesumo.rules.rewards import TERMS
from triplesumo.rules.teams import Teams

GOES_ON = PLAYING
"""Code of a match that goes on (``OUTCOME_CODES["playing"]``)."""
MAX_VALUE = 1e10
"""A state entry beyond this (or NaN) is bad, as MuJoCo's ``mju_isBad`` (``mjMAXVAL``) judges it."""


@dataclass(frozen=True)
class BatchedRules:
    """The game of one :class:`MatchConfig`, as small constant matrices over the roster.

    Built once on the host (numpy, float64); :meth:`to` copies the matrices into another
    namespace (e.g. torch on a device) for the functions below.
    """

    n_agents: int
    half_size: float
    max_steps: int
    force_clip: float
    team_onehot: Any
    """``(n_agents, n_teams)`` 1.0 where agent ``i`` plays for team ``t``."""
    opponents: Any
    """``(n_agents, n_agents)`` 1.0 where ``j`` is an opponent of ``i`` (row ``i``)."""
    partners: Any
    """``(n_agents, n_agents)`` 1.0 where ``j`` is a partner of ``i`` (row ``i``)."""
    n_opponents: Any
    """``(n_agents,)`` how many opponents each agent has (at least one in a valid roster): the divisor of the
    per-opponent sums, 1 with ``RewardConfig.opponents="sum"``."""
    n_partners: Any
    """``(n_agents,)`` how many partners, or 1 where there are none (the partner term is 0 then)."""
    others: Any
    """``(n_agents, n_agents - 1)`` integer: each agent's partners, then opponents, roster order
    (the order of the ``egocentric`` observation's blocks)."""
    weights: tuple[float, float, float, float]
    """C1, C2, C3 and the still punishment."""
    outcome_values: tuple[float, float, float]
    """Sparse reward of a win, a loss and a draw."""
    outcome_table: Any
    """``(5,)`` the sparse reward of each outcome code (0 for a match that goes on, and for an error)."""
    axis_dead_zone: float = 0.0
    """``RewardConfig.axis_dead_zone``: a per-axis direction within it counts as 0."""

    @classmethod
    def build(cls, config: MatchConfig, half_size: float) -> BatchedRules:
        teams = Teams.from_agents(config.agents)
        n = len(config.agents)
        onehot = np.zeros((n, len(teams.names)))
        onehot[np.arange(n), teams.team_of] = 1.0
        opponents, partners = np.zeros((n, n)), np.zeros((n, n))
        for i in range(n):
            opponents[i, teams.opponents[i]] = 1.0
            partners[i, teams.partners[i]] = 1.0
        others = np.stack([np.concatenate([teams.partners[i], teams.opponents[i]]) for i in range(n)]).astype(np.int64)
        r = config.reward
        table = np.zeros(max(GOES_ON, WIN_CODE, LOSS_CODE, DRAW_CODE, ERROR_CODE) + 1)
        table[[WIN_CODE, LOSS_CODE, DRAW_CODE]] = r.win, r.loss, r.draw
        return cls(n, float(half_size), config.max_steps, float(config.contact_force_clip), onehot, opponents,
                   partners, opponents.sum(1) if r.opponents == "mean" else np.ones(n),
                   np.maximum(partners.sum(1), 1.0), others,
                   (float(r.opponent_velocity), float(r.self_velocity), float(r.partner_velocity), float(r.still)),
                   (float(r.win), float(r.loss), float(r.draw)), table, float(r.axis_dead_zone))

    def to(self, convert: Any) -> BatchedRules:
        """The same rules with every matrix passed through ``convert`` (e.g. ``lambda a: torch.as_tensor(a, ...)``)."""
        return BatchedRules(self.n_agents, self.half_size, self.max_steps, self.force_clip,
                            convert(self.team_onehot), convert(self.opponents), convert(self.partners),
                            convert(self.n_opponents), convert(self.n_partners), convert(self.others),
                            self.weights, self.outcome_values, convert(self.outcome_table), self.axis_dead_zone)


# ------------------------------------------------------------------ outcome
def agents_out(pos: Any, half_size: float, xp: Any) -> Any:
    """``(E, n)`` bool: whose torso centre (``pos[..., :2]``) is outside the ring."""
    return xp.maximum(xp.abs(pos[..., 0]), xp.abs(pos[..., 1])) > half_size


def judge(out: Any, rules: BatchedRules, xp: Any) -> Any:
    """``(E, n)`` outcome code of every agent: :func:`triplesumo.rules.outcome.judge` per match.

    Nobody out: 0. Every team with an agent out loses, the others win; every team out: draw.
    """
    onehot = rules.team_onehot
    losing = (xp.where(out, 1.0, 0.0) @ onehot) > 0  # (E, T): the team has an agent out
    agent_lost = (xp.where(losing, 1.0, 0.0) @ onehot.T) > 0  # (E, n)
    code = xp.where(agent_lost, LOSS_CODE, WIN_CODE)
    code = xp.where(losing.all(-1)[:, None], DRAW_CODE, code)
    return xp.where(out.any(-1)[:, None], code, GOES_ON)


def bad_state(xp: Any, *arrays: Any) -> Any:
    """``(E,)`` bool: a match whose ``(E, k)`` state arrays hold NaN, inf or entries beyond :data:`MAX_VALUE`.

    The batched counterpart of MuJoCo's bad-qpos/qvel/qacc warnings and the CPU path's
    ``non_finite_state`` check (a NaN compares False, hence the ``~(... <= ...)``).
    """
    bad = None
    for a in arrays:
        b = (~(xp.abs(a) <= MAX_VALUE)).any(-1)
        bad = b if bad is None else bad | b
    return bad


# ------------------------------------------------------------------ rewards
def ordered_sum(values: Any, axis: int) -> Any:
    """Sum over ``axis`` (a small one: the roster) index by index, ``((v_0 + v_1) + v_2) + ...``.

    The association of :class:`~triplesumo.rules.rewards.RewardRule`'s Python loops, so that
    masked sums (zeros where an agent is not an opponent or partner; adding an exact zero
    changes nothing) give its results bit for bit, where ``sum`` or ``@`` may pair the terms
    in another order.
    """
    def at(j: int) -> tuple[Any, ...]:
        return (*(slice(None),) * axis, j) if axis >= 0 else (..., j, *(slice(None),) * (-axis - 1))

    total = values[at(0)]
    for j in range(1, values.shape[axis]):
        total = total + values[at(j)]
    return total


def reward_terms(pos: Any, vel: Any, code: Any, timed_out: Any, rules: BatchedRules, xp: Any) -> dict[str, Any]:
    """Every reward term of :data:`~triplesumo.rules.rewards.TERMS` as ``(E, n)`` arrays, plus
    ``dense_reward``, ``sparse_reward`` and ``reward`` (= dense + sparse, summed in that order,
    as :meth:`RewardRule.rows` does).

    ``pos``, ``vel``: ``(E, n, >=2)`` torso positions and world-frame velocities after the
    step; ``code``: :func:`judge`'s codes; ``timed_out``: ``(E,)`` the step limit is reached.
    In float64 the results equal :meth:`RewardRule.rows` bit for bit (the same operations
    in the same order: :func:`ordered_sum`).
    """
    c1, c2, c3, still = rules.weights
    xy, v = pos[..., :2], vel[..., :2]
    d = xy[:, None] - xy[:, :, None]  # (E, a, o, 2): from a to o
    s = xp.sign(d)  # the direction from a to o, per axis
    if rules.axis_dead_zone > 0:  # 0 inside the band (at 0 the paper's sign, untouched)
        s = xp.where(abs(d) > rules.axis_dead_zone, s, 0.0 * s)
    toward = (s * v[:, :, None]).sum(-1)  # (E, a, o): a moving toward o (a sum of two: exact in any order)
    away = (s * v[:, None]).sum(-1)  # (E, a, o): o moving away from a
    opp = rules.opponents
    opponent = c1 * (ordered_sum(away * opp, -1) / rules.n_opponents)
    # [e, j, i] = sum over the opponents o of i of toward[e, j, o], over i's opponents' count
    per_partner = ordered_sum(toward[:, :, None, :] * opp, -1) / rules.n_opponents
    roster = list(range(rules.n_agents))
    self_ = c2 * per_partner[:, roster, roster]
    partner = c3 * (ordered_sum(per_partner * rules.partners.T, 1) / rules.n_partners)
    sparse = rules.outcome_table[xp.where(timed_out[:, None] & (code == GOES_ON), DRAW_CODE, code)]
    dense = opponent + self_ + partner + still
    terms = dict(zip(TERMS, (opponent, self_, partner, xp.zeros_like(opponent) + still, sparse), strict=True))
    return {**terms, "dense_reward": dense, "sparse_reward": sparse, "reward": dense + sparse}


# ------------------------------------------------------------- observations
def clip(values: Any, limit: float, xp: Any) -> Any:
    return xp.clip(values, -limit, limit)


def paper_observation(pos: Any, vel: Any, forces: Any, qpos: Any, qvel: Any, rules: BatchedRules, xp: Any) -> Any:
    """``(E, D)`` float32 ``paper`` vector per match (the same for every agent): torso positions,
    torso velocities, clipped contact forces ``(E, n_agent_geoms, 3)``, qpos, qvel.

    :meth:`ObservationBuilder.global_state` per match.
    """
    e = pos.shape[0]
    parts = [pos.reshape(e, -1), vel.reshape(e, -1), clip(forces, rules.force_clip, xp).reshape(e, -1), qpos, qvel]
    return xp.concat(parts, axis=1)


def egocentric_observation(pos: Any, vel: Any, quat: Any, angvel: Any, joint_pos: Any, joint_vel: Any,
                           forces: Any, rules: BatchedRules, xp: Any) -> Any:
    """``(E, n, D)`` ``egocentric`` observation of every agent (:meth:`ObservationBuilder.build`).

    ``pos``, ``vel``, ``angvel``: ``(E, n, 3)``; ``quat``: ``(E, n, 4)``; ``joint_pos``,
    ``joint_vel``: ``(E, n, 8)``; ``forces``: ``(E, n, geoms_per_agent, 3)`` world frame, rotated
    into each agent's heading frame and then clipped.
    """
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
    local_forces = clip(forces @ rot_t, rules.force_clip, xp)  # rotate, then clip
    parts = [pos[..., 2:3], heading_quaternion(quat, yaw, xp), joint_pos, own_vel, angvel, joint_vel, edge[..., None],
             xp.concat([rel_pos, rel_vel], axis=-1).reshape(e, n, -1),
             local_forces.reshape(e, n, -1)]
    return xp.concat(parts, axis=-1)
