"""The protocol: its stages in order, each with what it runs and when it is complete, and the contest rule's
verdict."""

from __future__ import annotations

import csv
import dataclasses
import json
import shlex
from pathlib import Path
from typing import Any

from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.agents.zoo import policy_fingerprint
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.algos.td3 import TD3Config
from triplesumo.evaluation.compare import CompareConfig, compare, format_compare
from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate
from triplesumo.evaluation.metrics_csv import open_table, read_table_bytes, table_exists
from triplesumo.model.specs import PhysicsConfig
from triplesumo.reproduce.config import CONTEST_BAND, PUSH_MIN, ContestError, ReproduceConfig, Stage, ablation
from triplesumo.train.config import TrainConfig
from triplesumo.train.run_folder import command_for, training_done
from triplesumo.train.sweep import SweepConfig, Trial, finished, run_trial, trials


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not table_exists(path):
        return []
    with open_table(path) as fh:
        return list(csv.DictReader(fh))


def _fingerprint(policy: str) -> str | None:
    """:func:`policy_fingerprint`, None when the policy's files are gone."""
    try:
        return policy_fingerprint(policy)
    except FileNotFoundError:
        return None


def _rows_in(path: Path) -> int:
    """Complete rows of a metrics CSV (lines ending in a newline, less the header)."""
    if not table_exists(path):
        return 0
    return max(read_table_bytes(path).count(b"\n") - 1, 0)


def contest_verdict(counts: dict[str, dict[str, int]], ant: str, spider: str) -> dict[str, Any]:
    """The contest rule on stage 2's counts (``{"ant-pushes" | "spider-pushes" | "match": {n, n_win, n_loss,
    n_draw}}``, each from the learner's seat): every check with its value and bound, ``failed`` (one line per
    failed check) and the verdict ``contest``."""
    ant_push = counts["ant-pushes"]["n_win"] / counts["ant-pushes"]["n"]
    spider_push = counts["spider-pushes"]["n_win"] / counts["spider-pushes"]["n"]
    m = counts["match"]
    team_mwr = (m["n_loss"] - m["n_win"]) / m["n"]  # the Spider's losses are the team's wins
    lo, hi = CONTEST_BAND
    failed = []
    if ant_push < PUSH_MIN:
        failed.append(f"the Ant pushes a passive Spider out in {ant_push:.1%} of the starts (at least {PUSH_MIN:.0%})")
    if spider_push < PUSH_MIN:
        failed.append(f"the Spider pushes a passive Ant or Bug out (its win) in {spider_push:.1%} of the starts "
                      f"(at least {PUSH_MIN:.0%})")
    if not lo <= team_mwr <= hi:
        failed.append(f"with Bug passive the team's MWR is {team_mwr:+.3f} (the band is [{lo:+.2f}, {hi:+.2f}])")
    return {"ant": ant, "spider": spider, "matches": m["n"], "counts": counts, "push_min": PUSH_MIN,
            "band": list(CONTEST_BAND), "ant_pushes": ant_push, "spider_pushes": spider_push, "team_mwr": team_mwr,
            "team_wins": m["n_loss"] / m["n"], "team_losses": m["n_win"] / m["n"], "draws": m["n_draw"] / m["n"],
            "failed": failed, "contest": not failed}


def format_contest(facts: dict[str, Any]) -> str:
    """The contest checks as lines of text."""
    lo, hi = facts["band"]
    return "\n".join([
        f"  Ant pushes a passive Spider out: {facts['ant_pushes']:.1%} (at least {facts['push_min']:.0%})",
        f"  Spider pushes a passive Ant or Bug out: {facts['spider_pushes']:.1%} (at least {facts['push_min']:.0%})",
        f"  Bug passive: team wins {facts['team_wins']:.1%}, loses {facts['team_losses']:.1%}, draws "
        f"{facts['draws']:.1%}; team MWR {facts['team_mwr']:+.3f} (band [{lo:+.2f}, {hi:+.2f}])",
        f"  verdict: {'a contest' if facts['contest'] else 'NOT a contest'} ({facts['matches']:,} starts each)"])


class Protocol:
    """The stages of one reproduction folder, built from its config."""

    def __init__(self, cfg: ReproduceConfig) -> None:
        self.cfg = cfg
        self.out = Path(cfg.out).resolve()
        tiny = cfg.tiny
        self.steps = 20 if tiny else 500
        self.n_envs = 2 if tiny else cfg.n_envs
        self.epochs = {"ant": 2, "spider": 2, "bug": 2, "contest": 4, "eval": 4} if tiny else {
            "ant": cfg.ant_epochs, "spider": cfg.spider_epochs, "bug": cfg.bug_epochs, "contest": cfg.contest_epochs,
            "eval": cfg.eval_epochs}
        self.physics = PhysicsConfig(border_rim=cfg.border_rim)
        self.ant_policy, self.spider_policy = cfg.pair or (str(self.out / "ant" / "policy"),
                                                           str(self.out / "spider" / "policy"))
        self.stages = [
            *(self._pretrain_stage(role, against)
              for role, against in (() if cfg.pair else (("ant", "a still Spider, Bug still"),
                                                         ("spider", "a still Ant and Bug")))),
            Stage("contest", "is the pair a contest? (each side pushes; the team loses without Bug, not hopelessly)",
                  (self.out / "contest" / "contest.json",), self._contest_complete, self._contest),
            Stage("bug", "Bug per algorithm x seed in the pair's match (Ant and Spider frozen)", (self.out / "bug",),
                  lambda: all(finished(t) for t in self.bug_trials()), self._bug_stage),
            *([Stage("ablations", "paper-preset DDPG Bug with one change each, per seed", (self.out / "ablations",),
                     lambda: all(finished(t) for t in self.ablation_trials()),
                     lambda: self._train_trials(self.ablation_trials()))] if cfg.ablations else []),
            Stage("evaluation", "every Bug and the baselines on the same test matches",
                  (self.out / "evaluation" / "per_seed.csv",), self._evaluation_complete, self._evaluation),
            Stage("compare", "IQM [CI] by trial (algorithm, ablation)", (self.out / "compare" / "compare.json",),
                  self._compare_complete, self._compare),
        ]

    # ------------------------------------------------------------ train stages
    def _pretrain_stage(self, role: str, against: str) -> Stage:
        """Stage ``ant`` or ``spider`` (:meth:`pretrain`): done when its run finished and wrote its policy."""
        return Stage(role, f"the {role.capitalize()} learns to push: against {against}",
                     (self.out / role / "policy.json",), lambda: self._trained(self.pretrain(role)),
                     lambda: self._train(self.pretrain(role)))

    def _base(self, **kw: Any) -> TrainConfig:
        """A train config at the protocol's budgets; tiny networks and buffers when tiny."""
        extra: dict[str, Any] = {}
        if self.cfg.tiny:
            small: dict[str, Any] = {"hidden": (16, 16), "buffer_size": 2000, "learning_starts": 10, "batch_size": 8}
            extra = {"ddpg": DDPGConfig(learn_every=4, **small), "td3": TD3Config(learn_every=4, **small),
                     "sac": SACConfig(learn_every=4, **small),
                     "ppo": PPOConfig(hidden=(16, 16), n_steps=8, n_minibatches=2, n_epochs=2),
                     "checkpoint_every": 1}
        return TrainConfig(out=str(self.out), steps_per_epoch=self.steps, n_envs=self.n_envs,
                           progress=self.cfg.progress, tensorboard=not self.cfg.tiny, physics=self.physics,
                           allow_other_ring=self.cfg.allow_other_ring,
                           save_replay=self.cfg.save_replay, **extra, **kw)

    def pretrain(self, role: str) -> TrainConfig:
        """Stage ``ant`` or ``spider``: that side alone learns (DDPG) to push still opponents (every other agent
        passive: a body that neither leaves the ring by itself nor pushes back), on the pre-training reward."""
        others = tuple(f"{a}=passive" for a in ("ant", "bug", "spider") if a != role)
        base = self._base(name=role, learn=(f"{role}=ddpg",), policies=others, epochs=self.epochs[role],
                          seed=self.cfg.pretrain_seed, reward=self.cfg.pretrain)
        # one gradient step per 5 transitions, as the v1 pair learned (docs/REPRODUCTION.md)
        return base if self.cfg.tiny else dataclasses.replace(base, ddpg=DDPGConfig(learn_every=5),
                                                              checkpoint_every=250)

    def _trained(self, cfg: TrainConfig) -> bool:
        return training_done(cfg) and (Path(cfg.out) / cfg.name / "policy.json").exists()

    def _train(self, cfg: TrainConfig) -> list[str]:
        run_trial(cfg)  # resumes the run from its last checkpoint when there is one
        return [command_for(cfg)]

    def sweep(self) -> SweepConfig:
        return SweepConfig(grid=("learn=" + ",".join(f"bug={a}" for a in self.cfg.algos),
                                 "seed=" + ",".join(map(str, self.cfg.seeds))), out=str(self.out / "bug"))

    def bug_base(self) -> TrainConfig:
        base = self._base(name="bug", learner="bug", policies=(f"ant={self.ant_policy}",
                                                               f"spider={self.spider_policy}"),
                          epochs=self.epochs["bug"],
                          **({} if self.cfg.tiny else {"checkpoint_every": 500,
                                                       "max_env_steps": self.cfg.bug_env_steps}))
        if self.cfg.bug_eval_every:  # tiny: an evaluation of 2 matches every 20 env steps
            base = dataclasses.replace(base, eval_every=20 if self.cfg.tiny else self.cfg.bug_eval_every,
                                       eval_epochs=2 if self.cfg.tiny else self.cfg.bug_eval_epochs,
                                       eval_seed=self.cfg.eval_seed)
        k = self.cfg.bug_learn_every
        if self.cfg.tiny or not k:
            return base
        return dataclasses.replace(base, td3=dataclasses.replace(base.td3, learn_every=k),
                                   sac=dataclasses.replace(base.sac, learn_every=k))

    def bug_trials(self) -> list[Trial]:
        return trials(self.sweep(), self.bug_base())

    def ablation_trials(self) -> list[Trial]:
        """The DDPG Bug trials with each ablation (its own grid value), over the same seeds and budgets."""
        made: list[Trial] = []
        for item in self.cfg.ablations:
            field_name, raw, _ = ablation(item)
            made += trials(SweepConfig(grid=("learn=bug=ddpg", f"{field_name}={raw}",
                                             "seed=" + ",".join(map(str, self.cfg.seeds))),
                                       out=str(self.out / "ablations")), self.bug_base())
        return made

    def _train_trials(self, todo: list[Trial]) -> list[str]:
        left = [t for t in todo if not finished(t)]
        if self.cfg.ray:
            self._train_on_ray(left)
        else:
            for t in left:
                print(f"  Bug trial {t.name}")
                run_trial(t.config)
        return [command_for(t.config) for t in todo]

    def _train_on_ray(self, left: list[Trial]) -> None:
        """The trials as Ray tasks, as many at once as Ray has CPUs for; ``RuntimeError`` naming any that failed
        (the others finish first, and a re-run resumes the failed ones)."""
        if not left:
            return
        from triplesumo.integrations import ray_tasks  # only here: the core never imports Ray

        print(f"  {len(left)} Bug trials as Ray tasks, {self.cfg.cpus_per_trial} CPU each: "
              + ", ".join(t.name for t in left))

        def done(k: int, result: dict[str, Any]) -> None:
            state = f"error: {result['error']}" if "error" in result else f"{result['seconds']:.0f} s"
            print(f"  Bug trial {left[k].name}: {state}")

        with ray_tasks.session(self.cfg.ray_address, self.cfg.num_cpus or None):
            results = ray_tasks.run_trials_on_ray([t.config for t in left], done, self.cfg.cpus_per_trial)
        failed = [f"{t.name} ({r['error']})" for t, r in zip(left, results, strict=True) if "error" in r]
        if failed:
            raise RuntimeError("Bug trials failed on Ray: " + "; ".join(failed) + "; run the same command again "
                               "to resume them")

    # ------------------------------------------------------------ evaluations
    def _evaluate(self, ecfg: EvaluateConfig) -> list[str]:
        from triplesumo import _dcargs

        resume = (Path(ecfg.out) / "evaluation.json").exists()
        if self.cfg.ray:  # the same rows, played as Ray tasks
            from triplesumo.integrations import ray_tasks  # only here: the core never imports Ray

            ecfg = dataclasses.replace(ecfg, ray=True, ray_address=self.cfg.ray_address)
            with ray_tasks.ray_runner(ecfg.ray_address) as runner:
                evaluate(dataclasses.replace(ecfg, resume=resume), runner)
        else:
            evaluate(dataclasses.replace(ecfg, resume=resume))
        return [" ".join(shlex.quote(a) for a in ["triplesumo", "evaluate", *_dcargs.to_argv(ecfg)])]

    def contest_configs(self) -> dict[str, EvaluateConfig]:
        """Stage 2's three evaluations on the same held-out starts: each side against a passive opponent, and the
        match with Bug passive (played from the Spider's seat; the team's MWR is minus the Spider's)."""
        def one(name: str, learner: str, policy: str, others: tuple[str, ...]) -> EvaluateConfig:
            return EvaluateConfig(learner=learner, policy=(policy,), policies=others, baselines=(),
                                  epochs=self.epochs["contest"], seed=self.cfg.contest_seed,
                                  steps_per_epoch=self.steps, physics=self.physics,
                                  allow_other_ring=self.cfg.allow_other_ring,
                                  out=str(self.out / "contest" / name), n_envs=self.n_envs, progress=self.cfg.progress)

        return {"ant-pushes": one("ant-pushes", "ant", self.ant_policy, ("spider=passive", "bug=passive")),
                "spider-pushes": one("spider-pushes", "spider", self.spider_policy, ("ant=passive", "bug=passive")),
                "match": one("match", "spider", self.spider_policy, (f"ant={self.ant_policy}", "bug=passive"))}

    def _contest_complete(self) -> bool:
        path = self.out / "contest" / "contest.json"
        return path.exists() and json.loads(path.read_text()).get("matches") == self.epochs["contest"]

    def _contest(self) -> list[str]:
        commands: list[str] = []
        counts: dict[str, dict[str, int]] = {}
        for name, ecfg in self.contest_configs().items():
            commands += self._evaluate(ecfg)
            summary = json.loads((Path(ecfg.out) / "summary.json").read_text())
            c = next(iter(summary["candidates"].values()))
            counts[name] = {k: int(c[k]) for k in ("n", "n_win", "n_loss", "n_draw")}
        facts = contest_verdict(counts, *(self._in_out(p) for p in (self.ant_policy, self.spider_policy)))
        print(format_contest(facts))
        atomic_write_bytes(self.out / "contest" / "contest.json", (json.dumps(facts, indent=2) + "\n").encode())
        return commands

    def _in_out(self, policy: str) -> str:
        """A policy path relative to the folder when it lies in it (records that stay true when it moves)."""
        path = Path(policy).resolve()
        return str(path.relative_to(self.out)) if path.is_relative_to(self.out) else policy

    def _bug_stage(self) -> list[str]:
        """Stage 3, after the contest rule: :class:`ContestError` on a pair that failed it (tiny: a warning)."""
        facts = json.loads((self.out / "contest" / "contest.json").read_text())
        if not facts["contest"]:
            problem = (f"the pair {self.ant_policy} / {self.spider_policy} failed the contest rule: "
                       + "; ".join(facts["failed"]) + f" ({self.out / 'contest' / 'contest.json'})")
            if not self.cfg.tiny:
                raise ContestError(f"stage bug refused: {problem}. Bug would learn in a match that is no contest; "
                                   "train the pair longer or check another (--pair), then re-run")
            print(f"  warning (tiny, not enforced): {problem}")
        return self._train_trials(self.bug_trials())

    def evaluation_config(self) -> EvaluateConfig:
        return EvaluateConfig(learner="bug", policy=tuple(str(Path(t.config.out) / t.name / "policy")
                                                          for t in self.bug_trials() + self.ablation_trials()),
                              policies=(f"ant={self.ant_policy}", f"spider={self.spider_policy}"),
                              baselines=("passive", "random"), epochs=self.epochs["eval"], seed=self.cfg.eval_seed,
                              physics=self.physics, allow_other_ring=self.cfg.allow_other_ring,
                              steps_per_epoch=self.steps, out=str(self.out / "evaluation"), n_envs=self.n_envs,
                              progress=self.cfg.progress)

    def evaluation_rows(self) -> list[dict[str, str]]:
        """The test's rows (``evaluation/per_seed.csv``, one per candidate), each Bug's policy named where it is now.

        The evaluation records its candidates by the paths it was given, absolute; a folder that moved since (a
        clone elsewhere, a copy) recorded them at its old place. A recorded path that ends with the path of one of
        this folder's Bug policies inside the folder (``bug/<trial>/policy``) is that policy, here; baselines and
        policies from elsewhere are kept as recorded."""
        inside = {Path(p).relative_to(self.out).parts: p for p in self.evaluation_config().policy}
        rows = _read_csv(self.out / "evaluation" / "per_seed.csv")
        for row in rows:
            parts = Path(row["policy"]).parts
            row["policy"] = next((inside[parts[k:]] for k in range(len(parts)) if parts[k:] in inside), row["policy"])
        return rows

    def _evaluation_complete(self) -> bool:
        rows = self.evaluation_rows()
        want = set(self.evaluation_config().policy) | {"passive", "random"}
        return ({r["policy"] for r in rows} == want and all(int(r["epochs"]) == self.epochs["eval"] for r in rows)
                and all(_rows_in(self.out / "evaluation" / r["candidate"] / "metrics.csv") == self.epochs["eval"]
                        for r in rows)  # a killed evaluation's rows: per_seed.csv may predate them
                and all(r["sha256"] == _fingerprint(r["policy"]) for r in rows))  # not a retrained or removed Bug's

    def _evaluation(self) -> list[str]:
        return self._evaluate(self.evaluation_config())

    def compare_config(self) -> CompareConfig:
        return CompareConfig(folders=(str(self.out / "evaluation"),), by="trial", out=str(self.out / "compare"),
                             seed=self.cfg.eval_seed, reps=1000 if self.cfg.tiny else 10_000)

    def _compare_complete(self) -> bool:
        path = self.out / "compare" / "compare.json"
        if not path.exists() or not (self.out / "compare" / "compare.png").exists():
            return False
        table = json.loads(path.read_text())
        rows = _read_csv(self.out / "evaluation" / "per_seed.csv")
        return sorted(s for g in table["groups"] for s in g["scores"]) == sorted(float(r["test_mwr"]) for r in rows)

    def _compare(self) -> list[str]:
        ccfg = self.compare_config()
        print(format_compare(compare(ccfg)))
        return [f"triplesumo compare {shlex.quote(ccfg.folders[0])} --by {ccfg.by} --seed {ccfg.seed} "
                f"--reps {ccfg.reps} --out {shlex.quote(ccfg.out)}"]
