"""``triplesumo bench env``: env steps per second, measured in one run.

``--backend warp`` measures the MuJoCo Warp backend instead, at 1 to 16,384 matches
(:mod:`triplesumo.benchmarks.warp_env`); the default ``--backend cpu`` runs the variants below.

Variants, each on its own compiled model of the same :class:`MatchConfig`:

``raw_physics``
    ``mj_step(model, data, nstep=frame_skip)`` with the random controls written to
    ``data.ctrl``: no observations, rewards or checks. It replays the seeded starts and
    actions of ``match_core`` and restarts where that match's episodes end (a ring-exit
    test on the torso qpos and the step limit, a few us), so every single-match variant
    simulates the very same trajectories.
``parallel_env``
    ``triplesumo.parallel_env()``: ``step`` with a dict of actions, observations, rewards
    and infos, ``reset()`` when the agents are done. Target: >= 0.85 x ``raw_physics`` (first-out games; see
    ``--scenario`` below).
``match_core``
    The bare match core, ``Match.step_array`` on an ``(n_agents, 8)`` array.
``batch_<stepper>_<n>t``
    :class:`~triplesumo.envs.batch.MatchBatch` of ``n_matches`` matches on ``n`` threads
    (``mujoco``: ``mujoco.batch``; ``threads``: a Python thread pool), ``reset_one`` on
    every finished match; about ``steps`` env steps in total. ``batch_threads_1t`` is
    those matches stepped one after another (``Match.step_array``'s work), the baseline
    of ``..._vs_sequential``; ``..._vs_one_match`` compares with ``match_core``.
``raw_batch_<n>t``
    Raw ``mujoco.batch`` physics of ``n_matches`` matches on ``n`` threads: controls
    written, ``step(nstep=frame_skip)``, a match restarted (its state row loaded) where
    its episode ends (ring-exit test on the torso qpos, step limit); nothing else.
``vector_env_<n>t``
    The public batched API, ``triplesumo.vector_env(n_matches, num_threads=n)``: arrays
    of actions in; observations, rewards, flags, info arrays and autoreset out (its physics
    on Python threads, each match on its own ``MjData``; the rules over arrays). Target:
    ``vector_env_<n>t_vs_raw_batch`` >= 0.9 (the batched path costs no more Python per
    match than the single one).

``--scenario NAME`` measures a named game (``triplesumo.scenarios()``; default ``paper``).
Under ``elimination`` rules ``raw_physics`` still restarts on the first ring exit (it is the
physics reference rate), while the env variants play on until one side is left: the ratios then
compare different matches, and no target is reported (:func:`targets_apply`).

Actions are uniform in [-1, 1], drawn in advance from ``np.random.default_rng(seed)``.
In each of ``rounds`` rounds every variant replays the same seeded work, the variants
taking turns in chunks of about ``chunk`` env steps (A, B, C, ..., A, B, C, ...) so that
a change in the machine's load hits them alike. A rate is the median over rounds; a
ratio is the ratio of two such medians. The machine's load and number of usable CPUs
are recorded beside them: on a shared machine compare ratios, not rates.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from typing import Any

import mujoco
import numpy as np

from triplesumo.benchmarks import report, versions
from triplesumo.envs.batch import STEPPERS, MatchBatch, VectorMatches
from triplesumo.envs.match import Match
from triplesumo.envs.parallel import TripleSumoParallelEnv
from triplesumo.model.specs import PhysicsConfig
from triplesumo.rules import outcome as rules_outcome
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.scenarios import scenario_config

TARGET_ENV_VS_RAW = 0.85
"""The PettingZoo view must run at >= 0.85 x the raw physics rate (RK4): the rules and the view cost little."""
TARGET_VECTOR_VS_RAW_BATCH = 0.9
"""``vector_env`` must run at >= 0.9 x raw ``mujoco.batch`` physics of the same matches."""

LABELS = {
    "raw_physics": "raw physics (mj_step)",
    "parallel_env": "PettingZoo parallel_env",
    "match_core": "Match.step_array",
}

def run_env_benchmark(steps: int = 3000, n_matches: int = 16, n_threads: int = 2, integrator: str = "RK4",
                      seed: int = 0, rounds: int = 3, chunk: int = 250, obs_mode: str = "paper",
                      scenario: str = "paper") -> dict[str, Any]:
    """Measure every variant ``rounds`` times, interleaved; return rates, ratios and the setup.

    Within a round the variants take turns in chunks of about ``chunk`` env steps until
    each has run ``steps``, so that a change in the machine's load hits them alike.

    Keys: ``setup`` (sizes, physics, versions, CPUs, load), ``rates`` (median env steps/s
    by variant), ``rounds`` (each round's rate by variant), ``episodes`` (finished per
    round, by variant), ``ratios`` (``parallel_env_vs_raw``, ``match_core_vs_raw``, and
    for each batch variant ``<name>_vs_one_match`` against ``match_core`` and
    ``<name>_vs_sequential`` against ``batch_threads_1t``, the same matches stepped one
    after another), ``target`` (the ``parallel_env_vs_raw`` and ``vector_env`` goals and whether each was met;
    empty where no target applies, :func:`targets_apply`).
    """
    for name, value in (("steps", steps), ("n_matches", n_matches), ("n_threads", n_threads), ("rounds", rounds),
                        ("chunk", chunk)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    config = scenario_config(scenario, physics=PhysicsConfig(integrator=integrator), obs_mode=obs_mode)
    variants: dict[str, _Variant] = {
        "raw_physics": _RawPhysics(config, steps, seed),
        "parallel_env": _ParallelEnv(config, steps, seed),
        "match_core": _MatchCore(config, steps, seed),
    }
    per_match = max(1, steps // n_matches)
    for stepper, threads in _batch_variants(n_threads):
        batch = MatchBatch(config, n_matches, threads, stepper=stepper)
        variants[f"batch_{stepper}_{threads}t"] = _Batch(batch, per_match, seed)
    variants[f"raw_batch_{n_threads}t"] = _RawBatch(config, n_matches, n_threads, per_match, seed)
    variants[f"vector_env_{n_threads}t"] = _VectorEnv(VectorMatches(n_matches, config, n_threads), per_match, seed)
    load = os.getloadavg()
    per_round: dict[str, list[float]] = {name: [] for name in variants}
    try:
        for _ in range(rounds):
            for name, rate in _one_round(variants, chunk).items():
                per_round[name].append(rate)
    finally:
        for variant in variants.values():
            variant.close()
    rates = {name: float(np.median(r)) for name, r in per_round.items()}
    ratios = {
        "parallel_env_vs_raw": rates["parallel_env"] / rates["raw_physics"],
        "match_core_vs_raw": rates["match_core"] / rates["raw_physics"],
    }
    vector_vs_raw = rates[f"vector_env_{n_threads}t"] / rates[f"raw_batch_{n_threads}t"]
    ratios[f"vector_env_{n_threads}t_vs_raw_batch"] = vector_vs_raw
    for name in variants:
        if name.startswith("batch_"):
            ratios[f"{name}_vs_one_match"] = rates[name] / rates["match_core"]
            ratios[f"{name}_vs_sequential"] = rates[name] / rates[SEQUENTIAL]
    return {
        "setup": {
            "steps": steps, "n_matches": n_matches, "steps_per_match": per_match, "n_threads": n_threads,
            "rounds": rounds, "chunk": chunk, "seed": seed, "integrator": integrator, "obs_mode": obs_mode,
            "scenario": scenario,
            "timestep": config.physics.timestep, "frame_skip": config.physics.frame_skip,
            "versions": versions(), "cpu_count": os.cpu_count(),
            "usable_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
            "load_average_before": [round(x, 2) for x in load], "platform": platform.platform(),
        },
        "rates": rates,
        "rounds": per_round,
        "episodes": {name: v.episodes for name, v in variants.items()},
        "ratios": ratios,
        "target": ({"parallel_env_vs_raw": TARGET_ENV_VS_RAW,
                    "met": ratios["parallel_env_vs_raw"] >= TARGET_ENV_VS_RAW,
                    "vector_env_vs_raw_batch": TARGET_VECTOR_VS_RAW_BATCH,
                    "vector_env_met": vector_vs_raw >= TARGET_VECTOR_VS_RAW_BATCH}
                   if targets_apply(config) else {}),
    }


def targets_apply(config: MatchConfig) -> bool:
    """Whether the speed targets apply: they compare an env with the raw physics of the very same matches,
    which holds under first-out rules; under elimination rules the raw reference restarts at the first ring exit
    while the envs play on with fewer agents, so their ratios compare different matches."""
    return config.rules != "elimination"


def _one_round(variants: dict[str, _Variant], chunk: int) -> dict[str, float]:
    """Every variant from its seeded start to its end, taking turns; env steps/s by variant."""
    seconds = dict.fromkeys(variants, 0.0)
    done = dict.fromkeys(variants, 0)
    for variant in variants.values():
        variant.start()
    while any(done[name] < v.length for name, v in variants.items()):
        for name, v in variants.items():
            stop = min(v.length, done[name] + max(1, chunk // v.width))
            if stop > done[name]:
                begin = time.perf_counter()
                v.run(done[name], stop)
                seconds[name] += time.perf_counter() - begin
                done[name] = stop
    return {name: v.length * v.width / seconds[name] for name, v in variants.items()}


# ----------------------------------------------------------------- variants
def _actions(match: Match, steps: int, seed: int) -> np.ndarray:
    """``(steps, n_agents, action_width)`` float32 actions, uniform in [-1, 1], the same for every
    single-match variant."""
    shape = (steps, match.n_agents, match.action_width)
    return np.random.default_rng(seed).uniform(-1.0, 1.0, shape).astype(np.float32)


class _Variant:
    """A way of stepping: ``start`` (untimed) from the seeded start, then ``run`` steps ``[t0, t1)``."""

    length: int
    """Steps of one round."""
    width = 1
    """Env steps per step (matches stepped together)."""
    episodes = 0
    """Episodes finished in the current round."""

    def start(self) -> None:
        raise NotImplementedError

    def run(self, t0: int, t1: int) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Release threads or renderers."""


class _RawPhysics(_Variant):
    def __init__(self, config: MatchConfig, steps: int, seed: int) -> None:
        self.match, self.length, self.seed = Match(config), steps, seed
        sim = self.match.sim
        actions = _actions(self.match, steps, seed).astype(np.float64)
        mid, half_range = (sim.ctrl_high + sim.ctrl_low) / 2.0, (sim.ctrl_high - sim.ctrl_low) / 2.0  # as Match
        self.ctrl = np.zeros((steps, self.match.model.nu))  # actuator order: a step writes data.ctrl whole
        motors = sim.actuator_ids >= 0  # padding columns of smaller bodies drive nothing
        self.ctrl[:, sim.actuator_ids[motors]] = (mid + actions * half_range)[:, motors]

    def start(self) -> None:
        self.rng = np.random.default_rng(self.seed)  # the starts Match.reset(seed), then reset(), draw
        self.match.sim.reset(*self.match.start_state(self.rng))
        self.episodes = self.episode_length = 0

    def run(self, t0: int, t1: int) -> None:
        match, model, data, ctrl = self.match, self.match.model, self.match.data, self.ctrl
        torso, half, frame_skip = match.sim.torso_qpos, match.half_size, match.sim.frame_skip
        limit = match.config.max_steps
        for t in range(t0, t1):
            data.ctrl[:] = ctrl[t]
            mujoco.mj_step(model, data, nstep=frame_skip)
            self.episode_length += 1
            if self.episode_length >= limit or bool(rules_outcome.agents_out(data.qpos[torso], half, np).any()):
                match.sim.reset(*match.start_state(self.rng))
                self.episodes += 1
                self.episode_length = 0


class _ParallelEnv(_Variant):
    def __init__(self, config: MatchConfig, steps: int, seed: int) -> None:
        self.env, self.length, self.seed = TripleSumoParallelEnv(config), steps, seed
        match = self.env.match
        actions = _actions(match, steps, seed)
        self.actions = [{name: row[i, :match.action_sizes[i]] for i, name in enumerate(match.agents)}
                        for row in actions]

    def start(self) -> None:
        self.env.reset(seed=self.seed)
        self.episodes = 0

    def run(self, t0: int, t1: int) -> None:
        env, n = self.env, len(self.env.possible_agents)
        for t in range(t0, t1):
            actions = self.actions[t]
            env.step(actions if len(env.agents) == n else {a: actions[a] for a in env.agents})
            if not env.agents:
                env.reset()
                self.episodes += 1

    def close(self) -> None:
        self.env.close()


class _MatchCore(_Variant):
    def __init__(self, config: MatchConfig, steps: int, seed: int) -> None:
        self.match, self.length, self.seed = Match(config), steps, seed
        self.actions = _actions(self.match, steps, seed)

    def start(self) -> None:
        self.match.reset(self.seed)
        self.episodes = 0

    def run(self, t0: int, t1: int) -> None:
        match = self.match
        for t in range(t0, t1):
            match.step_array(self.actions[t])
            if match.over:
                match.reset()
                self.episodes += 1


class _Batch(_Variant):
    def __init__(self, batch: MatchBatch, per_match: int, seed: int) -> None:
        self.batch, self.length, self.width, self.seed = batch, per_match, batch.n_matches, seed
        shape = (per_match, batch.n_matches, batch.n_agents, batch.action_width)
        self.actions = np.random.default_rng(seed).uniform(-1.0, 1.0, shape).astype(np.float32)

    def start(self) -> None:
        self.batch.reset_all(self.seed)
        self.episodes = 0

    def run(self, t0: int, t1: int) -> None:
        batch = self.batch
        for t in range(t0, t1):
            batch.step(self.actions[t])
            for k in np.flatnonzero(batch.over):
                batch.reset_one(int(k))
                self.episodes += 1

    def close(self) -> None:
        self.batch.close()


class _RawBatch(_Variant):
    def __init__(self, config: MatchConfig, n_matches: int, n_threads: int, per_match: int, seed: int) -> None:
        self.matches = [Match(config) for _ in range(n_matches)]  # start states and state rows
        first = self.matches[0]
        self.length, self.width, self.seed = per_match, n_matches, seed
        self.raw = mujoco.batch.Batch(first.model, n_matches, nthread=n_threads, persistent=True)
        self.ctrl, self.qpos = self.raw.bind("ctrl"), self.raw.bind("qpos")
        sim = first.sim
        shape = (per_match, n_matches, first.n_agents, first.action_width)
        # The actions _Batch and _VectorEnv draw.
        actions = np.random.default_rng(seed).uniform(-1.0, 1.0, shape).astype(np.float32).astype(np.float64)
        mid, half_range = (sim.ctrl_high + sim.ctrl_low) / 2.0, (sim.ctrl_high - sim.ctrl_low) / 2.0
        self.controls = np.zeros((per_match, n_matches, first.model.nu))
        self.controls[..., sim.actuator_ids.ravel()] = (mid + actions * half_range).reshape(per_match, n_matches, -1)

    def _restart(self, k: int) -> None:
        match = self.matches[k]
        match.sim.reset(*match.start_state(self.rngs[k]))
        self.raw.reset(ids=[k], stage=int(mujoco.mjtStage.mjSTAGE_NONE))
        mujoco.mj_getState(match.model, match.data, self.raw.state[k], int(mujoco.mjtState.mjSTATE_INTEGRATION))
        self.lengths[k] = 0

    def start(self) -> None:
        from triplesumo.envs.seeding import match_seeds

        self.rngs = [np.random.default_rng(s) for s in match_seeds(self.seed, self.width)]
        self.lengths = np.zeros(self.width, np.int64)
        for k in range(self.width):
            self._restart(k)
        self.episodes = 0

    def run(self, t0: int, t1: int) -> None:
        first = self.matches[0]
        torso, half, limit = first.sim.torso_qpos, first.half_size, first.config.max_steps
        for t in range(t0, t1):
            self.ctrl[:] = self.controls[t]
            self.raw.step(nstep=first.sim.frame_skip)
            self.lengths += 1
            xy = np.abs(self.qpos[:, torso][..., :2])
            for k in np.flatnonzero((xy > half).any(axis=(1, 2)) | (self.lengths >= limit)):
                self._restart(int(k))
                self.episodes += 1


class _VectorEnv(_Variant):
    def __init__(self, env: VectorMatches, per_match: int, seed: int) -> None:
        self.env, self.length, self.width, self.seed = env, per_match, env.num_envs, seed
        shape = (per_match, env.num_envs, env.n_agents, env.act_dim)
        self.actions = np.random.default_rng(seed).uniform(-1.0, 1.0, shape).astype(np.float32)

    def start(self) -> None:
        self.env.reset(seed=self.seed)
        self.episodes = 0

    def run(self, t0: int, t1: int) -> None:
        for t in range(t0, t1):
            self.episodes += int(self.env.step(self.actions[t])[4]["_final_obs"].sum())

    def close(self) -> None:
        self.env.close()


SEQUENTIAL = "batch_threads_1t"
"""The batch's matches stepped one after another on the calling thread: step_array's work."""


def _batch_variants(n_threads: int) -> list[tuple[str, int]]:
    """The same matches sequentially, then each stepper on 1 and on ``n_threads`` threads."""
    variants = [("threads", 1), ("mujoco", 1)] + [(stepper, n_threads) for stepper in STEPPERS]
    return list(dict.fromkeys(variants))


# --------------------------------------------------------------------- report
def format_table(result: dict[str, Any]) -> str:
    """The readable table ``main`` prints."""
    setup, rates, ratios = result["setup"], result["rates"], result["ratios"]
    v = setup["versions"]
    lines = [
        f"TripleSumo env benchmark: scenario {setup.get('scenario', 'paper')}, {setup['obs_mode']} observations, "
        f"{setup['integrator']}, timestep "
        f"{setup['timestep']}, frame_skip {setup['frame_skip']}; median of {setup['rounds']} rounds, "
        f"interleaved in chunks of {setup['chunk']} env steps; seed {setup['seed']}",
        f"python {v['python']}, mujoco {v['mujoco']}, numpy {v['numpy']}; {setup['cpu_count']} CPUs "
        f"({setup['usable_cpus']} usable), load before {setup['load_average_before'][0]}",
        "",
        f"{'variant':46s} {'env steps/s':>11s} {'vs raw':>7s} {'vs 1 match':>10s} {'vs seq':>7s} {'episodes':>8s}",
    ]
    for name, rate in rates.items():
        if name.startswith("batch_"):
            _, stepper, threads = name.split("_")
            label = (f"MatchBatch {setup['n_matches']} x {setup['steps_per_match']} steps, "
                     f"{stepper}, {threads[:-1]} thread{'s' if threads != '1t' else ''}")
            versus = f"{ratios[f'{name}_vs_one_match']:10.2f} {ratios[f'{name}_vs_sequential']:7.2f}"
        elif name.startswith(("raw_batch_", "vector_env_")):
            what = "raw mujoco.batch physics" if name.startswith("raw") else "triplesumo.vector_env"
            threads = name.rsplit("_", 1)[1][:-1]
            label = f"{what} {setup['n_matches']} x {setup['steps_per_match']}, {threads} thr"
            versus = " " * 18
        else:
            label, versus = f"{LABELS[name]}, {setup['steps']} steps", " " * 18
        lines.append(f"{label:46s} {rate:11.0f} {rate / rates['raw_physics']:7.2f} {versus} "
                     f"{result['episodes'][name]:8d}")
    target = result["target"]
    if not target:
        lines += ["", "no speed target applies: under elimination rules the raw reference restarts at the first "
                  "ring exit while the envs play on, so the ratios compare different matches"]
        return "\n".join(lines)
    vector = ratios[f"vector_env_{setup['n_threads']}t_vs_raw_batch"]
    lines += ["", f"target parallel_env >= {target['parallel_env_vs_raw']} x raw physics: "
              f"{ratios['parallel_env_vs_raw']:.2f} ({'met' if target['met'] else 'NOT met'})",
              f"target vector_env >= {target['vector_env_vs_raw_batch']} x raw mujoco.batch physics of the "
              f"same matches: {vector:.2f} ({'met' if target['vector_env_met'] else 'NOT met'})"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="triplesumo bench env", description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=None,
                        help="env steps per variant and round (default: 3000; warp: 200 per size)")
    parser.add_argument("--matches", type=int, default=16, help="matches of the MatchBatch variants (default: 16)")
    parser.add_argument("--threads", type=int, default=2, help="threads of the MatchBatch variants (default: 2)")
    parser.add_argument("--rounds", type=int, default=3, help="repetitions; the median is reported (default: 3)")
    parser.add_argument("--chunk", type=int, default=250, help="env steps per turn of a variant (default: 250)")
    parser.add_argument("--integrator", default="RK4", help="MuJoCo integrator (default: RK4, the paper's)")
    parser.add_argument("--obs-mode", default="paper", help="observation mode: paper or egocentric (default: paper)")
    parser.add_argument("--seed", type=int, default=0, help="seed of starts and actions (default: 0)")
    parser.add_argument("--scenario", default="paper", help="named game: paper, ffa, pursuit, 2v2 (default: paper)")
    parser.add_argument("--json", metavar="PATH", default=None, help="also write the results as JSON to PATH")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test, not a measurement)")
    parser.add_argument("--backend", choices=["cpu", "warp"], default="cpu",
                        help="cpu: the variants above; warp: MuJoCo Warp env and raw physics (default: cpu)")
    parser.add_argument("--num-envs", default=None, metavar="N,N,...",
                        help="warp: comma-separated numbers of matches (default: 1,16,256,1024,4096,16384)")
    parser.add_argument("--device", default=None, help="warp: cuda, cuda:N or cpu (default: cuda if Warp sees one)")
    args = parser.parse_args(argv)
    if args.backend == "warp":
        args.steps = 200 if args.steps is None else args.steps
        return _main_warp(args)
    args.steps = 3000 if args.steps is None else args.steps
    if args.quick:
        args.steps, args.matches, args.rounds, args.chunk = 20, 2, 1, 10
    result = run_env_benchmark(steps=args.steps, n_matches=args.matches, n_threads=args.threads,
                               integrator=args.integrator, seed=args.seed, rounds=args.rounds,
                               chunk=args.chunk, obs_mode=args.obs_mode, scenario=args.scenario)
    report(format_table(result), result, args.json)
    return 0


def _main_warp(args: argparse.Namespace) -> int:
    from triplesumo.benchmarks import warp_env

    try:
        sizes = tuple(int(x) for x in args.num_envs.split(",")) if args.num_envs else warp_env.DEFAULT_SIZES
    except ValueError:
        raise SystemExit(f"--num-envs must be comma-separated integers, got {args.num_envs!r}") from None
    if not sizes or min(sizes) < 1:
        raise SystemExit(f"--num-envs must be integers >= 1, got {args.num_envs!r}")
    steps, rounds, warmup = args.steps, args.rounds, 10
    if args.quick:
        sizes, steps, rounds, warmup = (2,), 2, 1, 1
    result = warp_env.run_warp_benchmark(sizes=sizes, steps=steps, rounds=rounds, device=args.device,
                                         integrator=args.integrator, obs_mode=args.obs_mode, seed=args.seed,
                                         warmup=warmup, scenario=args.scenario)
    report(warp_env.format_table(result), result, args.json)
    return 0
