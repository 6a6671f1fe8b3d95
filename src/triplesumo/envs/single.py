"""The Gymnasium view: one learner acts, the other agents are driven by given policies."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from triplesumo.envs.match import Match
from triplesumo.envs.seeding import check_seed
from triplesumo.envs.viewing import RENDER_MODES, MatchAccess, MatchView
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.scenarios import resolve

Policy = Callable[[np.ndarray], np.ndarray]
"""Any callable from one observation to one normalised action in [-1, 1]^8. If it has a
``reset(seed)`` method, the env calls it at every reset with a seed derived from the
env's seed, so seeded episodes are reproducible."""


class TripleSumoEnv(MatchAccess, gym.Env):
    """TripleSumo seen by one learner (default Bug); the others follow fixed policies.

    ## Description
    The match of :class:`triplesumo.envs.parallel.TripleSumoParallelEnv` (read its
    docstring for the game, rewards and episode end), from one agent's seat: ``step``
    takes the learner's action, asks every other agent's policy for its action from its
    own observation, and returns the learner's observation, reward, termination,
    truncation and info.

    ## Action Space
    ``Box(-1, 1, (8,), float32)``, scaled to the learner's control range (Bug: +-0.18).

    ## Observation Space
    The learner's observation (``paper``: 222 floats; ``egocentric``: 79); layout in
    ``env.unwrapped.observation_structure``.

    ## Rewards
    The learner's hybrid reward; terms in ``info`` under ``reward_*`` keys.

    ## Episode End
    As the match: termination on a ring exit, truncation at the step limit (draw) or on a
    physics error. ``info["outcome"]`` is the learner's side's result as an int code
    (``triplesumo.rules.outcome.OUTCOME_CODES``: 0 playing, 1 win, 2 loss, 3 draw, 4 error).
    Under ``elimination`` rules the episode terminates when the learner is eliminated (with
    its placement reward) or the match ends; agents eliminated before it stop acting and
    their policies are no longer asked.

    ## Arguments
    ``scenario`` (``"paper"``; any of ``triplesumo.scenarios()``), ``learner`` (default: the
    scenario's, ``"bug"`` for the paper), ``policies`` (``{agent: callable}`` for the others; an agent
    without a policy is passive: zero action), ``render_mode`` (``"rgb_array"`` or
    ``"human"``), ``width``, ``height``, and any :class:`MatchConfig` field as a keyword.
    Registered ids: ``TripleSumo-v2`` (others passive unless given) and
    ``TripleSumo-Paper-v2`` (Ant and Spider from the shipped policy zoo), and one per other
    scenario with the others passive: ``TripleSumo-FFA-v2``, ``TripleSumo-Pursuit-v2``
    (learner: the evader), ``TripleSumo-2v2-v2``, ``TripleSumo-Bodies-v2``.

    ## Version History
    - v0: first release.
    - v0, fidelity fixes: ``egocentric`` observations changed and ``PhysicsConfig.border_rim``
      added (the paper's solid ring rim, off by default until v1); details in
      :class:`triplesumo.envs.parallel.TripleSumoParallelEnv`.
    - v1: the paper's solid ring rim by default, and the zoo rebuilt on it (details there).
    - v2: a fair start layout (every torso as far from the edges), a box rim that MuJoCo and
      MuJoCo Warp collide alike, and smaller position/heading reset noise (details there).
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 20}

    def __init__(self, learner: str | None = None, policies: Mapping[str, Policy] | None = None,
                 render_mode: str | None = None, width: int = 480, height: int = 480,
                 config: MatchConfig | None = None, scenario: str = "paper", **config_fields: Any) -> None:
        chosen, config, learner = resolve(scenario, config, learner, config_fields)
        self.scenario = chosen.name
        self.match = Match(config)
        if learner not in self.match.agents:
            raise ValueError(f"learner must be one of {list(self.match.agents)}, got {learner!r}")
        policies = dict(policies or {})
        unknown = [a for a in policies if a not in self.match.agents or a == learner]
        if unknown:
            raise ValueError(f"policies given for {unknown}, which are not non-learner agents "
                             f"of {list(self.match.agents)}")
        for name, policy in policies.items():
            if not callable(policy):
                raise ValueError(f"policy for {name!r} must be callable (observation -> action)")
        self.learner = learner
        self._learner_index = self.match.agents.index(learner)
        self.policies = policies
        self._others = [(i, a) for i, a in enumerate(self.match.agents) if a != learner]
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.match.sim.dt)}
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.match.observer.sizes[learner],), np.float32)
        size = self.match.action_sizes[self._learner_index]
        self.action_space = spaces.Box(-1.0, 1.0, (size,), np.float32)
        self.observation_structure = self.match.observer.structure[learner]
        self._obs: list[np.ndarray] = []
        self._view = MatchView(self.match, render_mode, width, height)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            seed = check_seed(seed)
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(2**63))
            self._np_random = np.random.default_rng(seed)
        children = np.random.SeedSequence(seed).spawn(len(self.policies) + 1)
        for child, policy in zip(children[1:], self.policies.values(), strict=True):
            reset = getattr(policy, "reset", None)
            if callable(reset):
                reset(seed=int(child.generate_state(1, np.uint64)[0]))
        self._obs, infos = self.match.reset(seed=seed)  # one seed, one start, whatever the view
        if self.render_mode == "human":
            self.render()
        return self._obs[self._learner_index], infos[self._learner_index]

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        if not self._obs:
            raise ResetNeeded("TripleSumoEnv.step called before reset(): call env.reset(seed=...) first")
        sizes = self.match.action_sizes
        actions = np.zeros((self.match.n_agents, self.match.action_width))
        actions[self._learner_index, :sizes[self._learner_index]] = self.match.check_action(self.learner, action)
        alive = self.match.alive
        for i, name in self._others:
            policy = self.policies.get(name)
            if policy is not None and alive[i]:
                actions[i, :sizes[i]] = self.match.check_action(name, policy(self._obs[i]))
        result = self.match.step_array(actions)
        self._obs = result.observations
        k = self._learner_index
        terminated = result.terminated or (result.eliminated is not None and result.eliminated[k])
        truncated = result.truncated and not terminated
        if self.render_mode == "human":
            self.render()
        return self._obs[k], float(result.rewards[k]), terminated, truncated, result.infos[k]

    def render(self) -> Any:  # an (height, width, 3) uint8 frame, or None (gymnasium's RenderFrame)
        return self._view.render()

    def close(self) -> None:
        self._view.close()
