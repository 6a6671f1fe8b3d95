"""Evaluation while training (``eval_every``), a piece beside the loop as SB3's ``EvalCallback`` is: every
``eval_every`` env steps each learner's current policy, frozen, plays the run's seeded test matches and a row
goes to its eval CSV. It draws on none of the training's generators: a run trains the same with or without it."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from triplesumo.agents.frozen import FrozenPolicy
from triplesumo.agents.zoo import policies_from_pairs
from triplesumo.envs.match import Match
from triplesumo.rules.config import MatchConfig
from triplesumo.train.config import TrainConfig
from triplesumo.train.learners import Learner
from triplesumo.train.logger import MetricsLog


def frozen_copy(learner: Learner) -> FrozenPolicy:
    """The learner's current deterministic policy as a numpy :class:`FrozenPolicy` (with its observation
    normaliser, frozen), what its policy file would hold now."""
    tensors = {f"actor.{k}": v.detach().cpu().numpy() for k, v in learner.algo.export_actor().state_dict().items()}
    norm = learner.algo.obs_norm
    if norm is not None:
        tensors |= {f"obs_norm.{k}": v.detach().cpu().numpy() for k, v in norm.state_dict().items()}
    return FrozenPolicy.from_tensors(tensors, prefix="actor.", obs_norm_prefix=None if norm is None else "obs_norm.")


class Evaluations:
    """The evaluations of a run: how many were made (:attr:`count`, the rows of each learner's eval CSV) and
    their wall time (:attr:`seconds`), over every session of the run."""

    def __init__(self, cfg: TrainConfig, match_cfg: MatchConfig, probe: Match, pairs: tuple[str, ...]) -> None:
        self.cfg, self.match_cfg, self.probe, self.pairs = cfg, match_cfg, probe, pairs
        self.count = 0
        """Evaluations made so far (``eval_every``): the rows of each learner's eval CSV."""
        self.seconds = 0.0
        """Wall time of the evaluations, over every session of the run."""

    def due(self, steps_before: int, steps_now: int) -> bool:
        """Whether a step from ``steps_before`` to ``steps_now`` env steps crossed a multiple of ``eval_every``."""
        every = self.cfg.eval_every
        return bool(every) and steps_now // every > steps_before // every

    def __call__(self, learners: Sequence[Learner], log: MetricsLog, env_steps: int, epochs: int,
                 train_seconds: float) -> bool:
        """Each learner's current policy, frozen (no exploration), on the run's seeded test matches
        (``eval_epochs`` from ``eval_seed``, on the CPU): a row of its eval CSV. True when every
        learner's test MWR reached ``eval_target``.

        The other agents play the run's fixed policies, built afresh from ``eval_seed`` (so every
        evaluation meets the same matches), and the other learners their current policies, frozen;
        a learner that plays several agents (``share="team"``) is rated in its first agent's seat.
        Nothing of the training is touched: it trains the same with or without evaluations."""
        from triplesumo.evaluation.evaluate import play_test_epochs
        from triplesumo.evaluation.metrics import summarize

        cfg, probe = self.cfg, self.probe
        t0 = time.perf_counter()
        fixed = policies_from_pairs(self.pairs, cfg.eval_seed, cfg.obs_mode, obs_dims=probe.observer.sizes,
                                    action_sizes=dict(zip(probe.agents, probe.action_sizes, strict=True)))
        frozen: dict[str, FrozenPolicy] = {}
        for learner in learners:
            policy = frozen_copy(learner)
            frozen |= {agent: policy for agent in learner.spec.agents}
        self.count += 1
        done: list[tuple[str, Any]] = []
        for learner in learners:
            agent = learner.spec.agents[0]
            others = {**fixed, **{a: p for a, p in frozen.items() if a != agent}}
            rows = play_test_epochs(frozen[agent], others, agent, cfg.eval_epochs, cfg.eval_seed, self.match_cfg,
                                    cfg.n_envs, cfg.n_threads)
            done.append((learner.name, summarize([r["outcome"] for r in rows], [r["steps"] for r in rows])))
        self.seconds += time.perf_counter() - t0
        for name, stats in done:
            log.evaluated(name, {
                "evaluation": self.count, "env_steps": env_steps, "epochs": epochs,
                "train_seconds": round(train_seconds, 3), "eval_seconds": round(self.seconds, 3),
                "test_matches": cfg.eval_epochs, "test_mwr": float(stats["mean_lwr"]),
                "test_mwr_lo": float(stats["mean_lwr_lo"]), "test_mwr_hi": float(stats["mean_lwr_hi"]),
                "n_win": stats["n_win"], "n_loss": stats["n_loss"], "n_draw": stats["n_draw"]})
            if cfg.progress:
                print(f"  evaluation {self.count} at {env_steps:,} env steps: {name} test MWR "
                      f"{float(stats['mean_lwr']):+.3f} [{float(stats['mean_lwr_lo']):+.3f}, "
                      f"{float(stats['mean_lwr_hi']):+.3f}] over {cfg.eval_epochs} matches")
        return cfg.eval_target is not None and all(float(stats["mean_lwr"]) >= cfg.eval_target for _, stats in done)
