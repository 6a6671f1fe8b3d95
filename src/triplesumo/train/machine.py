"""The machine a time was measured on, and its speed: what every timed result (``bench skill``, ``reproduce``)
records beside its times, since two machines with the same CPU name can differ in speed (shared machines, load)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from triplesumo.envs.batch import VectorMatches
from triplesumo.train.config import TrainConfig


def cpu_name() -> str:
    """The CPU's model name as the OS reports it (Linux: ``model name`` in /proc/cpuinfo, e.g. "AMD EPYC 9B14"),
    else what :func:`platform.processor` knows, else the architecture: the machine a time was measured on."""
    import platform

    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine(train_cfg: TrainConfig) -> dict[str, Any]:
    """Where the times were measured: the CPU (its cores), and the backend and device the matches stepped on
    (a GPU's own name where one did; none here means no GPU figure: "not measured")."""
    import os

    device = train_cfg.device or ("cpu" if train_cfg.backend == "cpu" else "cuda")
    gpu = None
    if device.startswith("cuda"):
        import torch

        gpu = torch.cuda.get_device_name(torch.device(device)) if torch.cuda.is_available() else None
    return {"cpu": cpu_name(), "cores": os.cpu_count(), "backend": train_cfg.backend,
            "device": device, "gpu": gpu, "n_threads": train_cfg.n_threads, "torch_threads": train_cfg.torch_threads}


REFERENCE_STEPS = 100
"""Steps of the reference collection (each steps all ``n_envs`` matches): 1,600 env steps for 16 matches."""


def reference_speed(train_cfg: TrainConfig, repeats: int = 3, seed: int = 0) -> dict[str, Any]:
    """The machine's speed on the bench's physics: milliseconds of wall time per env step of a fixed seeded
    collection (``train_cfg``'s match and ``n_envs`` matches on its ``n_threads`` MuJoCo threads, uniform random
    actions drawn from ``seed``, :data:`REFERENCE_STEPS` steps, no learner), the best of ``repeats``. The same
    collection on every machine, so that times to skill measured on two machines can be set side by side."""
    import numpy as np

    env = VectorMatches(train_cfg.n_envs, train_cfg.match_config(), train_cfg.n_threads)
    shape = (REFERENCE_STEPS, env.num_envs, env.n_agents, env.act_dim)
    actions = np.random.default_rng(seed).uniform(-1.0, 1.0, shape).astype(np.float32)
    times = []
    try:
        for _ in range(repeats):
            env.reset(seed=seed)
            t0 = time.perf_counter()
            for step in actions:
                env.step(step)
            times.append(time.perf_counter() - t0)
    finally:
        env.close()
    env_steps = REFERENCE_STEPS * train_cfg.n_envs
    return {"ms_per_env_step": round(1000 * min(times) / env_steps, 4), "env_steps": env_steps,
            "repeats": repeats, "n_envs": train_cfg.n_envs, "n_threads": train_cfg.n_threads}


REFERENCE_MS_PER_ENV_STEP = 0.7
"""The reference box of "reference seconds": its reference collection (:func:`reference_speed`) takes 0.7 ms per
env step (an idle 2-core AMD EPYC box measured 0.67-0.72)."""


def machine_ms_per_env_step(reference: Mapping[str, Mapping[str, Any]]) -> float:
    """A machine's speed over a timed run: the mean ``ms_per_env_step`` of its reference collections
    (``{"before": ..., "after": ...}``, each of :func:`reference_speed`; those measured so far)."""
    values = [float(r["ms_per_env_step"]) for r in reference.values()]
    if not values or not all(v > 0 for v in values):
        raise ValueError(f"a reference speed needs ms_per_env_step > 0 measured at least once, got {dict(reference)}")
    return sum(values) / len(values)


def reference_seconds(seconds: float, reference: Mapping[str, Mapping[str, Any]]) -> float:
    """``seconds`` measured on a machine with these reference collections, scaled to the reference box
    (:data:`REFERENCE_MS_PER_ENV_STEP`): ``seconds * 0.7 / ms``, with ``ms`` the mean of the collections before and
    after (:func:`machine_ms_per_env_step`). A time on a box twice as slow counts half: a slower box is not a miss."""
    return seconds * REFERENCE_MS_PER_ENV_STEP / machine_ms_per_env_step(reference)


DEVICE_REFERENCE_STEPS = 50
"""Timed steps of all the matches in the device reference collection (after one untimed step)."""


def device_reference(train_cfg: TrainConfig, steps: int = DEVICE_REFERENCE_STEPS, seed: int = 0) -> dict[str, Any]:
    """The device's speed on the run's physics, and its start-up cost: ``train_cfg.n_envs`` matches of its match
    on its Warp device, uniform random actions drawn on the device from ``seed``, no policy and no learner. The
    first step (building the batch, compiling or loading every Warp kernel, capturing the CUDA graphs) is timed
    apart as ``first_step_seconds``; the next ``steps`` give ``env_steps_per_s``. Run in a training's process
    before the training, it leaves Warp's kernels loaded, so the training's clock holds no compiling."""
    import torch

    from triplesumo.envs.warp import make_warp_vector_env

    t0 = time.perf_counter()
    env = make_warp_vector_env(train_cfg.match_config(), train_cfg.n_envs, train_cfg.device, seed=seed)
    try:
        dev = env.device
        sync: Any = (lambda: torch.cuda.synchronize(dev)) if dev.type == "cuda" else (lambda: None)
        gen = torch.Generator(device=dev).manual_seed(seed)
        shape = (env.num_envs, env.n_agents, env.act_dim)
        env.reset(seed=seed)
        env.step(torch.rand(shape, generator=gen, device=dev) * 2 - 1)
        torch.ones((64, 64), device=dev).matmul(torch.ones((64, 64), device=dev))  # (the learner's BLAS, loaded)
        sync()
        first = time.perf_counter() - t0
        actions = [torch.rand(shape, generator=gen, device=dev) * 2 - 1 for _ in range(min(steps, 16))]
        sync()
        t1 = time.perf_counter()
        for k in range(steps):
            env.step(actions[k % len(actions)])
        sync()
        seconds = time.perf_counter() - t1
    finally:
        env.close()
    return {"device": str(env.device), "n_envs": train_cfg.n_envs, "steps": steps,
            "env_steps": steps * train_cfg.n_envs, "first_step_seconds": round(first, 3),
            "env_steps_per_s": round(steps * train_cfg.n_envs / max(seconds, 1e-9), 1)}
