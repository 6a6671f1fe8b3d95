"""DDPG: target-network TD target, soft update, actor ascent, checkpoints, config validation."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import load_file, save_file

from triplesumo.agents.networks import Actor, ActorPolicy, Critic
from triplesumo.algos.ddpg import DDPG, DDPGConfig

torch.set_num_threads(1)

OBS_DIM, ACT_DIM, BATCH = 5, 2, 16
CONFIG = DDPGConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100)


def _batch(seed: int, n: int = BATCH, done: float | None = None) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "obs": rng.standard_normal((n, OBS_DIM)).astype(np.float32),
        "act": rng.uniform(-1, 1, (n, ACT_DIM)).astype(np.float32),
        "rew": rng.standard_normal(n).astype(np.float32),
        "next_obs": rng.standard_normal((n, OBS_DIM)).astype(np.float32),
        "done": (
            np.full(n, done, dtype=np.float32)
            if done is not None
            else (rng.random(n) < 0.3).astype(np.float32)
        ),
    }


def _perturb(module: torch.nn.Module, seed: int, size: float = 0.5) -> None:
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.add_(size * torch.randn(p.shape, generator=gen))


def _params(agent: DDPG) -> dict[str, torch.Tensor]:
    return agent.state_dict()


def _t(x: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(x)


# ------------------------------------------------------------------------------ networks


def test_networks_shapes_and_ranges() -> None:
    actor, critic = Actor(OBS_DIM, ACT_DIM, (8,)), Critic(OBS_DIM, ACT_DIM, (8, 4))
    _perturb(actor, 0, size=5.0)  # large weights: outputs must still be inside [-1, 1]
    obs = torch.randn(7, OBS_DIM)
    a = actor(obs)
    assert a.shape == (7, ACT_DIM) and a.abs().max() <= 1.0
    assert critic(obs, a).shape == (7,)
    policy = ActorPolicy(actor)
    one = policy(np.zeros(OBS_DIM, dtype=np.float64))
    many = policy(np.zeros((3, OBS_DIM)))
    assert one.shape == (ACT_DIM,) and one.dtype == np.float32
    assert many.shape == (3, ACT_DIM)
    # one row alone runs torch's matrix-vector kernel, a batch its matrix-matrix one: equal to float rounding
    # (bit-equal on most runs, not on all thread counts: it failed once under pytest -n 2 beside a training run)
    np.testing.assert_allclose(many[0], one, rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="obs"):
        policy(np.zeros(OBS_DIM + 1))
    with pytest.raises(ValueError, match="hidden"):
        Actor(OBS_DIM, ACT_DIM, ())


def test_actor_from_state_dict_infers_sizes() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=0)
    actor = Actor.from_state_dict(agent.state_dict())
    assert (actor.obs_dim, actor.act_dim, actor.hidden) == (OBS_DIM, ACT_DIM, (32, 16))
    obs = np.random.default_rng(0).standard_normal((4, OBS_DIM))
    np.testing.assert_array_equal(ActorPolicy(actor)(obs), agent.act(obs))


# ------------------------------------------------------------------------------ learning


def test_seeded_init_is_reproducible_and_leaves_global_rng() -> None:
    torch.manual_seed(123)
    expected = torch.rand(1)
    torch.manual_seed(123)
    a, b, c = (DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=s) for s in (1, 1, 2))
    assert torch.equal(torch.rand(1), expected)
    for key, value in a.state_dict().items():
        assert torch.equal(value, b.state_dict()[key])
    assert not torch.equal(
        a.state_dict()["actor.net.0.weight"], c.state_dict()["actor.net.0.weight"]
    )
    # Targets start as exact copies and never require gradients.
    for name, p in a.actor.named_parameters():
        assert torch.equal(p, a.actor_target.get_parameter(name))
    assert not any(p.requires_grad for p in a.critic_target.parameters())
    assert not any(p.requires_grad for p in a.actor_target.parameters())


def test_td_target_uses_target_networks() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=0)
    _perturb(agent.actor_target, 1)
    _perturb(agent.critic_target, 2)
    batch = _batch(0)
    y = agent.td_target(batch)

    with torch.no_grad():  # by hand, with the TARGET actor and TARGET critic
        s2 = _t(batch["next_obs"])
        q2 = agent.critic_target(s2, agent.actor_target(s2))
        expected = _t(batch["rew"]) + 0.99 * (1 - _t(batch["done"])) * q2
    torch.testing.assert_close(y, expected, rtol=0, atol=0)

    # Changing the online nets does not change y ...
    _perturb(agent.actor, 3)
    _perturb(agent.critic, 4)
    torch.testing.assert_close(agent.td_target(batch), y, rtol=0, atol=0)
    # ... changing either target net does.
    _perturb(agent.actor_target, 5)
    y_actor = agent.td_target(batch)
    assert not torch.allclose(y_actor, y)
    _perturb(agent.critic_target, 6)
    assert not torch.allclose(agent.td_target(batch), y_actor)


def test_critic_regresses_onto_td_target() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, dataclasses.replace(CONFIG, critic_lr=1e-2), seed=0)
    _perturb(agent.actor_target, 1)
    _perturb(agent.critic_target, 2)
    batch = _batch(1)
    with torch.no_grad():
        expected = F.mse_loss(
            agent.critic(_t(batch["obs"]), _t(batch["act"])), agent.td_target(batch)
        )
    info = agent.update(batch)
    assert info["critic_loss"] == pytest.approx(expected.item(), rel=1e-6)
    # Repeated critic steps on one batch shrink the loss towards the fixed target.
    target_before = agent.td_target(batch)
    losses = [agent.update_critic(batch)["critic_loss"] for _ in range(50)]
    assert losses[-1] < 0.5 * losses[0]
    torch.testing.assert_close(agent.td_target(batch), target_before, rtol=0, atol=0)


def test_done_removes_bootstrap() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=0)
    _perturb(agent.critic_target, 1)  # make Q' clearly non-zero
    terminal = _batch(2, done=1.0)
    ongoing = dict(terminal, done=np.zeros(BATCH, dtype=np.float32))
    torch.testing.assert_close(agent.td_target(terminal), _t(terminal["rew"]), rtol=0, atol=0)
    assert (agent.td_target(ongoing) - _t(ongoing["rew"])).abs().min() > 0
    # rew/done of shape (B, 1) are accepted too.
    column = dict(terminal, rew=terminal["rew"][:, None], done=terminal["done"][:, None])
    torch.testing.assert_close(agent.td_target(column), _t(terminal["rew"]), rtol=0, atol=0)


def test_soft_update_moves_targets_by_tau() -> None:
    config = dataclasses.replace(CONFIG, tau=0.25)
    agent = DDPG(OBS_DIM, ACT_DIM, config, seed=0)
    _perturb(agent.actor, 1)
    _perturb(agent.critic, 2)
    before = _params(agent)
    agent.soft_update_targets()
    after = _params(agent)
    for net in ("actor", "critic"):
        for key, online in before.items():
            if not key.startswith(f"{net}."):
                continue
            tkey = f"{net}_target.{key.removeprefix(net + '.')}"
            old = before[tkey]
            assert not torch.equal(old, online)
            torch.testing.assert_close(
                after[tkey], old + 0.25 * (online - old), rtol=1e-6, atol=1e-7
            )
            assert torch.equal(after[key], online)  # online nets untouched


def test_actor_step_raises_q_with_critic_fixed() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, dataclasses.replace(CONFIG, actor_lr=1e-3), seed=0)
    _perturb(agent.critic, 1)  # a critic with a non-trivial landscape
    batch = _batch(3, n=64)
    obs = _t(batch["obs"])

    def q_of_policy() -> float:
        with torch.no_grad():
            return agent.critic(obs, agent.actor(obs)).mean().item()

    critic_before = {k: v for k, v in _params(agent).items() if k.startswith("critic")}
    actor_before = _params(agent)["actor.net.0.weight"]
    q0 = q_of_policy()
    info = agent.update_actor(batch)
    assert info["actor_loss"] == pytest.approx(-q0, rel=1e-6)
    assert q_of_policy() > q0
    assert not torch.equal(_params(agent)["actor.net.0.weight"], actor_before)
    for key, value in critic_before.items():
        assert torch.equal(_params(agent)[key], value), key
    assert all(p.requires_grad for p in agent.critic.parameters())


def test_update_losses_finite_and_targets_move() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=0)
    before = _params(agent)
    for i in range(5):
        info = agent.update(_batch(i))
        assert set(info) == {"critic_loss", "actor_loss", "q_mean"}
        assert all(np.isfinite(v) for v in info.values())
    assert agent.num_updates == 5
    after = _params(agent)
    assert not torch.equal(
        after["critic_target.net.0.weight"], before["critic_target.net.0.weight"]
    )
    assert not torch.equal(after["actor_target.net.0.weight"], before["actor_target.net.0.weight"])


def test_updates_due_learns_one_step_in_k() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, DDPGConfig(hidden=(8,), learn_every=30, learning_starts=60), seed=0)
    steps = [n for n in range(1, 301) if agent.updates_due(n - 1, n, stored=10**6)]
    assert steps == list(range(60, 301, 30))  # not 29 of every 30 (the original code's bug)
    # Batched collection: n transitions at once cross several strides; G steps per stride.
    agent4 = DDPG(OBS_DIM, ACT_DIM, DDPGConfig(hidden=(8,), learn_every=2, gradient_steps=3,
                                               learning_starts=0), seed=0)
    assert agent4.updates_due(10, 17, stored=64) == 3 * 3  # strides at 12, 14, 16
    assert agent4.updates_due(10, 17, stored=63) == 0  # replay smaller than a batch


# ---------------------------------------------------------------------------- checkpoints


def test_state_dict_round_trip_gives_identical_actions(tmp_path) -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=0)
    for i in range(3):
        agent.update(_batch(i))
    path = tmp_path / "weights.safetensors"
    save_file(agent.state_dict(), path)
    restored = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=99)
    obs = np.random.default_rng(0).standard_normal((8, OBS_DIM))
    assert not np.array_equal(restored.act(obs), agent.act(obs))
    restored.load_state_dict(load_file(path))
    np.testing.assert_array_equal(restored.act(obs), agent.act(obs))
    torch.testing.assert_close(
        restored.td_target(_batch(5)), agent.td_target(_batch(5)), rtol=0, atol=0
    )


def test_load_state_dict_errors_name_the_key() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=0)
    state = agent.state_dict()
    missing = dict(state)
    del missing["critic_target.net.2.bias"]
    with pytest.raises(KeyError, match="critic_target.net.2.bias"):
        agent.load_state_dict(missing)
    with pytest.raises(KeyError, match="actor.extra"):
        agent.load_state_dict(state | {"actor.extra": torch.zeros(1)})
    other = DDPG(OBS_DIM + 1, ACT_DIM, CONFIG, seed=0).state_dict()
    with pytest.raises(ValueError, match="net.0.weight"):
        agent.load_state_dict(other)


def test_optimizer_resume_is_bit_for_bit(tmp_path) -> None:
    uninterrupted = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=0)
    for i in range(3):
        uninterrupted.update(_batch(i))
    # Checkpoint as safetensors + JSON, through files, no pickle.
    opt_tensors, meta = uninterrupted.optimizer_state()
    save_file(uninterrupted.state_dict(), tmp_path / "weights.safetensors")
    save_file(opt_tensors, tmp_path / "optim.safetensors")
    (tmp_path / "optim.json").write_text(json.dumps(meta))

    resumed = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=7)
    resumed.load_state_dict(load_file(tmp_path / "weights.safetensors"))
    resumed.load_optimizer_state(
        load_file(tmp_path / "optim.safetensors"), json.loads((tmp_path / "optim.json").read_text())
    )
    assert resumed.num_updates == 3
    for i in (3, 4):
        info_a = uninterrupted.update(_batch(i))
        info_b = resumed.update(_batch(i))
        assert info_a == info_b
    for key, value in uninterrupted.state_dict().items():
        assert torch.equal(resumed.state_dict()[key], value), key

    # Without the optimiser state (fresh Adam moments) the next update differs.
    fresh = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=7)
    fresh.load_state_dict(load_file(tmp_path / "weights.safetensors"))
    fresh.update(_batch(3))
    again = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=7)
    again.load_state_dict(load_file(tmp_path / "weights.safetensors"))
    again.load_optimizer_state(load_file(tmp_path / "optim.safetensors"), meta)
    again.update(_batch(3))
    assert not torch.equal(
        fresh.state_dict()["actor.net.0.weight"], again.state_dict()["actor.net.0.weight"]
    )


def test_load_optimizer_state_errors() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, CONFIG, seed=0)
    agent.update(_batch(0))
    tensors, meta = agent.optimizer_state()
    with pytest.raises(KeyError, match="critic_optimizer"):
        agent.load_optimizer_state(
            tensors, {k: v for k, v in meta.items() if k != "critic_optimizer"}
        )
    bad = dict(tensors)
    bad["actor_optimizer.state.0.exp_avg"] = torch.zeros(3)
    with pytest.raises(ValueError, match="actor_optimizer.state.0.exp_avg"):
        agent.load_optimizer_state(bad, meta)
    with pytest.raises(KeyError, match="bogus"):
        agent.load_optimizer_state(tensors | {"bogus.x": torch.zeros(1)}, meta)


# --------------------------------------------------------------------------------- config


def test_config_defaults_are_the_papers() -> None:
    c = DDPGConfig()
    assert (c.actor_lr, c.critic_lr, c.gamma, c.tau) == (1e-4, 1e-3, 0.99, 0.01)
    assert (c.batch_size, c.buffer_size, c.learn_every, c.hidden) == (64, 1_000_000, 30, (512, 256))
    assert (c.noise, c.noise_sigma, c.noise_theta) == ("ou", 0.2, 0.15)
    # JSON round trip (hidden comes back as a list) gives an equal config.
    assert DDPGConfig(**json.loads(json.dumps(dataclasses.asdict(c)))) == c


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("actor_lr", 0.0),
        ("critic_lr", -1e-3),
        ("gamma", 0.0),
        ("gamma", 1.5),
        ("tau", 0.0),
        ("tau", 1.01),
        ("batch_size", 0),
        ("buffer_size", 2.5),
        ("learn_every", 0),
        ("gradient_steps", 0),
        ("learning_starts", -1),
        ("hidden", ()),
        ("hidden", (64, 0)),
        ("noise", "brownian"),
        ("noise_sigma", -0.1),
        ("noise_theta", 0.0),
        ("weight_decay", -1.0),
        ("actor_lr", float("nan")),
        ("batch_size", True),
    ],
)
def test_config_validation_names_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        DDPGConfig(**{field: value})
