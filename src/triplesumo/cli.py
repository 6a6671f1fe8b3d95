"""The ``triplesumo`` command: subcommands generated from the config dataclasses."""

from __future__ import annotations

import argparse
import sys

from triplesumo import _dcargs


def _parser() -> argparse.ArgumentParser:
    from triplesumo.evaluation.play import PlayConfig

    parser = argparse.ArgumentParser(prog="triplesumo", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    play = sub.add_parser("play", help="play one seeded match between policies; --video FILE records it")
    _dcargs.add_arguments(play, PlayConfig)
    from triplesumo.train.config import TrainConfig

    train = sub.add_parser("train", help="train one agent with DDPG (the others follow given policies)")
    train.add_argument("--resume", metavar="RUN_DIR", default=None,
                       help="continue the killed or finished run in RUN_DIR (its saved config; "
                            "--epochs and --max-minutes may be raised)")
    _dcargs.add_arguments(train, TrainConfig)
    plot = sub.add_parser("plot", help="write the paper's figures (PNG) from a run folder's metrics.csv")
    plot.add_argument("run_dir", help="run folder (holds metrics.csv)")
    plot.add_argument("--window", type=int, default=200, help="λ of the rolling curves and MWR (default: 200)")
    bench = sub.add_parser("bench", help="benchmarks: 'bench env' or 'bench train' (--help for each)")
    bench.add_argument("which", choices=["env", "train"])
    bench.add_argument("rest", nargs=argparse.REMAINDER, help="options of the benchmark")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "play":
            from triplesumo.evaluation.play import PlayConfig, run_play

            run_play(_dcargs.build(PlayConfig, args))
        elif args.command == "train":
            from triplesumo.train.config import TrainConfig
            from triplesumo.train.loop import train

            if args.resume:
                allowed = ("epochs", "max_minutes", "progress")
                given = {k for k in vars(args) if k not in ("command", "resume")}
                if given - set(allowed):
                    extra = given - set(allowed)
                    flags = ", ".join(sorted("--" + k.replace("__", ".").replace("_", "-") for k in extra))
                    raise ValueError(f"with --resume the run's saved config is used; only --epochs, --max-minutes "
                                     f"and --progress may be given, not {flags}")
                overrides = {k: v for k, v in vars(args).items() if k in allowed}
                result = train(TrainConfig(), resume_dir=args.resume, overrides=overrides)
            else:
                result = train(_dcargs.build(TrainConfig, args))
            print(f"trained {result.epochs} epochs, {result.env_steps} env steps, {result.updates} updates "
                  f"in {result.seconds:.0f} s; MWR {result.mwr:+.3f}")
            print(f"run folder: {result.run_dir} (metrics.csv, plots/, checkpoints/, policy.json)")
        elif args.command == "plot":
            from pathlib import Path

            from triplesumo.evaluation.plots import plot_run, read_metrics_csv

            run_dir = Path(args.run_dir)
            paths = plot_run(read_metrics_csv(run_dir / "metrics.csv"), run_dir / "plots", window=args.window,
                             title=run_dir.name)
            print("\n".join(str(p) for p in paths))
        elif args.command == "bench":
            if args.which == "env":
                from triplesumo.benchmarks.env import main as bench_env

                bench_env(args.rest)
            else:
                from triplesumo.benchmarks.train import main as bench_train

                bench_train(args.rest)
    except (ValueError, FileNotFoundError, PermissionError, OSError) as exc:
        print(f"triplesumo {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
