"""The training loop: one DDPG learner in several matches at once, resumable.

Reads like the paper: collect a step of every match (learner acts with exploration
noise, the others follow their fixed policies), store the learner's transitions, and
every ``learn_every`` collected transitions do ``gradient_steps`` DDPG updates. Each
finished match is one *epoch*: its outcome, steps and rewards become a row of the
metrics CSV; the match is reset with fresh seeded noise.

Nothing is lost: a folder that already holds a run is never trained into again without
``resume`` (continue it) or ``start_over`` (move it aside first); the memory the replay
buffer needs is checked before anything is made; a learner whose losses, parameters or
actions stop being finite stops the run with a :class:`DivergenceError` naming the
learner, the update and the last good checkpoint.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shlex
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from triplesumo import ENV_VERSION, __version__
from triplesumo.agents.builtin import act_batch
from triplesumo.agents.policy_file import atomic_write_bytes, load_json, save_policy
from triplesumo.agents.zoo import expand_pairs, policies_from_pairs
from triplesumo.algos.base import DivergedError
from triplesumo.algos.ddpg import DDPG, DDPGConfig
from triplesumo.algos.noise import make_noise
from triplesumo.algos.replay import FIELDS, ReplayBuffer
from triplesumo.envs.batch import MatchBatch
from triplesumo.envs.match import Match
from triplesumo.evaluation.metrics import local_winning_rate, moving_winning_rate
from triplesumo.rules.config import RewardConfig
from triplesumo.rules.outcome import ERROR_CODE, outcome_name
from triplesumo.rules.rewards import TERMS
from triplesumo.rules.scenarios import scenario_config
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig
from triplesumo.train.logger import MetricsLog


@dataclass
class TrainResult:
    """Where a finished (or stopped) run stands."""

    run_dir: Path
    epochs: int
    env_steps: int
    updates: int
    mwr: float
    seconds: float
    timers: dict[str, float] = field(default_factory=dict)
    """Seconds spent in physics+rules (``env``), acting (``act``) and learning (``learn``)."""


RUN_FILES = ("config.json", "metrics.csv", "checkpoints", "policy.json", "policy.safetensors")
"""What makes a folder hold a run: training never writes into such a folder afresh."""


class RunExistsError(FileExistsError):
    """The run folder already holds a run (the message offers ``--resume`` and ``--start-over``)."""


class DivergenceError(FloatingPointError):
    """The learner's losses, parameters or actions are no longer finite (names learner, update, checkpoint)."""


def config_to_json(cfg: TrainConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def _check_keys(data: Any, cls: type, where: str, source: str) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ValueError(f"{source}: {where or 'the file'} must be a JSON object, got {type(data).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown, missing = sorted(set(data) - names), sorted(names - set(data))
    if unknown or missing:
        problems = [f"unknown key(s) {[where + k for k in unknown]}"] if unknown else []
        problems += [f"missing key(s) {[where + k for k in missing]}"] if missing else []
        raise ValueError(f"{source}: {' and '.join(problems)} (a {cls.__name__} has {sorted(names)})")
    return dict(data)


def config_from_json(data: dict[str, Any], source: str = "config.json") -> TrainConfig:
    """The :class:`TrainConfig` saved as ``data``; ``ValueError`` names ``source`` and any unknown or
    missing key (a config written by another version, or edited by hand)."""
    data = _check_keys(data, TrainConfig, "", source)
    data["reward"] = RewardConfig(**_check_keys(data["reward"], RewardConfig, "reward.", source))
    data["ddpg"] = DDPGConfig(**_check_keys(data["ddpg"], DDPGConfig, "ddpg.", source))
    data["policies"] = tuple(data["policies"])
    try:
        return TrainConfig(**data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from exc


def command_for(cfg: TrainConfig) -> str:
    """The ``triplesumo train`` command line that makes ``cfg`` (its non-default options)."""
    from triplesumo import _dcargs

    return " ".join(shlex.quote(a) for a in ["triplesumo", "train", *_dcargs.to_argv(cfg)])


def holds_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds (part of) a training run."""
    return any((Path(run_dir) / name).exists() for name in RUN_FILES)


def refuse_existing_run(run_dir: Path, start_over: bool) -> Path | None:
    """Refuse to train afresh into a folder holding a run; with ``start_over`` move it aside.

    Returns where the old run went (``RUN.old-K``, the first free K), or None.
    """
    run_dir = Path(run_dir)
    if not holds_run(run_dir):
        return None
    if not start_over:
        raise RunExistsError(
            f"run folder {run_dir} already holds a run ({', '.join(n for n in RUN_FILES if (run_dir / n).exists())}); "
            f"nothing was changed. Continue it with `triplesumo train --resume {run_dir}` (add --epochs N for more), "
            f"or start over with the same command plus --start-over (the old run is moved to {run_dir}.old-K), "
            "or choose another --name")
    k = 1
    while (aside := run_dir.with_name(f"{run_dir.name}.old-{k}")).exists():
        k += 1
    with checkpoint.writing(aside):
        os.replace(run_dir, aside)
    print(f"start over: the earlier run in {run_dir} was moved to {aside}")
    return aside


def replay_bytes(capacity: int, obs_dim: int, act_dim: int) -> int:
    """Bytes a full replay buffer of ``capacity`` transitions takes (float32 arrays)."""
    return capacity * (2 * obs_dim + act_dim + 2) * 4


def machine_memory() -> int:
    """Physical memory plus swap of this machine, in bytes (0 if unknown)."""
    try:
        info = dict(line.split(":", 1) for line in Path("/proc/meminfo").read_text().splitlines() if ":" in line)
        return sum(int(info[k].split()[0]) * 1024 for k in ("MemTotal", "SwapTotal") if k in info)
    except (OSError, ValueError):
        try:
            return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):
            return 0


def check_replay_memory(cfg: TrainConfig, obs_dim: int, act_dim: int) -> None:
    """``ValueError`` naming ``TrainConfig.ddpg.buffer_size`` if a full buffer cannot fit this machine."""
    need, have = replay_bytes(cfg.ddpg.buffer_size, obs_dim, act_dim), machine_memory()
    if have and need > have:
        raise ValueError(f"TrainConfig.ddpg.buffer_size={cfg.ddpg.buffer_size} needs {need / 2**30:.1f} GiB for a "
                         f"full replay buffer ({obs_dim}-value observations), more than this machine's "
                         f"{have / 2**30:.1f} GiB of memory and swap; nothing was made")


def prepare_run_dir(run_dir: Path) -> Path:
    """Create the run folder and prove it is writable now, not after hours."""
    run_dir = Path(run_dir)
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / ".write-test"
        probe.write_bytes(b"ok")
        probe.unlink()
    except OSError as exc:
        raise PermissionError(f"run folder {run_dir} is not writable: {exc.strerror or exc}") from exc
    return run_dir


class _Learner(threading.Thread):
    """Runs the DDPG updates due at one collection step, in a thread or inline."""

    def __init__(self, trainer: Trainer, due: int) -> None:
        super().__init__(name="ddpg-updates", daemon=True)
        self.trainer, self.due, self.seconds = trainer, due, 0.0
        self.error: BaseException | None = None
        self._launched = False

    def start(self) -> None:
        self._launched = True
        super().start()

    def run(self) -> None:
        t, cfg = time.perf_counter(), self.trainer.cfg
        trainer = self.trainer
        try:
            for _ in range(self.due):
                batch = trainer.replay.sample(cfg.ddpg.batch_size, trainer.sample_rng)
                try:
                    trainer.last_losses = losses = trainer.agent.update(batch)
                except DivergedError as exc:  # the learner's own finite check of its update stats
                    raise trainer.diverged(f"its losses are not finite ({exc})") from None
                bad = {k: v for k, v in losses.items() if not math.isfinite(v)}
                if bad:
                    raise trainer.diverged(f"its losses are not finite: {bad}")
            if self.due:
                bad_params = [name for name, p in trainer.parameters if not bool(torch.isfinite(p).all())]
                if bad_params:
                    raise trainer.diverged(f"its parameters are not finite: {bad_params[:4]}")
        except BaseException as exc:  # re-raised in the collecting thread by finish()
            self.error = exc
        self.seconds = time.perf_counter() - t

    def finish(self) -> None:
        if self._launched:
            self.join()
        if self.error is not None:
            raise self.error


class Trainer:
    """Trains ``cfg.learner`` with DDPG; :meth:`run` until ``cfg.epochs`` or ``max_minutes``."""

    def __init__(self, cfg: TrainConfig, run_dir: Path | None = None, resume: bool = False,
                 command: str | None = None, start_over: bool = False, from_checkpoint: str | None = None) -> None:
        self.cfg = cfg
        self.match_cfg = scenario_config(cfg.scenario, max_steps=cfg.steps_per_epoch, obs_mode=cfg.obs_mode,
                                         reward=cfg.reward)
        agent_names = list(self.match_cfg.agent_names)
        if cfg.learner not in agent_names:
            raise ValueError(f"TrainConfig.learner must be one of {agent_names} (scenario {cfg.scenario!r}), "
                             f"got {cfg.learner!r}")
        pairs = expand_pairs(cfg.policies, [a for a in agent_names if a != cfg.learner])
        unknown = [p.split("=")[0] for p in pairs if p.split("=")[0] not in agent_names]
        if unknown:
            raise ValueError(f"TrainConfig.policies names unknown agents {unknown}; agents are {agent_names}")
        run_dir = Path(run_dir) if run_dir else Path(cfg.out) / cfg.name
        if not resume:
            refuse_existing_run(run_dir, start_over)
        sizing = Match(self.match_cfg)
        check_replay_memory(cfg, sizing.observer.sizes[cfg.learner],
                            sizing.action_sizes[sizing.agents.index(cfg.learner)])
        self.run_dir = prepare_run_dir(run_dir)
        self.command = command or command_for(cfg)
        torch.set_num_threads(cfg.torch_threads)
        self.batch = MatchBatch(self.match_cfg, cfg.n_envs, cfg.n_threads)
        probe = self.batch.matches[0]
        self.L = probe.agents.index(cfg.learner)  # learner and policy agents were checked above
        try:
            self.policies = policies_from_pairs(
                pairs, cfg.seed, cfg.obs_mode, obs_dims=probe.observer.sizes,
                action_sizes=dict(zip(probe.agents, probe.action_sizes, strict=True)))
        except ValueError as err:
            raise ValueError(f"TrainConfig.policies (scenario {cfg.scenario!r}): {err}") from None
        self.others = [(probe.agents.index(a), p) for a, p in self.policies.items()]
        self.obs_dim = probe.observer.sizes[cfg.learner]
        self.act_dim = probe.action_sizes[self.L]
        self.agent = DDPG(self.obs_dim, self.act_dim, cfg.ddpg, seed=cfg.seed)
        self.parameters = [(f"{owner}.{name}", p) for owner, module in vars(self.agent).items()
                           if isinstance(module, torch.nn.Module) for name, p in module.named_parameters()]
        """Every parameter of the learner's networks, checked to be finite after its updates."""
        self.replay = ReplayBuffer(cfg.ddpg.buffer_size, self.obs_dim, self.act_dim)
        self.noise = make_noise(cfg.ddpg.noise, (cfg.n_envs, self.act_dim), cfg.ddpg.noise_sigma,
                                cfg.ddpg.noise_theta)
        self.rng = np.random.default_rng(cfg.seed)
        self.sample_rng = np.random.default_rng([cfg.seed, 1])
        """Replay sampling only (used by the update thread; never shared with collection)."""
        self.epochs_done = 0
        self.env_steps = 0
        self.lwr: list[float] = []
        self.finished_epoch_steps: list[int] = []
        """Length of every epoch finished by this process (not restored on resume)."""
        self.acc = [self._empty_acc() for _ in range(cfg.n_envs)]
        self.obs: list[list[np.ndarray]] = []
        self.timers = {"env": 0.0, "act": 0.0, "learn": 0.0, "wait": 0.0}
        """Seconds collecting (physics and rules), acting, learning (busy, in the update
        thread: overlaps "env" when overlap_learning is on) and waiting for learning."""
        self.last_losses: dict[str, float] = {}
        if resume:
            self._restore(from_checkpoint)
        else:
            for k in range(cfg.n_envs):
                self.obs.append(self.batch.reset_one(k, seed=self._episode_seed())[0])
            with checkpoint.writing(self.run_dir / "config.json"):
                atomic_write_bytes(self.run_dir / "config.json",
                                   (json.dumps(config_to_json(cfg), indent=2) + "\n").encode())
        self.log = MetricsLog(self.run_dir, self.epochs_done if resume else None, cfg.tensorboard)

    # ------------------------------------------------------------------ helpers
    def _episode_seed(self) -> int:
        return int(self.rng.integers(2**31 - 1))

    @staticmethod
    def _empty_acc() -> dict[str, float]:
        return dict.fromkeys(("dense_reward", "sparse_reward", *TERMS), 0.0)

    def _stacked_obs(self, agent: int) -> np.ndarray:
        return np.stack([o[agent] for o in self.obs])

    # -------------------------------------------------------------------- loop
    def collect_step(self) -> int:
        """Step every match once; returns the number of epochs that finished."""
        cfg, n = self.cfg, self.cfg.n_envs
        t0 = time.perf_counter()
        obs = self._stacked_obs(self.L)
        self.agent.observe(obs)  # the running observation normaliser (a no-op at the paper preset)
        probe = self.batch.matches[0]
        actions = np.zeros((n, probe.n_agents, probe.action_width))
        if self.env_steps < cfg.ddpg.learning_starts:
            learner_act = self.rng.uniform(-1.0, 1.0, (n, self.act_dim))  # warm-up: the learner only
        else:
            raw = self.agent.act(obs)
            if not np.isfinite(raw).all():
                raise self.diverged("its actions are not finite")
            learner_act = np.clip(raw + self.noise.sample(self.rng), -1.0, 1.0)
        actions[:, self.L, :self.act_dim] = learner_act
        for i, policy in self.others:
            actions[:, i, :probe.action_sizes[i]] = act_batch(policy, self._stacked_obs(i))
        t1 = time.perf_counter()
        # The DDPG updates due at this step learn from the replay as it was before the step,
        # so they can run while MuJoCo steps the matches (GIL released in mujoco.batch and in
        # torch's kernels). Overlapped or not, the result is bit for bit the same.
        before = self.env_steps
        after = before + n
        due = self.agent.updates_due(before, after, len(self.replay))
        learner = _Learner(self, due)
        if due and cfg.overlap_learning:
            learner.start()
        elif due:
            learner.run()
        results = self.batch.step(actions)
        t2 = time.perf_counter()
        learner.finish()
        t_joined = time.perf_counter()
        keep, rew, next_obs, done = [], [], [], []
        finished = 0
        self.env_steps = after  # counted before epochs end, so their rows include this step
        for k, res in enumerate(results):
            info = res.infos[self.L]
            acc = self.acc[k]
            for key in acc:
                acc[key] += info[key]
            if info["outcome"] != ERROR_CODE:  # a physics error's transition is dropped, never learned from
                keep.append(k)
                rew.append(res.rewards[self.L])
                next_obs.append(res.observations[self.L])
                out = res.eliminated is not None and res.eliminated[self.L]  # the learner left the match
                done.append(1.0 if res.terminated or out else 0.0)  # bootstrap through a draw by time limit
            if res.terminated or res.truncated or (res.eliminated is not None and res.eliminated[self.L]):
                finished += 1
                self._end_epoch(k, info)
                self.obs[k] = self.batch.reset_one(k, seed=self._episode_seed())[0]
                self.noise.reset(np.arange(n) == k)
            else:
                self.obs[k] = res.observations
        if keep:
            self.replay.add_batch(obs[keep], learner_act[keep], np.array(rew), np.stack(next_obs), np.array(done))
        t3 = time.perf_counter()
        self.timers["act"] += t1 - t0
        self.timers["env"] += (t2 - t1) + (t3 - t_joined)
        self.timers["learn"] += learner.seconds  # overlapped with "env" when overlap_learning is on
        self.timers["wait"] += t_joined - t2
        return finished

    def _end_epoch(self, k: int, info: dict[str, Any]) -> None:
        self.epochs_done += 1
        acc = self.acc[k]
        outcome = outcome_name(info["outcome"])
        lwr = float(local_winning_rate([outcome])[0])
        self.lwr.append(lwr)
        self.finished_epoch_steps.append(int(info["step"]))
        total = acc["dense_reward"] + acc["sparse_reward"]
        row = {"epoch": self.epochs_done, "outcome": outcome, "local_winning_rate": lwr,
               "steps": info["step"], "total_reward": total, **acc, "env_steps": self.env_steps,
               "wall_time": round(time.time(), 3)}
        self.log.epoch(row, self.mwr())
        self.acc[k] = self._empty_acc()

    def mwr(self) -> float:
        """MWR over the last λ epochs (mean over what exists for the first λ-1)."""
        if not self.lwr:
            return 0.0
        return float(moving_winning_rate(np.array(self.lwr[-self.cfg.window:]), self.cfg.window)[-1])

    def last_good(self) -> str:
        """Where the run can go on from: its latest checkpoint, in words."""
        try:
            folder = checkpoint.latest(self.run_dir)
        except checkpoint.CheckpointError:
            return "no checkpoint was saved before it (no good one exists)"
        return (f"the last good checkpoint {folder} is intact; "
                f"`triplesumo train --resume {self.run_dir}` continues from it")

    def diverged(self, what: str) -> DivergenceError:
        """The error that stops a diverging learner: names it, its update count and the last good checkpoint."""
        return DivergenceError(f"learner {self.cfg.learner!r} diverged at update {self.agent.num_updates} "
                               f"(epoch {self.epochs_done}, env step {self.env_steps}): {what}. Stopped; "
                               f"{self.last_good()}. Lower the learning rates (--ddpg.actor-lr, --ddpg.critic-lr) "
                               "or the reward scale")

    def run(self) -> TrainResult:
        cfg = self.cfg
        start = time.perf_counter()
        start_steps = self.env_steps
        bar = None
        if cfg.progress:
            from tqdm import tqdm

            bar = tqdm(total=cfg.epochs, initial=min(self.epochs_done, cfg.epochs), unit="epoch",
                       desc=f"train {cfg.learner}", dynamic_ncols=True)
        try:
            while self.epochs_done < cfg.epochs:
                before = self.epochs_done
                finished = self.collect_step()
                if finished and bar is not None:
                    bar.update(min(self.epochs_done, cfg.epochs) - min(before, cfg.epochs))
                    rate = (self.env_steps - start_steps) / max(time.perf_counter() - start, 1e-9)
                    bar.set_postfix(MWR=f"{self.mwr():+.3f}", steps_s=f"{rate:.0f}", refresh=False)
                crossed = finished and (self.epochs_done // cfg.checkpoint_every > before // cfg.checkpoint_every)
                timed_out = cfg.max_minutes > 0 and (time.perf_counter() - start) > cfg.max_minutes * 60
                if crossed or (timed_out and finished) or self.epochs_done >= cfg.epochs:
                    self.save()
                if timed_out and finished:
                    break
        except checkpoint.CheckpointWriteError as exc:
            if "last good checkpoint" in str(exc) or "no earlier checkpoint" in str(exc):
                raise
            raise checkpoint.CheckpointWriteError(exc.errno, f"{exc.strerror}; {self.last_good()}") from exc
        finally:
            if bar is not None:
                bar.close()
            self.log.close()
        self.finish_outputs()
        return TrainResult(self.run_dir, self.epochs_done, self.env_steps, self.agent.num_updates, self.mwr(),
                           time.perf_counter() - start, dict(self.timers))

    # ---------------------------------------------------------- checkpoints
    def manifest(self) -> dict[str, Any]:
        probe = self.batch.matches[0]
        spec = {a.name: a for a in self.match_cfg.agents}[self.cfg.learner]
        return {
            "agent": self.cfg.learner, "obs_mode": self.cfg.obs_mode,
            "action_scaling": f"normalised [-1, 1] scaled linearly to ctrl [-{spec.ctrl_range}, {spec.ctrl_range}]",
            "ctrl_range": spec.ctrl_range, "env_version": ENV_VERSION, "triplesumo_version": __version__,
            "mujoco_version": mujoco.__version__, "torch_version": torch.__version__,
            "seed": self.cfg.seed, "epochs": self.epochs_done, "env_steps": self.env_steps,
            "command": self.command, "trained_against": list(self.cfg.policies),
            "agents": list(probe.agents),
        }

    def save(self) -> Path:
        self.log.flush()
        opt_tensors, opt_meta = self.agent.optimizer_state()
        tensors = {**self.agent.state_dict(), **{f"optim.{k}": v for k, v in opt_tensors.items()}}
        snaps = [m.snapshot() for m in self.batch.matches]
        arrays: dict[str, np.ndarray] = {f"noise.{k}": v for k, v in self.noise.state_dict().items()}
        for k, s in enumerate(snaps):
            arrays[f"match{k}.physics"] = s["physics"]
            arrays[f"match{k}.last_obs"] = s["last_obs"]
            arrays[f"match{k}.warnings"] = s["warnings"]
            arrays[f"match{k}.obs"] = np.stack(self.obs[k])
        arrays["lwr"] = np.array(self.lwr)
        state = {
            "config": config_to_json(self.cfg), "manifest": self.manifest(), "epochs_done": self.epochs_done,
            "env_steps": self.env_steps, "optimizer": opt_meta, "rng": self.rng.bit_generator.state,
            "sample_rng": self.sample_rng.bit_generator.state,
            "matches": [{"steps": s["steps"], "over": s["over"], "rng": s["rng"]} for s in snaps],
            "acc": self.acc, "timers": self.timers,
            "policy_rngs": {a: p.rng.bit_generator.state for a, p in self.policies.items() if hasattr(p, "rng")},
        }
        folder = checkpoint.save(self.run_dir, self.epochs_done, tensors, state, arrays,
                                 self.replay.state_dict() if self.cfg.save_replay else None)
        with checkpoint.writing(f"{self.run_dir / 'policy'}.safetensors/.json",
                                f"; the last good checkpoint {folder} is intact"):
            save_policy(self.run_dir / "policy", self.agent.actor, self.manifest(), obs_norm=self.agent.obs_norm)
        return folder

    def _restore(self, from_checkpoint: str | None) -> None:
        if from_checkpoint is not None:
            folder = checkpoint.find(self.run_dir, from_checkpoint)
            loaded = checkpoint.load(folder, need_replay=self.cfg.save_replay)
        else:
            try:
                folder = checkpoint.latest(self.run_dir)
                loaded = checkpoint.load(folder, need_replay=self.cfg.save_replay)
            except checkpoint.CheckpointError as exc:
                intact = checkpoint.newest_intact(self.run_dir)
                if intact is None:
                    raise
                raise checkpoint.CheckpointError(
                    f"{exc} -- the latest checkpoint is damaged or missing; the newest intact one is {intact.name} "
                    f"(epoch {checkpoint.recorded_epoch(intact)}): `triplesumo train --resume {self.run_dir} "
                    f"--from {intact.name}` continues from it (later epochs are trained again)") from exc
        tensors, state, arrays, replay = loaded
        need_state = ("config", "optimizer", "rng", "sample_rng", "matches", "epochs_done", "env_steps", "acc")
        missing = [k for k in need_state if k not in state]
        if missing:
            raise checkpoint.CheckpointError(f"{folder / 'state.json'}: missing entries {missing}")
        try:
            saved = config_from_json(state["config"], f"{folder / 'state.json'} (its config)")
        except ValueError as exc:
            raise checkpoint.CheckpointError(str(exc)) from exc
        for name in ("learner", "obs_mode", "n_envs", "steps_per_epoch", "policies", "reward", "ddpg", "seed"):
            # (save_replay may differ: resuming without the replay buffer is allowed, not exact)
            if getattr(saved, name) != getattr(self.cfg, name):
                raise checkpoint.CheckpointError(
                    f"{folder / 'state.json'}: incompatible checkpoint: it was made with {name}="
                    f"{getattr(saved, name)!r}, this run has {getattr(self.cfg, name)!r} (from config.json)")
        need_arrays = ["lwr"] + [f"match{k}.{part}" for k in range(self.cfg.n_envs)
                                 for part in ("physics", "last_obs", "warnings", "obs")]
        missing = [k for k in need_arrays if k not in arrays]
        if missing:
            raise checkpoint.CheckpointError(f"{folder / 'arrays.npz'}: missing arrays {missing[:5]}")
        if replay is not None and (absent := [k for k in (*FIELDS, "pos", "size", "capacity") if k not in replay]):
            raise checkpoint.CheckpointError(f"{folder / 'replay.npz'}: missing arrays {absent}")
        try:
            self._restore_from(folder, tensors, state, arrays, replay)
        except (KeyError, IndexError, TypeError, ValueError, RuntimeError) as exc:
            if isinstance(exc, checkpoint.CheckpointError):
                raise
            raise checkpoint.CheckpointError(
                f"{folder} (state.json / arrays.npz / replay.npz / weights.safetensors): missing or malformed "
                f"entry: {exc!r}") from exc

    def _restore_from(self, folder: Path, tensors: dict[str, torch.Tensor], state: dict[str, Any],
                      arrays: dict[str, np.ndarray], replay: Mapping[str, np.ndarray] | None) -> None:
        self.agent.load_state_dict({k: v for k, v in tensors.items() if not k.startswith("optim.")})
        self.agent.load_optimizer_state({k[6:]: v for k, v in tensors.items() if k.startswith("optim.")},
                                        state["optimizer"])
        self.noise.load_state_dict({k[6:]: v for k, v in arrays.items() if k.startswith("noise.")})
        if replay is not None:
            self.replay.load_state_dict(replay)
        self.rng.bit_generator.state = state["rng"]
        self.sample_rng.bit_generator.state = state["sample_rng"]
        for k, match in enumerate(self.batch.matches):
            meta = state["matches"][k]
            match.restore({"physics": arrays[f"match{k}.physics"], "last_obs": arrays[f"match{k}.last_obs"],
                           "warnings": arrays[f"match{k}.warnings"], **meta})
            self.batch.reload(k)
            self.obs.append(list(arrays[f"match{k}.obs"]))
        for agent, rng_state in state.get("policy_rngs", {}).items():
            self.policies[agent].rng.bit_generator.state = rng_state
        self.epochs_done = int(state["epochs_done"])
        self.env_steps = int(state["env_steps"])
        self.acc = state["acc"]
        self.lwr = [float(x) for x in arrays["lwr"]]
        self.timers = {**self.timers, **state.get("timers", {})}

    def finish_outputs(self) -> None:
        """Plots from the metrics CSV (skipped when the run has no finished epoch)."""
        from triplesumo.evaluation.plots import plot_run, read_metrics_csv

        metrics = read_metrics_csv(self.run_dir / "metrics.csv")
        if len(metrics["epoch"]):
            plot_run(metrics, self.run_dir / "plots", window=self.cfg.window,
                     title=f"{self.cfg.learner} training ({self.run_dir.name})", label=self.cfg.learner.capitalize())


def train(cfg: TrainConfig, resume_dir: Path | None = None, overrides: dict[str, Any] | None = None,
          start_over: bool = False, from_checkpoint: str | None = None) -> TrainResult:
    """Start a run, or resume the one in ``resume_dir`` (with e.g. more epochs).

    A new run refuses a folder that already holds a run (:class:`RunExistsError`) unless
    ``start_over``, which moves that run aside to ``RUN.old-K`` first. ``from_checkpoint``
    (``epoch-N``) resumes from an older checkpoint than the latest, e.g. when the latest is
    damaged; the epochs after it are trained again.
    """
    if resume_dir is not None:
        resume_dir = Path(resume_dir)
        saved = config_from_json(load_json(resume_dir / "config.json"), str(resume_dir / "config.json"))
        cfg = dataclasses.replace(saved, **(overrides or {}))
        trainer = Trainer(cfg, run_dir=resume_dir, resume=True, from_checkpoint=from_checkpoint)
    else:
        if from_checkpoint is not None:
            raise ValueError("--from needs --resume RUN_DIR (it names a checkpoint of that run)")
        trainer = Trainer(cfg, start_over=start_over)
    return trainer.run()
