"""``triplesumo bench rllib``: env steps per second that one RLlib env runner collects, beside the raw env.

The paper's match (Bug learns, the zoo's Ant and Spider are frozen), built by
:func:`~triplesumo.integrations.rllib.make_config` in each layout below with one remote env
runner (``num_env_runners=1``). The runner samples ``warmup`` env steps untimed, then
``repeats`` rounds of ``steps`` env steps (``EnvRunner.sample``: RLlib's connectors, Bug's
RLModule exploring, episodes), each timed inside the runner's process, so Ray's transport
of the episodes is not counted. Before each round the **raw env** is timed for ``steps``
steps in a Ray task (the same kind of single-threaded worker process): the PettingZoo env,
one match, the zoo's numpy Ant and Spider acting, Bug's actions random. Rates are the
rounds' medians (on a shared box the load moves between rounds); ``ratio`` is the layout's
median over the raw env's; ``build_s`` is ``build_algo``'s wall time (the env runner and the
learner made).

Layouts:

``in_env_4`` (the default)
    The frozen agents act inside the env (``frozen_in_env=True``); RLlib holds Bug only;
    4 matches per runner (``ENVS_PER_RUNNER``); lean infos.
``in_env_1``
    As ``in_env_4`` with 1 match per runner.
``modules_1``
    The frozen Ant and Spider as RLlib modules (``frozen_in_env=False``, torch actors),
    1 match per runner, full infos: what ``in_env_4`` is measured against.
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

from triplesumo.benchmarks import report, versions

FROZEN = {"ant": "zoo:ant", "spider": "zoo:spider"}
LAYOUTS: dict[str, dict[str, Any]] = {
    "in_env_4": {"frozen_in_env": True, "envs": 4, "info_level": "outcome",
                 "what": "frozen Ant, Spider in the env; 4 matches per runner (default)"},
    "in_env_1": {"frozen_in_env": True, "envs": 1, "info_level": "outcome",
                 "what": "frozen Ant, Spider in the env; 1 match per runner"},
    "modules_1": {"frozen_in_env": False, "envs": 1, "info_level": "full",
                  "what": "before: frozen Ant, Spider as RLlib modules; 1 match; full infos"},
}
"""The measured layouts: :func:`make_config`'s ``frozen_in_env``, matches per env runner, infos."""


def raw_env_rate(steps: int, max_steps: int, seed: int) -> dict[str, Any]:
    """The PettingZoo env alone for ``steps`` steps: zoo numpy Ant and Spider acting, Bug random."""
    import numpy as np

    from triplesumo.agents.zoo import load
    from triplesumo.envs.parallel import parallel_env

    env = parallel_env(max_steps=max_steps)
    policies = {agent: load(spec.removeprefix("zoo:"))[0] for agent, spec in FROZEN.items()}
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    start = time.perf_counter()
    for k in range(steps):
        actions = {a: p(obs[a]) for a, p in policies.items()}
        actions["bug"] = rng.uniform(-1.0, 1.0, 8).astype(np.float32)
        obs, *_ = env.step(actions)
        if not env.agents:
            obs, _ = env.reset(seed=seed + k + 1)
    wall = time.perf_counter() - start
    env.close()
    return {"env_steps": steps, "seconds": wall, "env_steps_per_s": steps / wall}


def _sample(runner: Any, warmup: int, steps: int) -> dict[str, Any]:
    """Inside the env runner: ``warmup`` env steps untimed, then ``steps`` timed."""
    if warmup:
        runner.sample(num_timesteps=warmup)
    start = time.perf_counter()
    episodes = runner.sample(num_timesteps=steps)
    wall = time.perf_counter() - start
    done = sum(e.env_steps() for e in episodes)
    return {"env_steps": done, "seconds": wall, "env_steps_per_s": done / wall,
            "agents_in_episodes": sorted({str(a) for e in episodes for a in e.agent_ids}),
            "matches_per_runner": int(runner.num_envs), "modules": sorted(str(m) for m in runner.module.keys())}


def measure_layout(name: str, steps: int, warmup: int, max_steps: int, seed: int, repeats: int,
                   raw: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """One row: build the layout's algorithm with one remote env runner, then ``repeats`` rounds of the raw
    env (``raw()``) and the runner sampling, alternately; the row's rates are the rounds' medians."""
    from triplesumo.integrations.rllib import make_config

    layout = LAYOUTS[name]
    config = make_config("paper", policies_to_train=["bug"], frozen=FROZEN, frozen_in_env=layout["frozen_in_env"],
                         max_steps=max_steps)
    config = (config.environment(env_config={**config.env_config, "info_level": layout["info_level"]})
              .env_runners(num_env_runners=1, num_envs_per_env_runner=layout["envs"])
              .debugging(seed=seed))
    start = time.perf_counter()
    algo = config.build_algo()
    build = time.perf_counter() - start
    rounds, raws = [], []
    try:
        group = algo.env_runner_group
        assert group is not None, "an algorithm with env runners"
        for k in range(repeats):
            raws.append(raw()["env_steps_per_s"])
            sample = functools.partial(_sample, warmup=warmup if k == 0 else 0, steps=steps)
            rounds.append(group.foreach_env_runner(sample, local_env_runner=False)[0])
    finally:
        algo.stop()
    rate, raw_rate = statistics.median(r["env_steps_per_s"] for r in rounds), statistics.median(raws)
    return {**rounds[-1], "env_steps_per_s": rate, "raw_env_steps_per_s": raw_rate, "ratio": rate / raw_rate,
            "rounds_env_steps_per_s": [r["env_steps_per_s"] for r in rounds], "rounds_raw_env_steps_per_s": raws,
            "build_s": build, "what": layout["what"]}


def run_rllib_benchmark(steps: int = 2000, warmup: int = 200, max_steps: int = 500, seed: int = 0,
                        layouts: tuple[str, ...] = tuple(LAYOUTS), num_cpus: int = 2,
                        repeats: int = 3) -> dict[str, Any]:
    """Measure the layouts of the module docstring, each in ``repeats`` rounds alternating with the raw env."""
    import ray

    from triplesumo.integrations import ray_tasks

    unknown = sorted(set(layouts) - set(LAYOUTS))
    if unknown:
        raise ValueError(f"layouts: unknown layout(s) {unknown}; known: {list(LAYOUTS)}")
    result: dict[str, Any] = {"config": {"steps": steps, "warmup": warmup, "max_steps": max_steps, "seed": seed,
                                         "num_cpus": num_cpus, "env_runners": 1, "repeats": repeats},
                              "machine": {"cpus": os.cpu_count(), "load_avg_start": os.getloadavg()[0]},
                              "versions": {**versions("torch"), "ray": ray.__version__}, "layouts": {}}
    with ray_tasks.session("", num_cpus):
        raw_task = ray.remote(num_cpus=1)(raw_env_rate)
        ray.get(raw_task.remote(min(steps, 50), max_steps, seed))  # a warm worker: imports untimed

        def raw() -> dict[str, Any]:
            return ray.get(raw_task.remote(steps, max_steps, seed))

        for name in layouts:
            result["layouts"][name] = measure_layout(name, steps, warmup, max_steps, seed, repeats, raw)
    result["machine"]["load_avg_end"] = os.getloadavg()[0]
    return result


def format_table(result: dict[str, Any]) -> str:
    """The readable table ``main`` prints."""
    c, m = result["config"], result["machine"]
    lines = [f"RLlib sampling, 1 env runner, paper match (Bug learns, zoo Ant + Spider frozen), {c['steps']} env steps "
             f"after {c['warmup']} warm-up, medians of {c['repeats']} rounds; machine: {m['cpus']} CPUs, load "
             f"{m['load_avg_start']:.1f} -> {m['load_avg_end']:.1f}",
             f"{'layout':10s} {'RLlib env steps/s':>18s} {'raw env steps/s':>16s} {'ratio':>6s} {'build s':>8s}  what"]
    for name, row in result["layouts"].items():
        lines.append(f"{name:10s} {row['env_steps_per_s']:18.0f} {row['raw_env_steps_per_s']:16.0f} "
                     f"{row['ratio']:6.2f} {row['build_s']:8.1f}  {row['what']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="triplesumo bench rllib", description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=2000, help="timed env steps per layout (default: 2000)")
    parser.add_argument("--warmup", type=int, default=200, help="untimed env steps first (default: 200)")
    parser.add_argument("--max-steps", type=int, default=500, help="match step limit (default: the paper's 500)")
    parser.add_argument("--layouts", nargs="+", default=list(LAYOUTS), choices=list(LAYOUTS),
                        help="layouts to measure (default: all)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="rounds of raw env then RLlib per layout; rates are their medians (default: 3)")
    parser.add_argument("--num-cpus", type=int, default=2, help="CPUs of the local Ray (default: 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    parser.add_argument("--json", metavar="PATH", default=None, help="also write the results as JSON to PATH")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test, not a measurement)")
    args = parser.parse_args(argv)
    if args.quick:
        args.steps, args.warmup, args.max_steps, args.repeats = 40, 8, 30, 1
    for name in ("steps", "max_steps", "num_cpus", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.warmup < 0:
        parser.error("--warmup must be >= 0")
    result = run_rllib_benchmark(args.steps, args.warmup, args.max_steps, args.seed, tuple(args.layouts),
                                 args.num_cpus, args.repeats)
    report(format_table(result), result, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
