"""The twin critics' pessimism β (``pessimism``, TD3 and SAC; issue 53): their joint estimate is
``mean - β |Q_1 - Q_2| / 2``, the minimum at β = 1 (the default, bit for bit), the mean at 0, the maximum at -1. It
enters the TD target (TD3, SAC) and SAC's actor loss; a learner with another β resumes bit for bit."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from test_ddpg import ACT_DIM, BATCH, OBS_DIM, _batch, _perturb, _t
from test_sac_options import learn, resumes_bit_for_bit, twin_of
from triplesumo import _dcargs
from triplesumo.algos.ddpg import DDPG, DDPGConfig
from triplesumo.algos.offpolicy import combine_q
from triplesumo.algos.sac import SAC, SACConfig
from triplesumo.algos.td3 import TD3, TD3Config
from triplesumo.train.config import TrainConfig
from triplesumo.train.run_folder import config_from_json

torch.set_num_threads(1)

SAC_CFG = SACConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100, n_step=1, normalize_obs=False)
TD3_CFG = TD3Config(hidden=(32, 16), batch_size=BATCH, buffer_size=100, normalize_obs=False)


def test_combine_q_is_the_minimum_at_one_the_mean_at_zero_and_the_maximum_at_minus_one() -> None:
    gen = torch.Generator().manual_seed(0)
    q1, q2 = torch.randn(64, generator=gen), torch.randn(64, generator=gen)
    assert torch.equal(combine_q([q1, q2]), torch.minimum(q1, q2))  # the default, bit for bit
    assert torch.equal(combine_q([q1, q2], 1.0), torch.minimum(q1, q2))
    torch.testing.assert_close(combine_q([q1, q2], 0.0), (q1 + q2) / 2)
    torch.testing.assert_close(combine_q([q1, q2], -1.0), torch.maximum(q1, q2))
    torch.testing.assert_close(combine_q([q1, q2], 0.5), 0.75 * torch.minimum(q1, q2) + 0.25 * torch.maximum(q1, q2))
    assert combine_q([q1], 0.0) is q1  # one critic (DDPG) is its own estimate whatever β
    with pytest.raises(ValueError, match="one or two critics' values, got 3"):
        combine_q([q1, q2, q1], 0.0)


def _perturbed(cls: type, config: Any) -> Any:
    agent = cls(OBS_DIM, ACT_DIM, config, seed=0)
    for k, name in enumerate(("critic", "critic2", "critic_target", "critic2_target")):
        _perturb(getattr(agent, name), k + 1)  # away from the near-zero output layers: Q_1 and Q_2 differ
    return agent


@pytest.mark.parametrize("beta", [0.0, 0.5, -1.0])
def test_the_sac_td_target_reads_the_target_critics_joint_estimate(beta: float) -> None:
    agent = _perturbed(SAC, dataclasses.replace(SAC_CFG, pessimism=beta))
    twin = twin_of(agent)
    batch = _batch(3)
    b = {k: _t(v) for k, v in batch.items()}
    with torch.no_grad():
        a2, log_prob = twin.actor.sample(b["next_obs"], twin.generator)
        q1, q2 = (c(b["next_obs"], a2) for c in twin.critic_targets)
        assert (q1 - q2).abs().min() > 0
        joint = (q1 + q2) / 2 - beta * (q1 - q2).abs() / 2
        expected = b["rew"] + 0.99 * (1 - b["done"]) * (joint - twin.alpha * log_prob)
        minimum = b["rew"] + 0.99 * (1 - b["done"]) * (torch.minimum(q1, q2) - twin.alpha * log_prob)
    y = agent.td_target(batch)
    torch.testing.assert_close(y, expected)
    assert not torch.allclose(y, minimum)  # not clipped double Q


@pytest.mark.parametrize("beta", [0.0, -0.5])
def test_the_sac_actor_ascends_the_online_critics_joint_estimate(beta: float) -> None:
    agent = _perturbed(SAC, dataclasses.replace(SAC_CFG, pessimism=beta))
    twin = twin_of(agent)
    obs = _t(_batch(4)["obs"])
    with torch.no_grad():
        action, log_prob = twin.actor.sample(obs, twin.generator)
        q1, q2 = (c(obs, action) for c in twin.critics)
        joint = (q1 + q2) / 2 - beta * (q1 - q2).abs() / 2
        expected = (twin.alpha * log_prob - joint).mean()
        minimum = (twin.alpha * log_prob - torch.minimum(q1, q2)).mean()
    stats, _ = agent.update_actor(_batch(4))
    assert stats["actor_loss"] == pytest.approx(float(expected), rel=1e-5)
    assert stats["actor_loss"] != pytest.approx(float(minimum), rel=1e-3)


def test_the_td3_td_target_reads_the_joint_estimate_at_the_smoothed_action() -> None:
    agent = _perturbed(TD3, dataclasses.replace(TD3_CFG, pessimism=0.0))
    twin = twin_of(agent)
    batch = _batch(5)
    b = {k: _t(v) for k, v in batch.items()}
    with torch.no_grad():
        smoothed = twin.target_action(b["next_obs"])
        q1, q2 = (c(b["next_obs"], smoothed) for c in twin.critic_targets)
        expected = b["rew"] + 0.99 * (1 - b["done"]) * (q1 + q2) / 2
    torch.testing.assert_close(agent.td_target(batch), expected)


def test_the_default_is_clipped_double_q_and_another_beta_learns_otherwise() -> None:
    assert SACConfig().pessimism == TD3Config().pessimism == DDPGConfig().pessimism == 1.0
    runs = {}
    for beta in (None, 1.0, 0.0):
        config = SAC_CFG if beta is None else dataclasses.replace(SAC_CFG, pessimism=beta)
        agent = SAC(OBS_DIM, ACT_DIM, config, seed=0)
        runs[beta] = (learn(agent, range(4)), agent.state_dict())
    assert runs[None][0] == runs[1.0][0]  # an explicit 1 is the default, bit for bit
    assert all(torch.equal(runs[None][1][k], v) for k, v in runs[1.0][1].items())
    assert runs[0.0][0] != runs[1.0][0]
    assert any(not torch.equal(runs[0.0][1][k], v) for k, v in runs[1.0][1].items())
    # DDPG's one critic: β changes nothing
    ddpg = [DDPG(OBS_DIM, ACT_DIM, dataclasses.replace(DDPGConfig(hidden=(32, 16), batch_size=BATCH,
                                                                  buffer_size=100), pessimism=beta), seed=0)
            for beta in (1.0, -1.0)]
    assert learn(ddpg[0], range(3)) == learn(ddpg[1], range(3))


@pytest.mark.parametrize(("cls", "config"), [(SAC, dataclasses.replace(SAC_CFG, pessimism=0.0, normalize_obs=True)),
                                             (TD3, dataclasses.replace(TD3_CFG, pessimism=-0.5))])
def test_a_learner_with_another_pessimism_resumes_bit_for_bit(tmp_path: Path, cls: type, config: Any) -> None:
    def make(seed: int = 0) -> Any:
        return cls(OBS_DIM, ACT_DIM, config, seed=seed)

    agent = resumes_bit_for_bit(make, tmp_path)
    assert np.isfinite([v for stats in learn(agent, range(6, 8)) for v in stats.values()]).all()


@pytest.mark.parametrize("bad", [1.5, -2.0, float("nan"), True])
def test_pessimism_is_validated(bad: Any) -> None:
    with pytest.raises(ValueError, match=r"SACConfig\.pessimism"):
        SACConfig(pessimism=bad)
    with pytest.raises(ValueError, match=r"TD3Config\.pessimism"):
        TD3Config(pessimism=bad)


def test_pessimism_is_a_flag_a_fork_may_change_and_old_run_folders_read_the_minimum() -> None:
    assert "pessimism" in SACConfig.TUNABLE and "pessimism" in TD3Config.TUNABLE
    parser = argparse.ArgumentParser()
    _dcargs.add_arguments(parser, SACConfig, prefix="sac.")
    built = _dcargs.build(SACConfig, parser.parse_args(["--sac.pessimism", "0"]), prefix="sac.")
    assert built == dataclasses.replace(SACConfig(), pessimism=0.0)
    data = json.loads(json.dumps(dataclasses.asdict(TrainConfig(learn=("bug=sac", "ant=ddpg", "spider=td3")))))
    for algo in ("sac", "ddpg", "td3"):
        del data[algo]["pessimism"]  # a config.json written before the field
    cfg = config_from_json(data)
    assert (cfg.sac.pessimism, cfg.ddpg.pessimism, cfg.td3.pessimism) == (1.0, 1.0, 1.0)
