"""The public batched API (``triplesumo.vector_env``), its Gymnasium vector view and the SB3 adapter."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import triplesumo
from triplesumo.envs.match import Match
from triplesumo.envs.seeding import match_seeds
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.outcome import OUTCOME_CODES
from triplesumo.rules.rewards import REPORTED


def slot_actions(k: int, steps: int, n_agents: int = 3) -> np.ndarray:
    """The actions of slot ``k``: a stream that depends only on ``k``."""
    return np.random.default_rng(1000 + k).uniform(-1, 1, (steps, n_agents, 8))


def roll(num_envs: int, num_threads: int, steps: int, seed: int = 7, **config: object) -> list[tuple]:
    env = triplesumo.vector_env(num_envs, num_threads=num_threads, **config)
    acts = np.stack([slot_actions(k, steps) for k in range(num_envs)], axis=1)
    out = [env.reset(seed=seed)]
    out += [env.step(acts[t]) for t in range(steps)]
    env.close()
    return out


def test_shapes_types_and_infos_follow_the_contract() -> None:
    with triplesumo.vector_env(3, max_steps=4, obs_mode="egocentric") as env:
        assert (env.num_envs, env.n_agents, env.obs_dim, env.act_dim) == (3, 3, 79, 8)
        assert env.agents == ("ant", "bug", "spider")
        assert env.single_observation_space.shape == (79,) and env.single_action_space.shape == (8,)
        obs, infos = env.reset(seed=0)
        reset_keys = set(infos)
        assert obs.shape == (3, 3, 79) and obs.dtype == np.float32
        for t in range(4):
            obs, rew, term, trunc, infos = env.step(np.zeros((3, 3, 8)))
            assert set(infos) == reset_keys  # the same keys at reset and every step
            assert rew.shape == term.shape == trunc.shape == (3, 3)
            assert rew.dtype == np.float32 and term.dtype == trunc.dtype == bool
            for key in REPORTED:
                assert infos[key].shape == (3, 3)
            np.testing.assert_allclose(rew, infos["dense_reward"] + infos["sparse_reward"], rtol=1e-6)
            assert infos["outcome"].dtype == np.int64 and infos["step"].tolist() == [t + 1] * 3
        # the step limit: a truncated draw for every agent, already reset
        assert trunc.all() and not term.any()
        assert (infos["outcome"] == OUTCOME_CODES["draw"]).all() and infos["_final_obs"].all()
        assert [m.steps for m in env.matches] == [0, 0, 0]


def test_autoreset_gives_the_final_observation_and_the_next_match_from_the_slot_stream() -> None:
    config = MatchConfig(max_steps=3)
    with triplesumo.vector_env(2, max_steps=3) as env:
        env.reset(seed=11)
        single = Match(config)
        single.reset(seed=match_seeds(11, 2)[1])
        for _ in range(3):
            out = env.step(np.zeros((2, 3, 8)))
            last = single.step_array(np.zeros((3, 8)))
        assert np.array_equal(out[4]["final_obs"][1], np.stack(last.observations))
        next_obs, _ = single.reset()  # the slot's own generator goes on
        assert np.array_equal(out[0][1], np.stack(next_obs))
        assert not np.array_equal(out[0][0], out[0][1])


def test_ring_exit_outcome_is_reported_on_the_step_the_match_ends(place) -> None:
    with triplesumo.vector_env(2) as env:
        env.reset(seed=0)
        place(env.matches[1], "spider", x=3.0)
        env.batch.reload(1)
        _, rew, term, trunc, infos = env.step(np.zeros((2, 3, 8)))
    assert term[1].all() and not term[0].any() and not trunc.any()
    assert infos["outcome"][1].tolist() == [OUTCOME_CODES[o] for o in ("win", "win", "loss")]
    assert infos["out_of_ring"][1].tolist() == [False, False, True]
    assert rew[1, 2] < -300 and infos["_final_obs"].tolist() == [False, True]


def test_results_do_not_depend_on_num_envs_or_thread_count() -> None:
    steps = 40  # with max_steps=15: two autoresets per slot
    a = roll(2, 1, steps, max_steps=15)
    b = roll(3, 2, steps, max_steps=15)
    assert np.array_equal(a[0][0], b[0][0][:2])
    for t in range(1, steps + 1):
        for x, y in zip(a[t][:4], b[t][:4], strict=True):
            assert np.array_equal(x, y[:2]), f"step {t}"
        for key in (*REPORTED, "outcome", "step"):
            assert np.array_equal(a[t][4][key], b[t][4][key][:2]), (t, key)


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="unknown scenario .chess.; available"):
        triplesumo.vector_env(2, scenario="chess")
    with pytest.raises(ValueError, match="backend must be one of"):
        triplesumo.vector_env(2, backend="tpu")
    with pytest.raises(ValueError, match="device must be None or 'cpu'"):
        triplesumo.vector_env(2, device="cuda")
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['max_step'\]"):
        triplesumo.vector_env(2, max_step=3)
    with pytest.raises(ValueError, match="num_envs must be an integer >= 1"):
        triplesumo.vector_env(0)
    with triplesumo.vector_env(2) as env:
        with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
            env.step(np.zeros((2, 3, 8)))
        with pytest.raises(ValueError, match="seed must be an int, None or a list of 2 seeds"):
            env.reset(seed=[1, 2, 3])
        env.reset(seed=0)
        with pytest.raises(ValueError, match=r"actions must have shape \(2, 3, 8\)"):
            env.step(np.zeros((2, 8)))


# ----------------------------------------------------------------- Gymnasium vector view
def _compare_infos(x: dict, y: dict, where: str) -> None:
    assert set(x) == set(y), (where, set(x) ^ set(y))
    for key in x:
        if isinstance(x[key], dict):
            _compare_infos(x[key], y[key], f"{where}.{key}")
        elif x[key].dtype == object:
            assert all((u is None and v is None) or np.array_equal(u, v) for u, v in zip(x[key], y[key], strict=True))
        else:
            assert x[key].dtype == y[key].dtype and np.array_equal(x[key], y[key]), (where, key)


@pytest.mark.slow  # 10 s alone on the shared 2-core box
def test_make_vec_is_the_native_vector_env_and_equals_a_seeded_sync_vector_env() -> None:
    """Same game as N single envs: observations, rewards, flags and infos, exit and time limit alike."""
    kwargs = {"max_steps": 200}
    native = gym.make_vec("TripleSumo-Paper-v2", num_envs=3, **kwargs)
    sync = gym.make_vec("TripleSumo-Paper-v2", num_envs=3, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}, **kwargs)
    assert type(native.unwrapped).__name__ == "TripleSumoVectorEnv"
    assert native.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert native.observation_space == sync.observation_space and native.action_space == sync.action_space
    a, b = native.reset(seed=5), sync.reset(seed=5)
    assert np.array_equal(a[0], b[0])
    _compare_infos(a[1], b[1], "reset")
    rng = np.random.default_rng(0)
    exits = limits = 0
    for t in range(700):
        act = rng.uniform(-1, 1, (3, 8)).astype(np.float32)
        a, b = native.step(act), sync.step(act)
        assert native.observation_space.contains(a[0])
        for x, y in zip(a[:4], b[:4], strict=True):
            assert x.dtype == y.dtype and np.array_equal(x, y), f"step {t}"
        _compare_infos(a[4], b[4], f"step {t}")
        exits, limits = exits + int(a[2].sum()), limits + int(a[3].sum())
    assert exits >= 1 and limits >= 1  # both ways to end (ring exits and time limits with this seed)
    native.close()
    sync.close()


def test_vector_view_does_not_depend_on_num_envs_or_threads() -> None:
    runs = []
    for n, threads in ((2, 1), (4, 2)):
        env = gym.make_vec("TripleSumo-Paper-v2", num_envs=n, num_threads=threads, max_steps=20)
        obs, _ = env.reset(seed=3)
        rows = [obs[:2]]
        for t in range(45):
            act = np.stack([slot_actions(k, 45)[t, 0] for k in range(n)])
            obs, rew, term, trunc, info = env.step(act)
            rows += [obs[:2], rew[:2], info["outcome"][:2]]
        runs.append(rows)
        env.close()
    assert all(np.array_equal(x, y) for x, y in zip(*runs, strict=True))


# ------------------------------------------------------------------------ SB3 adapter
@pytest.mark.parametrize("algo", ["PPO", "SAC", "TD3", "DDPG"])
def test_sb3_trains_on_the_batched_path(algo: str) -> None:
    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    from triplesumo.integrations.sb3 import make_vec_env

    class Outcomes(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.outcomes: list[int] = []
            self.terminal: list[np.ndarray] = []

        def _on_step(self) -> bool:
            for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
                if done:
                    self.outcomes.append(info["outcome"])
                    self.terminal.append(info["terminal_observation"])
            return True

    from stable_baselines3.common.vec_env import VecCheckNan

    torch.set_num_threads(1)
    env = VecCheckNan(make_vec_env("TripleSumo-Paper-v2", n_envs=4, seed=0, max_steps=25), raise_exception=True)
    kwargs = ({"n_steps": 25, "batch_size": 50, "n_epochs": 2} if algo == "PPO" else
              {"learning_starts": 40, "batch_size": 32})
    model = getattr(stable_baselines3, algo)("MlpPolicy", env, seed=0, policy_kwargs={"net_arch": [32, 32]},
                                             **kwargs)
    before = [p.detach().clone() for p in model.policy.parameters()]
    callback = Outcomes()
    model.learn(200, callback=callback)
    assert any(not torch.equal(x, y) for x, y in zip(before, model.policy.parameters(), strict=True))
    assert len(callback.outcomes) >= 4  # at least one finished match per slot (25-step limit)
    assert set(callback.outcomes) <= {1, 2, 3} and all(o.shape == (222,) for o in callback.terminal)
    assert len(model.ep_info_buffer) == len(callback.outcomes)
    assert all(e["l"] <= 25 for e in model.ep_info_buffer)
    env.close()


@pytest.mark.parametrize("env_id", ["TripleSumo-FFA-v2", "TripleSumo-Pursuit-v2"])
def test_make_vec_of_the_elimination_scenarios_is_a_sync_vector_of_single_matches(env_id: str) -> None:
    """Issue 39, item 8: ``gym.make_vec`` works for every registered id in its default mode. The elimination
    scenarios have no native vector env (a learner out ends its own episode while its match goes on), so
    Gymnasium's SyncVectorEnv of single matches plays them; the learner's elimination ends its episode."""
    from triplesumo.registration import ELIMINATION_SCENARIOS

    assert {n for n in triplesumo.scenarios() if triplesumo.scenario_config(n).rules == "elimination"} == set(
        ELIMINATION_SCENARIOS)
    env = gym.make_vec(env_id, num_envs=2, max_steps=300)
    assert isinstance(env, gym.vector.SyncVectorEnv)
    obs, _ = env.reset(seed=0)
    ended = 0
    rng = np.random.default_rng(0)
    for _ in range(320):
        obs, reward, term, trunc, info = env.step(rng.uniform(-1, 1, (2, 8)).astype(np.float32))
        assert env.observation_space.contains(obs) and np.isfinite(reward).all()
        ended += int((term | trunc).sum())
    assert ended >= 2
    env.close()


def test_make_vec_refusing_its_arguments_says_why_and_nothing_else() -> None:
    """A refused ``make_vec`` raises its error and no ``AttributeError`` from ``__del__`` (issue 39, item 16)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", "import gymnasium as gym, triplesumo\n"
                          "try:\n    gym.make_vec('TripleSumo-v2', num_envs=0)\nexcept ValueError as e:\n"
                          "    print('refused:', e)\n"], capture_output=True, text=True, timeout=120)
    assert "refused: num_envs" in out.stdout, out.stdout + out.stderr
    assert "AttributeError" not in out.stderr and "Exception ignored" not in out.stderr, out.stderr


def test_a_batch_too_big_for_memory_is_refused_at_once(tmp_path, capsys) -> None:
    """``vector_env(10**6)``, ``gym.make_vec(num_envs=10**6)`` and ``train --n-envs 1000000`` built matches for
    over 100 s before memory ran out. The bytes per match are estimated from the first one and compared with the
    memory available before any other is built, where batches are built (``MatchBatch``)."""
    import time

    from triplesumo.cli import main
    from triplesumo.envs.batch import MatchBatch, available_memory, match_bytes

    first = Match(MatchConfig())
    assert match_bytes(first) > first.model.nbuffer + first.data.nbuffer  # more than MuJoCo's buffers alone
    assert match_bytes(first, "mujoco") == match_bytes(first) + first.data.nbuffer  # the batch's own MjData
    assert (available_memory() or 0) > 0
    huge = r"1,000,000 matches need about [\d,]+\.\d GiB \(0\.\d\d MiB each.*more than the [\d,]+\.\d GiB this machine"
    for make, name in ((lambda: MatchBatch(None, 10**6), "n_matches"),
                       (lambda: triplesumo.vector_env(10**6), "num_envs"),
                       (lambda: gym.make_vec("TripleSumo-Paper-v2", num_envs=10**6), "num_envs")):
        t0 = time.perf_counter()
        with pytest.raises(MemoryError, match=rf"{name}={huge}"):
            make()
        assert time.perf_counter() - t0 < 2.0, name
    t0 = time.perf_counter()
    with pytest.warns(UserWarning, match="gradient steps per step"):  # the schedule's own warning comes first
        assert main(["train", "--out", str(tmp_path), "--name", "huge", "--n-envs", "1000000", "--no-progress",
                     "--no-tensorboard"]) == 2
    assert time.perf_counter() - t0 < 2.0
    assert re.search(rf"TrainConfig\.n_envs={huge}", capsys.readouterr().err)
    assert not (tmp_path / "huge").exists()


def test_make_vec_refuses_complex_and_non_number_actions_naming_the_learner() -> None:
    """The native ``gym.make_vec`` view dropped an imaginary part (numpy's ComplexWarning) where the other views
    refuse it, and an object array with 'x' gave numpy's message; ``vector_env`` named no agent for 'x'."""
    env = gym.make_vec("TripleSumo-v2", num_envs=2, max_steps=5)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions of 'bug' must be real numbers, got complex values"):
        env.step(np.zeros((2, 8)) + 0.5j)
    with pytest.raises(ValueError, match=r"actions of 'bug' must be real numbers, got complex values"):
        env.step([[0.5j] * 8] * 2)
    hidden = np.zeros((2, 8), dtype=object)  # numpy casts a complex scalar in an object array with a warning only
    hidden[0, 0] = np.complex64(2j)
    with pytest.raises(ValueError, match=r"actions of 'bug' must be real numbers, got complex values"):
        env.step(hidden)
    pz = triplesumo.parallel_env()
    pz.reset(seed=0)
    with pytest.raises(ValueError, match=r"action of 'spider' must be real numbers, got complex values"):
        pz.step({"ant": np.zeros(8), "bug": np.zeros(8), "spider": hidden[0]})
    odd = np.zeros((2, 8), dtype=object)
    odd[1, 3] = "x"
    with pytest.raises(ValueError, match=r"actions of 'bug' must be real numbers of shape \(2, 8\); got 'x' \(str\) "
                                         r"at \[1, 3\], which is not a number"):
        env.step(odd)
    env.step(np.zeros((2, 8)))  # nothing was stepped by the refusals
    env.close()
    with triplesumo.vector_env(2, max_steps=5) as arrays:
        arrays.reset(seed=0)
        odd = np.zeros((2, 3, 8), dtype=object)
        odd[1, 2, 5] = "x"
        with pytest.raises(ValueError, match=r"match 1: action of 'spider' must be 8 real numbers, shape \(8,\); "
                                             r"got 'x' \(str\) at \[5\], which is not a number"):
            arrays.step(odd)
