"""The training loop: one DDPG learner in several matches at once, resumable.

Reads like the paper: collect a step of every match (learner acts with exploration
noise, the others follow their fixed policies), store the learner's transitions, and
every ``learn_every`` collected transitions do ``gradient_steps`` DDPG updates. Each
finished match is one *epoch*: its outcome, steps and rewards become a row of the
metrics CSV; the match is reset with fresh seeded noise.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from triplesumo import ENV_VERSION, __version__
from triplesumo.agents.builtin import act_batch
from triplesumo.agents.policy_file import save_policy
from triplesumo.agents.zoo import policies_from_pairs
from triplesumo.algos.ddpg import DDPG, DDPGConfig
from triplesumo.algos.noise import make_noise
from triplesumo.algos.replay import ReplayBuffer
from triplesumo.envs.batch import MatchBatch
from triplesumo.envs.match import ACTION_SIZE
from triplesumo.evaluation.metrics import local_winning_rate, moving_winning_rate
from triplesumo.rules.config import MatchConfig, RewardConfig
from triplesumo.rules.outcome import ERROR_CODE, outcome_name
from triplesumo.rules.rewards import TERMS
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


def config_to_json(cfg: TrainConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def config_from_json(data: dict[str, Any]) -> TrainConfig:
    data = dict(data)
    data["reward"] = RewardConfig(**data["reward"])
    data["ddpg"] = DDPGConfig(**data["ddpg"])
    data["policies"] = tuple(data["policies"])
    return TrainConfig(**data)


def command_for(cfg: TrainConfig) -> str:
    """The ``triplesumo train`` command line that makes ``cfg`` (its non-default options)."""
    from triplesumo import _dcargs

    return " ".join(shlex.quote(a) for a in ["triplesumo", "train", *_dcargs.to_argv(cfg)])


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
        try:
            for _ in range(self.due):
                batch = self.trainer.replay.sample(cfg.ddpg.batch_size, self.trainer.sample_rng)
                self.trainer.last_losses = self.trainer.agent.update(batch)
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
                 command: str | None = None) -> None:
        self.cfg = cfg
        agent_names = [a.name for a in MatchConfig().agents]
        if cfg.learner not in agent_names:
            raise ValueError(f"TrainConfig.learner must be one of {agent_names}, got {cfg.learner!r}")
        unknown = [p.split("=")[0] for p in cfg.policies if p.split("=")[0] not in agent_names]
        if unknown:
            raise ValueError(f"TrainConfig.policies names unknown agents {unknown}; agents are {agent_names}")
        self.run_dir = prepare_run_dir(Path(run_dir) if run_dir else Path(cfg.out) / cfg.name)
        self.command = command or command_for(cfg)
        torch.set_num_threads(cfg.torch_threads)
        self.match_cfg = MatchConfig(max_steps=cfg.steps_per_epoch, obs_mode=cfg.obs_mode, reward=cfg.reward)
        self.batch = MatchBatch(self.match_cfg, cfg.n_envs, cfg.n_threads)
        probe = self.batch.matches[0]
        self.L = probe.agents.index(cfg.learner)  # learner and policy agents were checked above
        self.policies = policies_from_pairs(cfg.policies, cfg.seed, cfg.obs_mode)
        self.others = [(probe.agents.index(a), p) for a, p in self.policies.items()]
        self.obs_dim = probe.observer.sizes[cfg.learner]
        self.agent = DDPG(self.obs_dim, ACTION_SIZE, cfg.ddpg, seed=cfg.seed)
        self.replay = ReplayBuffer(cfg.ddpg.buffer_size, self.obs_dim, ACTION_SIZE)
        self.noise = make_noise(cfg.ddpg.noise, (cfg.n_envs, ACTION_SIZE), cfg.ddpg.noise_sigma,
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
            self._restore()
        else:
            for k in range(cfg.n_envs):
                self.obs.append(self.batch.reset_one(k, seed=self._episode_seed())[0])
            (self.run_dir / "config.json").write_text(json.dumps(config_to_json(cfg), indent=2) + "\n")
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
        actions = np.zeros((n, self.batch.matches[0].n_agents, ACTION_SIZE))
        if self.env_steps < cfg.ddpg.learning_starts:
            learner_act = self.rng.uniform(-1.0, 1.0, (n, ACTION_SIZE))  # warm-up: the learner only
        else:
            learner_act = np.clip(self.agent.act(obs) + self.noise.sample(self.rng), -1.0, 1.0)
        actions[:, self.L] = learner_act
        for i, policy in self.others:
            actions[:, i] = act_batch(policy, self._stacked_obs(i))
        t1 = time.perf_counter()
        # The DDPG updates due at this step learn from the replay as it was before the step,
        # so they can run while MuJoCo steps the matches (GIL released in mujoco.batch and in
        # torch's kernels). Overlapped or not, the result is bit for bit the same.
        before = self.env_steps
        after = before + n
        due = 0
        if after >= cfg.ddpg.learning_starts and len(self.replay) >= cfg.ddpg.batch_size:
            due = (after // cfg.ddpg.learn_every - before // cfg.ddpg.learn_every) * cfg.ddpg.gradient_steps
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
                done.append(1.0 if res.terminated else 0.0)  # bootstrap through a draw by time limit
            if res.terminated or res.truncated:
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
        save_policy(self.run_dir / "policy", self.agent.actor, self.manifest())
        return folder

    def _restore(self) -> None:
        folder = checkpoint.latest(self.run_dir)
        tensors, state, arrays, replay = checkpoint.load(folder, need_replay=self.cfg.save_replay)
        need_state = ("config", "optimizer", "rng", "sample_rng", "matches", "epochs_done", "env_steps", "acc")
        missing = [k for k in need_state if k not in state]
        if missing:
            raise checkpoint.CheckpointError(f"{folder / 'state.json'}: missing entries {missing}")
        need_arrays = ["lwr"] + [f"match{k}.{part}" for k in range(self.cfg.n_envs)
                                 for part in ("physics", "last_obs", "warnings", "obs")]
        missing = [k for k in need_arrays if k not in arrays]
        if missing:
            raise checkpoint.CheckpointError(f"{folder / 'arrays.npz'}: missing arrays {missing[:5]}")
        try:
            self._restore_from(folder, tensors, state, arrays, replay)
        except (KeyError, IndexError, TypeError, ValueError, RuntimeError) as exc:
            if isinstance(exc, checkpoint.CheckpointError):
                raise
            raise checkpoint.CheckpointError(
                f"{folder} (state.json / arrays.npz / weights.safetensors): missing or malformed entry: "
                f"{exc!r}") from exc

    def _restore_from(self, folder: Path, tensors: dict[str, torch.Tensor], state: dict[str, Any],
                      arrays: dict[str, np.ndarray], replay: dict[str, np.ndarray] | None) -> None:
        saved = config_from_json(state["config"])
        for name in ("learner", "obs_mode", "n_envs", "steps_per_epoch", "policies", "reward", "ddpg", "seed"):
            # (save_replay may differ: resuming without the replay buffer is allowed, not exact)
            if getattr(saved, name) != getattr(self.cfg, name):
                raise checkpoint.CheckpointError(
                    f"{folder / 'state.json'}: incompatible checkpoint: it was made with {name}="
                    f"{getattr(saved, name)!r}, this run has {getattr(self.cfg, name)!r}")
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


def train(cfg: TrainConfig, resume_dir: Path | None = None, overrides: dict[str, Any] | None = None) -> TrainResult:
    """Start a run, or resume the one in ``resume_dir`` (with e.g. more epochs)."""
    if resume_dir is not None:
        resume_dir = Path(resume_dir)
        from triplesumo.agents.policy_file import load_json

        saved = config_from_json(load_json(resume_dir / "config.json"))
        cfg = dataclasses.replace(saved, **(overrides or {}))
        trainer = Trainer(cfg, run_dir=resume_dir, resume=True)
    else:
        trainer = Trainer(cfg)
    return trainer.run()
