"""SAC's ``critic_loss="hl_gauss"`` (issue 53): histogram critics learned by the HL-Gauss cross-entropy.

The histogram of a target, the critic's Q as its expectation, one update's loss against one computed by hand, a
critic that fits a return of this game's size, and resume equals uninterrupted (learner and training run).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from test_ddpg import ACT_DIM, BATCH, OBS_DIM, _batch, _perturb, _t  # the same random batches
from test_sac_options import TINY, resumed_equals_uninterrupted, resumes_bit_for_bit, twin_of
from triplesumo.agents.networks import Critic
from triplesumo.algos.hlgauss import SIGMA_RATIO, HLGaussCritic, bin_edges, hl_gauss
from triplesumo.algos.sac import SAC, LayerNormCritic, SACConfig
from triplesumo.train.config import TrainConfig
from triplesumo.train.run_folder import config_from_json

torch.set_num_threads(1)

CFG = SACConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100, critic_loss="hl_gauss", n_step=1,
                value_low=-10.0, value_high=10.0, value_bins=41)


def test_a_targets_histogram_is_a_distribution_centred_on_it_and_clipped_into_the_support() -> None:
    edges = bin_edges(-1000.0, 1000.0, 101)
    sigma = SIGMA_RATIO * 20.0
    centres = (edges[:-1] + edges[1:]) / 2
    y = torch.tensor([-300.0, 0.0, 123.4, 480.0, -2000.0, 5000.0])
    h = hl_gauss(y, edges, sigma)
    assert h.shape == (6, 101)
    assert (h >= 0).all()
    torch.testing.assert_close(h.sum(-1), torch.ones(6))
    mean = h @ centres
    torch.testing.assert_close(mean[:4], y[:4], atol=0.05, rtol=0)  # inside the support: its mean is the target
    assert -1000 < mean[4] < -980 and 980 < mean[5] < 1000  # outside it: the mass sits at the ends, not NaN
    assert h[0].argmax() == 35 and h[0, 35] < 0.6  # -300 sits in bin 35, its neighbours share the mass
    with pytest.raises(ValueError, match="low < high"):
        bin_edges(1.0, -1.0, 10)


def test_an_hl_gauss_critic_is_the_expectation_of_its_histogram() -> None:
    critic = HLGaussCritic(OBS_DIM, ACT_DIM, (32, 16), -10.0, 10.0, 41)
    _perturb(critic, 3)
    obs, act = torch.randn(7, OBS_DIM), torch.rand(7, ACT_DIM) * 2 - 1
    logits = critic.logits(obs, act)
    assert logits.shape == (7, 41)
    edges = torch.linspace(-10, 10, 42)
    centres = (edges[:-1] + edges[1:]) / 2
    torch.testing.assert_close(critic(obs, act), torch.softmax(logits, -1) @ centres)
    assert not torch.allclose(critic(obs, act), critic(obs, act.flip(0)))
    assert "edges" not in critic.state_dict()  # made from the config, not checkpointed


def test_an_hl_gauss_update_is_the_cross_entropy_against_the_td_targets_histogram() -> None:
    """The critic loss of one update equals the cross-entropy computed by hand from the pre-update weights and the
    learner's generator; the mean squared error on the same Q-values is another number."""
    agent = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(CFG, normalize_obs=False), seed=0)
    for i, net in enumerate(agent.critics + agent.critic_targets):
        _perturb(net, i + 1)
    twin = twin_of(agent)
    batch = _batch(3)
    b = {k: _t(v) for k, v in batch.items()}
    with torch.no_grad():
        next_action, next_log_prob = twin.actor.sample(b["next_obs"], twin.generator)
        next_q = torch.minimum(*(t(b["next_obs"], next_action) for t in twin.critic_targets))
        y = b["rew"] + 0.99 * (1 - b["done"]) * (next_q - 0.2 * next_log_prob)
        edges = torch.linspace(-10, 10, 42)
        target = hl_gauss(y, edges, SIGMA_RATIO * 20 / 41)
        expected = sum(-(target * F.log_softmax(c.logits(b["obs"], b["act"]), -1)).sum(-1).mean()
                       for c in twin.critics)
        mse = sum(F.mse_loss(c(b["obs"], b["act"]), y) for c in twin.critics)
        q_mean = twin.critic(b["obs"], b["act"]).mean()
    assert abs(float(mse) - float(expected)) > 1e-3
    stats = agent.update(batch)
    assert stats["critic_loss"] == pytest.approx(float(expected), rel=1e-5)
    assert stats["q_mean"] == pytest.approx(float(q_mean), rel=1e-5, abs=1e-6)


@pytest.mark.parametrize("low, high, bins", [(-1000.0, 1000.0, 101)])
def test_an_hl_gauss_critic_fits_a_return_of_this_games_size(low: float, high: float, bins: int) -> None:
    """Regressed onto fixed targets around -300 (a loss's size), it reaches them within a bin's width in the
    steps a squared-error critic of the same widths needs."""
    torch.manual_seed(0)
    obs, act = torch.randn(256, OBS_DIM), torch.rand(256, ACT_DIM) * 2 - 1
    y = -300.0 + 40.0 * torch.tanh(obs[:, 0])
    critic = HLGaussCritic(OBS_DIM, ACT_DIM, (64, 64), low, high, bins)
    optimizer = torch.optim.Adam(critic.parameters(), lr=1e-3)
    for _ in range(600):
        loss, _ = critic.regression_loss(obs, act, y)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        error = (critic(obs, act) - y).abs().mean()
    assert error < 10.0  # half a bin


def test_hl_gauss_goes_with_layer_norm_and_is_validated() -> None:
    agent = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(CFG, critic_norm="layer"), seed=0)
    assert isinstance(agent.critic, HLGaussCritic) and isinstance(agent.critic_target, HLGaussCritic)
    assert any(isinstance(m, torch.nn.LayerNorm) for m in agent.critic.modules())
    assert type(SAC(OBS_DIM, ACT_DIM, SACConfig(hidden=(8,)), seed=0).critic) is Critic  # the default: mse
    assert LayerNormCritic.block(4, 8)[1].normalized_shape == (8,)
    with pytest.raises(ValueError, match="SACConfig.critic_loss must be one of mse, hl_gauss"):
        SACConfig(critic_loss="huber")
    with pytest.raises(ValueError, match="SACConfig.critic_loss hl_gauss does not go with critic_norm batch"):
        SACConfig(critic_loss="hl_gauss", critic_norm="batch")
    with pytest.raises(ValueError, match="SACConfig.value_high must be above value_low"):
        SACConfig(value_low=5.0, value_high=5.0)
    with pytest.raises(ValueError, match="SACConfig.value_bins"):
        SACConfig(value_bins=1)


def test_an_hl_gauss_learner_resumes_bit_for_bit(tmp_path: Path) -> None:
    def make(seed: int = 0) -> SAC:
        return SAC(OBS_DIM, ACT_DIM, CFG, seed=seed)

    resumes_bit_for_bit(make, tmp_path)


def test_an_hl_gauss_training_run_resumed_equals_the_uninterrupted_one(tmp_path: Path) -> None:
    run_dir = resumed_equals_uninterrupted(tmp_path, dataclasses.replace(TINY, critic_norm="none",
                                                                         critic_loss="hl_gauss"))
    saved = json.loads((run_dir / "config.json").read_text())
    assert saved["sac"]["critic_loss"] == "hl_gauss" and saved["sac"]["value_bins"] == 101


def test_a_config_json_written_before_critic_loss_reads_back_with_squared_error_critics() -> None:
    data = json.loads(json.dumps(dataclasses.asdict(TrainConfig(learn=("bug=sac",)))))
    for key in ("critic_loss", "value_low", "value_high", "value_bins"):
        del data["sac"][key]
    sac = config_from_json(data).sac
    assert (sac.critic_loss, sac.value_low, sac.value_high, sac.value_bins) == ("mse", -1000.0, 1000.0, 101)
