"""``triplesumo bench env --backend warp``: env steps/s of the MuJoCo Warp backend, beside raw physics.

For each ``num_envs`` in ``--num-envs`` (default 1 to 16,384 matches) on one device:

``env``
    :class:`~triplesumo.envs.warp.WarpVectorMatches` ``step`` with uniform random actions
    in [-1, 1] (a pool of 16 action tensors drawn on the device in advance and cycled):
    physics (``frame_skip`` ``mujoco_warp.step`` and ``rne_postconstraint``, one CUDA graph),
    ring exits, outcome codes, reward terms, observations with contact forces, physics
    checks and SAME_STEP autoreset of finished matches (start states drawn on the host).
``raw``
    ``frame_skip`` calls of ``mujoco_warp.step`` on the same model and data (captured in
    one CUDA graph on a GPU, as mujoco_warp's own ``testspeed`` times it), controls fixed,
    no rules and no resets, from the state the env run left. Reported in env steps/s
    (matches x env steps / s; physics steps/s are ``frame_skip`` times that).

Each is warmed up (kernels compiled and loaded, graphs captured) and then timed over
``--steps`` env steps between device synchronisations, ``--rounds`` times alternating
env and raw; the median is reported. The targets: env/raw >= 0.7 (the rules cost little
beside the Warp physics), and 100,000 env steps/s for the paper match (RK4, 5 substeps)
on one H100.
"""

from __future__ import annotations

import platform
import time
from typing import Any

import numpy as np

from triplesumo.benchmarks import versions
from triplesumo.rules import MatchConfig
from triplesumo.rules.scenarios import scenario_config
from triplesumo.train.machine import cpu_name

DEFAULT_SIZES = (1, 16, 256, 1024, 4096, 16384)
TARGET_ENV_STEPS_PER_S = 100_000.0
TARGET_ENV_VS_RAW = 0.7


def run_warp_benchmark(sizes: tuple[int, ...] = DEFAULT_SIZES, steps: int = 200, rounds: int = 3,
                       device: str | None = None, integrator: str = "RK4", obs_mode: str = "paper",
                       seed: int = 0, warmup: int = 10, scenario: str = "paper") -> dict[str, Any]:
    """Measure env and raw rates for every size; a JSON-able dict. ``scenario``: a named game
    (``triplesumo.scenarios()`` with one body kind: elimination rules play on Warp too)."""
    import warp as wp

    from triplesumo.model.specs import PhysicsConfig

    config = scenario_config(scenario, physics=PhysicsConfig(integrator=integrator), obs_mode=obs_mode)
    device = device or ("cuda" if wp.is_cuda_available() else "cpu")
    rows = [_measure(config, n, device, steps, rounds, seed, warmup) for n in sizes]
    best = max(rows, key=lambda r: r["env_steps_per_s"])
    return {
        "setup": {"backend": "warp", "device": device, "device_name": _device_name(device), "sizes": list(sizes),
                  "steps": steps, "rounds": rounds, "warmup": warmup, "seed": seed, "integrator": integrator,
                  "obs_mode": obs_mode, "scenario": scenario, "timestep": config.physics.timestep,
                  "frame_skip": config.physics.frame_skip, "versions": versions("mujoco-warp", "warp-lang", "torch"),
                  "platform": platform.platform()},
        "rows": rows,
        "target": {"env_steps_per_s": TARGET_ENV_STEPS_PER_S, "env_vs_raw": TARGET_ENV_VS_RAW,
                   "best_num_envs": best["num_envs"],
                   "met_env_steps_per_s": best["env_steps_per_s"] >= TARGET_ENV_STEPS_PER_S,
                   "met_env_vs_raw_at_best": best["env_vs_raw"] >= TARGET_ENV_VS_RAW},
    }


def _measure(config: MatchConfig, n: int, device: str, steps: int, rounds: int, seed: int,
             warmup: int) -> dict[str, Any]:
    """One size: env and raw rates, alternating, ``rounds`` times."""
    import mujoco_warp as mjw
    import torch
    import warp as wp

    from triplesumo.envs.warp import make_warp_vector_env

    env = make_warp_vector_env(config, n, device=device, seed=seed)
    dev = env.device
    sync: Any = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    gen = torch.Generator(device=dev).manual_seed(seed)
    pool = [torch.rand((n, env.n_agents, env.act_dim), generator=gen, device=dev) * 2 - 1 for _ in range(16)]
    episodes = 0

    def env_run(count: int, counted: bool = True) -> float:
        nonlocal episodes
        sync()
        begin = time.perf_counter()
        for t in range(count):
            _, _, term, trunc, _ = env.step(pool[t % len(pool)])
        sync()
        elapsed = time.perf_counter() - begin
        if counted:
            episodes += int((term[:, 0] | trunc[:, 0]).sum())  # of the last step only: a cheap sample
        return elapsed

    def raw_once() -> None:
        for _ in range(env.frame_skip):
            mjw.step(env.m, env.d)

    graph: Any = None
    with wp.ScopedDevice(env.wp_device):
        env.reset(seed)
        env_run(warmup, counted=False)
        raw_once()
        if not env.wp_device.is_cpu:
            with wp.ScopedCapture(device=env.wp_device) as capture:
                raw_once()
            graph = capture.graph

        def raw_run(count: int) -> float:
            wp.synchronize_device(env.wp_device)
            begin = time.perf_counter()
            for _ in range(count):
                if graph is None:
                    raw_once()
                else:
                    wp.capture_launch(graph)
            wp.synchronize_device(env.wp_device)
            return time.perf_counter() - begin

        env_rates, raw_rates = [], []
        for _ in range(rounds):
            env.reset(seed)  # raw (and the warm-up) left the matches wherever physics took them
            env_rates.append(n * steps / env_run(steps))
            raw_rates.append(n * steps / raw_run(steps))
    env.close()
    env_rate, raw_rate = float(np.median(env_rates)), float(np.median(raw_rates))
    return {"num_envs": n, "env_steps_per_s": env_rate, "raw_env_steps_per_s": raw_rate,
            "raw_physics_steps_per_s": raw_rate * env.frame_skip, "env_vs_raw": env_rate / raw_rate,
            "env_rounds": env_rates, "raw_rounds": raw_rates, "episodes_last_steps": episodes}


def _device_name(device: str) -> str:
    import torch

    if device.startswith("cuda") and torch.cuda.is_available():
        return torch.cuda.get_device_name(torch.device(device))
    return cpu_name()


def format_table(result: dict[str, Any]) -> str:
    """The readable table ``triplesumo bench env --backend warp`` prints."""
    s, v = result["setup"], result["setup"]["versions"]
    lines = [
        f"TripleSumo env benchmark, backend warp on {s['device']} ({s['device_name']}): scenario "
        f"{s.get('scenario', 'paper')}, {s['obs_mode']} "
        f"observations, {s['integrator']}, timestep {s['timestep']}, frame_skip {s['frame_skip']}; median of "
        f"{s['rounds']} rounds of {s['steps']} env steps",
        f"mujoco {v['mujoco']}, mujoco-warp {v['mujoco-warp']}, warp-lang {v['warp-lang']}, torch {v['torch']}",
        "",
        f"{'matches':>8s} {'env steps/s':>12s} {'raw mujoco_warp':>16s} {'physics steps/s':>16s} {'env/raw':>8s} "
        f"{'ended':>9s}",
    ]
    for r in result["rows"]:
        lines.append(f"{r['num_envs']:8d} {r['env_steps_per_s']:12.0f} {r['raw_env_steps_per_s']:16.0f} "
                     f"{r['raw_physics_steps_per_s']:16.0f} {r['env_vs_raw']:8.2f} {r['episodes_last_steps']:9d}")
    t = result["target"]
    lines += ["", f"target >= {t['env_steps_per_s']:.0f} env steps/s: "
              f"{'met' if t['met_env_steps_per_s'] else 'NOT met'}; target env >= {t['env_vs_raw']} x raw at the "
              f"fastest size ({t['best_num_envs']} matches): {'met' if t['met_env_vs_raw_at_best'] else 'NOT met'}"]
    return "\n".join(lines)
