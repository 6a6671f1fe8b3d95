"""RLlib on TripleSumo: multi-agent envs, frozen-policy modules and ``AlgorithmConfig`` factories.

Works on RLlib's current API stack (RLModules, Learners, EnvRunners; Ray 2.54 to 2.x).
Needs the ``ray`` extra: ``pip install "triplesumo[ray]"``; ``import triplesumo`` never
imports Ray.

- :class:`TripleSumoMultiAgentEnv` is one match as an RLlib multi-agent env (around the
  PettingZoo env), built from an ``env_config`` holding :class:`~triplesumo.rules.MatchConfig`
  field overrides or a whole config under ``"match_config"``, and optionally ``"fixed"``:
  agents that act inside the env with the project's numpy policies, unseen by RLlib;
  :func:`register_envs` registers every scenario by name (``"triplesumo_paper_v2"``, ...) and every
  Gymnasium id (``"TripleSumo-Paper-v2"``, ...), so that remote env runners find them.
- :func:`make_config` returns an ``AlgorithmConfig`` (PPO by default) with one RLModule per
  agent (module ids = agent names) or per team (``share="team"``: module ids = team labels),
  the policy-mapping function, ``policies_to_train``, the project's observation and action
  spaces, :data:`ENVS_PER_RUNNER` matches per env runner, and :class:`OutcomeCallback` so
  that results carry win/loss/draw rates. Frozen modules' agents act inside the env
  (``frozen_in_env=True``, the default), so RLlib's modules and episodes hold the learners only.
- :class:`FrozenPolicyModule` plays any project policy (``"zoo:ant"``, a policy file,
  ``"zero"``, ``"random"``) as a deterministic RLlib module that never learns
  (``make_config(..., frozen_in_env=False)``).

Example (the paper's setup: Bug learns, the zoo's Ant and Spider are frozen)::

    import ray
    from triplesumo.integrations.rllib import make_config

    ray.init()
    config = make_config("paper", policies_to_train=["bug"],
                         frozen={"ant": "zoo:ant", "spider": "zoo:spider"})
    algo = config.build_algo()
    result = algo.train()
    result["env_runners"]["outcomes"]["bug"]["win"]   # Bug's win rate over recent episodes
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Collection, Mapping
from typing import Any

import gymnasium as gym
import numpy as np

try:
    from ray.rllib.algorithms.algorithm_config import AlgorithmConfig
    from ray.rllib.callbacks.callbacks import RLlibCallback
    from ray.rllib.core.columns import Columns
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec
    from ray.rllib.core.rl_module.torch.torch_rl_module import TorchRLModule
    from ray.rllib.env.multi_agent_env import MultiAgentEnv
    from ray.rllib.policy.policy import PolicySpec
    from ray.tune.registry import get_trainable_cls, register_env
except ImportError as exc:  # pragma: no cover - exercised in a subprocess test
    raise ImportError(
        "triplesumo.integrations.rllib needs Ray RLlib, which is not installed: "
        'pip install "triplesumo[ray]"'
    ) from exc

import torch

from triplesumo.agents.builtin import BUILTIN, act_batch
from triplesumo.agents.networks import ActorPolicy
from triplesumo.agents.policy_file import load_fixed_policy
from triplesumo.agents.zoo import find_policy_file, make_policy
from triplesumo.envs.parallel import TripleSumoParallelEnv
from triplesumo.integrations._threads import DEFAULT_THREADS, set_torch_threads
from triplesumo.registration import ENV_IDS
from triplesumo.rules.config import MatchConfig, check_shared_network
from triplesumo.rules.outcome import PLAYING, outcome_name
from triplesumo.rules.scenarios import scenario_config as named_scenario_config
from triplesumo.rules.scenarios import scenarios
from triplesumo.version import ENV_VERSION

__all__ = ["ENVS_PER_RUNNER", "OUTCOMES", "SCENARIOS", "SHARE_MODES", "FrozenPolicyModule", "OutcomeCallback",
           "TripleSumoMultiAgentEnv", "env_id", "fixed_policies", "make_config", "make_env", "make_gym_env",
           "match_config_from", "module_of_agent", "register_envs", "scenario_config"]

SCENARIOS: tuple[str, ...] = scenarios()
"""Named scenarios (``triplesumo.scenarios()``); each is registered as ``triplesumo_{name}_v2`` by
:func:`register_envs`."""
SHARE_MODES = (None, "team")
"""``share`` values of :func:`make_config`: one module per agent, or one per team."""
OUTCOMES = ("win", "loss", "draw", "error")
"""Outcomes of a match from an agent's side (``info[agent]["outcome"]`` on the last step)."""


# ----------------------------------------------------------------------------- envs
def scenario_config(scenario: str | MatchConfig = "paper", **overrides: Any) -> MatchConfig:
    """The :class:`MatchConfig` of a named scenario (or a given config) with field overrides."""
    if isinstance(scenario, MatchConfig):
        known = {f.name for f in dataclasses.fields(MatchConfig)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown MatchConfig field(s) {unknown}; known: {sorted(known)}")
        return dataclasses.replace(scenario, **overrides)
    if scenario not in SCENARIOS:
        raise _unknown_scenario(scenario)
    return named_scenario_config(scenario, **overrides)


def _unknown_scenario(scenario: object) -> ValueError:
    """The error for a scenario name RLlib's side does not know; a Gymnasium id gets its RLlib names."""
    if scenario in ENV_IDS:
        return ValueError(
            f"scenario: {scenario!r} is a Gymnasium id (the single-agent view), not a scenario; scenarios: "
            f"{list(SCENARIOS)}. Give RLlib the id with its module, 'triplesumo:{scenario}', or call register_envs() "
            "first (it registers the Gymnasium ids and the multi-agent names 'triplesumo_<scenario>_"
            f"{ENV_VERSION}' with Tune), else RLlib's remote env runners, which have not imported triplesumo, "
            "do not know it")
    return ValueError(f"scenario: unknown scenario {scenario!r}; known: {list(SCENARIOS)} (or pass a MatchConfig)")


def env_id(scenario: str) -> str:
    """RLlib env name of a scenario, e.g. ``"triplesumo_paper_v2"``."""
    if scenario not in SCENARIOS:
        raise _unknown_scenario(scenario)
    return f"triplesumo_{scenario}_{ENV_VERSION}"


def match_config_from(env_config: Mapping[str, Any] | None = None, scenario: str = "paper") -> MatchConfig:
    """The match an ``env_config`` asks for.

    ``env_config`` is either ``{"match_config": MatchConfig}`` (as :func:`make_config` sets
    it) or an optional ``"scenario"`` name (default ``scenario``) plus :class:`MatchConfig`
    field overrides (``{"max_steps": 200}``).
    """
    cfg = dict(env_config or {})
    match_config = cfg.pop("match_config", None)
    if match_config is None:
        return scenario_config(cfg.pop("scenario", scenario), **cfg)
    if cfg:
        raise ValueError(f"env_config: give either 'match_config' or scenario and field overrides, "
                         f"not both ({sorted(cfg)})")
    if not isinstance(match_config, MatchConfig):
        raise ValueError(f"env_config['match_config'] must be a MatchConfig, got {type(match_config).__name__}")
    return match_config


class TripleSumoMultiAgentEnv(MultiAgentEnv):
    """One TripleSumo match as an RLlib ``MultiAgentEnv`` around
    :class:`~triplesumo.envs.parallel.TripleSumoParallelEnv` (``env.par_env``).

    Built from an ``env_config`` (see :func:`match_config_from`), so RLlib can make it in
    any process from the class alone (remote env runners, restored checkpoints) without
    a registry entry. Two more entries:

    - ``"info_level"``: ``"full"`` (default) or ``"outcome"`` (infos hold only ``outcome``,
      ``place`` and ``eliminated``), as ``TripleSumoParallelEnv``'s.
    - ``"fixed"``: agent -> policy spec (``"zoo:ant"``, a policy file, ``"zero"``/``"passive"``,
      ``"random"``). These agents act inside the env, each from its own observation, with the
      project's numpy policy (trained ones as :func:`~triplesumo.agents.policy_file.load_fixed_policy`
      loads them, the way the Gymnasium ids play the zoo); RLlib never sees them: its observation,
      reward, termination and info dicts, and so its episodes and modules, hold the other agents
      only. The outcome of every agent of the match is still reported: on the step that ends the
      episode each RLlib agent's info gets ``"outcomes"`` (agent -> outcome code, the last one the
      match gave it). The episode ends with the match, or (elimination rules) once no RLlib agent
      is left in play, as the Gymnasium view does for its learner. ``reset(seed=s)`` reseeds the
      fixed ``"random"`` policies from ``s``.

    Without ``"fixed"`` every agent is RLlib's, as in RLlib's ``ParallelPettingZooEnv``.
    """

    def __init__(self, env_config: Mapping[str, Any] | None = None) -> None:
        super().__init__()
        cfg = dict(env_config or {})
        info_level = cfg.pop("info_level", "full")
        fixed = cfg.pop("fixed", None) or {}
        self.par_env = TripleSumoParallelEnv(match_config_from(cfg), info_level=info_level)
        self.fixed: dict[str, Any] = fixed_policies(self.par_env, fixed)
        """The agents that act inside the env: agent -> numpy policy (``obs -> action``)."""
        self._rllib_agents = [a for a in self.par_env.possible_agents if a not in self.fixed]
        self._in_play = list(self._rllib_agents)
        self.possible_agents = list(self._rllib_agents)
        self.agents = list(self._rllib_agents)
        obs_spaces: dict[str, gym.Space] = {a: self.par_env.observation_space(a) for a in self._rllib_agents}
        act_spaces: dict[str, gym.Space] = {a: self.par_env.action_space(a) for a in self._rllib_agents}
        self.observation_spaces, self.action_spaces = dict(obs_spaces), dict(act_spaces)  # type: ignore[assignment]
        self.observation_space = gym.spaces.Dict(obs_spaces)
        self.action_space = gym.spaces.Dict(act_spaces)
        self._fixed_obs: dict[str, np.ndarray] = {}
        self._codes: dict[str, int] = {}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if seed is not None and self.fixed:
            children = np.random.SeedSequence(seed).spawn(len(self.fixed))
            for child, policy in zip(children, self.fixed.values(), strict=True):
                reset = getattr(policy, "reset", None)
                if callable(reset):
                    reset(seed=int(child.generate_state(1, np.uint64)[0]))
        obs, infos = self.par_env.reset(seed=seed, options=options)
        self._in_play = list(self._rllib_agents)
        self.agents = list(self._in_play)
        if not self.fixed:
            return obs, infos
        self._fixed_obs = {a: obs[a] for a in self.fixed}
        self._codes = {}
        return {a: obs[a] for a in self._in_play}, {a: infos[a] for a in self._in_play}

    def step(self, action_dict: dict[Any, Any]) -> tuple[dict, dict, dict, dict, dict]:  # type: ignore[override]
        if not self.fixed:
            obs, rewards, terms, truncs, infos = self.par_env.step(action_dict)
            terms["__all__"] = all(terms.values())
            truncs["__all__"] = all(truncs.values())
            return obs, rewards, terms, truncs, infos
        actions = dict(action_dict)
        for agent, policy in self.fixed.items():
            if agent in self._fixed_obs:  # in play
                actions[agent] = policy(self._fixed_obs[agent])
        obs, rewards, terms, truncs, infos = self.par_env.step(actions)
        self._fixed_obs = {a: obs[a] for a in self.fixed if a in self.par_env.agents}  # those still in play
        for agent, info in infos.items():
            self._codes[agent] = int(info["outcome"])
        mine = [a for a in self._in_play if a in obs]
        self._in_play = [a for a in mine if a in self.par_env.agents]
        self.agents = list(self._in_play)
        over = not self._in_play  # the match ended, or every RLlib agent has left it
        obs, rewards = {a: obs[a] for a in mine}, {a: rewards[a] for a in mine}
        terms, truncs = {a: terms[a] for a in mine}, {a: truncs[a] for a in mine}
        infos = {a: infos[a] for a in mine}
        if over:
            for agent in mine:
                infos[agent] = {**infos[agent], "outcomes": dict(self._codes)}
        truncs["__all__"] = over and all(truncs.values())
        terms["__all__"] = over and not truncs["__all__"]
        return obs, rewards, terms, truncs, infos

    def close(self) -> None:
        self.par_env.close()

    def render(self) -> Any:
        return self.par_env.render()

    @property
    def get_sub_environments(self) -> TripleSumoParallelEnv:
        return self.par_env


def fixed_policies(env: TripleSumoParallelEnv, fixed: Mapping[str, str]) -> dict[str, Any]:
    """The numpy policies of the env's ``fixed`` agents (agent -> spec), checked against the match:
    errors name the ``fixed`` entry (an unknown agent, every agent fixed, a spec that is not a string,
    an unknown policy, a policy file made for other observations)."""
    if not isinstance(fixed, Mapping):
        raise ValueError(f"fixed must map agent names to policy specs, got {type(fixed).__name__}")
    agents = env.possible_agents
    unknown = sorted(set(fixed) - set(agents))
    if unknown:
        raise ValueError(f"fixed: unknown agent(s) {unknown}; the match's agents are {agents}")
    if set(fixed) == set(agents):
        raise ValueError(f"fixed: every agent {agents} would act inside the env; leave at least one to RLlib")
    out: dict[str, Any] = {}
    for agent, spec in fixed.items():
        if not isinstance(spec, str):
            raise ValueError(f"fixed[{agent!r}] must be a policy spec string ('zoo:NAME', a policy file, "
                             f"{sorted(BUILTIN)}), got {spec!r}")
        size = int(env.action_space(agent).shape[0])
        if spec in BUILTIN:
            out[agent] = make_policy(spec, seed=0, action_size=size)
            continue
        obs_dim = int(env.observation_space(agent).shape[0])
        try:
            out[agent] = load_fixed_policy(find_policy_file(spec), expect_obs_mode=env.config.obs_mode,
                                           expect_obs_dim=obs_dim)[0]
        except (ValueError, FileNotFoundError) as exc:
            raise type(exc)(f"fixed[{agent!r}]: {exc}") from exc
    return out


def make_env(env_config: Mapping[str, Any] | None = None, scenario: str = "paper") -> TripleSumoMultiAgentEnv:
    """An RLlib multi-agent env of one match of ``scenario`` (see :func:`match_config_from`); an ``info_level``
    entry (``"full"``, ``"outcome"``) sets how much its infos say (``TripleSumoParallelEnv``), a ``fixed`` entry
    (agent -> policy spec) which agents act inside the env (:class:`TripleSumoMultiAgentEnv`)."""
    cfg = dict(env_config or {})
    extra: dict[str, Any] = {key: cfg.pop(key) for key in ("info_level", "fixed") if key in cfg}
    return TripleSumoMultiAgentEnv({"match_config": match_config_from(cfg, scenario), **extra})


def _creator(scenario: str) -> Any:
    def create(env_config: Mapping[str, Any]) -> TripleSumoMultiAgentEnv:
        return make_env(env_config, scenario=scenario)

    return create


def make_gym_env(env_config: Mapping[str, Any], gym_id: str) -> gym.Env:
    """``gym.make(gym_id, **env_config)``: a Gymnasium id of TripleSumo as Tune's env creator. Being a function of
    this module, it imports triplesumo (which registers the Gymnasium ids) in the process that calls it."""
    return gym.make(gym_id, **dict(env_config))


def register_envs() -> list[str]:
    """Register every scenario and every Gymnasium id by name with RLlib (Tune's env registry); returns the names.

    For hand-written configs: ``PPOConfig().environment("triplesumo_paper_v2")`` (the multi-agent env of a scenario,
    :func:`make_env`) or ``PPOConfig().environment("TripleSumo-Paper-v2")`` (the Gymnasium id, single-agent: Bug
    learns). An RLlib env runner in another process has not imported triplesumo, so Gymnasium does not know the
    ids there (unless given with the module, ``"triplesumo:TripleSumo-Paper-v2"``); Tune's registry reaches every
    process. :func:`make_config` passes the env class itself, which needs no registry.
    """
    names = []
    for scenario in SCENARIOS:
        register_env(env_id(scenario), _creator(scenario))
        names.append(env_id(scenario))
    for gym_id in ENV_IDS:
        register_env(gym_id, functools.partial(make_gym_env, gym_id=gym_id))
        names.append(gym_id)
    return names


# ----------------------------------------------------------------------------- modules
class FrozenPolicyModule(TorchRLModule):
    """A project policy as an RLlib module that never learns and never explores.

    ``model_config``: ``policy`` is a policy spec of :func:`triplesumo.zoo.make_policy`
    (``"zoo:ant"``, a policy-file path, ``"zero"``/``"passive"``, ``"random"``); ``obs_mode``
    (optional) is checked against the policy file's; ``seed`` seeds ``"random"``. A trained
    actor acts deterministically (the same action in exploration and inference) and is held
    as the ``actor`` sub-network (its weights are the module's state); the module's
    output is the action itself (``Columns.ACTIONS``), so RLlib samples nothing. Keep the
    module out of ``policies_to_train``: its training forward pass raises.
    """

    def setup(self) -> None:
        cfg: dict[str, Any] = dict(self.model_config or {})  # type: ignore[arg-type]
        if "policy" not in cfg:
            raise ValueError("FrozenPolicyModule: model_config needs 'policy' (e.g. 'zoo:ant', 'zero')")
        self.policy = make_policy(str(cfg["policy"]), seed=int(cfg.get("seed", 0)),
                                  expect_obs_mode=cfg.get("obs_mode"))
        expected = getattr(self.policy, "obs_dim", None)
        shape = getattr(self.observation_space, "shape", None)
        size = int(np.prod(shape)) if shape is not None else None
        if expected is not None and size is not None and expected != size:
            raise ValueError(f"FrozenPolicyModule: policy {cfg['policy']!r} expects {expected} observation "
                             f"values, the module's observation space has {size}")
        if isinstance(self.policy, ActorPolicy):
            self.actor = self.policy.actor
            self.actor.requires_grad_(False)

    def _forward(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        obs = batch[Columns.OBS]
        obs_np = obs.detach().cpu().numpy() if isinstance(obs, torch.Tensor) else np.asarray(obs)
        actions = act_batch(self.policy, obs_np.astype(np.float32, copy=False))
        return {Columns.ACTIONS: torch.as_tensor(actions, dtype=torch.float32)}

    def _forward_train(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        raise NotImplementedError("FrozenPolicyModule never learns: leave it out of policies_to_train")


# ----------------------------------------------------------------------------- metrics
class OutcomeCallback(RLlibCallback):
    """Logs each agent's match outcome at episode end.

    Results get ``result["env_runners"]["outcomes"][agent][o]`` for ``o`` in
    :data:`OUTCOMES`: the fraction of recent episodes (window 100) that ended so for that
    agent's side, read from ``info[agent]["outcome"]`` on the last step, and for the agents that
    act inside the env (``fixed``) from the ``"outcomes"`` the env adds to that last info.
    """

    window = 100

    def on_episode_end(self, *, episode: Any, metrics_logger: Any = None, **kwargs: Any) -> None:
        if metrics_logger is None:
            return
        codes: dict[str, Any] = {}
        for agent, info in episode.get_infos(-1).items():
            if isinstance(info, Mapping):
                codes.update(info.get("outcomes", {}))
                codes[agent] = info.get("outcome")
        for agent, code in codes.items():
            if code is None or int(code) == PLAYING:  # the episode was cut (not ended by the game)
                continue
            outcome = outcome_name(int(code))
            for kind in OUTCOMES:
                metrics_logger.log_value(("outcomes", agent, kind), float(outcome == kind),
                                         reduce="mean", window=self.window)


# ----------------------------------------------------------------------------- config
def module_of_agent(config: MatchConfig, share: str | None = None) -> dict[str, str]:
    """Module id of every agent: its name, or with ``share="team"`` its team label."""
    if share not in SHARE_MODES:
        raise ValueError(f"share must be one of {list(SHARE_MODES)}, got {share!r}")
    return {a.name: (a.team if share == "team" else a.name) for a in config.agents}


class _PolicyMapping:
    """``policy_mapping_fn``: agent id -> module id (a picklable lookup)."""

    def __init__(self, modules: Mapping[str, str]) -> None:
        self.modules = dict(modules)

    def __call__(self, agent_id: str, episode: Any = None, **kwargs: Any) -> str:
        return self.modules[agent_id]


ENVS_PER_RUNNER = 4
"""Matches each env runner plays at once (RLlib's ``num_envs_per_env_runner``) in :func:`make_config`'s
configs: RLlib then runs its connectors and modules on batches of this many observations per step."""


def make_config(scenario: str | MatchConfig = "paper", policies_to_train: Collection[str] | None = None,
                algo: str = "PPO", share: str | None = None, frozen: Mapping[str, str] | None = None,
                frozen_in_env: bool = True, threads: int | None = DEFAULT_THREADS, **overrides: Any) -> AlgorithmConfig:
    """An RLlib ``AlgorithmConfig`` for a TripleSumo match, on the new API stack.

    Args:
        scenario: A name of :data:`SCENARIOS` or a :class:`MatchConfig`.
        policies_to_train: Module ids that learn; default: every module not in ``frozen``.
        algo: An RLlib algorithm name (``"PPO"``, ``"APPO"``, ...).
        share: ``None``: one module per agent (ids = agent names); ``"team"``: one per team
            (ids = team labels, e.g. ``"team"`` for Ant and Bug, ``"spider"``).
        frozen: Module id -> policy spec (``"zoo:ant"``, a policy-file path, ``"zero"``,
            ``"random"``) of the modules that never learn. Modules that are neither
            frozen nor trained are RLlib's default modules left as initialised.
        frozen_in_env: ``True`` (default): the frozen modules' agents act inside the env
            (its ``fixed`` entry) with the project's numpy policies, and RLlib's modules,
            multi-agent dicts and episodes hold only the other agents (several times the
            env steps/s of ``False`` per env runner: ``triplesumo bench rllib``); their
            outcomes are still reported. ``False``: every agent is RLlib's, the frozen ones
            played by :class:`FrozenPolicyModule` (the torch actor) as RLlib modules.
        threads: torch's intra-op threads in this process (``torch.set_num_threads``), set here: the driver
            holds the learner (RLlib's default ``num_learners=0``) and, with ``num_env_runners=0``, samples too.
            1 by default (torch's default of one thread per core stalls on a busy 2-core box; Ray's remote env
            runners start with ``OMP_NUM_THREADS=1``); ``None`` leaves torch's setting.
        **overrides: :class:`MatchConfig` fields (``max_steps=200``, ``obs_mode=...``).

    The env reports lean infos (``info_level="outcome"``: outcome, place, eliminated) and each
    env runner plays :data:`ENVS_PER_RUNNER` matches at once. The rest (batch sizes, learning
    rate, env runners, seeds) is set on the returned config the RLlib way:
    ``make_config(...).training(lr=1e-4).env_runners(num_env_runners=2)``.
    """
    match_config = scenario_config(scenario, **overrides)
    set_torch_threads(threads, "threads")
    modules = module_of_agent(match_config, share)
    module_ids = list(dict.fromkeys(modules.values()))
    frozen = dict(frozen or {})
    unknown = sorted(set(frozen) - set(module_ids))
    if unknown:
        raise ValueError(f"frozen: unknown module id(s) {unknown}; module ids are {module_ids}")
    if policies_to_train is None:
        train = [m for m in module_ids if m not in frozen]
    else:
        if isinstance(policies_to_train, str):
            raise ValueError(f"policies_to_train must be a collection of module ids, got the string "
                             f"{policies_to_train!r} (use [{policies_to_train!r}])")
        train = list(policies_to_train)
        unknown = sorted(set(train) - set(module_ids))
        if unknown:
            raise ValueError(f"policies_to_train: unknown module id(s) {unknown}; module ids are {module_ids}")
        both = sorted(set(train) & set(frozen))
        if both:
            raise ValueError(f"policies_to_train: module(s) {both} are also frozen")
    if not train:
        raise ValueError("policies_to_train: nothing would learn; name at least one module id")
    for module in module_ids:
        if frozen.get(module) not in BUILTIN:  # a built-in acts the same in every seat
            check_shared_network(match_config.obs_mode, [a for a, m in modules.items() if m == module],
                                 f"share={share!r} (module {module!r})")

    env_config: dict[str, Any] = {"match_config": match_config, "info_level": "outcome"}
    if frozen_in_env and frozen:
        env_config["fixed"] = {agent: frozen[m] for agent, m in modules.items() if m in frozen}
        modules = {agent: m for agent, m in modules.items() if m not in frozen}
        module_ids = [m for m in module_ids if m not in frozen]
    env = TripleSumoMultiAgentEnv(env_config)  # loads the fixed policies: a bad spec fails here
    try:
        spaces: dict[str, tuple[Any, Any]] = {}
        for agent, module in modules.items():
            pair = (env.par_env.observation_space(agent), env.par_env.action_space(agent))
            if module in spaces and spaces[module] != pair:
                raise ValueError(f"share={share!r}: agents mapped to module {module!r} have different spaces")
            spaces[module] = pair
    finally:
        env.close()

    specs: dict[str, RLModuleSpec] = {}
    for k, module in enumerate(module_ids):
        obs_space, act_space = spaces[module]
        if module in frozen:
            model_config = {"policy": frozen[module], "obs_mode": match_config.obs_mode, "seed": k}
            specs[module] = RLModuleSpec(module_class=FrozenPolicyModule, observation_space=obs_space,
                                         action_space=act_space, model_config=model_config)
            FrozenPolicyModule(observation_space=obs_space, action_space=act_space,  # fail early on a bad spec
                               inference_only=True, model_config=model_config)
        else:
            specs[module] = RLModuleSpec(observation_space=obs_space, action_space=act_space)

    try:
        algo_cls = get_trainable_cls(algo)
    except Exception as exc:  # Tune raises its own error types for unknown names
        raise ValueError(f"algo: unknown RLlib algorithm {algo!r} ({exc})") from exc
    config: AlgorithmConfig = (
        algo_cls.get_default_config()
        .api_stack(enable_rl_module_and_learner=True, enable_env_runner_and_connector_v2=True)
        .environment(env=TripleSumoMultiAgentEnv, env_config=env_config)
        .env_runners(num_envs_per_env_runner=ENVS_PER_RUNNER)
        # Spaces given per module: RLlib's own inference from an env failed intermittently
        # ("observation_space not provided in PolicySpec") for per-team modules.
        .multi_agent(policies={m: PolicySpec(observation_space=spaces[m][0], action_space=spaces[m][1])
                               for m in module_ids},
                     policy_mapping_fn=_PolicyMapping(modules),
                     policies_to_train=train)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs=specs))
        .callbacks(OutcomeCallback)
    )
    return config
