"""The policies shipped in the package: manifests, safe loading, deterministic acting."""

from __future__ import annotations

import json

import numpy as np
import pytest

import triplesumo
from triplesumo.agents import zoo
from triplesumo.envs.match import Match
from triplesumo.model import V0_PHYSICS, PhysicsConfig
from triplesumo.rules.scenarios import scenario_config

SHIPPED = ("ant", "spider", "bug")


def test_the_zoo_ships_the_paper_roster_and_the_self_play_policies() -> None:
    assert set(zoo.available()) >= {*SHIPPED, "spider-selfplay", "spider-selfplay-v1", "spider-selfplay-v2",
                                     "ffa-selfplay"}


@pytest.mark.parametrize("name", zoo.available())
def test_shipped_policy_manifest_says_how_it_was_made(name: str) -> None:
    manifest = json.loads((zoo.ZOO_DIR / f"{name}.json").read_text())
    scenario = manifest.get("scenario", "paper")
    if scenario == "paper":
        assert manifest["agent"] == name.split("-")[0]  # spider-selfplay plays the Spider
        assert manifest["obs_mode"] == "paper"
    else:  # e.g. ffa-selfplay: a free-for-all network, egocentric so that it takes any seat
        assert name.split("-")[0] == scenario and manifest["obs_mode"] == "egocentric"
        assert manifest["agent"] in scenario_config(scenario).agent_names
    assert manifest["command"].startswith("triplesumo train")
    assert isinstance(manifest["seed"], int)
    assert manifest["epochs"] > 0
    assert manifest["mujoco_version"] and manifest["env_version"] in ("v0", triplesumo.ENV_VERSION)
    # the simulation it was trained on: that of its env version (a manifest without physics: v0's)
    physics = PhysicsConfig(**manifest["physics"]) if "physics" in manifest else V0_PHYSICS
    assert (physics == PhysicsConfig()) == (manifest["env_version"] == triplesumo.ENV_VERSION)
    if name in SHIPPED:  # the paper roster that TripleSumo-Paper-v1 plays with is the current version's
        assert manifest["env_version"] == triplesumo.ENV_VERSION
    assert "evaluation" in manifest


@pytest.mark.parametrize("name", zoo.available())
def test_shipped_policy_loads_by_name_and_acts_deterministically(name: str) -> None:
    policy, manifest = triplesumo.zoo.load(name)
    match = Match(scenario_config(manifest.get("scenario", "paper"), obs_mode=manifest["obs_mode"]))
    obs, _ = match.reset(seed=3)
    i = match.agents.index(manifest["agent"])
    a1, a2 = policy(obs[i]), policy(obs[i].copy())
    assert a1.shape == (8,) and a1.dtype == np.float32
    assert np.array_equal(a1, a2)
    assert np.all(np.abs(a1) <= 1.0)
    batch = policy(np.stack([obs[i], obs[i]]))
    assert np.allclose(batch[0], a1, atol=1e-6)
    assert manifest["obs_dim"] == obs[i].shape[0]


def test_paper_env_uses_the_shipped_ant_and_spider() -> None:
    import gymnasium as gym

    env = gym.make("TripleSumo-Paper-v1")
    env.reset(seed=0)
    env.step(np.zeros(8, dtype=np.float32))
    data, match = env.unwrapped.data, env.unwrapped.match
    for agent in ("ant", "spider"):
        ids = match.sim.actuator_ids[match.agents.index(agent)]
        assert np.abs(data.ctrl[ids]).sum() > 0, agent
    assert np.abs(data.ctrl[match.sim.actuator_ids[match.agents.index("bug")]]).sum() == 0
