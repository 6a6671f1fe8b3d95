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
