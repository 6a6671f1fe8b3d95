"""TD3, SAC and PPO on the shared core: each one's maths, the normaliser, policy files,
checkpoints, finite checks, configs, and a tiny learning check per algorithm."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from test_ddpg import ACT_DIM, BATCH, OBS_DIM, _batch, _perturb, _t  # the same random batches
from test_ddpg import CONFIG as CONFIG_DDPG
from triplesumo.agents.networks import ActorPolicy, GaussianActor, gaussian_log_prob, tanh_log_det_jacobian
from triplesumo.agents.normalizer import ObsNormalizer
from triplesumo.agents.policy_file import load_policy, save_policy
from triplesumo.algos.base import Algorithm, DivergenceError
from triplesumo.algos.ddpg import DDPG, DDPGConfig
from triplesumo.algos.ppo import PPO, PPOConfig, clipped_surrogate, gae
from triplesumo.algos.replay import ReplayBuffer
from triplesumo.algos.sac import SAC, SACConfig
from triplesumo.algos.td3 import TD3, TD3Config

torch.set_num_threads(1)

TD3_CFG = TD3Config(hidden=(32, 16), batch_size=BATCH, buffer_size=100)
SAC_CFG = SACConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100, n_step=1)  # one-step batches here
PPO_CFG = PPOConfig(hidden=(32, 16), n_steps=8, n_minibatches=4, n_epochs=2)


def _copy_generator(agent: Algorithm) -> torch.Generator:
    assert agent.generator is not None
    return torch.Generator().set_state(agent.generator.get_state())


# ----------------------------------------------------------------------------------- TD3


def test_td3_target_is_min_of_target_critics_at_smoothed_action() -> None:
    agent = TD3(OBS_DIM, ACT_DIM, dataclasses.replace(TD3_CFG, normalize_obs=False), seed=0)
    _perturb(agent.actor_target, 0)
    _perturb(agent.critic_target, 1, size=0.05)
    _perturb(agent.critic2_target, 2, size=0.05)
    batch = _batch(0)
    gen = _copy_generator(agent)
    y = agent.td_target(batch)
    with torch.no_grad():  # by hand: TARGET actor, clipped noise, min of the TARGET critics
        s2 = _t(batch["next_obs"])
        mu = agent.actor_target(s2)
        eps = torch.randn(mu.shape, generator=gen)
        a2 = (mu + (0.2 * eps).clamp(-0.5, 0.5)).clamp(-1, 1)
        q1, q2 = agent.critic_target(s2, a2), agent.critic2_target(s2, a2)
        expected = _t(batch["rew"]) + 0.99 * (1 - _t(batch["done"])) * torch.minimum(q1, q2)
    torch.testing.assert_close(y, expected, rtol=0, atol=0)
    assert (q1 < q2).any() and (q2 < q1).any()  # both critics are the min somewhere


def test_td3_smoothing_noise_is_clipped() -> None:
    config = dataclasses.replace(TD3_CFG, policy_noise=10.0, noise_clip=0.1)
    agent = TD3(OBS_DIM, ACT_DIM, config, seed=0)
    obs = _t(_batch(1, n=256)["next_obs"])
    with torch.no_grad():
        mu = agent.actor_target(obs)
        smoothed = agent.target_action(obs)
    step = (smoothed - mu).abs()
    assert step.max() <= 0.1 + 1e-6  # σ̃ = 10 would move far more without the clip
    assert (step > 0.099).float().mean() > 0.9  # ... and it does reach the clip


def test_td3_actor_and_targets_update_every_policy_delay() -> None:
    agent = TD3(OBS_DIM, ACT_DIM, dataclasses.replace(TD3_CFG, policy_delay=3), seed=0)
    stepped = []
    for i in range(6):
        actor = agent.state_dict()["actor.net.0.weight"]
        target = agent.state_dict()["critic_target.net.0.weight"]
        critic = agent.state_dict()["critic2.net.0.weight"]
        stats = agent.update(_batch(i))
        moved = not torch.equal(agent.state_dict()["actor.net.0.weight"], actor)
        assert moved == ("actor_loss" in stats)
        assert moved == (not torch.equal(agent.state_dict()["critic_target.net.0.weight"], target))
        assert not torch.equal(agent.state_dict()["critic2.net.0.weight"], critic)  # critics every step
        stepped.append(moved)
    assert stepped == [False, False, True, False, False, True]


# ----------------------------------------------------------------------------------- SAC


def test_sac_target_includes_entropy_term() -> None:
    agent = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(SAC_CFG, alpha=0.7, normalize_obs=False), seed=0)
    _perturb(agent.critic_target, 1)
    _perturb(agent.critic2_target, 2)
    batch = _batch(2)
    gen = _copy_generator(agent)
    y = agent.td_target(batch)
    with torch.no_grad():
        s2 = _t(batch["next_obs"])
        mean, log_std = agent.actor.distribution(s2)
        u = mean + log_std.exp() * torch.randn(mean.shape, generator=gen)
        a2 = torch.tanh(u)
        logp = gaussian_log_prob(u, mean, log_std) - torch.log(1 - a2.square()).sum(-1)
        q = torch.minimum(agent.critic_target(s2, a2), agent.critic2_target(s2, a2))
        expected = _t(batch["rew"]) + 0.99 * (1 - _t(batch["done"])) * (q - 0.7 * logp)
    torch.testing.assert_close(y, expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize(("target_entropy", "rises"), [(10.0, True), (-100.0, False)])
def test_sac_temperature_rises_when_entropy_is_below_target(target_entropy: float, rises: bool) -> None:
    agent = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(SAC_CFG, target_entropy=target_entropy), seed=0)
    before = agent.alpha
    stats = agent.update(_batch(3))
    assert (stats["entropy"] < target_entropy) == rises
    assert (agent.alpha > before) == rises
    assert stats["alpha"] == pytest.approx(agent.alpha)


def test_sac_fixed_temperature_has_no_optimizer() -> None:
    agent = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(SAC_CFG, learn_alpha=False, alpha=0.3), seed=0)
    stats = agent.update(_batch(4))
    assert "alpha_loss" not in stats and stats["alpha"] == pytest.approx(0.3)
    assert agent.optimizers == ("actor_optimizer", "critic_optimizer")


def test_tanh_log_prob_matches_numerical_density() -> None:
    """log π(a) of a = tanh(u), u ~ N(μ, σ²), against the CDF's finite difference."""
    mean, log_std = torch.tensor([[0.3]], dtype=torch.float64), torch.tensor([[math.log(0.8)]], dtype=torch.float64)
    normal = torch.distributions.Normal(0.3, 0.8)
    h = 1e-5
    for a in (-0.95, -0.5, 0.0, 0.4, 0.99):
        u = torch.tensor([[math.atanh(a)]], dtype=torch.float64)
        logp = gaussian_log_prob(u, mean, log_std) - tanh_log_det_jacobian(u)
        hi, lo = (normal.cdf(torch.tensor(math.atanh(a + s * h), dtype=torch.float64)) for s in (1, -1))
        numerical = float((hi - lo) / (2 * h))
        assert float(logp.exp()) == pytest.approx(numerical, rel=1e-4)


def test_gaussian_actor_sample_and_export() -> None:
    actor = GaussianActor(OBS_DIM, ACT_DIM, (16,), state_dependent_std=True)
    _perturb(actor, 0, size=2.0)
    obs = torch.randn(64, OBS_DIM)
    action, logp = actor.sample(obs, torch.Generator().manual_seed(0))
    assert action.abs().max() <= 1 and logp.shape == (64,)
    mean, log_std = actor.distribution(obs)
    assert log_std.min() >= -5 and log_std.max() <= 2
    torch.testing.assert_close(actor.to_actor()(obs), torch.tanh(mean), rtol=0, atol=0)


# ----------------------------------------------------------------------------------- PPO


def test_gae_hand_computed_with_termination_and_truncation() -> None:
    gamma, lam = 0.9, 0.5
    # One match, 4 steps: step 1 terminates (a win), step 2 is truncated (bootstrap 10).
    r = torch.tensor([[1.0], [2.0], [3.0], [4.0]])
    v = torch.tensor([[0.5], [1.0], [1.5], [2.0]])
    term = torch.tensor([[0.0], [1.0], [0.0], [0.0]])
    trunc = torch.tensor([[0.0], [0.0], [1.0], [0.0]])
    next_v = torch.tensor([[1.0], [99.0], [10.0], [3.0]])  # 99 is after a terminal: never used
    adv = gae(r, v, next_v, term, trunc, gamma, lam)
    a3 = 4 + 0.9 * 3 - 2.0  # last step bootstraps from V(next obs) = 3
    a2 = 3 + 0.9 * 10 - 1.5  # truncated: bootstrap from V(final obs), no carry from step 3
    a1 = 2 - 1.0  # terminated: no bootstrap, no carry
    a0 = (1 + 0.9 * 1.0 - 0.5) + 0.9 * 0.5 * a1
    torch.testing.assert_close(adv[:, 0], torch.tensor([a0, a1, a2, a3]))
    # λ = 1 without ends is the discounted return minus V.
    ones = torch.zeros(3, 1)
    mc = gae(torch.ones(3, 1), torch.zeros(3, 1), torch.zeros(3, 1), ones, ones, 0.5, 1.0)
    torch.testing.assert_close(mc[:, 0], torch.tensor([1.75, 1.5, 1.0]))


def test_gae_stops_its_trace_at_a_dropped_row() -> None:
    """Issue 39, item 3: a physics-error row (reward 0, terminated, ``valid`` 0, left out of the loss) carries
    nothing back; the valid step before it ends at its own δ, bootstrapping from V of the state it reached (here
    0.9 = 1 + 0.9 * 1.0 - 1.0, where the leak made it 0.9 - 0.9 * 0.5 * 1.0)."""
    gamma, lam = 0.9, 0.5
    r = torch.tensor([[1.0], [0.0], [2.0]])
    v = torch.tensor([[1.0], [1.0], [0.5]])  # V(s_1) = 1.0: the state before the bad physics step
    term = torch.tensor([[0.0], [1.0], [0.0]])  # the error row is recorded as terminated
    trunc = torch.zeros(3, 1)
    valid = torch.tensor([[1.0], [0.0], [1.0]])
    next_v = torch.tensor([[1.0], [7.0], [0.0]])
    adv = gae(r, v, next_v, term, trunc, gamma, lam, valid)
    assert adv[0, 0].item() == pytest.approx(1 + 0.9 * 1.0 - 1.0)
    leaked = gae(r, v, next_v, term, trunc, gamma, lam)  # without valid: the old trace through the dropped row
    assert leaked[0, 0].item() == pytest.approx(0.9 + 0.9 * 0.5 * (0 - 1.0))
    torch.testing.assert_close(adv[1:], leaked[1:])  # only the step before the dropped row changes


@pytest.mark.parametrize(("advantage", "ratio", "zero"), [
    (1.0, 1.5, True), (1.0, 1.1, False), (1.0, 0.5, False),
    (-1.0, 0.5, True), (-1.0, 0.9, False), (-1.0, 1.5, False),
])
def test_ppo_ratio_clipping_gradient(advantage: float, ratio: float, zero: bool) -> None:
    log_ratio = torch.tensor([math.log(ratio)], requires_grad=True)
    loss = clipped_surrogate(log_ratio, torch.tensor([advantage]), clip=0.2)
    loss.backward()
    assert log_ratio.grad is not None
    assert (float(log_ratio.grad.abs()) == 0.0) == zero
    assert loss.item() == pytest.approx(-advantage * (min(max(ratio, 0.8), 1.2) if zero else ratio))


def _ppo_rollout(agent: PPO, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    for t in range(agent.config.n_steps):
        obs = rng.standard_normal((3, OBS_DIM))
        agent.observe(obs)
        agent.explore(obs, rng)
        agent.record(rng.standard_normal(3), np.array([0, 0, t == 3]), np.array([t == 5, 0, 0]),
                     rng.standard_normal((3, OBS_DIM)))
    return rng.standard_normal((3, OBS_DIM))


def test_ppo_rollout_bootstraps_truncation_and_first_ratio_is_one() -> None:
    agent = PPO(OBS_DIM, ACT_DIM, dataclasses.replace(PPO_CFG, normalize_obs=False), seed=0)
    rng = np.random.default_rng(0)
    final = rng.standard_normal((3, OBS_DIM)).astype(np.float32)
    for t in range(agent.config.n_steps):
        agent.explore(rng.standard_normal((3, OBS_DIM)), rng)
        agent.record(np.ones(3), np.zeros(3), np.array([t == 2, 0, 0]), final)
    with torch.no_grad():
        v_final = agent.critic(_t(final))
    assert float(agent.rollout["bootstrap"][2, 0]) == pytest.approx(float(v_final[0]))
    last = rng.standard_normal((3, OBS_DIM))
    adv, _ = agent.advantages(last)
    r = agent.rollout
    with torch.no_grad():
        next_v = torch.cat([r["value"][1:], agent.critic(agent.tensor(last))[None]])
    next_v[2, 0] = v_final[0]
    torch.testing.assert_close(adv, gae(r["reward"], r["value"], next_v, r["terminated"], r["truncated"],
                                        0.99, 0.95))
    # The stored log-probs are the policy's: before any step the ratio is exactly 1.
    mean, log_std = agent.actor.distribution(r["obs"])
    torch.testing.assert_close(gaussian_log_prob(r["u"], mean, log_std), r["log_prob"])
    stats = agent.update(last)
    assert set(stats) == {"actor_loss", "critic_loss", "entropy", "approx_kl", "clip_fraction"}
    assert agent.step == 0 and agent.num_updates == 1 and not agent.rollout_full


def test_ppo_resume_mid_rollout_is_bit_for_bit(tmp_path: Path) -> None:
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(2)
    uninterrupted, resumed = _make("ppo"), _make("ppo", seed=5)

    def steps(agent: PPO, rng: np.random.Generator, n: int) -> None:
        for _ in range(n):
            obs = rng.standard_normal((3, OBS_DIM))
            agent.observe(obs)
            agent.explore(obs, rng)
            agent.record(rng.standard_normal(3), rng.random(3) < 0.2, np.zeros(3))

    assert isinstance(uninterrupted, PPO) and isinstance(resumed, PPO)
    steps(uninterrupted, rng_a, 5)
    np.savez(tmp_path / "rollout.npz", **uninterrupted.rollout_state())
    save_file(uninterrupted.state_dict(), tmp_path / "w.safetensors")
    tensors, meta = uninterrupted.optimizer_state()
    resumed.load_state_dict(load_file(tmp_path / "w.safetensors"))
    resumed.load_optimizer_state(tensors, meta)
    with np.load(tmp_path / "rollout.npz", allow_pickle=False) as data:
        resumed.load_rollout_state({k: data[k] for k in data.files})
    rng_b.bit_generator.state = rng_a.bit_generator.state  # the trainer restores its rng too
    steps(uninterrupted, rng_a, 3)
    steps(resumed, rng_b, 3)
    last = np.ones((3, OBS_DIM))
    assert uninterrupted.update(last) == resumed.update(last)
    for key, value in uninterrupted.state_dict().items():
        assert torch.equal(resumed.state_dict()[key], value), key


def test_ppo_record_errors() -> None:
    agent = PPO(OBS_DIM, ACT_DIM, PPO_CFG, seed=0)
    with pytest.raises(RuntimeError, match="explore"):
        agent.record(np.zeros(3), np.zeros(3), np.zeros(3))
    agent.explore(np.zeros((3, OBS_DIM)), np.random.default_rng(0))
    with pytest.raises(ValueError, match="final_obs"):
        agent.record(np.zeros(3), np.zeros(3), np.ones(3))
    with pytest.raises(RuntimeError, match="0 of 8"):
        agent.update(np.zeros((3, OBS_DIM)))


# ----------------------------------------------------------------------------- normaliser


def test_normalizer_matches_numpy_over_chunks_and_is_frozen_in_policies() -> None:
    rng = np.random.default_rng(0)
    data = rng.normal(3.0, 2.0, (1000, OBS_DIM)) * np.arange(1, OBS_DIM + 1)
    norm = ObsNormalizer(OBS_DIM)
    for chunk in np.array_split(data, [1, 7, 300, 301, 999]):
        norm.update(chunk)
    np.testing.assert_allclose(norm.mean.numpy(), data.mean(0), rtol=1e-12)
    np.testing.assert_allclose(norm.var.numpy(), data.var(0), rtol=1e-10)
    assert float(norm.count) == 1000
    with pytest.raises(ValueError, match="non-finite"):
        norm.update(np.full((1, OBS_DIM), np.nan))
    # A policy applies the statistics and never changes them.
    agent = TD3(OBS_DIM, ACT_DIM, TD3_CFG, seed=0)
    agent.observe(data)
    state = {k: v.clone() for k, v in agent.state_dict().items() if k.startswith("obs_norm.")}
    obs = data[:4]
    first = agent.act(obs)
    for _ in range(3):
        np.testing.assert_array_equal(agent.act(obs), first)
    for key, value in state.items():
        assert torch.equal(agent.state_dict()[key], value)
    with torch.no_grad():
        expected = agent.actor(((_t(obs) - _t(data.mean(0))) / _t(np.sqrt(data.var(0) + 1e-8))).float())
    np.testing.assert_allclose(first, expected.numpy(), atol=1e-6)
    assert not np.allclose(ActorPolicy(agent.actor)(obs), first)  # the normaliser matters


# --------------------------------------------------------------------------- policy files


@pytest.mark.parametrize("name", ["ddpg", "td3", "sac", "ppo"])
def test_policy_file_round_trip_is_the_deterministic_policy(tmp_path: Path, name: str) -> None:
    agent = _make(name)
    rng = np.random.default_rng(0)
    agent.observe(rng.normal(2.0, 3.0, (50, OBS_DIM)))
    if not isinstance(agent, PPO):
        for i in range(2):
            agent.update(_batch(i))
    _perturb(agent.actor, 5)
    save_policy(tmp_path / "p", agent.export_actor(), {"agent": "bug", "obs_mode": "paper", "algo": name},
                obs_norm=agent.obs_norm)
    policy, manifest = load_policy(tmp_path / "p")
    assert manifest["obs_norm"] == (name != "ddpg") and manifest["algo"] == name
    assert set(load_file(tmp_path / "p.safetensors")) == {
        k for k in agent.state_dict() if k.startswith(("actor.net.", "obs_norm."))}
    obs = rng.normal(2.0, 3.0, (8, OBS_DIM))
    np.testing.assert_allclose(policy(obs), agent.act(obs), atol=1e-6)


# ---------------------------------------------------------------------------- checkpoints


def _make(name: str, seed: int = 0) -> Algorithm:
    if name == "ddpg":
        return DDPG(OBS_DIM, ACT_DIM, DDPGConfig(hidden=(32, 16), batch_size=BATCH), seed=seed)
    if name == "td3":
        return TD3(OBS_DIM, ACT_DIM, TD3_CFG, seed=seed)
    if name == "sac":
        return SAC(OBS_DIM, ACT_DIM, SAC_CFG, seed=seed)
    return PPO(OBS_DIM, ACT_DIM, PPO_CFG, seed=seed)


def _train(agent: Algorithm, rounds: range) -> list[dict[str, float]]:
    out = []
    for i in rounds:
        if isinstance(agent, PPO):
            out.append(agent.update(_ppo_rollout(agent, i)))
        else:
            assert hasattr(agent, "update")
            agent.observe(_batch(100 + i)["obs"])
            out.append(agent.update(_batch(i)))
    return out


@pytest.mark.parametrize("name", ["td3", "sac", "ppo"])
def test_resume_is_bit_for_bit(tmp_path: Path, name: str) -> None:
    uninterrupted = _make(name)
    _train(uninterrupted, range(3))
    tensors, meta = uninterrupted.optimizer_state()
    save_file(uninterrupted.state_dict(), tmp_path / "w.safetensors")
    save_file(tensors, tmp_path / "o.safetensors")
    (tmp_path / "o.json").write_text(json.dumps(meta))
    resumed = _make(name, seed=7)
    resumed.load_state_dict(load_file(tmp_path / "w.safetensors"))
    resumed.load_optimizer_state(load_file(tmp_path / "o.safetensors"), json.loads((tmp_path / "o.json").read_text()))
    assert _train(uninterrupted, range(3, 5)) == _train(resumed, range(3, 5))
    for key, value in uninterrupted.state_dict().items():
        assert torch.equal(resumed.state_dict()[key], value), key
    with pytest.raises(KeyError, match="generator.state"):
        resumed.load_optimizer_state({k: v for k, v in tensors.items() if k != "generator.state"}, meta)


def test_ddpg_checkpoint_has_no_generator_or_normaliser() -> None:
    agent = _make("ddpg")
    tensors, _ = agent.optimizer_state()
    assert "generator.state" not in tensors
    assert not any(k.startswith("obs_norm.") for k in agent.state_dict())


# ------------------------------------------------------------------------ finite checks


@pytest.mark.parametrize("name", ["ddpg", "td3", "sac"])
def test_divergence_is_reported_with_the_update_index(name: str) -> None:
    agent = _make(name)
    agent.update(_batch(0))
    agent.check_finite()
    bad = _batch(1)
    bad["rew"][0] = np.inf
    with pytest.raises(DivergenceError, match="update 1: critic_loss"):
        agent.update(bad)
    agent = _make(name)
    with torch.no_grad():
        agent.critic.net[0].weight[0, 0] = float("nan")
    with pytest.raises(DivergenceError, match=r"critic\.net\.0\.weight"):
        agent.check_finite()


def test_the_old_name_of_the_divergence_error_still_works_and_warns() -> None:
    import triplesumo.algos.base as base

    with pytest.warns(DeprecationWarning, match="DivergedError is deprecated: use DivergenceError"):
        old = base.DivergedError
    assert old is DivergenceError


# --------------------------------------------------------------------------------- configs


@pytest.mark.parametrize("cls", [DDPGConfig, TD3Config, SACConfig, PPOConfig])
@pytest.mark.parametrize("value", [1e30, 1e300, 0.0, float("inf"), 1.5])
def test_learning_rates_are_bounded(cls: type, value: float) -> None:
    field = "lr" if cls is PPOConfig else "actor_lr"
    with pytest.raises(ValueError, match=f"{cls.__name__}.{field} "):
        cls(**{field: value})


@pytest.mark.parametrize(("cls", "field", "value"), [
    (TD3Config, "policy_delay", 0), (TD3Config, "policy_noise", -0.1), (TD3Config, "noise_clip", float("nan")),
    (TD3Config, "critic_lr", 2.0), (SACConfig, "alpha", 0.0), (SACConfig, "alpha_lr", 1e30),
    (SACConfig, "learn_alpha", 1), (SACConfig, "target_entropy", float("inf")), (SACConfig, "tau", 0.0),
    (PPOConfig, "gae_lambda", 1.5), (PPOConfig, "clip_coef", 0.0), (PPOConfig, "n_minibatches", 0),
    (PPOConfig, "target_kl", -1.0), (PPOConfig, "hidden", ()), (PPOConfig, "clip_value", "yes"),
    (PPOConfig, "max_grad_norm", 0.0),
])
def test_config_validation_names_the_field(cls: type, field: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"{cls.__name__}.{field} "):
        cls(**{field: value})


def test_defaults_and_json_round_trip() -> None:
    td3, sac, ppo = TD3Config(), SACConfig(), PPOConfig()
    assert (td3.policy_noise, td3.noise_clip, td3.policy_delay, td3.tau, td3.noise) == (0.2, 0.5, 2, 0.005, "gaussian")
    assert (sac.alpha, sac.learn_alpha, sac.target_entropy, sac.hidden) == (0.2, True, None, (256, 256))
    assert (ppo.clip_coef, ppo.gae_lambda, ppo.n_epochs, ppo.n_minibatches) == (0.2, 0.95, 10, 32)
    assert all(c.normalize_obs for c in (td3, sac, ppo)) and not DDPGConfig().normalize_obs
    for c in (td3, sac, ppo):
        assert type(c)(**json.loads(json.dumps(dataclasses.asdict(c)))) == c
    assert SAC(OBS_DIM, 3, SAC_CFG, seed=0).target_entropy == -3.0


# ---------------------------------------------------------------------- tiny learning checks
# A 1-D continuous bandit: observation s ~ U(-1, 1), reward -(a - s/2)², every step terminal.
# Each learner must bring its deterministic action within 0.1 of s/2 in a few seconds.


def _bandit_error(agent: Algorithm) -> float:
    s = np.linspace(-1, 1, 21, dtype=np.float32)[:, None]
    return float(np.abs(agent.act(s)[:, 0] - s[:, 0] / 2).mean())


@pytest.mark.parametrize("name", ["ddpg", "td3", "sac"])
def test_off_policy_learners_solve_a_bandit(name: str) -> None:
    common = {"hidden": (32, 32), "batch_size": 64, "learning_starts": 0, "buffer_size": 4096}
    config = {"ddpg": DDPGConfig(actor_lr=1e-3, **common), "td3": TD3Config(actor_lr=1e-3, critic_lr=1e-3, **common),
              "sac": SACConfig(actor_lr=1e-3, target_entropy=-4.0, n_step=1, **common)}[name]  # one-step bandit
    agent = {"ddpg": DDPG, "td3": TD3, "sac": SAC}[name](1, 1, config, seed=0)  # type: ignore[abstract]
    assert isinstance(agent, (DDPG, SAC))
    rng = np.random.default_rng(0)
    replay = ReplayBuffer(4096, 1, 1)
    s = rng.uniform(-1, 1, (4096, 1))
    a = rng.uniform(-1, 1, (4096, 1))
    replay.add_batch(s, a, -((a - s / 2) ** 2)[:, 0], s, np.ones(4096))
    agent.observe(s)
    before = _bandit_error(agent)
    for _ in range(600):
        agent.update(replay.sample(64, rng))
    assert before > 0.2 and _bandit_error(agent) < 0.1


@pytest.mark.slow  # 4 s alone on the shared 2-core box
def test_ppo_solves_a_bandit() -> None:
    agent = PPO(1, 1, PPOConfig(hidden=(32, 32), n_steps=8, n_minibatches=4, n_epochs=4, lr=3e-3,
                                log_std_init=-1.0), seed=0)
    rng = np.random.default_rng(0)
    before = _bandit_error(agent)
    s = rng.uniform(-1, 1, (32, 1))
    for _ in range(60):
        for _ in range(agent.config.n_steps):
            agent.observe(s)
            a = agent.explore(s, rng)
            agent.record(-((a - s / 2) ** 2)[:, 0], np.ones(32), np.zeros(32))
            s = rng.uniform(-1, 1, (32, 1))
        agent.update(s)
    assert before > 0.2 and _bandit_error(agent) < 0.1


def test_trainer_feeds_and_saves_the_normaliser(tmp_path: Path) -> None:
    from test_train import TINY_DDPG, tiny
    from triplesumo.train.loop import Trainer

    cfg = tiny(tmp_path, epochs=1, ddpg=dataclasses.replace(TINY_DDPG, normalize_obs=True))
    result = Trainer(cfg).run()
    policy, manifest = load_policy(result.run_dir / "policy")
    assert manifest["obs_norm"] and policy.obs_norm is not None
    assert float(policy.obs_norm.count) == result.env_steps  # every learner observation, once
    assert float(policy.obs_norm.var.min()) != 1.0  # the statistics moved


@pytest.mark.parametrize("algo", ["ddpg", "td3", "sac"])
def test_a_copy_of_the_actor_acts_with_the_weights_of_its_last_sync(algo: str) -> None:
    """The trainer's collection acts with a copy of the actor while the updates change the actor (in a thread):
    the copy keeps the weights of its last ``sync_acting`` and then acts bit for bit as the actor itself."""
    from triplesumo.algos.noise import make_noise

    cls, config = {"ddpg": (DDPG, CONFIG_DDPG), "td3": (TD3, TD3_CFG), "sac": (SAC, SAC_CFG)}[algo]
    apart, together = cls(OBS_DIM, ACT_DIM, config, seed=0), cls(OBS_DIM, ACT_DIM, config, seed=0)
    apart.act_apart()
    obs = np.random.default_rng(5).standard_normal((3, OBS_DIM)).astype(np.float32)

    def explore(agent: Any) -> np.ndarray:
        noise = None if algo == "sac" else make_noise("gaussian", (3, ACT_DIM), 0.1, 0.15)
        return agent.explore(obs, np.random.default_rng(1), noise)

    for agent in (apart, together):
        agent.observe(obs)  # (the normaliser is shared: the copy reads its statistics as they are)
    before = explore(apart)
    np.testing.assert_array_equal(before, explore(together))
    for agent in (apart, together):
        for k in range(2):  # (TD3 steps its actor on every second update)
            agent.update(_batch(k))
    np.testing.assert_array_equal(explore(apart), before)  # not synced: the weights before the updates
    assert not np.array_equal(explore(together), before)
    apart.sync_acting()
    np.testing.assert_array_equal(explore(apart), explore(together))
    state = together.state_dict()
    for k in range(2):
        together.update(_batch(10 + k))
    apart.load_state_dict(together.state_dict())  # a load changes the actor too: the next sync copies it
    apart.sync_acting()
    np.testing.assert_array_equal(explore(apart), explore(together))
    assert state.keys() == apart.state_dict().keys()  # the copy is no module of the checkpoint
