"""RLlib integration on a real local Ray: frozen zoo policies stay frozen, Bug learns,
episodes end with the game's outcomes; and Ray stays an optional import."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import triplesumo
from triplesumo.agents.policy_file import load_policy
from triplesumo.agents.zoo import ZOO_DIR
from triplesumo.rules.outcome import DRAW_CODE, PLAYING

ZOO_FROZEN = {"ant": "zoo:ant", "spider": "zoo:spider"}


@pytest.fixture(scope="module")
def rllib() -> Any:
    pytest.importorskip("ray.rllib", reason='the "ray" extra is not installed (pip install "triplesumo[ray]")')
    from triplesumo.integrations import rllib

    return rllib


@pytest.fixture(scope="module")
def local_ray(rllib: Any, ray_session: Any) -> None:
    """The module's RLlib tests run on the shared local Ray (conftest's ``ray_session``)."""


def _tiny(config: Any) -> Any:
    """A couple of hundred env steps per iteration, learned in-process."""
    return (config.env_runners(num_env_runners=0)
            .training(train_batch_size_per_learner=256, minibatch_size=64, num_epochs=1)
            .debugging(seed=0))


def _weights(algo: Any) -> dict[str, dict[str, torch.Tensor]]:
    return {m: {k: torch.as_tensor(v).clone() for k, v in w.items()}
            for m, w in algo.learner_group.get_weights().items()}


def _changed(before: dict[str, torch.Tensor], after: dict[str, torch.Tensor]) -> bool:
    assert before.keys() == after.keys()
    return any(not torch.equal(before[k], after[k]) for k in before)


def _check_outcomes(rllib: Any, result: dict[str, Any]) -> None:
    """Every agent's outcome rates reported, and consistent between the sides of the paper's match."""
    outcomes = result["env_runners"]["outcomes"]
    for agent in ("ant", "bug", "spider"):
        rates = outcomes[agent]
        assert sum(rates[o] for o in rllib.OUTCOMES) == pytest.approx(1.0)
    for o in rllib.OUTCOMES:
        assert outcomes["ant"][o] == pytest.approx(outcomes["bug"][o]), "partners must share an outcome"
    assert outcomes["spider"]["win"] == pytest.approx(outcomes["bug"]["loss"])
    assert outcomes["spider"]["loss"] == pytest.approx(outcomes["bug"]["win"])
    # 100-step matches against the zoo: some end by a ring-out, not all by the step limit.
    assert outcomes["spider"]["win"] + outcomes["spider"]["loss"] > 0


@pytest.mark.usefixtures("local_ray")
@pytest.mark.slow  # 18 s alone on the shared 2-core box
def test_bug_learns_while_the_zoo_ant_and_spider_act_inside_the_env(rllib: Any, tmp_path: Any) -> None:
    """Issue 39, item 14: by default the frozen agents play inside the env, so RLlib's modules, episodes and
    dicts hold Bug only, each env runner plays ENVS_PER_RUNNER matches, and every outcome is still reported."""
    from ray.rllib.algorithms.algorithm import Algorithm

    config = _tiny(rllib.make_config("paper", policies_to_train=["bug"], frozen=ZOO_FROZEN, max_steps=100))
    assert config.num_envs_per_env_runner == rllib.ENVS_PER_RUNNER == 4
    assert config.env_config["fixed"] == ZOO_FROZEN and config.env_config["info_level"] == "outcome"
    algo = config.build_algo()
    try:
        before = _weights(algo)
        assert set(before) == {"bug"} and set(algo.env_runner.module.keys()) == {"bug"}
        assert algo.env_runner.env.num_envs == 4
        for _ in range(2):
            result = algo.train()
        after = _weights(algo)
        episodes = algo.env_runner.sample(num_timesteps=40)
        algo.save_to_path(str(tmp_path / "ckpt"))
    finally:
        algo.stop()
    restored = Algorithm.from_checkpoint(str(tmp_path / "ckpt"))
    try:
        again = _weights(restored)
    finally:
        restored.stop()
    assert not _changed(after["bug"], again["bug"]), "Bug differs after restoring the checkpoint"
    assert _changed(before["bug"], after["bug"]), "PPO did not update Bug"
    assert {a for e in episodes for a in e.agent_ids} == {"bug"}
    assert len({e.id_ for e in episodes}) >= 4  # one (partial) episode per match at least
    assert result["env_runners"]["num_episodes_lifetime"] >= 4
    _check_outcomes(rllib, result)


@pytest.mark.usefixtures("local_ray")
@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_bug_learns_while_the_zoo_ant_and_spider_modules_stay_frozen(rllib: Any) -> None:
    """``frozen_in_env=False``: the old layout, the frozen agents as FrozenPolicyModules inside RLlib."""
    config = _tiny(rllib.make_config("paper", policies_to_train=["bug"], frozen=ZOO_FROZEN, max_steps=100,
                                     frozen_in_env=False))
    assert "fixed" not in config.env_config
    algo = config.build_algo()
    try:
        before = _weights(algo)
        assert set(before) == {"ant", "bug", "spider"}
        for _ in range(2):
            result = algo.train()
        after = _weights(algo)
        # What the learner sends to env runners (the acting part), and what the local env runner acts with.
        sent = algo.learner_group.get_state(components="learner/rl_module/bug", inference_only=True)
        sent = sent["learner"]["rl_module"]["bug"]
        acting = algo.get_module("bug").state_dict()
    finally:
        algo.stop()
    assert _changed(before["bug"], after["bug"]), "PPO did not update Bug"
    for agent in ("ant", "spider"):
        assert not _changed(before[agent], after[agent]), f"frozen {agent} changed"
        shipped = load_policy(ZOO_DIR / agent)[0].actor.state_dict()
        for key, value in shipped.items():
            assert torch.equal(after[agent][f"actor.{key}"], value), f"{agent} is not the zoo's {key}"
    assert "pi.net.mlp.0.weight" in sent and not any(k.startswith("vf.") for k in sent)
    assert all(torch.equal(torch.as_tensor(v), acting[k]) for k, v in sent.items()), "env runner acts with stale Bug"
    assert result["env_runners"]["num_episodes_lifetime"] >= 4
    _check_outcomes(rllib, result)


@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_fixed_agents_act_exactly_as_the_zoos_numpy_policies(rllib: Any) -> None:
    """The env's ``fixed`` agents play the zoo's numpy policies (``triplesumo.zoo.load``) from their own
    observations: the same match, step for step, as the PettingZoo env driven by hand."""
    from triplesumo import zoo

    env = rllib.make_env({"max_steps": 60, "fixed": ZOO_FROZEN})
    assert env.possible_agents == ["bug"] and set(env.observation_spaces) == set(env.action_spaces) == {"bug"}
    reference = triplesumo.parallel_env(max_steps=60, info_level="full")
    policies = {a: zoo.load(spec[4:])[0] for a, spec in ZOO_FROZEN.items()}
    obs, infos = env.reset(seed=3)
    ref_obs, _ = reference.reset(seed=3)
    assert set(obs) == set(infos) == {"bug"}
    rng = np.random.default_rng(0)
    over, steps = False, 0
    while not over:
        bug = rng.uniform(-1, 1, 8).astype(np.float32)
        actions = {a: p(ref_obs[a]) for a, p in policies.items()}
        ref_obs, ref_rewards, ref_terms, ref_truncs, ref_infos = reference.step({**actions, "bug": bug})
        obs, rewards, terms, truncs, infos = env.step({"bug": bug})
        np.testing.assert_array_equal(obs["bug"], ref_obs["bug"])
        assert set(obs) == set(rewards) == set(infos) == {"bug"} and rewards["bug"] == ref_rewards["bug"]
        over, steps = terms["__all__"] or truncs["__all__"], steps + 1
        assert over == (not reference.agents)
    assert infos["bug"]["outcomes"] == {a: i["outcome"] for a, i in ref_infos.items()}
    assert 0 < steps <= 60 and env.agents == []


@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_an_episode_ends_once_no_rllib_agent_is_left_in_play(rllib: Any, place: Any) -> None:
    """Elimination rules (ffa): a fixed agent out stops acting and the episode goes on; the RLlib agent out
    ends the episode (terminated), reporting the outcomes so far, though the others still play."""
    fixed = {"ant": "random", "spider": "zero", "beetle": "zero"}
    env = rllib.make_env({"max_steps": 50, "n_agents": 4, "fixed": fixed}, scenario="ffa")
    env.reset(seed=0)
    match = env.par_env.match
    place(match, "spider", x=3.0, y=0.0)
    obs, _, terms, truncs, infos = env.step({"bug": np.zeros(8, np.float32)})
    assert set(obs) == {"bug"} and not terms["__all__"] and not truncs["__all__"] and env.agents == ["bug"]
    assert "spider" not in env.par_env.agents
    place(match, "bug", x=3.0, y=0.0)
    obs, _, terms, truncs, infos = env.step({"bug": np.zeros(8, np.float32)})
    assert terms == {"bug": True, "__all__": True} and truncs == {"bug": False, "__all__": False}
    assert env.par_env.agents == ["ant", "beetle"] and env.agents == []
    codes = infos["bug"]["outcomes"]
    assert set(codes) == {"ant", "bug", "spider", "beetle"} and codes["bug"] == infos["bug"]["outcome"] != PLAYING
    assert codes["spider"] != PLAYING and codes["ant"] == codes["beetle"] == PLAYING  # these two play on


@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_fixed_random_agents_are_reseeded_by_reset(rllib: Any) -> None:
    env = rllib.make_env({"max_steps": 20, "fixed": {"ant": "random", "spider": "random"}})

    def play(seed: int) -> list[np.ndarray]:
        env.reset(seed=seed)
        return [env.step({"bug": np.zeros(8, np.float32)})[0]["bug"] for _ in range(5)]

    first, again, other = play(4), play(4), play(5)
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    assert not all(np.array_equal(a, b) for a, b in zip(first, other, strict=True))


@pytest.mark.parametrize(("fixed", "exc", "message"), [
    ({"beetle": "zero"}, ValueError, r"fixed: unknown agent\(s\) \['beetle'\]; the match's agents are"),
    ({"ant": "zero", "bug": "zero", "spider": "zero"}, ValueError, "leave at least one to RLlib"),
    ({"ant": 3}, ValueError, r"fixed\['ant'\] must be a policy spec string"),
    ({"ant": "zoo:beetle"}, FileNotFoundError, r"fixed\['ant'\]: no policy 'beetle' in the zoo"),
    ({"ant": "no/such/policy"}, ValueError, r"fixed\['ant'\]: unknown policy 'no/such/policy'"),
    (["ant"], ValueError, "fixed must map agent names to policy specs"),
])
@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_bad_fixed_entries_are_refused_naming_the_entry(rllib: Any, fixed: Any, exc: type, message: str) -> None:
    with pytest.raises(exc, match=message):
        rllib.make_env({"fixed": fixed})


@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_a_fixed_policy_file_for_other_observations_is_refused(rllib: Any) -> None:
    with pytest.raises(ValueError, match=r"fixed\['ant'\]: .*trained with obs_mode 'paper'"):
        rllib.make_env({"fixed": {"ant": "zoo:ant"}, "obs_mode": "egocentric"})
    with pytest.raises(ValueError, match=r"fixed\['ant'\]: .*trained with obs_mode 'paper'"):
        rllib.make_config("paper", frozen={"ant": "zoo:ant"}, obs_mode="egocentric")


@pytest.mark.usefixtures("local_ray")
@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_self_play_team_module_against_spider_module_both_learn(rllib: Any) -> None:
    config = _tiny(rllib.make_config("paper", share="team", max_steps=60, obs_mode="egocentric"))
    config = config.training(train_batch_size_per_learner=128)
    assert set(config.policies_to_train) == {"team", "spider"}
    algo = config.build_algo()
    try:
        before = _weights(algo)
        algo.train()
        after = _weights(algo)
    finally:
        algo.stop()
    assert set(before) == {"team", "spider"}
    assert _changed(before["team"], after["team"]) and _changed(before["spider"], after["spider"])


@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_policy_mapping_per_agent_and_per_team(rllib: Any) -> None:
    per_agent = rllib.make_config("paper", policies_to_train=["bug"])
    per_team = rllib.make_config("paper", share="team", policies_to_train=["team"], frozen={"spider": "zero"},
                                 obs_mode="egocentric")
    assert [per_agent.policy_mapping_fn(a, None) for a in ("ant", "bug", "spider")] == ["ant", "bug", "spider"]
    assert [per_team.policy_mapping_fn(a, None) for a in ("ant", "bug")] == ["team", "team"]
    assert per_team.env_config["fixed"] == {"spider": "zero"} and set(per_team.policies) == {"team"}
    old = rllib.make_config("paper", share="team", policies_to_train=["team"], frozen={"spider": "zero"},
                            obs_mode="egocentric", frozen_in_env=False)
    assert [old.policy_mapping_fn(a, None) for a in ("ant", "bug", "spider")] == ["team", "team", "spider"]
    assert "fixed" not in old.env_config and set(old.policies) == {"team", "spider"}
    spec = per_agent.get_multi_rl_module_spec()
    assert spec.rl_module_specs["bug"].observation_space.shape == (222,)
    assert spec.rl_module_specs["bug"].action_space.shape == (8,)
    assert per_team.env_config["match_config"].agent_names == ("ant", "bug", "spider")
    egocentric = rllib.make_config("paper", policies_to_train=["bug"], obs_mode="egocentric")
    assert egocentric.get_multi_rl_module_spec().rl_module_specs["ant"].observation_space.shape == (79,)


@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_frozen_module_plays_the_zoo_policy_deterministically(rllib: Any) -> None:
    from gymnasium import spaces
    from ray.rllib.core.columns import Columns

    obs_space, act_space = spaces.Box(-np.inf, np.inf, (222,), np.float32), spaces.Box(-1, 1, (8,), np.float32)
    module = rllib.FrozenPolicyModule(observation_space=obs_space, action_space=act_space, inference_only=False,
                                      model_config={"policy": "zoo:spider", "obs_mode": "paper"})
    obs = torch.as_tensor(np.random.default_rng(0).normal(size=(5, 222)), dtype=torch.float32)
    explore = module.forward_exploration({Columns.OBS: obs})[Columns.ACTIONS]
    infer = module.forward_inference({Columns.OBS: obs})[Columns.ACTIONS]
    expected = load_policy(ZOO_DIR / "spider")[0](obs.numpy())
    np.testing.assert_allclose(explore.numpy(), expected, atol=1e-6)
    np.testing.assert_array_equal(explore.numpy(), infer.numpy())
    with pytest.raises(NotImplementedError, match="policies_to_train"):
        module.forward_train({Columns.OBS: obs})
    zero = rllib.FrozenPolicyModule(observation_space=obs_space, action_space=act_space,
                                    model_config={"policy": "zero"})
    assert not zero.forward_inference({Columns.OBS: obs})[Columns.ACTIONS].any()
    with pytest.raises(ValueError, match="expects 222 observation values"):
        rllib.FrozenPolicyModule(observation_space=spaces.Box(-np.inf, np.inf, (79,), np.float32),
                                 action_space=act_space, model_config={"policy": "zoo:ant"})


@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_registered_env_plays_a_match_to_its_end(rllib: Any) -> None:
    assert rllib.register_envs() == [*(f"triplesumo_{name}_v2" for name in triplesumo.scenarios()),
                                     *triplesumo.envs.ENV_IDS]
    env = rllib.make_env({"max_steps": 7})
    obs, _ = env.reset(seed=1)
    assert set(obs) == {"ant", "bug", "spider"} and env.observation_space["bug"].shape == (222,)
    steps, over = 0, False
    while not over:
        obs, rewards, terms, truncs, infos = env.step({a: np.zeros(8, np.float32) for a in obs})
        steps, over = steps + 1, truncs["__all__"] or terms["__all__"]
    assert steps == 7 and truncs["__all__"] and {i["outcome"] for i in infos.values()} == {DRAW_CODE}
    env.close()
    by_class = rllib.TripleSumoMultiAgentEnv({"scenario": "paper", "obs_mode": "egocentric"})
    assert by_class.observation_space["spider"].shape == (79,)
    with pytest.raises(ValueError, match="not both"):
        rllib.TripleSumoMultiAgentEnv({"match_config": rllib.scenario_config(), "max_steps": 5})


@pytest.mark.slow  # 7 s alone on the shared 2-core box
def test_make_config_sets_one_torch_thread_unless_told_otherwise(rllib: Any) -> None:
    """The driver holds RLlib's learner; torch's default threads (one per core) stall on a busy 2-core box."""
    code = ("import torch; torch.set_num_threads(2); from triplesumo.integrations.rllib import make_config; "
            "make_config('paper', threads=None); kept = torch.get_num_threads(); make_config('paper'); "
            "print(kept, torch.get_num_threads())")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split() == ["2", "1"], proc.stdout


@pytest.mark.usefixtures("local_ray")
@pytest.mark.slow  # 8 s alone on the shared 2-core box
def test_a_gymnasium_id_without_its_module_builds_on_remote_env_runners_once_registered(rllib: Any) -> None:
    """A remote env runner has not imported triplesumo, so Gymnasium does not know "TripleSumo-Paper-v2" there
    (RLlib's driver then fails with an IndexError); register_envs() registers the Gymnasium ids with Tune too."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.tune.registry import ENV_CREATOR, _global_registry

    assert "TripleSumo-Paper-v2" in rllib.register_envs()
    assert _global_registry.contains(ENV_CREATOR, "TripleSumo-Paper-v2")
    config = (PPOConfig().environment("TripleSumo-Paper-v2", env_config={"max_steps": 20})
              .env_runners(num_env_runners=1, sample_timeout_s=120)
              .training(train_batch_size_per_learner=64, minibatch_size=32, num_epochs=1).debugging(seed=0))
    algo = config.build_algo()
    try:
        result = algo.train()
        assert result["env_runners"]["num_env_steps_sampled_lifetime"] >= 64
        assert algo.env_runner_group.num_healthy_remote_workers() == 1
    finally:
        algo.stop()


RLLIB_PAGE = Path(__file__).resolve().parents[1] / "docs" / "ray-rllib.md"


def _remote_runner_forms() -> str:
    """The block of docs/ray-rllib.md that shows the forms of a Gymnasium id that remote env runners find."""
    found = re.search(r"<!-- no-test: run by tests/test_rllib\.py[^\n]*-->\n```python\n(.*?)^```",
                      RLLIB_PAGE.read_text(), re.S | re.M)
    assert found, "docs/ray-rllib.md lost its block of the remote-runner forms"
    return found.group(1)


@pytest.mark.slow  # three local Rays of its own, each with a remote env runner: about two minutes on a 2-core box
def test_the_documented_forms_of_a_gymnasium_id_build_on_remote_env_runners_and_the_bare_id_alone_fails(
        rllib: Any) -> None:
    """docs/ray-rllib.md, "A Gymnasium id on remote env runners", run as written in a process of its own (no
    register_envs() anywhere): the id with its module, and the bare id under Ray's worker_process_setup_hook, build
    PPO with one remote env runner (which makes the env); the bare id alone then fails as the page says."""
    checks = textwrap.dedent("""
        ray.shutdown()
        ray.init()  # no hook, no register_envs(): the remote runner does not know the bare id
        try:
            PPOConfig().environment("TripleSumo-Paper-v2").env_runners(num_env_runners=1).build_algo()
        except Exception as exc:
            print("bare id alone:", type(exc).__name__)
        else:
            raise AssertionError("the bare id built on a remote env runner with nothing registering it")
    """)
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env |= {"PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src") + os.pathsep + env.get("PYTHONPATH", ""),
            "MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", _remote_runner_forms() + checks], capture_output=True, text=True,
                          timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "bare id alone: IndexError" in proc.stdout, proc.stdout  # RLlib's symptom, as the page names it


@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_a_gymnasium_id_given_as_a_scenario_names_rllibs_names(rllib: Any) -> None:
    with pytest.raises(ValueError, match=r"'TripleSumo-Paper-v2' is a Gymnasium id.*register_envs\(\)"):
        rllib.env_id("TripleSumo-Paper-v2")
    with pytest.raises(ValueError, match=r"'TripleSumo-Paper-v2' is a Gymnasium id.*register_envs\(\)"):
        rllib.make_config("TripleSumo-Paper-v2")


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"scenario": "chess"}, "scenario: unknown scenario 'chess'"),
    ({"policies_to_train": ["beetle"]}, r"policies_to_train: unknown module id\(s\) \['beetle'\]"),
    ({"policies_to_train": "bug"}, "collection of module ids"),
    ({"policies_to_train": ["bug"], "frozen": {"bug": "zero"}}, r"\['bug'\] are also frozen"),
    ({"policies_to_train": [], "frozen": {"ant": "zero"}}, "nothing would learn"),
    ({"frozen": {"team": "zero"}}, r"frozen: unknown module id\(s\) \['team'\]"),
    ({"frozen": {"ant": "zoo:beetle"}}, "no policy 'beetle' in the zoo"),
    ({"frozen": {"ant": "zoo:ant"}, "obs_mode": "egocentric"}, "trained with obs_mode 'paper'"),
    ({"share": "all"}, "share must be one of"),
    ({"share": "team"},  # paper observations: one vector for both seats of the module
     r"share='team' \(module 'team'\): one network for seats \['ant', 'bug'\] with obs_mode 'paper'"),
    ({"algo": "NoSuchAlgo"}, "algo: unknown RLlib algorithm 'NoSuchAlgo'"),
    ({"threads": 0}, r"threads must be an int >= 1 \(torch.set_num_threads\) or None, got 0"),
    ({"max_step": 5}, r"unknown option\(s\) \['max_step'\]"),
])
@pytest.mark.slow  # builds RLlib for the module, 13 s
def test_make_config_rejects_bad_input_naming_the_problem(rllib: Any, kwargs: dict, message: str) -> None:
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        rllib.make_config(**kwargs)


def test_core_never_imports_ray_and_a_missing_ray_names_the_extra() -> None:
    core = ("import triplesumo, triplesumo.envs, triplesumo.zoo, triplesumo.integrations, sys; "
            "triplesumo.parallel_env().reset(seed=0); "
            "assert not [m for m in sys.modules if m == 'ray' or m.startswith('ray.')], 'ray imported'")
    subprocess.run([sys.executable, "-c", core], check=True)
    blocked = ("import sys; sys.modules['ray'] = None\n"
               "for name in ('rllib', 'ray_tasks'):\n"
               "    try:\n        __import__('triplesumo.integrations.' + name)\n"
               "    except ImportError as e:\n        print(e)\n")
    out = subprocess.run([sys.executable, "-c", blocked], check=True, capture_output=True, text=True).stdout
    assert out.count('pip install "triplesumo[ray]"') == 2, out


@pytest.mark.parametrize("obs_mode", ["paper", "egocentric"])
def test_rllibs_env_checker_passes_every_scenario_without_a_warning(obs_mode: str,
                                                                    caplog: pytest.LogCaptureFixture) -> None:
    """Issue 39, item 12: RLlib's own checker (reset and step observations inside their spaces, float32 as the
    spaces say) on every scenario, warning-free; the observations it saw are checked here too."""
    import logging

    from ray.rllib.utils.pre_checks.env import check_multiagent_environments

    from triplesumo.integrations import rllib

    for scenario in triplesumo.scenarios():
        extra = {"evader_obs_noise": 0.5} if scenario == "pursuit" else {}
        env = rllib.make_env({"max_steps": 5, "obs_mode": obs_mode, **extra}, scenario=scenario)
        agents = env.par_env.possible_agents
        fixed = rllib.make_env({"max_steps": 5, "obs_mode": obs_mode, **extra, "info_level": "outcome",
                                "fixed": dict.fromkeys(agents[1:], "random")}, scenario=scenario)
        assert fixed.possible_agents == agents[:1]
        for checked in (env, fixed):
            with caplog.at_level(logging.WARNING):
                check_multiagent_environments(checked)
            obs, _ = checked.reset(seed=1)
            for agent, o in obs.items():
                assert o.dtype == np.float32 and checked.get_observation_space(agent).contains(o), (scenario, agent)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING], caplog.text
    lean = rllib.make_env({"max_steps": 5, "info_level": "outcome"})
    lean.reset(seed=0)
    *_, infos = lean.step({a: lean.get_action_space(a).sample() for a in lean.get_agent_ids()})
    assert set(infos["bug"]) == {"outcome", "place", "eliminated"}


@pytest.mark.usefixtures("local_ray")
@pytest.mark.slow  # 21 s alone on the shared 2-core box
def test_bench_rllib_reports_each_layouts_rate_beside_the_raw_env(tmp_path: Any,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """``triplesumo bench rllib --quick``: one row per layout, with RLlib's and the raw env's rates, their
    ratio, the build time, and what RLlib held (the speed itself is for the benchmark, not for a test)."""
    import json

    from triplesumo.cli import main

    out = tmp_path / "rllib.json"
    assert main(["bench", "rllib", "--quick", "--layouts", "in_env_4", "modules_1", "--json", str(out)]) == 0
    table = capsys.readouterr().out
    result = json.loads(out.read_text())
    assert list(result["layouts"]) == ["in_env_4", "modules_1"] and "ratio" in table and "in_env_4" in table
    assert result["config"]["env_runners"] == 1 and result["machine"]["cpus"] >= 1 and "ray" in result["versions"]
    for row in result["layouts"].values():
        assert row["env_steps"] >= result["config"]["steps"] and row["seconds"] > 0 and row["build_s"] > 0
        assert row["ratio"] == pytest.approx(row["env_steps_per_s"] / row["raw_env_steps_per_s"])
        assert len(row["rounds_env_steps_per_s"]) == len(row["rounds_raw_env_steps_per_s"]) == 1  # --quick: 1 round
    new, old = result["layouts"]["in_env_4"], result["layouts"]["modules_1"]
    assert new["modules"] == new["agents_in_episodes"] == ["bug"] and new["matches_per_runner"] == 4
    assert old["modules"] == old["agents_in_episodes"] == ["ant", "bug", "spider"] and old["matches_per_runner"] == 1
