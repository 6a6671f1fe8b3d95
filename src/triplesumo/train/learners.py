"""The learners of a training run: which agents learn, with which algorithm, and how each
learner acts, stores what it saw and learns.

A :class:`Learner` drives one algorithm for one agent, or (``share="team"``) for all the
learning agents of a team, in every match of the batch: its *rows* are the ``n_envs x
len(agents)`` (match, agent) pairs, match-major. Off-policy learners (DDPG, TD3, SAC) store
their rows' transitions in their own replay buffer and run the updates
:meth:`~triplesumo.algos.offpolicy.OffPolicyAlgorithm.updates_due` says, in a thread beside
the physics (:meth:`OffPolicyLearner.run_updates`); PPO records its rows into its ``(T, rows)``
rollout and updates when the rollout is full (:meth:`PPOLearner.finish_step`). A row whose
agent is out of its match (elimination rules) stays out until the match is reset: it adds no
transition (PPO keeps it in the rollout's shape, marked invalid).

On a device-resident collection (``train --backend warp``) observations, actions, rewards and
flags arrive as torch tensors on the learner's ``device`` and stay there: the networks act on
them, the replay buffer (:class:`~triplesumo.algos.replay.TorchReplayBuffer`) and PPO's rollout
store them; only the random draws (warm-up actions, exploration noise, replay indices) come from
the host generators, which keeps their streams and checkpoints those of the CPU path.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from triplesumo.algos.base import Algorithm, DivergedError, not_finite
from triplesumo.algos.ddpg import DDPG
from triplesumo.algos.noise import ActionNoise, make_noise
from triplesumo.algos.offpolicy import OffPolicyAlgorithm
from triplesumo.algos.ppo import PPO
from triplesumo.algos.replay import FIELDS, ReplayBuffer, TorchReplayBuffer
from triplesumo.algos.sac import SAC
from triplesumo.algos.td3 import TD3
from triplesumo.rules.config import check_shared_network
from triplesumo.train.config import TrainConfig

ALGORITHMS: dict[str, type[Algorithm]] = {"ddpg": DDPG, "td3": TD3, "sac": SAC, "ppo": PPO}
"""``--learn AGENT=ALGO`` names -> learner classes (each configured by ``TrainConfig.<algo>``)."""


@dataclass(frozen=True)
class LearnerSpec:
    """One learner: its name (its agent's, or ``ant+bug`` for a shared team network), its
    algorithm and the agents it acts for, in roster order."""

    name: str
    algo: str
    agents: tuple[str, ...]


def learner_specs(cfg: TrainConfig, roster: tuple[str, ...] | list[str], teams: Mapping[str, str]) -> list[LearnerSpec]:
    """The learners of ``cfg`` in this roster (``teams``: agent -> team label).

    Raises ``ValueError`` naming the field: an unknown agent, or (``share="team"``) a team
    whose learning agents use different algorithms.
    """
    learning = cfg.learners()
    field = "TrainConfig.learn" if cfg.learn else "TrainConfig.learner"
    unknown = [a for a in learning if a not in roster]
    if unknown:
        raise ValueError(f"{field} names unknown agents {unknown}; agents are {list(roster)} "
                         f"(scenario {cfg.scenario!r})")
    if cfg.share == "none":  # (learner_config names only agents that learn here: checked by the config)
        return [LearnerSpec(agent, algo, (agent,)) for agent, algo in learning.items()]
    groups: dict[str, list[str]] = {}
    for agent in learning:
        groups.setdefault(teams[agent], []).append(agent)
    specs = []
    for team, members in groups.items():
        algos = sorted({learning[a] for a in members})
        if len(algos) > 1:
            raise ValueError(f"TrainConfig.share=team: the learning agents of team {team!r} use different algorithms "
                             f"({', '.join(f'{a}={learning[a]}' for a in members)}); a shared network needs one")
        ordered = tuple(a for a in roster if a in members)
        check_shared_network(cfg.obs_mode, ordered, f"TrainConfig.share=team (team {team!r})")
        specs.append(LearnerSpec("+".join(ordered), algos[0], ordered))
    named = sorted(set(cfg.learner_configs()) - {spec.name for spec in specs})
    if named:
        raise ValueError(f"TrainConfig.learner_config names {named}, not learners of this run; its learners are "
                         f"{[spec.name for spec in specs]}")
    return specs


class Learner:
    """One algorithm acting for ``spec.agents`` (match indices ``index``) in ``n_envs`` matches."""

    algo: Algorithm

    def __init__(self, spec: LearnerSpec, index: list[int], position: int, cfg: TrainConfig,
                 obs_dim: int, act_dim: int, device: torch.device | None = None) -> None:
        self.spec, self.name, self.index = spec, spec.name, index
        self.config: Any = cfg.algo_config(spec.name)
        self.device = device
        """Torch device of a device-resident collection (its inputs are tensors there); None: numpy."""
        self.algo = ALGORITHMS[spec.algo](obs_dim, act_dim, self.config, seed=cfg.seed + position,
                                          device=device or "cpu")
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.n_rows = cfg.n_envs * len(index)
        self.active = np.ones(self.n_rows, dtype=bool)
        """Rows still in their match (False once the agent is out, until the match is reset)."""
        self.collected = 0
        """Transitions this learner has collected (its rows in play, step after step)."""
        self.parameters = [(f"{owner}.{name}", p) for owner, module in vars(self.algo).items()
                           if isinstance(module, torch.nn.Module) for name, p in module.named_parameters()]
        """Every parameter of the learner's networks, checked to be finite after its updates."""
        self.last_stats: dict[str, float] = {}
        self._sums: dict[str, float] = {}
        self._counts: dict[str, int] = {}

    def rows_of(self, match: int) -> np.ndarray:
        """Mask of the rows that belong to match ``match``."""
        rows = np.zeros(self.n_rows, dtype=bool)
        rows[match * len(self.index):(match + 1) * len(self.index)] = True
        return rows

    def act(self, obs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Training actions ``(n_rows, act_dim)`` in [-1, 1] for observations ``(n_rows, obs_dim)``."""
        raise NotImplementedError

    def store(self, obs: Any, action: Any, reward: Any, next_obs: Any, terminated: Any, truncated: Any,
              valid: Any, played: np.ndarray) -> None:
        """Take the step of every row: ``played`` rows were in their match, ``valid`` ones are
        real steps (no physics error); ``terminated`` rows end without a bootstrap."""
        raise NotImplementedError

    def reset_rows(self, rows: np.ndarray) -> None:
        """The matches of ``rows`` were reset (e.g. restart their exploration noise)."""

    def add_stats(self, stats: dict[str, float]) -> None:
        self.last_stats = stats
        for key, value in stats.items():
            self._sums[key] = self._sums.get(key, 0.0) + value
            self._counts[key] = self._counts.get(key, 0) + 1

    def take_stats(self) -> dict[str, float]:
        """Means of the stats reported since the last call (for the learning CSV)."""
        means = {k: v / self._counts[k] for k, v in self._sums.items()}
        self._sums, self._counts = {}, {}
        return means

    def check_parameters(self) -> str | None:
        bad = not_finite(self.parameters)
        return f"its parameters are not finite: {bad[:4]}" if bad else None

    # ------------------------------------------------------------------ checkpoints
    def tensors(self) -> dict[str, torch.Tensor]:
        opt_tensors, _ = self.algo.optimizer_state()
        return {**self.algo.state_dict(), **{f"optim.{k}": v for k, v in opt_tensors.items()}}

    def state(self) -> dict[str, Any]:
        return {"optimizer": self.algo.optimizer_state()[1], "collected": self.collected,
                "stats": [self._sums, self._counts]}

    def arrays(self) -> dict[str, np.ndarray]:
        return {"active": self.active.copy()}

    def load(self, tensors: Mapping[str, torch.Tensor], state: Mapping[str, Any],
             arrays: Mapping[str, np.ndarray]) -> None:
        self.algo.load_state_dict({k: v for k, v in tensors.items() if not k.startswith("optim.")})
        self.algo.load_optimizer_state({k[6:]: v for k, v in tensors.items() if k.startswith("optim.")},
                                       state["optimizer"])
        self.collected = int(state["collected"])
        self._sums, self._counts = (dict(x) for x in state["stats"])
        self.active = np.asarray(arrays["active"], dtype=bool).copy()


class OffPolicyLearner(Learner):
    """DDPG, TD3 or SAC: random warm-up, exploration noise (or SAC's sampling), replay, updates."""

    algo: OffPolicyAlgorithm

    def __init__(self, spec: LearnerSpec, index: list[int], position: int, cfg: TrainConfig,
                 obs_dim: int, act_dim: int, device: torch.device | None = None) -> None:
        super().__init__(spec, index, position, cfg, obs_dim, act_dim, device)
        c = self.config
        self.replay = (ReplayBuffer(c.buffer_size, obs_dim, act_dim) if device is None
                       else TorchReplayBuffer(c.buffer_size, obs_dim, act_dim, device))
        self.noise: ActionNoise | None = None
        """The exploration noise process (DDPG, TD3); SAC samples its own policy."""
        if hasattr(c, "noise"):
            self.noise = make_noise(c.noise, (self.n_rows, act_dim), c.noise_sigma, c.noise_theta)
        self.sample_rng = np.random.default_rng([cfg.seed, 1 + position])
        """Replay sampling only (used by the update thread; never shared with collection)."""

    def act(self, obs: Any, rng: np.random.Generator) -> Any:
        self.algo.observe(obs)  # the running observation normaliser (a no-op at the paper preset)
        if self.collected < self.config.learning_starts:
            warm = rng.uniform(-1.0, 1.0, (self.n_rows, self.act_dim))  # warm-up
            return warm if self.device is None else self.algo.tensor(warm)
        if self.noise is None:
            action = self.algo.explore(obs, rng)
            if not _finite(action):
                raise DivergedError("its actions are not finite")
            return action
        raw = self.algo.act(obs)
        if not _finite(raw):
            raise DivergedError("its actions are not finite")
        if self.device is not None:
            return (raw + self.algo.tensor(self.noise.sample(rng))).clamp(-1.0, 1.0)
        return np.clip(raw + self.noise.sample(rng), -1.0, 1.0)

    def updates_due(self) -> int:
        """Updates due at this step: they read the replay as it is before the step."""
        return self.algo.updates_due(self.collected, self.collected + int(self.active.sum()), len(self.replay))

    def run_updates(self, due: int) -> None:
        """``due`` gradient updates on replay samples; ``DivergedError`` says what is not finite."""
        for _ in range(due):
            batch = self.replay.sample(self.config.batch_size, self.sample_rng)
            try:
                stats = self.algo.update(batch)
            except DivergedError as exc:  # the learner's own finite check of its update stats
                raise DivergedError(f"its losses are not finite ({exc})") from None
            bad = {k: v for k, v in stats.items() if not math.isfinite(v)}
            if bad:
                raise DivergedError(f"its losses are not finite: {bad}")
            self.add_stats(stats)
        if due and (problem := self.check_parameters()):
            raise DivergedError(problem)

    def store(self, obs: Any, action: Any, reward: Any, next_obs: Any, terminated: Any, truncated: Any,
              valid: Any, played: np.ndarray) -> None:
        """Store the rows that played this step (``played``) and are real steps (``valid``):
        done = terminated (a draw by time limit bootstraps)."""
        del truncated
        self.collected += int(played.sum())
        if self.device is not None:  # tensors on the device: the rows kept are gathered there
            keep_t = valid & torch.as_tensor(played, device=self.device)
            self.replay.add_batch(obs[keep_t], action[keep_t], reward[keep_t], next_obs[keep_t],
                                  terminated[keep_t].to(torch.float32))
            return
        keep = valid & played
        if keep.any():
            self.replay.add_batch(obs[keep], action[keep], reward[keep], next_obs[keep],
                                  terminated[keep].astype(np.float64))

    def reset_rows(self, rows: np.ndarray) -> None:
        if self.noise is not None:
            self.noise.reset(rows)

    def state(self) -> dict[str, Any]:
        return super().state() | {"sample_rng": self.sample_rng.bit_generator.state}

    def arrays(self) -> dict[str, np.ndarray]:
        noise = self.noise.state_dict() if self.noise is not None else {}
        return super().arrays() | {f"noise.{k}": v for k, v in noise.items()}

    def load(self, tensors: Mapping[str, torch.Tensor], state: Mapping[str, Any],
             arrays: Mapping[str, np.ndarray]) -> None:
        super().load(tensors, state, arrays)
        self.sample_rng.bit_generator.state = state["sample_rng"]
        if self.noise is not None:
            self.noise.load_state_dict({k[6:]: v for k, v in arrays.items() if k.startswith("noise.")})

    def load_replay(self, replay: Mapping[str, np.ndarray], prefix: str) -> None:
        absent = [k for k in (*FIELDS, "pos", "size", "capacity") if f"{prefix}{k}" not in replay]
        if absent:
            raise KeyError(f"replay arrays {[prefix + k for k in absent]}")
        self.replay.load_state_dict({k: replay[f"{prefix}{k}"] for k in (*FIELDS, "pos", "size", "capacity")})


class PPOLearner(Learner):
    """PPO: samples its policy, records ``(T, n_rows)`` rollouts, updates when one is full."""

    algo: PPO

    def act(self, obs: Any, rng: np.random.Generator) -> Any:
        self.algo.observe(obs)
        action = self.algo.explore(obs, rng)
        if not _finite(action):
            raise DivergedError("its actions are not finite")
        return action

    def store(self, obs: Any, action: Any, reward: Any, next_obs: Any, terminated: Any, truncated: Any,
              valid: Any, played: np.ndarray) -> None:
        """Record the step of every row; rows out of play or with a physics error are invalid."""
        del obs, action
        self.collected += int(played.sum())
        if self.device is not None:  # tensors on the device
            ok_t = valid & torch.as_tensor(played, device=self.device)
            self.algo.record(torch.where(ok_t, reward, 0.0), torch.where(ok_t, terminated, True),
                             torch.where(ok_t, truncated, False), next_obs, valid=ok_t)
            return
        ok = valid & played
        self.algo.record(np.where(ok, reward, 0.0), np.where(ok, terminated, True), np.where(ok, truncated, False),
                         next_obs, valid=ok)

    def update_if_full(self, next_obs: np.ndarray) -> bool:
        """Train on the rollout if it is full (``next_obs``: the rows' observations now)."""
        if not self.algo.rollout_full:
            return False
        self.add_stats(self.algo.update(next_obs))
        if problem := self.check_parameters():
            raise DivergedError(problem)
        return True

    def arrays(self) -> dict[str, np.ndarray]:
        return super().arrays() | {f"rollout.{k}": v for k, v in self.algo.rollout_state().items()}

    def load(self, tensors: Mapping[str, torch.Tensor], state: Mapping[str, Any],
             arrays: Mapping[str, np.ndarray]) -> None:
        super().load(tensors, state, arrays)
        self.algo.load_rollout_state({k[8:]: v for k, v in arrays.items() if k.startswith("rollout.")})


def make_learner(spec: LearnerSpec, index: list[int], position: int, cfg: TrainConfig,
                 obs_dim: int, act_dim: int, device: torch.device | None = None) -> OffPolicyLearner | PPOLearner:
    """The learner for ``spec`` (``position``: its place among the run's learners, which offsets its seeds;
    ``device``: where a device-resident collection keeps its tensors, None for numpy)."""
    cls = PPOLearner if spec.algo == "ppo" else OffPolicyLearner
    return cls(spec, index, position, cfg, obs_dim, act_dim, device)


def host(x: Any) -> np.ndarray:
    """``x`` as a numpy array (a device tensor is copied to the host)."""
    return x.cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def _finite(x: Any) -> bool:
    """Whether every entry of ``x`` (a numpy array or a tensor) is finite."""
    return bool(torch.isfinite(x).all()) if isinstance(x, torch.Tensor) else bool(np.isfinite(x).all())
