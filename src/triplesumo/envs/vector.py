"""The Gymnasium vector view: one learner in each of many matches, stepped together.

``gym.make_vec("TripleSumo-Paper-v2", num_envs=N)`` reaches :class:`TripleSumoVectorEnv`
through the ids' ``vector_entry_point``: no subprocesses, the physics of the ``N``
matches on MuJoCo's threads (:class:`~triplesumo.envs.batch.VectorMatches`), the other
agents' fixed policies called once per step on all ``N`` observations.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from triplesumo.envs.batch import VectorMatches
from triplesumo.envs.match import real_array
from triplesumo.envs.seeding import check_seed, match_seeds
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.scenarios import resolve

BatchPolicy = Callable[[np.ndarray], np.ndarray]
"""A fixed policy for the vector view: ``(n, obs_dim)`` observations to ``(n, 8)`` actions
in [-1, 1] (the zoo's policies and trained actors take batches)."""


class TripleSumoVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` matches of :class:`~triplesumo.envs.single.TripleSumoEnv`, as one
    ``gymnasium.vector.VectorEnv``.

    Each slot plays exactly the game of ``TripleSumoEnv`` (same learner, fixed policies,
    observation, reward, info keys and episode end), and seeds alike: ``reset(seed=s)``
    seeds slot ``k`` as ``TripleSumoEnv.reset(seed=s + k)`` (Gymnasium's convention for
    vector envs), and every autoreset as ``TripleSumoEnv.reset()`` does; so a seeded run
    equals ``gym.make_vec(id, N, vectorization_mode="sync",
    vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})`` step for step, at any
    thread count, and slot ``k`` does not depend on ``N``. (A policy's own ``reset(seed)``
    is not called: fixed policies here are deterministic batch callables.)

    Autoreset: ``SAME_STEP``. On a step where slot ``k`` ends, ``obs[k]`` is the first
    observation of its next match, ``infos["final_obs"][k]`` the last one of the finished
    match, ``infos["final_info"]`` that match's info (``outcome``, terms, ``step``), and
    the top-level info of slot ``k`` the new match's reset info; ``_key`` arrays mark the
    rows that hold a value, as in Gymnasium's ``SyncVectorEnv``.

    Arguments: ``num_envs``, ``learner`` (``"bug"``), ``policies`` (``{agent: BatchPolicy}``;
    an agent without one is passive), ``num_threads`` (MuJoCo threads; default one per
    usable CPU), and :class:`MatchConfig` fields as keywords or ``config=``.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, learner: str | None = None,
                 policies: Mapping[str, BatchPolicy] | None = None, num_threads: int | None = None,
                 config: MatchConfig | None = None, render_mode: str | None = None, scenario: str = "paper",
                 **config_fields: Any) -> None:
        if render_mode is not None:
            raise ValueError(f"the vector view does not render (render_mode={render_mode!r}); render one "
                             "match with gym.make(id, render_mode='rgb_array')")
        _, config, learner = resolve(scenario, config, learner, config_fields)
        if config.rules == "elimination":
            raise ValueError(f"scenario {scenario!r}: the single-learner vector view plays first-out rules only "
                             "(a learner eliminated mid-match would need its slot reset while the match goes "
                             "on); use gym.make(id) per match, or triplesumo.vector_env for every agent")
        self.matches = VectorMatches(num_envs, config, num_threads)
        self.matches.reset_seed = self._autoreset_seed  # autoresets draw seeds as TripleSumoEnv.reset() does
        agents = self.matches.agents
        if learner not in agents:
            self.matches.close()
            raise ValueError(f"learner must be one of {list(agents)}, got {learner!r}")
        policies = dict(policies or {})
        unknown_agents = [a for a in policies if a not in agents or a == learner]
        if unknown_agents:
            self.matches.close()
            raise ValueError(f"policies given for {unknown_agents}, which are not non-learner agents of {list(agents)}")
        self.learner = learner
        self.policies = policies
        self._learner_index = agents.index(learner)
        self._driven = [(agents.index(a), a, p) for a, p in policies.items()]
        self.num_envs = num_envs
        self.render_mode = None
        self.autoreset_mode = AutoresetMode.SAME_STEP  # read as an attribute by Gymnasium >= 1.1 clients (TorchRL)
        self.single_observation_space = self.matches.single_observation_space
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.matches.action_sizes[self._learner_index],), np.float32)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.matches.matches[0].sim.dt)}
        self._env_rngs: list[np.random.Generator | None] = [None] * num_envs
        self._obs = np.zeros((num_envs, self.matches.n_agents, self.matches.obs_dim), np.float32)

    def _autoreset_seed(self, k: int) -> int:
        """Seed of slot ``k``'s next match at an autoreset (``VectorMatches.reset_seed``)."""
        return self._match_seed(k, None)

    def _match_seed(self, k: int, seed: int | None) -> int:
        """Slot ``k``'s match seed for ``TripleSumoEnv.reset(seed=seed)`` (its seed chain)."""
        rng = self._env_rngs[k]
        if seed is None:
            if rng is None:
                rng = np.random.default_rng()
            seed = int(rng.integers(2**63))
        self._env_rngs[k] = np.random.default_rng(seed)
        return seed

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, Sequence) and not isinstance(seed, str):
            if len(seed) != self.num_envs:
                raise ValueError(f"seed must be an int, None or a list of {self.num_envs} seeds, got {seed!r}")
            seeds = [None if s is None else check_seed(s) for s in seed]
        else:
            seeds = [*match_seeds(seed, self.num_envs)]  # seed + k, checked
        self._obs, infos = self.matches.reset([self._match_seed(k, s) for k, s in enumerate(seeds)])
        return self._obs[:, self._learner_index].copy(), self._learner_infos(infos, None)

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        sizes, L = self.matches.action_sizes, self._learner_index
        expected = (self.num_envs, sizes[L])
        act = real_array(actions, f"actions of {self.learner!r}", f"real numbers of shape {expected}", copy=False)
        if act.shape != expected:
            raise ValueError(f"actions must have shape ({self.num_envs}, {sizes[L]}), got {act.shape}")
        full = np.zeros((self.num_envs, self.matches.n_agents, self.matches.act_dim))
        full[:, L, :sizes[L]] = act
        for i, name, policy in self._driven:
            driven = real_array(policy(self._obs[:, i]), f"policy of {name!r}: its actions",
                                f"real numbers of shape ({self.num_envs}, {sizes[i]})", copy=False)
            if driven.shape != (self.num_envs, sizes[i]):
                raise ValueError(f"policy of {name!r} must map ({self.num_envs}, obs_dim) observations to "
                                 f"({self.num_envs}, {sizes[i]}) actions, got {driven.shape}")
            full[:, i, :sizes[i]] = driven
        self._obs, _, terminated, truncated, infos = self.matches.step(full)
        L = self._learner_index
        reward = infos["dense_reward"][:, L] + infos["sparse_reward"][:, L]  # float64, as TripleSumoEnv's
        return (self._obs[:, L].copy(), reward, terminated[:, L], truncated[:, L],
                self._learner_infos(infos, infos["_final_obs"]))

    def _learner_infos(self, infos: dict[str, np.ndarray], ended: np.ndarray | None) -> dict[str, Any]:
        """The learner's columns in Gymnasium's vector-info layout (``_key`` masks)."""
        L, n = self._learner_index, self.num_envs
        every = np.ones(n, bool)
        steps = infos["step"]
        own = {key: value[:, L] for key, value in infos.items() if value.ndim == 2 and key != "final_obs"}
        out: dict[str, Any] = {}
        for key, value in own.items():
            out[key], out[f"_{key}"] = value, every
        out["step"], out["_step"] = steps, every
        if ended is not None and ended.any():
            final_obs = np.full(n, None, dtype=object)
            for k in np.flatnonzero(ended):
                final_obs[k] = infos["final_obs"][k, L].copy()
            final_info = {key: np.where(ended, out[key], 0).astype(out[key].dtype) for key in (*own, "step")}
            final_info.update({f"_{key}": ended.copy() for key in (*own, "step")})
            for key in (*own, "step"):  # the slots that reset show the new match's reset info
                out[key] = np.where(ended, 0, out[key]).astype(out[key].dtype)
            out["final_obs"], out["_final_obs"] = final_obs, ended.copy()
            out["final_info"], out["_final_info"] = final_info, ended.copy()
        return out

    def close_extras(self, **kwargs: Any) -> None:
        matches = getattr(self, "matches", None)  # absent when __init__ refused its arguments
        if matches is not None:
            matches.close()
