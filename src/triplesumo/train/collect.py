"""Collection over the batched matches: every learner acts for its agents (with exploration), the fixed
policies and league members for theirs; the matches step; each learner is handed its transitions and, when
due, learns (off-policy updates in a thread beside the physics, PPO when its rollout is full); every finished
match is an *epoch* whose rows go to the metrics tables.

The matches are the public batched API (``triplesumo.vector_env``'s contract): arrays ``(n_envs, n_agents,
...)`` in and out, Gymnasium SAME_STEP autoreset (a finished match's last observation, outcome codes and reward
terms in ``infos``), each next match seeded from the run's generator through ``reset_seed``. ``backend="cpu"``
is :class:`VectorMatches` (numpy), ``backend="warp"`` is MuJoCo Warp's ``WarpMatchBatch`` (torch tensors on
``device``, kept there by the learners). One collection path serves both.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch

from triplesumo.agents.builtin import RandomPolicy, ZeroPolicy, act_batch
from triplesumo.algos.base import DivergedError
from triplesumo.envs.batch import MatchBatch, VectorMatches
from triplesumo.envs.match import Match
from triplesumo.evaluation.metrics import local_winning_rate, moving_winning_rate
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.outcome import ERROR_CODE, PLAYING
from triplesumo.rules.outcome import outcome_name as code_name
from triplesumo.rules.rewards import TERMS
from triplesumo.train.config import TrainConfig
from triplesumo.train.learners import Learner, OffPolicyLearner, PPOLearner, host
from triplesumo.train.logger import MetricsLog
from triplesumo.train.seats import Seats

ACC_KEYS = ("dense_reward", "sparse_reward", *TERMS)
"""What a learning agent's epoch sums (its metrics row's reward columns), in the order of ``state.json``'s ``acc``."""

SAT_OUT: dict[str, Any] = {"outcome": "", "step": 0, "sat_out": True}
"""The ``final`` entry of a learning agent whose seat a league member takes for a match (self-play
with several learning sides): its epoch does not wait for it, and it writes no metrics row."""


class DivergenceError(FloatingPointError):
    """A learner's losses, parameters or actions are no longer finite (names learner, update, checkpoint)."""


def outcome_label(code: int) -> str:
    """An outcome code as the metrics' name (win, loss, draw, error; "" while the match goes on)."""
    return "" if int(code) == PLAYING else code_name(int(code))


def make_env(cfg: TrainConfig, match_cfg: MatchConfig) -> Any:
    """The run's matches through the batched API (``triplesumo.vector_env``'s contract):
    :class:`VectorMatches` (``backend="cpu"``, numpy) or ``WarpMatchBatch`` (``"warp"``,
    torch tensors on the device). Errors name the option."""
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


class Updates(threading.Thread):
    """Runs the off-policy updates due at one collection step (every learner's, in turn), in a
    thread beside the physics or inline."""

    def __init__(self, due: list[tuple[OffPolicyLearner, int]],
                 diverged: Callable[[Learner, str], DivergenceError]) -> None:
        super().__init__(name="offpolicy-updates", daemon=True)
        self.due, self.diverged, self.seconds = due, diverged, 0.0
        self.error: BaseException | None = None
        self._launched = False

    def start(self) -> None:
        self._launched = True
        super().start()

    def run(self) -> None:
        t = time.perf_counter()
        try:
            for learner, due in self.due:
                try:
                    learner.run_updates(due)
                except DivergedError as exc:
                    raise self.diverged(learner, str(exc)) from None
        except BaseException as exc:  # re-raised in the collecting thread by finish()
            self.error = exc
        self.seconds = time.perf_counter() - t

    def finish(self) -> None:
        if self._launched:
            self.join()
        if self.error is not None:
            raise self.error


class Collector:
    """Steps the run's ``n_envs`` matches and keeps where they stand: observations, each learning agent's sums
    of the epoch so far, who is still in play, the epochs and env steps done, every agent's local winning rates.

    One *epoch* is one match: it ends when the match is over or when every learning agent in it is out
    (elimination rules); each learning agent then gets one row in its metrics table (self-play with both
    sides learning: each agent that played it; one that sat it out has none). ``on_match_end(k, outcomes,
    places)`` is called for every epoch of a self-play run (the league rates it); ``diverged`` makes the error
    that stops a diverging learner.
    """

    def __init__(self, cfg: TrainConfig, probe: Match, env: Any, device: torch.device | None,
                 learners: Sequence[Learner], others: list[tuple[int, Any]], on_device: dict[int, Any],
                 seats: Seats, rng: np.random.Generator, diverged: Callable[[Learner, str], DivergenceError]) -> None:
        self.cfg, self.probe, self.env, self.device, self.seats = cfg, probe, env, device, seats
        self.learners, self.rng, self.diverged = list(learners), rng, diverged
        self.agents = [a for learner in learners for a in learner.spec.agents]
        """The learning agents, learner by learner."""
        self.agent_index = [probe.agents.index(a) for a in self.agents]
        """Roster index of each learning agent."""
        self.elimination = probe.elimination
        """Elimination rules (ffa, pursuit): an agent may leave its match before the match ends."""
        self.others = others
        """Roster index and policy of every agent that does not learn."""
        self.on_device = on_device
        """Roster index -> a trained fixed policy acting on the device (``warp``; others act on the host)."""
        env.reset_seed = lambda k: self.episode_seed()  # a finished match's next seed, in match order
        self.log: MetricsLog | None = None
        """Where epochs are written (set by the trainer once the run's tables are open)."""
        self.on_match_end: Callable[[int, np.ndarray, np.ndarray], None] | None = None
        self.epochs_done = 0
        self.env_steps = 0
        self.lwr: dict[str, list[float]] = {a: [] for a in self.agents}
        self.finished_epoch_steps: list[int] = []
        """Length of every epoch finished by this process (not restored on resume)."""
        self.acc: Any = self.zeros((cfg.n_envs, len(self.agents), len(ACC_KEYS)), float64=True)
        """Each match's sums of :data:`ACC_KEYS` so far, per learning agent (on the device for warp)."""
        self.final: dict[str, list[dict[str, Any] | None]] = {a: [None] * cfg.n_envs for a in self.agents}
        """The last info (outcome, step) of a learning agent already out of a match still running."""
        self.playing = np.ones((cfg.n_envs, len(self.agents)), dtype=bool)
        """Per match, per learning agent: still in play (``final`` is None)."""
        self.obs: Any = None
        """Every match's current observations ``(n_envs, n_agents, obs_dim)`` (numpy, or a device tensor)."""
        self.timers = {"env": 0.0, "act": 0.0, "learn": 0.0, "wait": 0.0}
        """Seconds collecting (physics and rules), acting, learning (off-policy updates run in a
        thread: they overlap "env" when overlap_learning is on; PPO's run inline) and waiting
        for learning."""

    # ------------------------------------------------------------------ matches
    def start(self) -> None:
        """Seat every match and reset them all (a new run)."""
        n = self.cfg.n_envs
        for k in range(n):
            self.seat(k)
        self.playing = np.array([[self.final[a][k] is None for a in self.agents] for k in range(n)],
                                dtype=bool)  # False: the agent sits the match out
        self.obs = self.env.reset(seed=[self.episode_seed() for _ in range(n)])[0]

    def seat(self, k: int) -> None:
        """Draw match ``k``'s league members (:meth:`Seats.draw`); a learner whose seats they take sits the match
        out: its rows are out of play and it gets no metrics row for it."""
        if self.seats.league is None:
            return
        self.seats.draw(k)
        for learner in self.learners:
            plays = self.seats.plays(learner, k)
            learner.active[learner.rows_of(k)] = plays
            for agent in learner.spec.agents:
                self.final[agent][k] = None if plays else dict(SAT_OUT)

    def episode_seed(self) -> int:
        return int(self.rng.integers(2**31 - 1))

    def zeros(self, shape: tuple[int, ...], float64: bool = False) -> Any:
        """Zeros where the run's arrays live: numpy float64 on ``cpu``, a float32 (or float64) tensor on the device."""
        if self.device is None:
            return np.zeros(shape)
        return torch.zeros(shape, dtype=torch.float64 if float64 else torch.float32, device=self.device)

    def rows(self, learner: Learner) -> Any:
        """The learner's observations, ``(n_envs x len(agents), obs_dim)``, match-major."""
        return self.obs[:, learner.index].reshape(-1, learner.obs_dim)

    @property
    def batch(self) -> MatchBatch:
        """The matches of a ``cpu`` run (``VectorMatches.batch``), e.g. for a scenario test placing an
        agent by hand (then ``batch.reload(k)``); a ``warp`` run has none."""
        if not isinstance(self.env, VectorMatches):
            raise AttributeError("a backend='warp' run has no MatchBatch (its matches live on the device)")
        return self.env.batch

    # -------------------------------------------------------------------- step
    def step(self) -> int:
        """Step every match once; returns the number of epochs that finished."""
        cfg, n, probe = self.cfg, self.cfg.n_envs, self.probe
        t0 = time.perf_counter()
        actions = self.zeros((n, probe.n_agents, probe.action_width))
        seen, acted = [], []
        for learner in self.learners:
            obs = self.rows(learner)
            try:
                act = learner.act(obs, self.rng)
            except DivergedError as exc:
                raise self.diverged(learner, str(exc)) from None
            actions[:, learner.index, :learner.act_dim] = act.reshape(n, len(learner.index), learner.act_dim)
            seen.append(obs)
            acted.append(act)
        for i, policy in self.others:
            if i in self.seats.league_seats or (self.device is not None and isinstance(policy, ZeroPolicy)):
                continue
            if i in self.on_device:
                actions[:, i, :probe.action_sizes[i]] = self.on_device[i](self.obs[:, i])
            elif self.device is None:
                actions[:, i, :probe.action_sizes[i]] = act_batch(policy, self.obs[:, i])
            else:  # warp: drawn on the host from the policy's own generator (its cpu stream), one copy
                fixed = policy.sample(n) if isinstance(policy, RandomPolicy) else act_batch(
                    policy, host(self.obs[:, i]))
                actions[:, i, :probe.action_sizes[i]] = torch.as_tensor(fixed, dtype=torch.float32,
                                                                        device=self.device)
        if self.device is None:
            self.seats.act_on_host(actions, self.obs)
        elif self.seats.league is not None:
            self.seats.act_on_device(actions, self.obs)
        t1 = time.perf_counter()
        # The off-policy updates due at this step learn from the replay as it was before the
        # step, so they can run while MuJoCo steps the matches (GIL released in mujoco.batch and
        # in torch's kernels). Overlapped or not, the result is bit for bit the same.
        due = [(lr, d) for lr in self.learners if isinstance(lr, OffPolicyLearner) and (d := lr.updates_due())]
        updates = Updates(due, self.diverged)
        if due and cfg.overlap_learning:
            updates.start()
        elif due:
            updates.run()
        obs, _, terminated, truncated, infos = self.env.step(actions)  # finished matches are already reset
        t2 = time.perf_counter()
        updates.finish()
        t_joined = time.perf_counter()
        self.env_steps += n  # counted before epochs end, so their rows include this step
        where = np.where if self.device is None else torch.where
        done = infos["_final_obs"]
        next_obs = where(done[:, None, None], infos["final_obs"], obs)  # a finished match's last observation
        reward = infos["dense_reward"] + infos["sparse_reward"]
        error = infos["outcome"] == ERROR_CODE
        for learner, seen_obs, act in zip(self.learners, seen, acted, strict=True):
            self._store(learner, seen_obs, act, next_obs, reward, terminated, truncated, error)
        finished = self._account(obs, terminated, infos)
        t3 = time.perf_counter()
        for learner in self.learners:
            if isinstance(learner, PPOLearner):
                try:
                    learner.update_if_full(self.rows(learner))
                except DivergedError as exc:
                    raise self.diverged(learner, str(exc)) from None
        learned = time.perf_counter() - t3
        self.timers["act"] += t1 - t0
        self.timers["env"] += (t2 - t1) + (t3 - t_joined)
        self.timers["learn"] += updates.seconds + learned  # the thread's part overlaps "env"
        self.timers["wait"] += t_joined - t2
        return finished

    def _store(self, learner: Learner, obs: Any, act: Any, next_obs: Any, reward: Any, terminated: Any,
               truncated: Any, error: Any) -> None:
        """Hand the learner its rows' step (``(n_envs, n_agents, ...)`` arrays of the whole batch):
        rewards, next observations, ends, which rows played."""
        idx = learner.index
        rew = reward[:, idx].reshape(-1)
        nxt = next_obs[:, idx].reshape(-1, learner.obs_dim)
        term = terminated[:, idx].reshape(-1)  # the match was won or lost, or the agent left it
        trunc = truncated[:, idx].reshape(-1) & ~term  # a draw by time limit bootstraps
        valid = ~error[:, idx].reshape(-1)  # a physics error's transition is never learned from
        active = learner.active
        if not active.all():  # rows out of play (elimination rules, or sat out in self-play): nothing
            on: Any = active if self.device is None else torch.as_tensor(active, device=self.device)
            where: Any = np.where if self.device is None else torch.where
            rew, term, trunc = where(on, rew, 0.0), term & on, trunc & on
            valid, nxt = valid | ~on, where(on[:, None], nxt, obs)
        learner.store(obs, act, rew, nxt, term, trunc, valid, active.copy())
        if self.elimination:  # an agent that left stays out until its match is reset
            learner.active &= ~term

    def _account(self, obs: Any, terminated: Any, infos: Mapping[str, Any]) -> int:
        """Add the step to every learning agent's sums; end the epoch of each match that is over
        (already reset by the env) or whose learning agents are all out (reset here). Returns how
        many epochs ended."""
        assert self.log is not None
        league = self.seats.league
        terms: Any
        if self.device is None:
            terms = np.stack([infos[key][:, self.agent_index] for key in ACC_KEYS], axis=-1)
        else:
            terms = torch.stack([infos[key][:, self.agent_index] for key in ACC_KEYS], dim=-1).double()
        if self.playing.all():
            self.acc += terms
        elif self.device is None:  # an agent out of a match still running adds nothing more to its epoch
            self.acc += np.where(self.playing[..., None], terms, 0.0)
        else:  # (or one sitting it out, self-play)
            self.acc += torch.where(torch.as_tensor(self.playing[..., None], device=self.device), terms, 0.0)
        self.obs = obs
        done = host(infos["_final_obs"])
        out = host(terminated[:, self.agent_index]) if self.elimination else None
        events = done | out.any(-1) if out is not None else done
        rows = np.flatnonzero(events)
        if not len(rows):
            return 0
        sel: Any = rows if self.device is None else torch.as_tensor(rows, device=self.device)
        outcome, steps = host(infos["outcome"][sel]), host(infos["step"][sel])
        places = host(infos["place"][sel]) if league is not None else None
        sums = host(self.acc[sel])
        ended = []
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
            for j, agent in enumerate(self.agents):
                code = outcome[r, self.agent_index[j]]
                last = self.final[agent][k] or {"outcome": outcome_label(code), "step": int(steps[r])}
                if "sat_out" not in last:  # a learner that sat the match out (self-play) has no row for it
                    self._agent_row(agent, last, sums[r, j])
                self.final[agent][k] = None
            self.finished_epoch_steps.append(int(steps[r]))
            for learner in self.learners:
                self.log.learned(learner.name, self.epochs_done, learner.algo.num_updates, learner.take_stats())
            if league is not None:
                assert places is not None and self.on_match_end is not None
                self.on_match_end(k, outcome[r], places[r])
                self.seat(k)
            if not over:  # every learning agent is out: the epoch ends before the match does
                self.obs[k] = self.env.restart(k, self.episode_seed())
            for learner in self.learners:
                lrows = learner.rows_of(k)
                learner.active[lrows] = self.seats.plays(learner, k) if league is not None else True
                learner.reset_rows(lrows)
            self.playing[k] = [self.final[a][k] is None for a in self.agents]  # False: sits this match out
            ended.append(k)
        if ended:
            self.acc[ended if self.device is None else torch.as_tensor(ended, device=self.device)] = 0.0
        return len(ended)

    def _agent_row(self, agent: str, last: dict[str, Any], acc: np.ndarray) -> None:
        assert self.log is not None
        sums = dict(zip(ACC_KEYS, acc.tolist(), strict=True))
        lwr = float(local_winning_rate([last["outcome"]])[0])
        self.lwr[agent].append(lwr)
        total = sums["dense_reward"] + sums["sparse_reward"]
        row = {"epoch": len(self.lwr[agent]), "outcome": last["outcome"], "local_winning_rate": lwr,
               "steps": last["step"], "total_reward": total, **sums, "env_steps": self.env_steps,
               "wall_time": round(time.time(), 3)}  # epoch: the agent's own matches (= the run's, unless it sat out)
        self.log.epoch(agent, row, self.mwr(agent))

    def mwr(self, agent: str | None = None) -> float:
        """MWR of ``agent`` (default: the first learning agent) over the last λ epochs (mean
        over what exists for the first λ-1)."""
        lwr = self.lwr[agent or self.agents[0]]
        if not lwr:
            return 0.0
        return float(moving_winning_rate(np.array(lwr[-self.cfg.window:]), self.cfg.window)[-1])
