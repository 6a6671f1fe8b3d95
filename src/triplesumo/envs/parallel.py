"""The PettingZoo view of a match: a native ``ParallelEnv``."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from triplesumo.envs.match import Match
from triplesumo.envs.viewing import RENDER_MODES, MatchAccess, MatchView
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.scenarios import get_scenario, scenarios_doc
from triplesumo.version import ENV_VERSION


class TripleSumoParallelEnv(MatchAccess, ParallelEnv):
    """TripleSumo: three quadrupeds on a sumo ring, Ant and Bug against Spider.

    ## Description
    A reimplementation of the three-agent sumo game of Wang, Das and Millard, *Learning
    cooperative behaviours in adversarial multi-agent systems* (TAROS 2022), built on
    OpenAI's RoboSumo. Three identical four-legged MuJoCo bodies start on a raised square
    ring (the *tatami*, playable half-size 2) and push each other off it.

    ## Agents
    ``ant`` (red, team), ``bug`` (blue, team) and ``spider`` (green, alone). Motor control
    ranges: Spider +-0.22, Ant +-0.20, Bug +-0.18 (read from the compiled model). Other
    rosters (free-for-all, M-vs-1) are ``MatchConfig.agents``.

    ## Action Space
    ``Box(-1, 1, (8,), float32)`` per agent: hip and ankle torques of the four legs (order
    hip_1, ankle_1, ..., hip_4, ankle_4), scaled linearly to the agent's control range.
    With ``AgentSpec.body`` an agent may be RoboSumo's bug (6 legs, 12 values) or spider
    (8 legs, 16 values) instead (``triplesumo.model.BODIES_AGENTS``: the paper's match with
    Ant, Bug and Spider bodies).
    Finite values beyond +-1 are clipped. NaN or inf raises ``ValueError`` naming the
    agent; wrong shapes, missing or unknown agents raise ``ValueError`` saying what was
    expected. Actions are copied.

    ## Observation Space
    ``Box(-inf, inf, (n,), float32)`` per agent. ``obs_mode="paper"`` (default, n = 222):
    torso positions (9) and velocities (9) of the three agents, the world-frame contact
    force on each of the 39 agent geoms summed over all its contacts (117, clipped to
    +-100 N), all qpos (45) and qvel (42); the same vector for every agent.
    ``obs_mode="egocentric"`` (n = 79): the agent's own body state (its orientation in its
    heading frame), the other agents' torso positions and velocities in its heading frame,
    its distance to the ring edge and its contact forces (rotated into the heading frame,
    then clipped to +-100 N). Blocks and sizes: ``env.observation_structure[agent]``; details in
    :mod:`triplesumo.rules.observations`.

    ## Rewards
    Every agent gets the paper's hybrid reward from its side's point of view,
    ``dense + sparse``, reported term by term in ``info[agent]`` (the reward is their exact
    sum):

    - ``reward_opponent_velocity = C1 * mean_o sum_{k=x,y} sign(p_o,k - p_i,k) * v_o,k``
      (positive when the opponent moves away)
    - ``reward_self_velocity = C2 * mean_o sum_k sign(p_o,k - p_i,k) * v_i,k``
      (positive when the agent moves toward the opponent)
    - ``reward_partner_velocity = C3 * mean_j mean_o sum_k sign(p_o,k - p_j,k) * v_j,k``
      over partners ``j`` (Spider has none: 0)
    - ``reward_still``: the still punishment, a negative constant every step
    - ``reward_outcome``: +500 win, -400 loss, 0 draw, on the final step

    Means are over opponents ``o`` (Spider has two: Ant and Bug; ``RewardConfig.opponents="sum"``
    sums over them instead). Each ``sign`` (per axis ``k``)
    counts 0 where the two torsos' ``k`` coordinates differ by at most
    ``RewardConfig.axis_dead_zone`` metres (default 0: the paper's sign). Defaults C1 = C2 = C3 = 5,
    still -4 (the paper's code); see :class:`triplesumo.rules.RewardConfig`. ``info`` also
    has ``dense_reward``, ``sparse_reward``, ``outcome`` (an int code for the agent's side:
    0 while playing, 1 win, 2 loss, 3 draw, 4 physics error;
    ``triplesumo.rules.outcome.OUTCOME_CODES`` / ``outcome_name``), ``out_of_ring`` (bool:
    is this agent out) and ``step``. Infos have the same keys and numeric types at reset
    and at every step, so tensor-based clients (TorchRL) can stack them.

    ## Starting State
    The fair layout (env v2, ``PhysicsConfig.layout="fair"``): every torso starts
    ``start_edge`` (1.0 m) from its nearest edge of the ring and as far from the edge behind
    it. Up to four agents stand on the ring's diagonals (Ant at (-1, -1), Bug at (1, 1),
    Spider at (1, -1)), facing the centre turned by one common angle so that no leg rests on
    the rim; rosters that fit no fair start (five or six agents, or some custom rosters of
    mixed bodies) keep the circle below
    (:mod:`triplesumo.model.layout`). Torso at height 1.25 so they drop onto the tatami.
    Seeded noise (``ResetNoise(position=0.02, yaw=0.05)``): uniform +-0.02 m on x and y,
    +-0.05 rad on yaw, +-0.1 rad on every leg joint, Gaussian 0.1 on every qvel. Zero noise
    gives an identical start. v1's circle (``layout="circle"``, ``triplesumo.model.V1_PHYSICS``):
    agents evenly spaced on a circle of radius 1.4 around the centre (Ant at angle 0, Bug at
    120 degrees, Spider at 240), facing the centre, noise +-0.1 m on x and y and +-0.1 rad on yaw.

    ## Episode End
    Termination: on the step the torso centre (free-joint position, current after the
    step) of any agent leaves the ring (``max(|x|, |y|) > 2``). Spider out: the team wins;
    Ant or Bug out: Spider wins; both sides out in the same step: a draw. Truncation: the
    step limit (default 500) is reached, a draw; or MuJoCo reports a physics warning (bad
    qacc, full contact or constraint memory, non-finite state): outcome code 4 and
    ``env.unwrapped.match.physics_error`` says what happened (``on_physics_error="raise"``
    raises ``PhysicsError`` instead). All agents end together, and leave ``env.agents``; a
    ``step({})`` after that returns five empty dicts (as PettingZoo's own parallel envs do;
    SuperSuit's ``black_death_v3`` sends it), any other step says to ``reset()`` first.

    ## Arguments
    ``triplesumo.parallel_env(render_mode=None, **config)`` where ``config`` are fields of
    :class:`triplesumo.rules.MatchConfig` (``max_steps``, ``obs_mode``, ``reward``,
    ``physics``, ``reset_noise``, ``agents``, ``contact_force_clip``,
    ``on_physics_error``, ``rules``, ``evader``, ``evader_obs_noise``), plus ``width``/``height``
    of rendered frames. ``scenario`` (default ``"paper"``) picks a named game
    (``triplesumo.scenarios()``); the config fields and its roster sizes override it.
    ``info_level="outcome"`` keeps each info to ``outcome``, ``place`` and ``eliminated`` (TorchRL and
    RLlib users who do not read the reward terms: TorchRL copies every entry each step).

    ## Agents That Leave
    Under ``elimination`` rules (``ffa``, ``pursuit``) an agent out is terminated on that step
    with its placement reward and is absent from ``env.agents`` from the next step; ``step``
    then takes actions of the agents in play only. ``state()`` keeps its size: the ``paper``
    vector plus one flag per agent (1.0 once eliminated).

    ## Version History
    - v0: first release.
    - v0, fidelity fixes (the default ``paper`` observations and physics are unchanged, so the
      shipped zoo policies play exactly as before; no version bump):
      ``egocentric`` observations changed: ``self_orientation`` is the torso's quaternion in
      its heading frame (was the world-frame quaternion, although documented as heading
      frame), and contact forces are rotated into the heading frame before they are
      clipped (were clipped on world axes first, so components reached ~141 N).
      Policies trained on ``egocentric`` observations before this must be retrained.
      ``PhysicsConfig.border_rim`` added: ``border_rim=True`` is the paper's (and
      RoboSumo's) ring, whose four border cylinders form a solid 3 cm rim; the default
      stayed ``False`` (visual markers) until v1.
    - v1: the paper's ring by default (``PhysicsConfig.border_rim=True``: the border
      cylinders collide, a solid 3 cm rim that agents hit), and a zoo rebuilt on it with the
      paper's budgets (Ant 3,000 and Spider 20,000 epochs; ``triplesumo reproduce``). Ids and
      names end in ``-v1`` / ``_v1``; making a ``-v0`` id raises Gymnasium's ``DeprecatedEnv``.
      ``PhysicsConfig(border_rim=False)`` (``triplesumo.model.V0_PHYSICS``) is v0's
      simulation; the first self-play Spider (``docs/runs/zoo-history/spider-selfplay-v0``) was trained on it.
    - v2: a fair start and a rim both engines collide alike. Every torso starts as far from
      its nearest edge and from the edge behind it (``PhysicsConfig.layout="fair"``: up to four
      agents on the ring's diagonals, 1.0 m from two edges as in the paper's code, turned so
      that no leg rests on the rim; v1's circle of 1.4 m started the Ant 0.60 m from the edge
      behind it and the others 0.79 m from theirs). The rim is four boxes of the cylinders'
      height and width (``PhysicsConfig.rim_shape="box"``): MuJoCo Warp and MuJoCo part on a
      cylinder once legs touch it. The fair start's reset noise on torso positions and headings
      is ``ResetNoise(position=0.02, yaw=0.05)`` (v1's circle: 0.1 and 0.1) so that it keeps the
      agents' edge distances within 5 cm of each other (``MatchConfig.reset_noise`` left out is
      the layout's). Ids and names end in ``-v2`` / ``_v2``; making a ``-v1`` id raises
      Gymnasium's ``DeprecatedEnv`` naming the ``-v2`` id. ``triplesumo.model.V1_PHYSICS`` is
      v1's simulation, start and noise, on which the v1 zoo was trained.
    """

    metadata = {"render_modes": list(RENDER_MODES), "name": f"triplesumo_{ENV_VERSION}", "is_parallelizable": True,
                "render_fps": 20}

    def __init__(self, config: MatchConfig | None = None, render_mode: str | None = None,
                 width: int = 480, height: int = 480, scenario: str = "paper", info_level: str = "full") -> None:
        if info_level not in INFO_LEVELS:
            raise ValueError(f"info_level must be one of {list(INFO_LEVELS)}, got {info_level!r}")
        self.info_level = info_level
        self._info_keys = INFO_LEVELS[info_level]
        self.scenario = get_scenario(scenario).name
        self.match = Match(config)
        self.config = self.match.config
        self.render_mode = render_mode
        self.possible_agents = list(self.match.agents)
        self.agents: list[str] = []
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.match.sim.dt),
                         "name": get_scenario(scenario).pettingzoo_name}
        self._obs_spaces = {
            a: spaces.Box(-np.inf, np.inf, (self.match.observer.sizes[a],), np.float32)
            for a in self.possible_agents
        }
        self._act_spaces = {a: spaces.Box(-1.0, 1.0, (size,), np.float32)
                            for a, size in zip(self.possible_agents, self.match.action_sizes, strict=True)}
        n_state = len(self.match.state())
        self.state_space = spaces.Box(-np.inf, np.inf, (n_state,), np.float32)
        self.observation_structure = self.match.observer.structure
        self._view = MatchView(self.match, render_mode, width, height)

    def observation_space(self, agent: str) -> spaces.Box:
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self._act_spaces[agent]

    def reset(self, seed: int | None = None, options: dict | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        obs, infos = self.match.reset(seed=seed)
        self.agents = list(self.possible_agents)
        if self.render_mode == "human":
            self.render()
        return dict(zip(self.agents, obs, strict=True)), dict(zip(self.agents, map(self._lean, infos), strict=True))

    def _lean(self, info: dict[str, Any]) -> dict[str, Any]:
        """``info`` as the env's ``info_level`` reports it."""
        return info if self._info_keys is None else {k: info[k] for k in self._info_keys}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            if self.match.started and isinstance(actions, Mapping) and not actions:
                return {}, {}, {}, {}, {}  # no agent left to act (PettingZoo's parallel envs do the same)
            raise RuntimeError(self.match.why_not_playing())
        result = self.match.step_array(self.match.actions_from_dict(actions))
        names = self.agents
        if len(names) == self.match.n_agents:
            obs = dict(zip(names, result.observations, strict=True))
            rewards = dict(zip(names, result.rewards.tolist(), strict=True))
            infos = dict(zip(names, map(self._lean, result.infos), strict=True))
        else:  # some left on earlier steps
            index = [self.possible_agents.index(a) for a in names]
            obs = {a: result.observations[i] for a, i in zip(names, index, strict=True)}
            rewards = {a: float(result.rewards[i]) for a, i in zip(names, index, strict=True)}
            infos = {a: self._lean(result.infos[i]) for a, i in zip(names, index, strict=True)}
        terms = dict.fromkeys(names, result.terminated)
        truncs = dict.fromkeys(names, result.truncated)
        if result.eliminated is not None:  # out by the rules: terminated, even on the step the limit stops the rest
            for a, leaving in zip(self.possible_agents, result.eliminated, strict=True):
                if leaving:
                    terms[a], truncs[a] = True, False
        if result.terminated or result.truncated:
            self.agents = []
        elif result.eliminated is not None:
            self.agents = self.match.agents_in_play
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terms, truncs, infos

    def state(self) -> np.ndarray:
        """The global state: the ``paper`` observation vector (plus elimination flags under
        ``elimination`` rules)."""
        return self.match.state()

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """A frame in ``render_mode``; ``mode`` may only repeat it (RLlib passes one)."""
        return self._view.render(mode)

    def close(self) -> None:
        self._view.close()


TripleSumoParallelEnv.__doc__ = (TripleSumoParallelEnv.__doc__ or "") + "\n## Scenarios\n" + scenarios_doc()


def parallel_env(render_mode: str | None = None, width: int = 480, height: int = 480, scenario: str = "paper",
                 info_level: str = "full", **config: Any) -> TripleSumoParallelEnv:
    """Make the PettingZoo ``ParallelEnv`` of a named scenario (``triplesumo.scenarios()``);
    ``config`` are :class:`MatchConfig` fields or the scenario's roster sizes; ``info_level``
    (:data:`INFO_LEVELS`) how much each step's infos say."""
    return TripleSumoParallelEnv(get_scenario(scenario).config(**config), render_mode=render_mode, width=width,
                                 height=height, scenario=scenario, info_level=info_level)


INFO_LEVELS: dict[str, tuple[str, ...] | None] = {"full": None, "outcome": ("outcome", "place", "eliminated")}
"""What an agent's info holds: ``full`` (every reward term, the step, ring exits: what the docs and metrics
use) or ``outcome`` (the outcome code, place and elimination flag only). Clients that copy every info entry
each step into tensors (TorchRL's ``PettingZooWrapper`` clones about 36 per step) run faster on ``outcome``."""
