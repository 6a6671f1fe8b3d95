"""Env speed from a checkout: ``python benchmarks/bench_env.py --help`` (the same as ``triplesumo bench env``)."""
from triplesumo.benchmarks.env import main

raise SystemExit(main())
