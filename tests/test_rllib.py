"""RLlib integration on a real local Ray: frozen zoo policies stay frozen, Bug learns,
episodes end with the game's outcomes; and Ray stays an optional import."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import numpy as np
import pytest
import torch

import triplesumo
from triplesumo.agents.policy_file import load_policy
from triplesumo.agents.zoo import ZOO_DIR
from triplesumo.rules.outcome import DRAW_CODE

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


@pytest.mark.usefixtures("local_ray")
def test_bug_learns_while_the_zoo_ant_and_spider_stay_frozen(rllib: Any, tmp_path: Any) -> None:
    from ray.rllib.algorithms.algorithm import Algorithm

    config = _tiny(rllib.make_config("paper", policies_to_train=["bug"], frozen=ZOO_FROZEN, max_steps=100))
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
        algo.save_to_path(str(tmp_path / "ckpt"))
    finally:
        algo.stop()
    restored = Algorithm.from_checkpoint(str(tmp_path / "ckpt"))
    try:
        again = _weights(restored)
    finally:
        restored.stop()
    for module in after:
        assert not _changed(after[module], again[module]), f"{module} differs after restoring the checkpoint"

    assert _changed(before["bug"], after["bug"]), "PPO did not update Bug"
    for agent in ("ant", "spider"):
        assert not _changed(before[agent], after[agent]), f"frozen {agent} changed"
        shipped = load_policy(ZOO_DIR / agent)[0].actor.state_dict()
        for key, value in shipped.items():
            assert torch.equal(after[agent][f"actor.{key}"], value), f"{agent} is not the zoo's {key}"
    assert "pi.net.mlp.0.weight" in sent and not any(k.startswith("vf.") for k in sent)
    assert all(torch.equal(torch.as_tensor(v), acting[k]) for k, v in sent.items()), "env runner acts with stale Bug"

    runners = result["env_runners"]
    assert runners["num_episodes_lifetime"] >= 4
    outcomes = runners["outcomes"]
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


def test_policy_mapping_per_agent_and_per_team(rllib: Any) -> None:
    per_agent = rllib.make_config("paper", policies_to_train=["bug"])
    per_team = rllib.make_config("paper", share="team", policies_to_train=["team"], frozen={"spider": "zero"},
                                 obs_mode="egocentric")
    assert [per_agent.policy_mapping_fn(a, None) for a in ("ant", "bug", "spider")] == ["ant", "bug", "spider"]
    assert [per_team.policy_mapping_fn(a, None) for a in ("ant", "bug", "spider")] == ["team", "team", "spider"]
    spec = per_agent.get_multi_rl_module_spec()
    assert spec.rl_module_specs["bug"].observation_space.shape == (222,)
    assert spec.rl_module_specs["bug"].action_space.shape == (8,)
    assert per_team.env_config["match_config"].agent_names == ("ant", "bug", "spider")
    egocentric = rllib.make_config("paper", policies_to_train=["bug"], obs_mode="egocentric")
    assert egocentric.get_multi_rl_module_spec().rl_module_specs["ant"].observation_space.shape == (79,)


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


def test_registered_env_plays_a_match_to_its_end(rllib: Any) -> None:
    assert rllib.register_envs() == [f"triplesumo_{name}_v2" for name in triplesumo.scenarios()]
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
    ({"max_step": 5}, r"unknown option\(s\) \['max_step'\]"),
])
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
        with caplog.at_level(logging.WARNING):
            check_multiagent_environments(env)
        obs, _ = env.reset(seed=1)
        for agent, o in obs.items():
            assert o.dtype == np.float32 and env.observation_space[agent].contains(o), (scenario, agent)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING], caplog.text
    lean = rllib.make_env({"max_steps": 5, "info_level": "outcome"})
    lean.reset(seed=0)
    *_, infos = lean.step({a: lean.get_action_space(a).sample() for a in lean.get_agent_ids()})
    assert set(infos["bug"]) == {"outcome", "place", "eliminated"}
