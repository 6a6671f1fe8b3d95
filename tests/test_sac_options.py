"""SAC's learner options for time to skill (issue 53): each one's update, and resume equals uninterrupted.

``critic_norm="layer"``: both critics and their targets put a LayerNorm after each hidden linear layer.
``critic_norm="batch"``: CrossQ's critics, batch norm before each linear layer and no targets; the TD target is read
from one training-mode pass of ``[(s, a); (s', a')]``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file
from torch import nn

from test_ddpg import ACT_DIM, BATCH, OBS_DIM, _batch, _perturb, _t  # the same random batches
from triplesumo.algos.sac import BATCH_NORM_MOMENTUM, SAC, BatchNormCritic, LayerNormCritic, SACConfig
from triplesumo.train.config import TrainConfig
from triplesumo.train.loop import train

torch.set_num_threads(1)

CFG = SACConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100, critic_norm="layer", n_step=1)


def _layer_norms(module: nn.Module) -> list[nn.LayerNorm]:
    return [m for m in module.modules() if isinstance(m, nn.LayerNorm)]


def test_layer_norm_critics_and_targets_normalise_each_hidden_layer() -> None:
    agent = SAC(OBS_DIM, ACT_DIM, CFG, seed=0)
    for name in ("critic", "critic2", "critic_target", "critic2_target"):
        critic = getattr(agent, name)
        assert isinstance(critic, LayerNormCritic)
        assert [ln.normalized_shape for ln in _layer_norms(critic)] == [(32,), (16,)], name
    assert not _layer_norms(agent.actor)  # the actor (and so the exported policy) is unchanged
    assert not _layer_norms(SAC(OBS_DIM, ACT_DIM, dataclasses.replace(CFG, critic_norm="none"), seed=0).critic)
    # the same seed builds the same actor with either critic
    plain = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(CFG, critic_norm="none"), seed=0)
    assert torch.equal(plain.actor.net[0].weight, agent.actor.net[0].weight)


def test_a_layer_norm_critic_does_not_grow_with_its_first_layer() -> None:
    """Scaling the first layer's weights and bias by 50 leaves Q as it was (LayerNorm undoes the scale); a plain
    critic's Q moves."""
    obs, act = _t(_batch(0)["obs"]), _t(_batch(0)["act"])
    for norm, same in (("layer", True), ("none", False)):
        agent = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(CFG, critic_norm=norm), seed=0)
        _perturb(agent.critic, 3)  # away from the near-zero output initialisation
        with torch.no_grad():
            before = agent.critic(obs, act)
            agent.critic.net[0].weight.mul_(50.0)
            agent.critic.net[0].bias.mul_(50.0)
            after = agent.critic(obs, act)
        assert torch.allclose(before, after, atol=1e-4) == same, norm


def test_a_layer_norm_update_steps_the_norms_and_their_targets_follow() -> None:
    agent = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(CFG, tau=0.1), seed=0)
    gain = _layer_norms(agent.critic)[0].weight.detach().clone()
    gain_target = _layer_norms(agent.critic_target)[0].weight.detach().clone()
    assert torch.equal(gain, gain_target)
    stats = agent.update(_batch(1))
    new_gain = _layer_norms(agent.critic)[0].weight.detach()
    assert not torch.equal(new_gain, gain)  # the critics' Adam steps the LayerNorm gains
    torch.testing.assert_close(_layer_norms(agent.critic_target)[0].weight, gain_target.lerp(new_gain, 0.1))
    assert np.isfinite(list(stats.values())).all()
    state = agent.state_dict()
    assert {"critic.net.1.weight", "critic.net.1.bias", "critic2_target.net.4.weight"} <= set(state)


def _batch_norms(module: nn.Module) -> list[nn.BatchNorm1d]:
    return [m for m in module.modules() if isinstance(m, nn.BatchNorm1d)]


BN = dataclasses.replace(CFG, critic_norm="batch")


def test_batch_norm_critics_normalise_before_each_linear_layer_and_have_no_targets() -> None:
    agent = SAC(OBS_DIM, ACT_DIM, BN, seed=0)
    for critic in agent.critics:
        assert isinstance(critic, BatchNormCritic) and not critic.training  # evaluation mode outside the critic step
        assert [bn.num_features for bn in _batch_norms(critic)] == [OBS_DIM + ACT_DIM, 32, 16]
    assert not hasattr(agent, "critic_target") and agent.critic_targets == [] and agent.target_pairs == ()
    assert not any(key.startswith("critic_target") for key in agent.state_dict())
    assert {"critic.net.0.running_mean", "critic2.net.6.running_var"} <= set(agent.state_dict())
    assert not _batch_norms(agent.actor)
    plain = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(CFG, critic_norm="none"), seed=0)
    assert torch.equal(plain.actor.net[0].weight, agent.actor.net[0].weight)  # the same actor from the same seed
    assert plain.target_pairs  # the class's targets are untouched


def twin_of(agent: Any) -> Any:
    """A learner of ``agent``'s class and config built under another seed, with its weights and generator state: it
    draws the samples ``agent``'s next update will, for a hand computation of that update."""
    twin = type(agent)(OBS_DIM, ACT_DIM, agent.config, seed=5)
    twin.load_state_dict(agent.state_dict())
    assert twin.generator is not None and agent.generator is not None
    twin.generator.set_state(agent.generator.get_state())
    return twin


def test_a_batch_norm_critic_step_regresses_both_halves_of_one_joint_pass() -> None:
    """The critic loss of an update is the one computed by hand from a joint training-mode pass of
    ``[(s, a); (s', a')]`` with the pre-update weights and generator; the input layer's running mean moves toward
    the mean of both halves (not of ``(s, a)`` alone); the critics end in evaluation mode."""
    agent = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(BN, normalize_obs=False), seed=0)
    _perturb(agent.critic, 1)
    _perturb(agent.critic2, 2)
    twin = twin_of(agent)
    batch = _batch(3)
    b = {k: _t(v) for k, v in batch.items()}
    with torch.no_grad():
        next_action, next_log_prob = twin.actor.sample(b["next_obs"], twin.generator)
        obs, act = torch.cat([b["obs"], b["next_obs"]]), torch.cat([b["act"], next_action])
        joint = []
        for critic in twin.critics:
            critic.train()
            joint.append(critic(obs, act))
        q = [j[:BATCH] for j in joint]
        y = b["rew"] + 0.99 * (1 - b["done"]) * (torch.minimum(joint[0][BATCH:], joint[1][BATCH:])
                                                  - 0.2 * next_log_prob)
        expected = sum(torch.mean((qi - y) ** 2) for qi in q)
        apart = twin.critic.train()(b["obs"], b["act"])  # (s, a) alone: other batch statistics, other Q
    assert not torch.allclose(apart, q[0], atol=1e-4)
    stats = agent.update(batch)
    assert stats["critic_loss"] == pytest.approx(float(expected), rel=1e-5)
    assert stats["q_mean"] == pytest.approx(float(q[0].mean()), rel=1e-5, abs=1e-7)
    first = _batch_norms(agent.critic)[0]
    torch.testing.assert_close(first.running_mean[:OBS_DIM], BATCH_NORM_MOMENTUM * obs[:, :OBS_DIM].mean(0))
    assert int(first.num_batches_tracked) == 1
    assert not agent.critic.training and not agent.critic2.training


def test_critic_norm_is_validated() -> None:
    with pytest.raises(ValueError, match="SACConfig.critic_norm must be one of none, layer, batch"):
        SACConfig(critic_norm="group")
    assert SACConfig().critic_norm == "none"  # the default is unchanged
    assert SACConfig(**json.loads(json.dumps(dataclasses.asdict(CFG)))) == CFG


def learn(agent: Any, rounds: range) -> list[dict[str, float]]:
    """One update per round on the shared random batches, the normaliser seeing the round's observations first;
    the updates' stats."""
    out = []
    for i in rounds:
        agent.observe(_batch(100 + i)["obs"])
        out.append(agent.update(_batch(i)))
    return out


def reloaded(agent: Any, fresh: Any, tmp_path: Path) -> Any:
    """``fresh`` (a learner built under another seed) loaded with ``agent``'s weights and optimiser state, through
    safetensors and JSON files, as a checkpoint holds them."""
    tensors, meta = agent.optimizer_state()
    save_file(agent.state_dict(), tmp_path / "w.safetensors")
    save_file(tensors, tmp_path / "o.safetensors")
    (tmp_path / "o.json").write_text(json.dumps(meta))
    fresh.load_state_dict(load_file(tmp_path / "w.safetensors"))
    fresh.load_optimizer_state(load_file(tmp_path / "o.safetensors"), json.loads((tmp_path / "o.json").read_text()))
    return fresh


def resumes_bit_for_bit(make: Callable[..., Any], tmp_path: Path) -> Any:
    """Learn 3 rounds, reload into a learner built with another seed, and assert that 3 more rounds give the same
    stats and state as the uninterrupted learner's; return the uninterrupted learner."""
    uninterrupted = make()
    learn(uninterrupted, range(3))
    resumed = reloaded(uninterrupted, make(seed=7), tmp_path)
    assert learn(uninterrupted, range(3, 6)) == learn(resumed, range(3, 6))
    for key, value in uninterrupted.state_dict().items():
        assert torch.equal(resumed.state_dict()[key], value), key
    return uninterrupted


@pytest.mark.parametrize("norm", ["layer", "batch"])
def test_a_normalised_critic_learner_resumes_bit_for_bit(tmp_path: Path, norm: str) -> None:
    def make(seed: int = 0) -> SAC:
        return SAC(OBS_DIM, ACT_DIM, dataclasses.replace(CFG, critic_norm=norm), seed=seed)

    uninterrupted = resumes_bit_for_bit(make, tmp_path)
    if norm == "layer":  # a plain critic's checkpoint lacks the norms
        with pytest.raises(KeyError, match=r"missing key 'critic\.net\.1\.bias' \(8 missing\)"):
            make().load_state_dict({k: v for k, v in uninterrupted.state_dict().items() if ".net.1." not in k})
    else:  # the running statistics are checkpointed and moved (they are part of what resumes)
        assert int(uninterrupted.state_dict()["critic.net.0.num_batches_tracked"]) == 6
        with pytest.raises(KeyError, match=r"missing key 'critic\.net\.0\.running_var'"):
            make().load_state_dict({k: v for k, v in uninterrupted.state_dict().items() if "running_var" not in k})


E = 2
TINY = SACConfig(hidden=(16, 16), buffer_size=2000, learning_starts=40, batch_size=16, learn_every=2,
                 critic_norm="layer")


def resumed_equals_uninterrupted(out: Path, sac: SACConfig) -> Path:
    """A tiny run of a SAC Bug with ``sac`` trained whole for 2E epochs, and for E epochs then resumed to 2E: the
    same epochs, env steps and updates (some), and the same policy bit for bit. Returns the interrupted run's
    folder."""
    def tiny(name: str, epochs: int) -> TrainConfig:
        return TrainConfig(name=name, out=str(out), learn=("bug=sac",), policies=("ant=zero", "spider=random"),
                           epochs=epochs, steps_per_epoch=30, n_envs=2, checkpoint_every=E, seed=3, sac=sac,
                           progress=False, tensorboard=False)

    whole = train(tiny("whole", 2 * E))
    killed = train(tiny("killed", E))
    resumed = train(TrainConfig(), resume_dir=killed.run_dir, overrides={"epochs": 2 * E})
    assert (resumed.epochs, resumed.env_steps, resumed.updates) == (whole.epochs, whole.env_steps, whole.updates)
    assert whole.updates > 0
    a, b = load_file(str(whole.run_dir / "policy.safetensors")), load_file(str(killed.run_dir / "policy.safetensors"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    return killed.run_dir


@pytest.mark.parametrize("norm", ["layer", "batch"])
def test_a_normalised_critic_training_run_resumed_equals_the_uninterrupted_one(tmp_path: Path, norm: str) -> None:
    run_dir = resumed_equals_uninterrupted(tmp_path, dataclasses.replace(TINY, critic_norm=norm))
    saved = json.loads((run_dir / "config.json").read_text())
    assert saved["sac"]["critic_norm"] == norm


def test_a_config_json_written_before_critic_norm_reads_back_with_the_norm_it_trained_with() -> None:
    """A run folder from before ``sac.critic_norm`` resumes as it trained (no norm); an unknown SAC key is still
    refused by name."""
    import dataclasses
    import json

    import pytest

    from triplesumo.train.config import TrainConfig
    from triplesumo.train.run_folder import config_from_json

    data = json.loads(json.dumps(dataclasses.asdict(TrainConfig(learn=("bug=sac",)))))
    del data["sac"]["critic_norm"]
    assert config_from_json(data).sac.critic_norm == "none"
    data["sac"]["critic_nrom"] = "layer"
    with pytest.raises(ValueError, match="critic_nrom"):
        config_from_json(data, "old/config.json")
