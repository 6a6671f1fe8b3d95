"""The examples of the RL-libraries guide with each real client library, run as a user would run them.

Each ``<!-- example: NAME -->`` code block of docs/libraries.md runs in a fresh Python process
(with a time limit, so a hang, like the old fork deadlock, fails instead of stalling CI),
followed by checks of what it left behind. The blocks are the documentation: if an
example breaks, the guide is wrong.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import triplesumo

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "libraries.md"
_BLOCK = re.compile(r"<!-- example: ([\w-]+) -->\s*```python\n(.*?)```", re.S)


def guide_examples() -> dict[str, str]:
    return {name: code for name, code in _BLOCK.findall(GUIDE.read_text())}


def run_python(code: str, timeout: float = 240.0) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1"}  # one torch thread: a busy 2-core CI box stalls two
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout,
                              env=env, cwd=ROOT)
    except subprocess.TimeoutExpired as exc:
        raise AssertionError(f"the example did not finish in {timeout} s (hung?):\n{code}") from exc
    assert proc.returncode == 0, f"example failed:\n{code}\n--- stderr ---\n{proc.stderr[-4000:]}"
    return proc.stdout


# What each example must leave behind: checks appended to its code.
CHECKS = {
    "gymnasium-vector": """
        from triplesumo.envs.vector import TripleSumoVectorEnv
        assert isinstance(envs.unwrapped, TripleSumoVectorEnv), type(envs.unwrapped)
        assert obs.shape == (16, 222) and reward.shape == (16,) and info["outcome"].shape == (16,)
    """,
    "sb3": """
        assert model.num_timesteps >= 256 and env.num_envs == 8 and torch.get_num_threads() == 1
        assert len(model.ep_info_buffer) >= 8  # the comment promises returns: 16-step matches end
        assert all({"r", "l", "t"} <= set(e) for e in model.ep_info_buffer)
    """,
    "gymnasium-async": """
        from gymnasium.vector import AsyncVectorEnv
        assert isinstance(envs.unwrapped, AsyncVectorEnv) and obs.shape == (2, 222)
        assert info["outcome"].dtype.kind == "i"
    """,
    "vector-env": """
        assert obs.shape == (16, 3, 79) and rewards.dtype == np.float32 and terminated.shape == (16, 3)
        assert set(triplesumo.rules.rewards.REPORTED) <= set(info)
    """,
    "torchrl": """
        assert rollout["state"].shape == (10, 222)
        assert rollout["bug", "info", "outcome"].shape[0] == 10
    """,
    "supersuit": """
        assert env.num_envs == 6
    """,
}


def test_every_guide_example_is_checked() -> None:
    assert set(guide_examples()) == set(CHECKS)


SLOW_GUIDES = ("sb3", "supersuit", "torchrl")
"""Guide examples that train or wrap through another library: 9 to 11 s each alone on the shared 2-core box."""


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_GUIDES else n
                                  for n in sorted(CHECKS)])
def test_guide_example_runs(name: str) -> None:
    code = guide_examples()[name]
    if name == "gymnasium-async":
        # The case that hung: the parent built the Paper env and ran torch before forking.
        code = textwrap.dedent("""
            import gymnasium as gym, numpy as np, torch, triplesumo
            torch.set_num_threads(2)
            triplesumo.zoo.make_policy("zoo:ant")(np.zeros((4, 222), np.float32))
            gym.make("TripleSumo-Paper-v2").reset(seed=0)
        """) + code
    run_python(code + textwrap.dedent(CHECKS[name]) + "\nprint('checked')\n")


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_sb3_subproc_vec_env_with_fork_after_the_parent_built_the_env() -> None:
    out = run_python(textwrap.dedent("""
        import gymnasium as gym, numpy as np, torch, triplesumo
        from stable_baselines3.common.env_util import make_vec_env
        from stable_baselines3.common.vec_env import SubprocVecEnv
        torch.set_num_threads(2)
        triplesumo.zoo.make_policy("zoo:spider")(np.zeros((4, 222), np.float32))
        gym.make("TripleSumo-Paper-v2").reset(seed=0)
        env = make_vec_env("TripleSumo-Paper-v2", n_envs=2, vec_env_cls=SubprocVecEnv,
                           vec_env_kwargs={"start_method": "fork"}, env_kwargs={"max_steps": 3})
        env.reset()
        dones = [env.step(np.zeros((2, 8), np.float32))[2] for _ in range(3)]
        assert dones[-1].all() and not dones[0].any()
        env.close()
        print("forked fine")
    """), timeout=120)
    assert "forked fine" in out


@pytest.mark.parametrize("obs_mode", ["paper", "egocentric"])
def test_torchrl_check_env_specs_passes(obs_mode: str) -> None:
    import torch
    from torchrl.envs import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    import triplesumo

    env = PettingZooWrapper(triplesumo.parallel_env(obs_mode=obs_mode, max_steps=6), return_state=True)
    check_env_specs(env, seed=0)
    rollout = env.rollout(8, break_when_any_done=False)  # crosses a reset: infos keep their keys and types
    outcome = rollout["next", "spider", "info", "outcome"].flatten()
    assert outcome[5].item() == 3 and outcome[0].item() == 0  # draw at the step limit, playing before
    assert rollout["next", "bug", "info", "out_of_ring"].dtype in (torch.bool, torch.float32)
    env.close()


def test_torchrl_gymenv_makes_the_registered_id_by_name() -> None:
    """TorchRL's ``GymEnv(id)`` first passes ``frameskip``; an unknown keyword is a ``TypeError`` (and still a
    ``ValueError`` naming the option), on which it retries without it (issue 39, item 6)."""
    from torchrl.envs import GymEnv
    from torchrl.envs.utils import check_env_specs

    from triplesumo.rules.scenarios import UnknownOptionError

    with pytest.raises(TypeError, match=r"unknown option\(s\) \['frameskip'\]"):
        triplesumo.scenario_config("paper", frameskip=1)
    assert issubclass(UnknownOptionError, ValueError)
    env = GymEnv("TripleSumo-Paper-v2", max_steps=5)
    check_env_specs(env, seed=0)
    rollout = env.rollout(6, break_when_any_done=False)
    assert rollout["observation"].shape == (6, 222) and rollout["next", "truncated"][4].item()
    env.close()


def test_torchrl_gymwrapper_takes_the_native_vector_env() -> None:
    """``GymWrapper(gym.make_vec(...))`` reads ``env.autoreset_mode`` as an attribute (Gymnasium >= 1.1 vector envs
    have it; issue 39, item 7)."""
    from gymnasium.vector import AutoresetMode
    from torchrl.envs import GymWrapper

    vec = gym.make_vec("TripleSumo-Paper-v2", num_envs=4, max_steps=5)
    assert vec.autoreset_mode == AutoresetMode.SAME_STEP == vec.metadata["autoreset_mode"]
    env = GymWrapper(vec)
    rollout = env.rollout(7, break_when_any_done=False)
    assert rollout["observation"].shape == (4, 7, 222)
    assert rollout["next", "truncated"][:, 4].all() and not rollout["next", "done"][:, 3].any()
    env.close()


def test_the_gymnasium_and_pettingzoo_paths_do_not_import_torch() -> None:
    """Issue 39, item 9: the zoo's fixed policies run on numpy, so making and stepping the paper env (its Ant
    and Spider from the zoo), its vector env and the PettingZoo env never imports torch (8-17 s under load,
    paid again by every worker process). Checked in a fresh interpreter."""
    out = subprocess.run([sys.executable, "-c", textwrap.dedent("""
        import sys, warnings
        warnings.simplefilter("ignore")
        import gymnasium as gym
        import numpy as np
        import triplesumo
        env = gym.make("TripleSumo-Paper-v2")
        env.reset(seed=0)
        env.step(np.zeros(8, np.float32))
        vec = gym.make_vec("TripleSumo-Paper-v2", num_envs=2)
        vec.reset(seed=0)
        vec.step(np.zeros((2, 8), np.float32))
        pz = triplesumo.parallel_env()
        pz.reset(seed=0)
        pz.step({a: np.zeros(8, np.float32) for a in pz.agents})
        print("torch" in sys.modules)
    """)], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.strip() == "False", out.stdout + out.stderr


def test_a_lean_info_level_keeps_the_outcome_for_torchrl() -> None:
    """Issue 39, item 13: ``info_level="outcome"`` keeps outcome, place and eliminated (at reset and every step,
    the same keys and types, as TorchRL's PettingZooWrapper needs) and passes its spec check; the full infos
    hold every reward term besides. Its speed-up is a benchmark figure (the issue note), not a test."""
    from torchrl.envs import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    lean = triplesumo.parallel_env(info_level="outcome", max_steps=6)
    _, infos = lean.reset(seed=0)
    assert all(set(i) == {"outcome", "place", "eliminated"} for i in infos.values())
    *_, infos = lean.step({a: lean.action_space(a).sample() for a in lean.agents})
    assert all(set(i) == {"outcome", "place", "eliminated"} for i in infos.values())
    full = triplesumo.parallel_env(max_steps=6)
    full.reset(seed=0)
    assert {"reward_still", "reward_outcome", "step"} <= set(full.step(
        {a: np.zeros(8, np.float32) for a in full.agents})[4]["bug"])
    with pytest.raises(ValueError, match="info_level must be one of"):
        triplesumo.parallel_env(info_level="none")
    env = PettingZooWrapper(triplesumo.parallel_env(info_level="outcome", max_steps=6), return_state=True)
    check_env_specs(env, seed=0)
    rollout = env.rollout(8, break_when_any_done=False)
    assert set(rollout["next", "bug", "info"].keys()) == {"outcome", "place", "eliminated"}
    assert rollout["next", "bug", "info", "outcome"].flatten()[5].item() == 3  # a draw at the step limit
    env.close()


def test_supersuit_black_death_plays_to_the_step_limit() -> None:
    """SuperSuit's ``black_death_v3`` steps the env once more after all agents have left (its done test is
    ``terminated & truncated``), with no actions; that step raised "the match is over". PettingZoo's own parallel
    envs return empty dicts then, and so does ours: black death, alone and on the guide's vector-env route, plays
    match after match through the step limit and ring exits."""
    import supersuit as ss

    env = ss.black_death_v3(triplesumo.parallel_env(max_steps=3))
    for seed in (0, 1):
        env.reset(seed=seed)
        steps = 0
        while env.agents:
            _, _, terms, truncs, _ = env.step({a: np.zeros(8, np.float32) for a in env.agents})
            steps += 1
        assert steps == 4 and all(terms.values()) and all(truncs.values())  # its extra step ends the episode
    vec = ss.pettingzoo_env_to_vec_env_v1(ss.black_death_v3(triplesumo.parallel_env(obs_mode="egocentric",
                                                                                     max_steps=3)))
    vec = ss.concat_vec_envs_v1(vec, 2, num_cpus=0, base_class="stable_baselines3")
    vec.reset()
    done = np.zeros(vec.num_envs, int)
    for _ in range(13):  # three matches of each copy, and more
        *_, dones, _ = vec.step(np.random.default_rng(0).uniform(-1, 1, (vec.num_envs, 8)))
        done += dones
    assert (done == 3).all()
    ffa = ss.black_death_v3(triplesumo.parallel_env(scenario="ffa", max_steps=40))  # agents leave mid-match
    ffa.reset(seed=0)
    rng = np.random.default_rng(0)
    while ffa.agents:
        ffa.step({a: rng.uniform(-1, 1, 8) for a in ffa.agents})


def test_the_sb3_adapter_sets_one_torch_thread_unless_told_otherwise() -> None:
    # SB3 trains in the process that builds its env; torch's default (a thread per core) ran its PPO and SAC
    # several times slower on a busy 2-core box. A fresh process, so that this one's thread settings stay.
    out = run_python(textwrap.dedent("""
        import torch
        torch.set_num_threads(2)
        from triplesumo.integrations.sb3 import make_vec_env
        make_vec_env("TripleSumo-v2", n_envs=1, threads=None).close()
        kept = torch.get_num_threads()
        make_vec_env("TripleSumo-v2", n_envs=1).close()
        default = torch.get_num_threads()
        make_vec_env("TripleSumo-v2", n_envs=1, threads=2).close()
        print(kept, default, torch.get_num_threads())
        try:
            make_vec_env("TripleSumo-v2", threads=0)
        except ValueError as exc:
            print(exc)
    """))
    assert out.splitlines()[0] == "2 1 2", out
    assert "threads must be an int >= 1" in out and "got 0" in out, out


def _bug_start(obs: dict[str, np.ndarray]) -> np.ndarray:
    return np.asarray(obs["bug"])


def test_one_seed_starts_the_same_match_in_the_gymnasium_views() -> None:
    """docs/libraries.md: match k of gym.make_vec(id, num_envs=N).reset(seed=s) is gym.make(id).reset(seed=s + k)'s,
    which is parallel_env().reset(seed=s + k)'s (Bug's observation at the start)."""
    seed, n = 7, 3
    envs = gym.make_vec("TripleSumo-v2", num_envs=n)
    vec, _ = envs.reset(seed=seed)
    envs.close()
    for k in range(n):
        single, _ = gym.make("TripleSumo-v2").reset(seed=seed + k)
        parallel, _ = triplesumo.parallel_env().reset(seed=seed + k)
        np.testing.assert_array_equal(vec[k], single, err_msg=f"make_vec match {k}")
        np.testing.assert_array_equal(_bug_start(parallel), single, err_msg=f"parallel_env seed {seed + k}")


def test_one_seed_starts_the_same_match_in_vector_env() -> None:
    """docs/libraries.md: match k of triplesumo.vector_env(num_envs=N).reset(seed=s) is the match of
    parallel_env().reset(seed=s + k)."""
    seed, n = 7, 3
    env = triplesumo.vector_env(num_envs=n)
    obs, _ = env.reset(seed=seed)
    bug = env.agents.index("bug")
    env.close()
    for k in range(n):
        parallel, _ = triplesumo.parallel_env().reset(seed=seed + k)
        np.testing.assert_array_equal(obs[k, bug], _bug_start(parallel), err_msg=f"vector_env match {k}")
