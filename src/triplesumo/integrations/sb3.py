"""Stable-Baselines3 on TripleSumo's batched path: a ``VecEnv`` with no subprocesses.

:class:`TripleSumoVecEnv` presents :class:`~triplesumo.envs.vector.TripleSumoVectorEnv`
(``gym.make_vec``'s native TripleSumo vector env: ``N`` matches whose physics MuJoCo
steps together on its threads, the fixed opponents acting on all ``N`` at once) as an
SB3 ``VecEnv``, so PPO, SAC, TD3 and DDPG train on many matches in one process::

    from stable_baselines3 import PPO
    from triplesumo.integrations.sb3 import make_vec_env

    env = make_vec_env("TripleSumo-Paper-v2", n_envs=8)  # also sets one torch thread (threads=1)
    PPO("MlpPolicy", env).learn(10_000)

SB3's conventions: when match ``k`` ends, the returned observation is already its next
match's first, ``infos[k]["terminal_observation"]`` the last one,
``infos[k]["TimeLimit.truncated"]`` says a truncation without termination, and
``infos[k]["episode"]`` (``r`` return, ``l`` length, ``t`` seconds, as SB3's ``Monitor``
writes it) feeds SB3's ``ep_rew_mean``/``ep_len_mean`` logs. Each info also has the
finished match's ``outcome`` code (``triplesumo.rules.outcome.OUTCOME_CODES``) and
reward terms. Needs the ``sb3`` extra (``pip install "triplesumo[sb3]"``).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from triplesumo.envs.vector import TripleSumoVectorEnv
from triplesumo.integrations._threads import DEFAULT_THREADS, set_torch_threads
from triplesumo.registration import PAPER_ID


class TripleSumoVecEnv(VecEnv):
    """An SB3 ``VecEnv`` over a :class:`TripleSumoVectorEnv` (see the module docstring)."""

    def __init__(self, vector_env: TripleSumoVectorEnv) -> None:
        if not isinstance(vector_env, TripleSumoVectorEnv):
            raise ValueError(f"vector_env must be a TripleSumoVectorEnv (gym.make_vec(...).unwrapped), "
                             f"got {type(vector_env).__name__}")
        self.vector_env = vector_env
        super().__init__(vector_env.num_envs, vector_env.single_observation_space,
                         vector_env.single_action_space)
        self._actions: np.ndarray | None = None
        self._returns = np.zeros(self.num_envs)
        self._lengths = np.zeros(self.num_envs, np.int64)
        self._t0 = time.time()

    def reset(self) -> np.ndarray:
        seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
        obs, infos = self.vector_env.reset(seed=seeds)
        self.reset_infos = [_row(infos, k) for k in range(self.num_envs)]
        self._returns[:] = 0.0
        self._lengths[:] = 0
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async(actions)")
        obs, rewards, terminated, truncated, infos = self.vector_env.step(self._actions)
        self._actions = None
        self._returns += rewards
        self._lengths += 1
        dones = terminated | truncated
        ended = infos.get("_final_obs", np.zeros(self.num_envs, bool))
        out = []
        for k in range(self.num_envs):
            if dones[k]:
                info = _row(infos["final_info"], k)
                info["terminal_observation"] = infos["final_obs"][k]
                info["TimeLimit.truncated"] = bool(truncated[k] and not terminated[k])
                info["episode"] = {"r": float(self._returns[k]), "l": int(self._lengths[k]),
                                   "t": round(time.time() - self._t0, 6)}
                self.reset_infos[k] = _row(infos, k)
                self._returns[k], self._lengths[k] = 0.0, 0
            else:
                info = _row(infos, k)
            out.append(info)
        assert bool((dones == ended).all()), "every ended match must carry its final observation"
        return obs, rewards.astype(np.float32), dones, out

    def close(self) -> None:
        self.vector_env.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs

    # The matches are one object, not num_envs envs: attributes are the vector env's.
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.vector_env, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.vector_env, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        method = getattr(self.vector_env, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]


def _row(infos: dict[str, Any], k: int) -> dict[str, Any]:
    """Env ``k``'s info from Gymnasium's vector-info layout (keys whose ``_key`` mask holds)."""
    return {key: value[k].item() if isinstance(value[k], np.generic) else value[k]
            for key, value in infos.items()
            if not key.startswith("_") and key not in ("final_obs", "final_info") and infos[f"_{key}"][k]}


def make_vec_env(env_id: str = PAPER_ID, n_envs: int = 1, seed: int | None = None,
                 threads: int | None = DEFAULT_THREADS,
                 **kwargs: Any) -> TripleSumoVecEnv:
    """``gym.make_vec(env_id, n_envs, **kwargs)`` as an SB3 ``VecEnv`` (``seed`` seeds the first reset).

    ``threads``: torch's intra-op threads in this process (``torch.set_num_threads``), set here because SB3 trains in
    the process that builds its env: 1 by default, since SB3's PPO and SAC ran several times slower on a 2-core box
    with torch's default (one thread per core, which stall whenever another process holds a core); ``None`` leaves
    torch's setting as it is.
    """
    set_torch_threads(threads, "threads")
    vector = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", **kwargs)
    env = TripleSumoVecEnv(vector.unwrapped)
    if seed is not None:
        env.seed(seed)
    return env
