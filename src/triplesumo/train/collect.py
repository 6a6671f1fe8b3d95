"""Collection over the batched matches: the :class:`Collector` steps them with the actions it is given and
returns a :class:`Step`, the transitions of every seat and a :class:`MatchEnd` record of every *epoch* (one
match) that finished, with each learning agent's metrics row. It keeps where the matches stand (observations,
each learning agent's sums of the epoch so far, who is still in play, the epochs and env steps done) and
gives it as its :meth:`Collector.state_dict`; it learns nothing and writes nothing.

The matches are the public batched API (``triplesumo.vector_env``'s contract): arrays ``(n_envs, n_agents,
...)`` in and out, Gymnasium SAME_STEP autoreset (a finished match's last observation, outcome codes and reward
terms in ``infos``), each next match seeded from the run's generator through ``reset_seed``. ``backend="cpu"``
is :class:`VectorMatches` (numpy), ``backend="warp"`` is MuJoCo Warp's ``WarpVectorMatches`` (torch tensors on
``device``, kept there by the learners). One collection path serves both.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from triplesumo.algos.base import DivergenceError
from triplesumo.envs.batch import MatchBatch, VectorMatches
from triplesumo.envs.match import Match
from triplesumo.evaluation.metrics import local_winning_rate, moving_winning_rate
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.outcome import ERROR_CODE, PLAYING
from triplesumo.rules.outcome import outcome_name as code_name
from triplesumo.rules.rewards import TERMS
from triplesumo.train.arrays import Arrays, host
from triplesumo.train.checkpoint import State
from triplesumo.train.config import TrainConfig
from triplesumo.train.learners import Learner

ACC_KEYS = ("dense_reward", "sparse_reward", *TERMS)
"""What a learning agent's epoch sums (its metrics row's reward columns), in the order of ``state.json``'s ``acc``."""

SAT_OUT: dict[str, Any] = {"outcome": "", "step": 0, "sat_out": True}
"""The ``final`` entry of a learning agent whose seat a league member takes for a match (self-play
with several learning sides): its epoch does not wait for it, and it writes no metrics row."""

__all__ = ["ACC_KEYS", "Collector", "DivergenceError", "MatchEnd", "Step", "make_env", "outcome_label"]


def outcome_label(code: int) -> str:
    """An outcome code as the metrics' name (win, loss, draw, error; "" while the match goes on)."""
    return "" if int(code) == PLAYING else code_name(int(code))


def make_env(cfg: TrainConfig, match_cfg: MatchConfig,
             reset_seed: Callable[[int], int | None] | None = None) -> Any:
    """The run's matches through the batched API (``triplesumo.vector_env``'s contract):
    :class:`VectorMatches` (``backend="cpu"``, numpy) or ``WarpVectorMatches`` (``"warp"``,
    torch tensors on the device), each finished match's next one seeded by ``reset_seed(k)``. Errors name the
    option."""
    env = _build_env(cfg, match_cfg)
    env.reset_seed = reset_seed
    return env


def _build_env(cfg: TrainConfig, match_cfg: MatchConfig) -> Any:
    if cfg.backend == "warp":
        try:
            from triplesumo.envs.warp import make_warp_vector_env
        except ImportError as exc:
            raise ImportError(f"TrainConfig.backend='warp' needs MuJoCo Warp: pip install \"triplesumo[gpu]\" "
                              f"({exc})") from None
        try:
            return make_warp_vector_env(match_cfg, cfg.n_envs, cfg.device)
        except (NotImplementedError, ValueError) as exc:
            raise ValueError(f"TrainConfig.backend='warp' (scenario {cfg.scenario!r}, device {cfg.device!r}): "
                             f"{exc}") from None
    try:
        return VectorMatches(cfg.n_envs, match_cfg, cfg.n_threads)
    except ValueError as exc:  # the same error (a BatchMemoryError stays one), naming the run's option
        said = str(exc).replace("num_envs=", "TrainConfig.n_envs=")
        raise type(exc)(f"TrainConfig (scenario {cfg.scenario!r}, obs_mode {cfg.obs_mode!r}): {said}") from None


def match_parts(on_device: bool, arrays: Mapping[str, np.ndarray]) -> tuple[str, ...]:
    """The arrays of each match (``match<k>.<part>``) a checkpoint of this backend holds: cpu every
    ``Match.snapshot`` array; warp (``on_device``) the world's state, or none in a checkpoint written before warp
    resumed exactly (its matches then restart)."""
    if not on_device:
        return ("physics", "last_obs", "warnings", "obs")
    return ("physics", "obs") if "match0.physics" in arrays else ()


@dataclass
class MatchEnd:
    """A finished epoch: match ``match`` ended (or every learning agent in it is out), the run's ``epoch``-th."""

    match: int
    epoch: int
    outcomes: np.ndarray
    """Every seat's outcome code."""
    places: np.ndarray
    """Every seat's place."""
    rows: dict[str, tuple[dict[str, Any], float]] = field(default_factory=dict)
    """Each learning agent that played it: its metrics row and its MWR with it."""


@dataclass
class Step:
    """One step of every match: ``(n_envs, n_agents, ...)`` arrays (a finished match's last observation in
    ``next_obs``, already reset in :attr:`Collector.obs`) and the epochs it finished, in match order."""

    next_obs: Any
    reward: Any
    terminated: Any
    truncated: Any
    error: Any
    """A physics error ended the match: its transitions are never learned from."""
    ended: list[MatchEnd]


class Collector:
    """Steps the run's ``n_envs`` matches and keeps where they stand: observations, each learning agent's sums
    of the epoch so far, who is still in play, the epochs and env steps done, every agent's local winning rates.

    One *epoch* is one match: it ends when the match is over or when every learning agent in it is out
    (elimination rules); each learning agent then gets one row (self-play with both sides learning: each agent
    that played it; one that sat it out has none). Every match is seeded from ``rng``, in match order.
    """

    def __init__(self, cfg: TrainConfig, match_cfg: MatchConfig, probe: Match, agents: Sequence[str],
                 rng: np.random.Generator) -> None:
        self.cfg, self.probe, self.rng = cfg, probe, rng
        self.env = make_env(cfg, match_cfg, reset_seed=lambda k: self.episode_seed())
        """The matches (a finished one is reset by the env itself, seeded in match order)."""
        self.xp = Arrays(getattr(self.env, "device", None) if cfg.backend == "warp" else None)
        """Where the matches' arrays live (numpy, or torch tensors on the device of a ``warp`` run)."""
        self.agents = list(agents)
        """The learning agents, learner by learner."""
        self.agent_index = [probe.agents.index(a) for a in self.agents]
        """Roster index of each learning agent."""
        self.elimination = probe.elimination
        """Elimination rules (ffa, pursuit): an agent may leave its match before the match ends."""
        self.epochs_done = 0
        self.env_steps = 0
        self.lwr: dict[str, list[float]] = {a: [] for a in self.agents}
        self.finished_epoch_steps: list[int] = []
        """Length of every epoch finished by this process (not restored on resume)."""
        self.acc: Any = self.xp.zeros((cfg.n_envs, len(self.agents), len(ACC_KEYS)), float64=True)
        """Each match's sums of :data:`ACC_KEYS` so far, per learning agent (on the device for warp)."""
        self.final: dict[str, list[dict[str, Any] | None]] = {a: [None] * cfg.n_envs for a in self.agents}
        """The last info (outcome, step) of a learning agent already out of a match still running."""
        self.playing = np.ones((cfg.n_envs, len(self.agents)), dtype=bool)
        """Per match, per learning agent: still in play (``final`` is None)."""
        self.obs: Any = None
        """Every match's current observations ``(n_envs, n_agents, obs_dim)`` (numpy, or a device tensor)."""

    # ------------------------------------------------------------------ matches
    def reset(self) -> None:
        """Start every match (a new run), each from the next seed of the run's generator."""
        self.obs = self.env.reset(seed=[self.episode_seed() for _ in range(self.cfg.n_envs)])[0]

    def begin_match(self, k: int, sitting_out: Sequence[str] = ()) -> None:
        """Match ``k``'s epoch starts; the learning agents ``sitting_out`` (a league member takes their seats)
        play no part in it and get no row for it."""
        for j, agent in enumerate(self.agents):
            self.final[agent][k] = dict(SAT_OUT) if agent in sitting_out else None
            self.playing[k, j] = agent not in sitting_out

    def episode_seed(self) -> int:
        return int(self.rng.integers(2**31 - 1))

    def rows(self, learner: Learner) -> Any:
        """The learner's observations, ``(n_envs x len(agents), obs_dim)``, match-major."""
        return self.obs[:, learner.index].reshape(-1, learner.obs_dim)

    def actions(self, learners: Sequence[Learner], acted: Sequence[Any]) -> Any:
        """The step's actions ``(n_envs, n_agents, action_width)``: each learner's in its columns, zeros in
        every other seat (for the seats to fill)."""
        n, probe = self.cfg.n_envs, self.probe
        actions = self.xp.zeros((n, probe.n_agents, probe.action_width))
        for learner, act in zip(learners, acted, strict=True):
            actions[:, learner.index, :learner.act_dim] = act.reshape(n, len(learner.index), learner.act_dim)
        return actions

    @property
    def batch(self) -> MatchBatch:
        """The matches of a ``cpu`` run (``VectorMatches.batch``), e.g. for a scenario test placing an
        agent by hand (then ``batch.reload(k)``); a ``warp`` run has none."""
        if not isinstance(self.env, VectorMatches):
            raise AttributeError("a backend='warp' run has no MatchBatch (its matches live on the device)")
        return self.env.batch

    # -------------------------------------------------------------------- step
    def step(self, actions: Any) -> Step:
        """Step every match once with ``actions``; the epochs that finished are accounted and their matches
        already started again."""
        obs, _, terminated, truncated, infos = self.env.step(actions)  # finished matches are already reset
        self.env_steps += self.cfg.n_envs  # counted before epochs end, so their rows include this step
        done = infos["_final_obs"]
        step = Step(next_obs=self.xp.where(done[:, None, None], infos["final_obs"], obs),
                    reward=infos["dense_reward"] + infos["sparse_reward"], terminated=terminated,
                    truncated=truncated, error=infos["outcome"] == ERROR_CODE, ended=[])
        step.ended = self._account(obs, terminated, infos)
        return step

    def _account(self, obs: Any, terminated: Any, infos: Mapping[str, Any]) -> list[MatchEnd]:
        """Add the step to every learning agent's sums; end the epoch of each match that is over
        (already reset by the env) or whose learning agents are all out (restarted here)."""
        xp = self.xp
        terms = xp.stack([infos[key][:, self.agent_index] for key in ACC_KEYS], axis=-1)
        if self.playing.all():
            self.acc += terms
        else:  # an agent out of a match still running (or sitting it out) adds nothing more to its epoch
            self.acc += xp.where(xp.put(self.playing[..., None]), terms, 0.0)
        self.obs = obs
        done = host(infos["_final_obs"])
        out = host(terminated[:, self.agent_index]) if self.elimination else None
        events = done | out.any(-1) if out is not None else done
        rows = np.flatnonzero(events)
        if not len(rows):
            return []
        sel = xp.put(rows)
        outcome, steps, places = (host(infos[key][sel]) for key in ("outcome", "step", "place"))
        sums = host(self.acc[sel])
        ended: list[MatchEnd] = []
        for r, k in enumerate(rows.tolist()):
            if out is not None:
                for j, agent in enumerate(self.agents):
                    if self.final[agent][k] is None and out[k, j]:  # left the match: its epoch waits for the match
                        code = outcome[r, self.agent_index[j]]
                        self.final[agent][k] = {"outcome": outcome_label(code), "step": int(steps[r])}
                        self.playing[k, j] = False
            over = bool(done[k])
            if not over and any(self.final[a][k] is None for a in self.agents):
                continue
            self.epochs_done += 1
            end = MatchEnd(k, self.epochs_done, outcome[r], places[r])
            for j, agent in enumerate(self.agents):
                code = outcome[r, self.agent_index[j]]
                last = self.final[agent][k] or {"outcome": outcome_label(code), "step": int(steps[r])}
                if "sat_out" not in last:  # a learner that sat the match out (self-play) has no row for it
                    end.rows[agent] = self._agent_row(agent, last, sums[r, j])
                self.final[agent][k] = None
            self.playing[k] = True
            self.finished_epoch_steps.append(int(steps[r]))
            if not over:  # every learning agent is out: the epoch ends before the match does
                self.obs[k] = self.env.restart(k, self.episode_seed())
            ended.append(end)
        if ended:
            self.acc[xp.put(np.array([e.match for e in ended]))] = 0.0
        return ended

    def _agent_row(self, agent: str, last: dict[str, Any], acc: np.ndarray) -> tuple[dict[str, Any], float]:
        sums = dict(zip(ACC_KEYS, acc.tolist(), strict=True))
        lwr = float(local_winning_rate([last["outcome"]])[0])
        self.lwr[agent].append(lwr)
        total = sums["dense_reward"] + sums["sparse_reward"]
        row = {"epoch": len(self.lwr[agent]), "outcome": last["outcome"], "local_winning_rate": lwr,
               "steps": last["step"], "total_reward": total, **sums, "env_steps": self.env_steps,
               "wall_time": round(time.time(), 3)}  # epoch: the agent's own matches (= the run's, unless it sat out)
        return row, self.mwr(agent)

    def mwr(self, agent: str | None = None) -> float:
        """MWR of ``agent`` (default: the first learning agent) over the last λ epochs (mean
        over what exists for the first λ-1)."""
        lwr = self.lwr[agent or self.agents[0]]
        if not lwr:
            return 0.0
        return float(moving_winning_rate(np.array(lwr[-self.cfg.window:]), self.cfg.window)[-1])

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> State:
        """Every match's exact state (the env's ``snapshot``: arrays apart, the rest in ``matches``), its
        observations, the epoch sums so far, who is out, the counters and the local winning rates."""
        snaps = self.env.snapshot()
        obs, acc = host(self.obs), host(self.acc).tolist()
        arrays: dict[str, np.ndarray] = {}
        for k, s in enumerate(snaps):
            arrays |= {f"match{k}.{key}": v for key, v in s.items() if isinstance(v, np.ndarray)}
            arrays[f"match{k}.obs"] = np.array(obs[k])
        arrays |= {f"lwr.{agent}": np.array(lwr) for agent, lwr in self.lwr.items()}
        return State(json={
            "epochs_done": self.epochs_done, "env_steps": self.env_steps,
            "matches": [{key: v for key, v in s.items() if not isinstance(v, np.ndarray)}
                        for s in snaps],  # steps, generator, who is still in play (elimination rules)
            "acc": {agent: [dict(zip(ACC_KEYS, per_match[j], strict=True)) for per_match in acc]
                    for j, agent in enumerate(self.agents)},
            "final": self.final}, arrays=arrays)

    def load_state_dict(self, state: State) -> bool:
        """Restore :meth:`state_dict`: every match continues exactly where it was. A ``warp`` checkpoint written
        before warp resumed exactly holds no matches: they start again (each from the next seed), and False
        says so (their epochs in progress are dropped)."""
        n, arrays, saved = self.cfg.n_envs, state.arrays, state.json
        parts = match_parts(self.xp.on_device, arrays)
        state.require([f"lwr.{a}" for a in self.agents] + [f"match{k}.{part}" for k in range(n) for part in parts])
        continued = bool(parts)
        if continued:
            self.obs = self.xp.put(np.stack([np.asarray(arrays[f"match{k}.obs"], dtype=np.float32) for k in range(n)]))
            self.env.restore([{part: arrays[f"match{k}.{part}"] for part in parts if part != "obs"}
                              | saved["matches"][k] for k in range(n)], self.obs)
            self.final = {a: saved["final"][a] for a in self.agents}
            self.acc = self.xp.put(np.array([[[saved["acc"][a][k][key] for key in ACC_KEYS] for a in self.agents]
                                             for k in range(n)], dtype=np.float64))
        else:
            self.reset()
        self.playing = np.array([[self.final[a][k] is None for a in self.agents] for k in range(n)], dtype=bool)
        self.epochs_done = int(saved["epochs_done"])
        self.env_steps = int(saved["env_steps"])
        self.lwr = {a: [float(x) for x in arrays[f"lwr.{a}"]] for a in self.agents}
        return continued
