"""The learners of a training run: which agents learn, with which algorithm, and how each
learner acts, stores what it saw and learns.

A :class:`Learner` drives one algorithm for one agent, or (``share="team"``) for all the
learning agents of a team, in every match of the batch: its *rows* are the ``n_envs x
len(agents)`` (match, agent) pairs, match-major. The training loop calls it: :meth:`Learner.act`,
:meth:`Learner.store` (its columns of a collected :class:`~triplesumo.train.collect.Step`),
:meth:`Learner.begin_match` when a match of its rows starts, and :meth:`Learner.learn`.
Off-policy learners (DDPG, TD3, SAC) store their rows' transitions in their own replay buffer and
run the updates :meth:`~triplesumo.algos.offpolicy.OffPolicyAlgorithm.updates_due` says, in a
thread beside the physics (:class:`Updates`); PPO records its rows into its ``(T, rows)`` rollout
and updates when the rollout is full. A row whose agent is out of its match (elimination rules)
stays out until the match is reset: it adds no transition (PPO keeps it in the rollout's shape,
marked invalid). Each learner keeps its own state (:meth:`Learner.state_dict`).

On a device-resident collection (``train --backend warp``) observations, actions, rewards and
flags arrive as torch tensors on the learner's ``device`` and stay there: the networks act on
them, the replay buffer (:class:`~triplesumo.algos.replay.TorchReplayBuffer`) and PPO's rollout
store them; only the random draws (warm-up actions, exploration noise, replay indices) come from
the host generators, which keeps their streams and checkpoints those of the CPU path.
"""

from __future__ import annotations

import math
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from triplesumo.algos.base import Algorithm, DivergenceError, not_finite
from triplesumo.algos.ddpg import DDPG
from triplesumo.algos.noise import ActionNoise, make_noise
from triplesumo.algos.nstep import NStepReturns, TorchNStepReturns
from triplesumo.algos.offpolicy import OffPolicyAlgorithm
from triplesumo.algos.ppo import PPO
from triplesumo.algos.replay import ReplayBuffer, TorchReplayBuffer
from triplesumo.algos.sac import SAC
from triplesumo.algos.td3 import TD3
from triplesumo.rules.config import check_shared_network
from triplesumo.train.arrays import Arrays, finite, host
from triplesumo.train.checkpoint import State
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
    unknown = [a for a in learning if a not in roster]
    if unknown:
        raise ValueError(f"TrainConfig.learn names unknown agents {unknown}; agents are {list(roster)} "
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


class Transitions(Protocol):
    """One collected step of every match, ``(n_envs, n_agents, ...)`` arrays of the whole batch
    (:class:`~triplesumo.train.collect.Step`)."""

    next_obs: Any
    reward: Any
    terminated: Any
    truncated: Any
    error: Any


class Learner:
    """One algorithm acting for ``spec.agents`` (match indices ``index``) in ``n_envs`` matches."""

    algo: Algorithm

    def __init__(self, spec: LearnerSpec, index: list[int], position: int, cfg: TrainConfig,
                 obs_dim: int, act_dim: int, device: torch.device | None = None, elimination: bool = False) -> None:
        self.spec, self.name, self.index = spec, spec.name, index
        self.config: Any = cfg.algo_config(spec.name)
        self.xp = Arrays(device)
        """Where its inputs live: numpy, or tensors on the device of a device-resident collection."""
        self.elimination = elimination
        """Whether an agent may leave its match before the match ends (its rows then stay out until it is reset)."""
        self.algo = ALGORITHMS[spec.algo](obs_dim, act_dim, self.config, seed=cfg.seed + position,
                                          device=device or "cpu")
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.n_rows = cfg.n_envs * len(index)
        self.active = np.ones(self.n_rows, dtype=bool)
        """Rows in play: False once the agent is out of its match, or while a league member takes its seat,
        until :meth:`begin_match`."""
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

    def diverged(self, what: str) -> DivergenceError:
        return DivergenceError(what, learner=self.name)

    def prepare(self, obs: Any) -> None:
        """Before the step's updates begin: its observations ``(n_rows, obs_dim)`` join the running observation
        normaliser (a no-op at the paper preset), which those updates read."""
        self.algo.observe(obs)

    def act(self, obs: Any, rng: np.random.Generator) -> Any:
        """Training actions ``(n_rows, act_dim)`` in [-1, 1] for observations ``(n_rows, obs_dim)`` (after
        :meth:`prepare` with them), with its exploration (drawn from ``rng``); :class:`DivergenceError` when they
        are not finite."""
        action = self._explore(obs, rng)
        if not finite(action):
            raise self.diverged("its actions are not finite")
        return action

    def _explore(self, obs: Any, rng: np.random.Generator) -> Any:
        raise NotImplementedError

    def store(self, obs: Any, action: Any, step: Transitions) -> None:
        """Take its rows of a collected step: it acted ``action`` on ``obs`` (its rows). Rows out of play
        add nothing; a physics error's transition is never learned from; a draw by time limit bootstraps. With
        elimination rules an agent that left stays out until its match starts again (:meth:`begin_match`)."""
        idx, xp = self.index, self.xp
        reward = step.reward[:, idx].reshape(-1)
        next_obs = step.next_obs[:, idx].reshape(-1, self.obs_dim)
        terminated = step.terminated[:, idx].reshape(-1)  # the match was won or lost, or the agent left it
        truncated = step.truncated[:, idx].reshape(-1) & ~terminated
        valid = ~step.error[:, idx].reshape(-1)
        if not self.active.all():  # rows out of play (elimination rules, or sat out in self-play): nothing
            on = xp.put(self.active)
            reward, terminated, truncated = xp.where(on, reward, 0.0), terminated & on, truncated & on
            valid, next_obs = valid | ~on, xp.where(on[:, None], next_obs, obs)
        played = self.active.copy()
        self.collected += int(played.sum())
        self._record(obs, action, reward, next_obs, terminated, truncated, valid, played)
        if self.elimination:
            self.active &= ~host(terminated)

    def _record(self, obs: Any, action: Any, reward: Any, next_obs: Any, terminated: Any, truncated: Any,
                valid: Any, played: np.ndarray) -> None:
        """Keep the step of every row: ``played`` rows were in their match, ``valid`` ones are real steps."""
        raise NotImplementedError

    def begin_match(self, match: int, plays: bool = True) -> None:
        """Match ``match`` starts again (its rows back in play, or out while a league member takes the seats:
        ``plays`` False)."""
        rows = self.rows_of(match)
        self.active[rows] = plays
        self._reset_rows(rows)

    def _reset_rows(self, rows: np.ndarray) -> None:
        """The matches of ``rows`` start again (e.g. restart their exploration noise)."""

    def learn(self, obs: Any) -> None:
        """Learn if its schedule says so after a step (``obs``: its rows' observations now)."""

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

    def check_parameters(self) -> None:
        bad = not_finite(self.parameters)
        if bad:
            raise self.diverged(f"its parameters are not finite: {bad[:4]}")

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self, replay: bool = True) -> State:
        """Its networks and optimiser (tensors), counters, stats and which rows are in play; ``replay`` is
        the off-policy learners' buffer."""
        opt_tensors, opt_state = self.algo.optimizer_state()
        return State(json={"optimizer": opt_state, "collected": self.collected, "stats": [self._sums, self._counts]},
                     arrays={"active": self.active.copy()},
                     tensors={**self.algo.state_dict(), **{f"optim.{k}": v for k, v in opt_tensors.items()}})

    def load_state_dict(self, state: State) -> None:
        """Restore :meth:`state_dict` (its replay buffer only where ``state.replay`` holds it)."""
        tensors = state.tensors
        self.algo.load_state_dict({k: v for k, v in tensors.items() if not k.startswith("optim.")})
        self.algo.load_optimizer_state({k.removeprefix("optim."): v for k, v in tensors.items()
                                        if k.startswith("optim.")}, state.json["optimizer"])
        self.collected = int(state.json["collected"])
        self._sums, self._counts = (dict(x) for x in state.json["stats"])
        self.active = np.asarray(state.arrays["active"], dtype=bool).copy()

    def all_in_play(self) -> None:
        """Every row in play (its matches all restarted)."""
        self.active[:] = True


class OffPolicyLearner(Learner):
    """DDPG, TD3 or SAC: random warm-up, exploration noise (or SAC's sampling), replay, updates."""

    algo: OffPolicyAlgorithm

    def __init__(self, spec: LearnerSpec, index: list[int], position: int, cfg: TrainConfig,
                 obs_dim: int, act_dim: int, device: torch.device | None = None, elimination: bool = False) -> None:
        super().__init__(spec, index, position, cfg, obs_dim, act_dim, device, elimination)
        c = self.config
        self.nstep: NStepReturns | None = None
        """The rows' pending n-step windows (``n_step`` > 1); None: one-step transitions go straight to replay."""
        if c.n_step > 1:
            self.nstep = (NStepReturns(c.n_step, c.gamma, self.n_rows, obs_dim, act_dim) if device is None
                          else TorchNStepReturns(c.n_step, c.gamma, self.n_rows, obs_dim, act_dim, device))
        self.replay = (ReplayBuffer(c.buffer_size, obs_dim, act_dim, discount=self.nstep is not None)
                       if device is None else TorchReplayBuffer(c.buffer_size, obs_dim, act_dim, device,
                                                                discount=self.nstep is not None))
        self.noise: ActionNoise | None = None
        """The exploration noise process (DDPG, TD3); SAC samples its own policy."""
        if hasattr(c, "noise"):
            self.noise = make_noise(c.noise, (self.n_rows, act_dim), c.noise_sigma, c.noise_theta)
        self.sample_rng = np.random.default_rng([cfg.seed, 1 + position])
        """Replay sampling only (used by the update thread; never shared with collection)."""
        self.algo.act_apart()  # collection acts with a copy of the actor, so the updates may run beside acting

    def prepare(self, obs: Any) -> None:
        """As :meth:`Learner.prepare`; then the actor that acts takes the weights of the updates so far."""
        super().prepare(obs)
        self.algo.sync_acting()

    def _explore(self, obs: Any, rng: np.random.Generator) -> Any:
        if self.collected < self.config.learning_starts:  # warm-up
            return self.xp.put(rng.uniform(-1.0, 1.0, (self.n_rows, self.act_dim)), float32=True)
        return self.algo.explore(obs, rng, self.noise)

    def updates_due(self) -> int:
        """Updates due at this step: they read the replay as it is before the step."""
        return self.algo.updates_due(self.collected, self.collected + int(self.active.sum()), len(self.replay))

    def draw(self, due: int) -> list[Any]:
        """The replay samples of ``due`` gradient updates, drawn now (in the order the updates take them): the
        replay may take new transitions once they are drawn."""
        return [self.replay.sample(self.config.batch_size, self.sample_rng) for _ in range(due)]

    def run_updates(self, due: int, batches: Sequence[Any] | None = None) -> None:
        """``due`` gradient updates on replay samples (``batches``: already :meth:`draw` n; the same ones);
        :class:`DivergenceError` says what is not finite."""
        for batch in self.draw(due) if batches is None else batches:
            try:
                stats = self.algo.update(batch)
            except DivergenceError as exc:  # the algorithm's own finite check of its update stats
                raise self.diverged(f"its losses are not finite ({exc})") from None
            bad = {k: v for k, v in stats.items() if not math.isfinite(v)}
            if bad:
                raise self.diverged(f"its losses are not finite: {bad}")
            self.add_stats(stats)
        if due:
            self.check_parameters()

    def _record(self, obs: Any, action: Any, reward: Any, next_obs: Any, terminated: Any, truncated: Any,
                valid: Any, played: np.ndarray) -> None:
        """Store the rows that played this step and are real steps: done = terminated (a draw by time limit
        bootstraps); with n-step returns, the n-step transitions the step completes."""
        if self.nstep is not None:
            self.replay.add_batch(**self.nstep.push(obs, action, reward, next_obs, terminated, truncated, valid,
                                                    played))
            return
        del truncated
        keep = valid & self.xp.put(played)  # (on the device the rows kept are gathered there)
        self.replay.add_batch(obs[keep], action[keep], reward[keep], next_obs[keep], terminated[keep])

    def _reset_rows(self, rows: np.ndarray) -> None:
        if self.noise is not None:
            self.noise.reset(rows)

    def state_dict(self, replay: bool = True) -> State:
        noise = self.noise.state_dict() if self.noise is not None else {}
        state = super().state_dict()
        state.json["sample_rng"] = self.sample_rng.bit_generator.state
        state.arrays |= {f"noise.{k}": v for k, v in noise.items()}
        if self.nstep is not None:
            state.arrays |= {f"nstep.{k}": v for k, v in self.nstep.state_dict().items()}
        state.replay = self.replay.state_dict() if replay else None
        return state

    def load_state_dict(self, state: State) -> None:
        super().load_state_dict(state)
        self.sample_rng.bit_generator.state = state.json["sample_rng"]
        if self.noise is not None:
            self.noise.load_state_dict({k.removeprefix("noise."): v for k, v in state.arrays.items()
                                        if k.startswith("noise.")})
        if self.nstep is not None:
            self.nstep.load_state_dict({k.removeprefix("nstep."): v for k, v in state.arrays.items()
                                        if k.startswith("nstep.")})
        if state.replay is not None:
            keys = (*self.replay.fields, "pos", "size", "capacity")
            absent = [k for k in keys if k not in state.replay]
            if absent:
                raise KeyError(f"replay arrays {[f'{self.name}.{k}' for k in absent]}")
            self.replay.load_state_dict({k: state.replay[k] for k in keys})


class PPOLearner(Learner):
    """PPO: samples its policy, records ``(T, n_rows)`` rollouts, updates when one is full."""

    algo: PPO

    def _explore(self, obs: Any, rng: np.random.Generator) -> Any:
        return self.algo.explore(obs, rng)

    def _record(self, obs: Any, action: Any, reward: Any, next_obs: Any, terminated: Any, truncated: Any,
                valid: Any, played: np.ndarray) -> None:
        """Record the step of every row; rows out of play or with a physics error are invalid."""
        del obs, action
        xp = self.xp
        ok = valid & xp.put(played)
        self.algo.record(xp.where(ok, reward, 0.0), xp.where(ok, terminated, True), xp.where(ok, truncated, False),
                         next_obs, valid=ok)

    def learn(self, obs: Any) -> None:
        """Train on the rollout if it is full (``obs``: the rows' observations now)."""
        if not self.algo.rollout_full:
            return
        try:
            stats = self.algo.update(obs)
        except DivergenceError as exc:  # the algorithm's own finite check of its update stats
            raise self.diverged(str(exc)) from None
        self.add_stats(stats)
        self.check_parameters()

    def state_dict(self, replay: bool = True) -> State:
        state = super().state_dict()
        state.arrays |= {f"rollout.{k}": v for k, v in self.algo.rollout_state().items()}
        return state

    def load_state_dict(self, state: State) -> None:
        super().load_state_dict(state)
        self.algo.load_rollout_state({k.removeprefix("rollout."): v for k, v in state.arrays.items()
                                      if k.startswith("rollout.")})


def make_learner(spec: LearnerSpec, index: list[int], position: int, cfg: TrainConfig, obs_dim: int, act_dim: int,
                 device: torch.device | None = None, elimination: bool = False) -> OffPolicyLearner | PPOLearner:
    """The learner for ``spec`` (``position``: its place among the run's learners, which offsets its seeds;
    ``device``: where a device-resident collection keeps its tensors, None for numpy; ``elimination``: agents
    may leave their match before it ends)."""
    cls = PPOLearner if spec.algo == "ppo" else OffPolicyLearner
    return cls(spec, index, position, cfg, obs_dim, act_dim, device, elimination)


class UpdateThread:
    """The long-lived thread that runs the overlapped off-policy updates of every step, one job after another
    (:func:`update_thread`: one per process). A thread started per step cost its creation and the wait for it to
    run at every collection step. Each job runs with the torch thread count of the thread that submitted it."""

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue[tuple[Callable[[], None], int]] = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._loop, name="offpolicy-updates", daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while True:
            job, threads = self._jobs.get()
            if torch.get_num_threads() != threads:  # (a thread keeps the count it first ran with)
                torch.set_num_threads(threads)
            job()

    def submit(self, job: Callable[[], None]) -> None:
        """Run ``job`` in the thread, after the jobs before it (``job`` keeps its own errors)."""
        self._jobs.put((job, torch.get_num_threads()))


_UPDATE_THREAD: tuple[int, UpdateThread] | None = None


def update_thread() -> UpdateThread:
    """This process's :class:`UpdateThread`, started on first use (again in a forked child)."""
    global _UPDATE_THREAD
    if _UPDATE_THREAD is None or _UPDATE_THREAD[0] != os.getpid() or not _UPDATE_THREAD[1].thread.is_alive():
        _UPDATE_THREAD = (os.getpid(), UpdateThread())
    return _UPDATE_THREAD[1]


class Updates:
    """The off-policy updates due at one collection step (every learner's, in turn), computed before the step
    (they read the replay as it was): :meth:`begin` runs them in the :class:`UpdateThread` beside acting and the
    physics (``overlap``: the GIL is released in MuJoCo's batch and in torch's kernels; the learners act with a
    copy of their actor) or inline; they draw every replay sample first, and :meth:`drawn` waits for that (the
    replay may then take the step's transitions); :meth:`finish` waits for them and raises what stopped them.
    Overlapped or not, the result is bit for bit the same."""

    def __init__(self, learners: Sequence[Learner]) -> None:
        self.due = [(lr, d) for lr in learners if isinstance(lr, OffPolicyLearner) and (d := lr.updates_due())]
        self.seconds = 0.0
        self.error: BaseException | None = None
        self._launched = False
        self._drawn = threading.Event()
        self._done = threading.Event()

    @property
    def overlapped(self) -> bool:
        """Whether they run in the thread (else they ran inline in :meth:`begin`)."""
        return self._launched

    def begin(self, overlap: bool) -> Updates:
        if self.due and overlap:
            self._launched = True
            update_thread().submit(self.run)
        elif self.due:
            self.run()
        return self

    def run(self) -> None:
        t = time.perf_counter()
        try:
            drawn = [(learner, due, learner.draw(due)) for learner, due in self.due]
            self._drawn.set()
            for learner, due, batches in drawn:
                learner.run_updates(due, batches)
        except BaseException as exc:  # re-raised in the collecting thread by finish()
            self.error = exc
        finally:
            self.seconds = time.perf_counter() - t
            self._drawn.set()
            self._done.set()

    def drawn(self) -> None:
        """Wait until the updates have drawn their replay samples."""
        if self._launched:
            self._drawn.wait()

    def finish(self) -> None:
        if self._launched:
            self._done.wait()
        if self.error is not None:
            raise self.error
