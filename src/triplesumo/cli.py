"""The ``triplesumo`` command: subcommands generated from the config dataclasses."""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import shlex
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from triplesumo import _dcargs, _extras
from triplesumo._lock import FolderInUseError

if TYPE_CHECKING:
    from triplesumo.evaluation.parallel import TaskRunner


def _parser(command: str | None = None) -> argparse.ArgumentParser:
    """Every command's options, or with ``command`` that one's only: the others are listed, their configs (and
    the libraries those import, torch for ``train``) left unloaded, so that a core install runs ``play``."""

    def wants(name: str) -> bool:
        return command is None or command == name

    parser = argparse.ArgumentParser(prog="triplesumo", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="the main job: train Bug briefly in the shipped ongoing match, "
                                       "evaluate it against baselines, record a match")
    if wants("demo"):
        from triplesumo.demo import DemoConfig

        _dcargs.add_arguments(demo, DemoConfig)
    play = sub.add_parser("play", help="play one seeded match between policies; --video FILE records it")
    if wants("play"):
        from triplesumo.evaluation.play import PlayConfig

        _dcargs.add_arguments(play, PlayConfig)
    train = sub.add_parser("train", help="train learning agents (DDPG, TD3, SAC or PPO; the others follow given "
                                              "policies)")
    train.add_argument("--resume", metavar="RUN_DIR", default=None,
                       help="continue the killed or finished run in RUN_DIR (its saved config; "
                            "--epochs and --max-minutes may be raised; --no-save-replay resumes from a checkpoint "
                            "whose replay buffer was not kept, with an empty buffer: not bit-exact)")
    train.add_argument("--fork", metavar="RUN_DIR", default=None,
                       help="a new run (--name NEW; --out defaults to RUN_DIR's folder) that continues RUN_DIR's "
                            "latest checkpoint (or --from epoch-N) under changed --league.* rules or budgets "
                            "(--epochs, --max-minutes, ...); RUN_DIR is not changed. Writes NEW/fork.json")
    train.add_argument("--from", dest="from_checkpoint", metavar="epoch-N", default=None,
                       help="with --resume: continue from this checkpoint of the run instead of the latest (e.g. "
                            "when the latest is damaged: the error names the newest intact one); later epochs are "
                            "trained again. The run folder becomes that checkpoint's first, even with --epochs not "
                            "past it: metrics cut back, policy files from it, latest.json naming it, later "
                            "checkpoints removed. With --fork: the checkpoint the fork starts from")
    train.add_argument("--start-over", action="store_true",
                       help="train afresh although OUT/NAME already holds a run: that run is first moved aside to "
                            "OUT/NAME.old-K (without this, training refuses such a folder and changes nothing)")
    if wants("train"):
        from triplesumo.train.config import TrainConfig

        _dcargs.add_arguments(train, TrainConfig)
    evaluate = sub.add_parser("evaluate", help="test epochs of a policy (no exploration) against passive and "
                                               "random baselines in the same matches")
    if wants("evaluate"):
        from triplesumo.evaluation.evaluate import EvaluateConfig

        _dcargs.add_arguments(evaluate, EvaluateConfig)
    tournament = sub.add_parser("tournament", help="seeded matches between named policies in every seat they can "
                                                   "take: openskill leaderboard and cross-play matrix")
    if wants("tournament"):
        from triplesumo.evaluation.tournament import TournamentConfig

        _dcargs.add_arguments(tournament, TournamentConfig)
    compare = sub.add_parser("compare", help="statistics across seeds from evaluation folders: IQM with stratified "
                                             "bootstrap intervals, probability of improvement (rliable)")
    compare.add_argument("folders", nargs="+", help="evaluation folders (each holds per_seed.csv)")
    if wants("compare"):
        from triplesumo.evaluation.compare import CompareConfig

        _dcargs.add_arguments(compare, CompareConfig, skip=("folders",))
    sweep = sub.add_parser("sweep", help="a grid of train runs (any TrainConfig field: --grid seed=0,1,2 --grid "
                                         "ddpg.actor_lr=1e-4,1e-3) as Ray tasks, resumable; one summary "
                                         "(needs the ray extra)")
    if wants("sweep"):
        from triplesumo.train.config import TrainConfig
        from triplesumo.train.sweep import SweepConfig

        sweep.add_argument("--grid", action="extend", nargs="+", default=argparse.SUPPRESS, metavar="FIELD=V1,V2",
                           help=_dcargs.field_docs(SweepConfig)["grid"] + " (repeat --grid for more fields)")
        _dcargs.add_arguments(sweep, SweepConfig, skip=("grid",))
        # --eval-seed is the sweep's and its trials' (TrainConfig.eval_seed, read from the same option): one set of
        # seeded test matches for the evaluations during training and after it
        _dcargs.add_arguments(sweep, TrainConfig, skip=("out", "name", "eval_seed"))
    reproduce = sub.add_parser("reproduce", help="the whole reproduction protocol (Ant, Spider, contest check, Bug per "
                                                 "algorithm x seed, evaluation, compare, REPRODUCTION.md), "
                                                 "resumable; --tiny for a smoke run")
    if wants("reproduce"):
        from triplesumo.reproduce import ReproduceConfig

        _dcargs.add_arguments(reproduce, ReproduceConfig)
    compact = sub.add_parser("compact", help="keep only what resuming a run needs (its newest checkpoint and the "
                                             "league members its pools and in-flight matches hold), e.g. before "
                                             "committing it; the evicted members deleted are listed in "
                                             "league/pruned.json")
    compact.add_argument("run_dir", help="run folder (holds checkpoints/)")
    compact.add_argument("--drop-replay", action="store_true",
                         help="also delete the checkpoint's replay buffer (a repository keeps none): the run then "
                              "resumes with an empty buffer")
    pack = sub.add_parser("pack", help="gzip the large tables (*.csv) of a finished output folder into NAME.csv.gz, "
                                       "e.g. before committing it beside a docs page; every command reads them as "
                                       "before, and a resume unpacks a table it appends to")
    pack.add_argument("folder", help="output folder (run, evaluation, tournament, reproduction), searched recursively")
    pack.add_argument("--min-kb", type=int, default=64, help="pack tables of at least this many KiB (default: 64)")
    average = sub.add_parser("average", help="average the actor weights of snapshots of one run (stochastic weight "
                                             "averaging) into a new policy file that names its sources")
    average.add_argument("policies", nargs="+", help="policy files of one run (e.g. "
                                                     "runs/x/league/members/spider-00{40,41,42}/spider)")
    average.add_argument("--out", required=True, help="the averaged policy file to write (e.g. runs/x/swa-spider)")
    plot = sub.add_parser("plot", help="write the paper's figures (PNG) from a run folder's metrics.csv, or an "
                                       "evaluation folder's comparison plots from its recorded rows")
    plot.add_argument("run_dir", help="run folder (holds metrics.csv, or metrics-<agent>.csv per learning agent), "
                                      "or an evaluation folder (holds summary.json)")
    plot.add_argument("--window", type=int, default=None, help="λ of the rolling curves and MWR (default: 200; an "
                                                               "evaluation folder's: the one it used)")
    zoo = sub.add_parser("zoo", help="list the shipped policies, or publish a trained one into the zoo")
    zoo.add_argument("action", choices=["list", "publish"])
    zoo.add_argument("policy", nargs="?", help="publish: the run's policy file (e.g. runs/ant/policy)")
    zoo.add_argument("name", nargs="?", help="publish: the zoo name (e.g. ant)")
    zoo.add_argument("--evaluation", default=None, help="publish: a JSON file of evaluation results to record")
    replay = sub.add_parser("replay", help="re-render a match file from play/evaluate --record (--video FILE), "
                                           "checking it re-simulates bit for bit")
    replay.add_argument("file", help="match file (.npz)")
    if wants("replay"):
        from triplesumo.evaluation.replay import ReplayConfig

        _dcargs.add_arguments(replay, ReplayConfig)
    view = sub.add_parser("view", help="write a match file as one self-contained HTML page that replays it in a "
                                       "browser, offline: play, scrub, orbit, follow an agent, reward terms")
    view.add_argument("file", help="match file (.npz) from play/evaluate --record")
    if wants("view"):
        from triplesumo.evaluation.viewer import ViewConfig

        _dcargs.add_arguments(view, ViewConfig)
    bench = sub.add_parser("bench", help="benchmarks: 'bench env', 'bench train', 'bench ray', 'bench rllib' "
                                         "(RLlib's env steps/s per env runner), 'bench skill' (time to skill per "
                                         "algorithm) or 'bench skill-gpu' (time to skill on MuJoCo Warp, "
                                         "thousands of matches on a GPU) (--help for each)")
    bench.add_argument("which", choices=["env", "train", "ray", "rllib", "skill", "skill-gpu"])
    bench.add_argument("rest", nargs=argparse.REMAINDER, help="options of the benchmark")
    return parser


@contextlib.contextmanager
def _runner(ray: bool, address: str) -> Iterator[TaskRunner | None]:
    """The task runner a command hands down: Ray's for ``--ray`` (connected inside the block), else none (the
    matches are played in this process). Ray is imported only here, and only for ``--ray``."""
    if not ray:
        yield None
        return
    from triplesumo.integrations.ray_tasks import ray_runner

    with ray_runner(address) as runner:
        yield runner


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), "")  # (the only options before it are -h, --help)
    try:
        args = _parser(command).parse_args(argv)
        # the extras it needs (and --video's, --backend warp's), checked before it starts, not when it writes its
        # plots or video or first steps the device
        _extras.require(command, (*(("video",) if getattr(args, "video", None) else ()),
                                  *(("gpu",) if getattr(args, "backend", None) == "warp" else ())))
        if args.command == "demo":
            from triplesumo.demo import DemoConfig, run_demo

            run_demo(_dcargs.build(DemoConfig, args))
        elif args.command == "play":
            from triplesumo.evaluation.play import PlayConfig, run_play

            run_play(_dcargs.build(PlayConfig, args))
        elif args.command == "train":
            from triplesumo.train.config import TrainConfig
            from triplesumo.train.loop import train
            from triplesumo.train.run_folder import RESUME_OVERRIDES, flag_list

            plain = ("command", "resume", "fork", "from_checkpoint", "start_over")
            typed = shlex.join(["triplesumo", *argv])  # this command's leg records it (RUN/legs.json)
            given = {k for k in vars(args) if k not in plain}
            if args.fork:
                import dataclasses

                from triplesumo.train.fork import fork_run, parent_config

                if args.resume or args.start_over:
                    raise ValueError("--fork makes a new run; it cannot be given with --resume or --start-over")
                if "name" not in given:
                    raise ValueError("--fork needs --name NEW: the fork's own run folder (OUT/NEW)")
                parent = Path(args.fork)
                saved = parent_config(parent)
                base = saved if "out" in given else dataclasses.replace(saved, out=str(parent.parent))
                run_dir = fork_run(parent, _dcargs.build(TrainConfig, args, base=base), args.from_checkpoint)
                print(f"forked {parent} into {run_dir} (fork.json says from where and what changed)")
                result = train(TrainConfig(), resume_dir=run_dir, session_command=typed)
            elif args.resume:
                allowed = RESUME_OVERRIDES
                if args.start_over:
                    raise ValueError("--start-over starts a new run; it cannot be given with --resume")
                if given - set(allowed):
                    extra = given - set(allowed)
                    flags = ", ".join(sorted("--" + k.replace("__", ".").replace("_", "-") for k in extra))
                    raise ValueError(f"with --resume the run's saved config is used; only "
                                     f"{flag_list(allowed)} may be given, not {flags}")
                overrides = {k: v for k, v in vars(args).items() if k in allowed}
                result = train(TrainConfig(), resume_dir=args.resume, overrides=overrides,
                               from_checkpoint=args.from_checkpoint, session_command=typed)
            else:
                if args.from_checkpoint:
                    raise ValueError("--from needs --resume RUN_DIR or --fork RUN_DIR (it names a checkpoint of "
                                     "that run)")
                cfg = _dcargs.build(TrainConfig, args)
                result = train(cfg, start_over=args.start_over, session_command=typed)
            print(f"trained {result.epochs} epochs, {result.env_steps} env steps, {result.updates} updates "
                  f"in {result.seconds:.0f} s; MWR {result.mwr:+.3f}")
            if len(result.mwrs) > 1:
                print("MWR " + ", ".join(f"{a} {m:+.3f}" for a, m in result.mwrs.items()))
            print(f"run folder: {result.run_dir} (metrics*.csv, learning*.csv, plots/, checkpoints/, policy*.json)")
        elif args.command == "evaluate":
            from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate, format_summary

            cfg = _dcargs.build(EvaluateConfig, args)
            with _runner(cfg.ray, cfg.ray_address) as runner:
                summary = evaluate(cfg, runner)
            print(format_summary(summary))
            print(f"report: {cfg.out}/summary.json; plots: {cfg.out}/compare_mwr.png, {cfg.out}/*/plots/")
            if cfg.record_html:
                print(f"match pages: {cfg.out}/*/matches/epoch_*.html (open one in a browser)")
        elif args.command == "tournament":
            from triplesumo.evaluation.tournament import TournamentConfig, format_leaderboard, run_tournament

            tcfg = _dcargs.build(TournamentConfig, args)
            with _runner(tcfg.ray, tcfg.ray_address) as runner:
                print(format_leaderboard(run_tournament(tcfg, runner=runner)))
            tag = "" if tcfg.rate_by == "policy" else "_by_seat"
            ladder = f", ladder{tag}.png" if (Path(tcfg.out) / f"ladder{tag}.png").exists() else ""
            print(f"tables: {tcfg.out}/leaderboard{tag}.csv, crossplay{tag}.csv, results{tag}.json; "
                  f"plots: {tcfg.out}/leaderboard{tag}.png, crossplay{tag}.png{ladder}")
        elif args.command == "compare":
            from triplesumo.evaluation.compare import CompareConfig, compare, format_compare

            ccfg = _dcargs.build(CompareConfig, args)
            print(format_compare(compare(ccfg)))
            print(f"tables: {ccfg.out}/compare.csv, improvement.csv, compare.json; plot: {ccfg.out}/compare.png")
        elif args.command == "sweep":
            from triplesumo.train.config import TrainConfig
            from triplesumo.train.sweep import SweepConfig, format_sweep, run_sweep

            scfg = _dcargs.build(SweepConfig, args)
            base = _dcargs.build(TrainConfig, argparse.Namespace(**{k: v for k, v in vars(args).items() if k != "out"}))
            if scfg.workers:
                from triplesumo.evaluation.parallel import ProcessRunner

                print(format_sweep(run_sweep(scfg, base, ProcessRunner(scfg.workers))))
            else:
                if importlib.util.find_spec("ray") is None:
                    raise ValueError('triplesumo sweep runs its trials on Ray, which is not installed: '
                                     'pip install "triplesumo[ray]", or give --workers N to run them on N processes '
                                     'of this machine')
                from triplesumo.integrations.ray_tasks import ray_runner

                with ray_runner(scfg.address, scfg.num_cpus or None, scfg.max_retries) as ray_tasks:
                    print(format_sweep(run_sweep(scfg, base, ray_tasks)))
            print(f"summary: {scfg.out}/summary.csv, summary.json" + (f"; compare: {scfg.out}/compare/"
                                                                      if scfg.evaluate_epochs else ""))
        elif args.command == "reproduce":
            from triplesumo.reproduce import ContestError, PairError, ReproduceConfig, run_reproduce

            try:
                run_reproduce(_dcargs.build(ReproduceConfig, args))
            except (ContestError, PairError) as exc:  # a protocol's check refused to go on: a verdict, not a crash
                print(f"triplesumo reproduce: stopped: {exc}", file=sys.stderr)
                return 2
        elif args.command == "compact":
            from triplesumo.train.fork import compact_run

            removed = compact_run(Path(args.run_dir), drop_replay=args.drop_replay)
            print(f"{args.run_dir}: removed {len(removed['checkpoints'])} older checkpoint(s) "
                  f"{removed['checkpoints']} and {len(removed['members'])} evicted league member(s) "
                  f"(listed in league/pruned.json)" + ("" if not removed["replay"] else " and the replay buffer")
                  + ("; it resumes with an empty replay buffer" if removed["replay"] else "; it resumes as before"))
        elif args.command == "pack":
            from triplesumo.evaluation.metrics_csv import pack_tables

            before = sum(p.stat().st_size for p in Path(args.folder).rglob("*.csv") if p.is_file())
            packed = pack_tables(Path(args.folder), args.min_kb * 1024)
            after = sum(p.stat().st_size for p in Path(args.folder).rglob("*.csv") if p.is_file()) + sum(
                p.stat().st_size for p in packed)
            print(f"{args.folder}: packed {len(packed)} table(s) (*.csv -> *.csv.gz); its tables take "
                  f"{after / 1e6:.1f} MB instead of {before / 1e6:.1f} MB, and read as before")
        elif args.command == "average":
            from triplesumo.agents.average import average_policies

            made = average_policies(args.policies, args.out, command=shlex.join(["triplesumo", *argv]))
            print(f"{args.out}: the mean of {len(args.policies)} {made['agent']} policies "
                  f"(epochs {[s['epochs'] for s in made['average']['sources']]})")
        elif args.command == "plot":
            if (Path(args.run_dir) / "summary.json").is_file():  # an evaluation folder: its comparison plots
                from triplesumo.evaluation.evaluate import plot_evaluation_folder

                drawn = plot_evaluation_folder(args.run_dir, args.window)
            else:
                from triplesumo.train.run_folder import plot_metrics

                drawn = plot_metrics(args.run_dir, 200 if args.window is None else args.window)
            print("\n".join(str(p) for p in drawn))
        elif args.command == "zoo":
            import json

            from triplesumo.agents import zoo as zoo_module

            if args.action == "list":
                names = zoo_module.available()
                width = max((len(n) for n in names), default=8)
                for name in names:
                    meta = zoo_module.manifest_of(name)  # (an alias's: its target's)
                    ev = meta.get("evaluation", {})
                    mwr = (f" test_mwr={ev['test_mwr']:+.3f} [{ev['test_mwr_lo']:+.3f}, {ev['test_mwr_hi']:+.3f}]"
                           if "test_mwr" in ev else "")
                    was = f" (was zoo:{meta['renamed_from']})" if "renamed_from" in meta else ""
                    target = zoo_module.alias_target(name)
                    was += f" (alias of zoo:{target})" if target else ""
                    print(f"{name:{width}s} agent={meta['agent']} env={meta.get('env_version', 'v0')} "
                          f"obs_mode={meta['obs_mode']} epochs={meta.get('epochs')} seed={meta.get('seed')}{mwr}{was}  "
                          f"made by: {meta.get('command')}")
            else:
                from triplesumo.zoo import publish  # (refuses a manifest whose ring is invalid)

                if not args.policy or not args.name:
                    raise ValueError("zoo publish needs POLICY and NAME")
                evaluation = json.loads(Path(args.evaluation).read_text()) if args.evaluation else None
                print(publish(Path(args.policy), args.name, evaluation))
        elif args.command == "replay":
            from triplesumo.evaluation.replay import ReplayConfig, run_replay

            run_replay(Path(args.file), _dcargs.build(ReplayConfig, args))
        elif args.command == "view":
            from triplesumo.evaluation.viewer import ViewConfig, run_view

            run_view(Path(args.file), _dcargs.build(ViewConfig, args))
        elif args.command == "bench":
            if args.which == "env":
                from triplesumo.benchmarks.env import main as bench_env

                bench_env(args.rest)
            elif args.which == "train":
                from triplesumo.benchmarks.train import main as bench_train

                bench_train(args.rest)
            elif args.which == "skill":
                from triplesumo.benchmarks.skill import main as bench_skill

                bench_skill(args.rest)
            elif args.which == "skill-gpu":
                from triplesumo.benchmarks.skill_gpu import main as bench_skill_gpu

                bench_skill_gpu(args.rest)
            elif args.which == "rllib":
                from triplesumo.benchmarks.rllib import main as bench_rllib

                bench_rllib(args.rest)
            else:
                from triplesumo.benchmarks.ray import main as bench_ray

                bench_ray(args.rest)
    except ModuleNotFoundError as exc:  # an optional library that is not installed: the extra that installs it
        message = _extras.missing_message(command, exc.name or "")
        if message is None:
            raise
        print(message, file=sys.stderr)
        return 2
    except (ValueError, FileNotFoundError, PermissionError, OSError, FloatingPointError, FolderInUseError) as exc:
        print(f"triplesumo {command}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
