"""The off-policy learners' ``update_dtype`` (issue 53, item 2): bfloat16 matrix products in the updates.

Under ``update_dtype="bfloat16"`` each gradient update runs under ``torch.autocast``: the hidden layers' products
in bfloat16, every output layer (:class:`~triplesumo.agents.networks.FloatHead`), the losses, the weights and
Adam's state in float32. Acting and exported policies are float32 either way.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file
from torch import nn

from test_ddpg import ACT_DIM, BATCH, OBS_DIM, _batch, _perturb, _t  # the same random batches
from test_sac_options import TINY, resumed_equals_uninterrupted
from triplesumo.agents.networks import FloatHead
from triplesumo.algos.ddpg import DDPG, DDPGConfig
from triplesumo.algos.sac import SAC, SACConfig
from triplesumo.algos.td3 import TD3, TD3Config

torch.set_num_threads(1)

LEARNERS = {
    "ddpg": (DDPG, DDPGConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100)),
    "td3": (TD3, TD3Config(hidden=(32, 16), batch_size=BATCH, buffer_size=100, policy_delay=1)),
    "sac": (SAC, SACConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100, n_step=1)),
}


def _make(name: str, dtype: str, seed: int = 0):  # type: ignore[no-untyped-def]
    cls, cfg = LEARNERS[name]
    agent = cls(OBS_DIM, ACT_DIM, dataclasses.replace(cfg, update_dtype=dtype), seed=seed)
    for module in agent.modules:  # away from the near-zero output initialisation, the same for both dtypes
        if module != "obs_norm":
            _perturb(getattr(agent, module), 11)
    return agent


def _output_dtypes(agent, batch) -> dict[str, set[torch.dtype]]:  # type: ignore[no-untyped-def]
    """The dtypes every hidden ``nn.Linear`` and every :class:`FloatHead` returned during one update."""
    seen: dict[str, set[torch.dtype]] = {"hidden": set(), "head": set()}
    hooks = []
    for name in agent.modules:
        for layer in getattr(agent, name).modules():
            if isinstance(layer, nn.Linear):
                kind = "head" if isinstance(layer, FloatHead) else "hidden"
                hooks.append(layer.register_forward_hook(
                    lambda _m, _i, out, kind=kind: seen[kind].add(out.dtype)))
    try:
        agent.update(batch)
    finally:
        for hook in hooks:
            hook.remove()
    return seen


def test_a_float_head_is_a_linear_layer_outside_autocast_and_float32_inside() -> None:
    torch.manual_seed(0)
    head, plain = FloatHead(8, 3), nn.Linear(8, 3)
    plain.load_state_dict(head.state_dict())
    x = torch.randn(5, 8)
    assert torch.equal(head(x), plain(x))  # bit for bit nn.Linear
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert plain(x).dtype == torch.bfloat16
        out = head(x.bfloat16())
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, plain(x.bfloat16().float()))  # the product of the bf16 input, in float32


@pytest.mark.parametrize("name", sorted(LEARNERS))
def test_bfloat16_updates_multiply_in_bfloat16_and_keep_heads_weights_and_adam_in_float32(name: str) -> None:
    agent = _make(name, "bfloat16")
    seen = _output_dtypes(agent, _batch(1))
    assert seen == {"hidden": {torch.bfloat16}, "head": {torch.float32}}
    full = _make(name, "float32").state_dict()
    assert {k: v.dtype for k, v in agent.state_dict().items()} == {k: v.dtype for k, v in full.items()}
    assert agent.state_dict()["critic.net.0.weight"].dtype == torch.float32
    tensors, _ = agent.optimizer_state()
    assert tensors and all(t.dtype == torch.float32 for t in tensors.values() if t.is_floating_point())
    # float32 updates never enter bfloat16
    assert _output_dtypes(_make(name, "float32"), _batch(1)) == {"hidden": {torch.float32}, "head": {torch.float32}}
    # acting is float32 whatever the updates ran in
    assert agent.act(_batch(2)["obs"]).dtype.name == "float32"
    with torch.no_grad():
        assert agent.actor(_t(_batch(2)["obs"])).dtype == torch.float32


@pytest.mark.parametrize("name", sorted(LEARNERS))
def test_a_bfloat16_update_is_the_float32_update_rounded(name: str) -> None:
    """From the same weights on the same batch, one bfloat16 update moves every weight as the float32 one does up
    to bfloat16's rounding (8 bits of mantissa, about 0.4%), and not bit for bit."""
    full, half = _make(name, "float32"), _make(name, "bfloat16")
    before = {k: v.clone() for k, v in full.state_dict().items()}
    assert all(torch.equal(before[k], v) for k, v in half.state_dict().items())
    stats_full, stats_half = full.update(_batch(1)), half.update(_batch(1))
    assert stats_full.keys() == stats_half.keys()
    for key in ("critic_loss", "q_mean"):
        assert stats_half[key] == pytest.approx(stats_full[key], rel=0.05, abs=1e-3), key
    moved_full = torch.cat([(full.state_dict()[k] - before[k]).flatten() for k in before])
    moved_half = torch.cat([(half.state_dict()[k] - before[k]).flatten() for k in before])
    assert not torch.equal(moved_full, moved_half)
    cosine = torch.nn.functional.cosine_similarity(moved_full, moved_half, dim=0)
    assert cosine > 0.95, f"the bfloat16 step points elsewhere (cosine {cosine:.3f})"


def test_a_bfloat16_critic_fits_a_fixed_target_as_the_float32_one_does() -> None:
    """2,000 critic steps onto the same TD target, Q on this game's scale (about -300 in trained runs): both dtypes
    bring the loss down by orders of magnitude (bfloat16 Q-values would stall at their rounding: the heads are
    float32; and a cast cached across steps would freeze the hidden layers)."""
    losses = {}
    for dtype in ("float32", "bfloat16"):
        agent = _make("ddpg", dtype)
        b = agent.batch(_batch(3))
        y = 300.0 + 10.0 * torch.randn(BATCH, generator=torch.Generator().manual_seed(0))  # Q on this game's scale
        curve = []
        for _ in range(2000):
            with agent.update_precision():
                curve.append(agent.regress_critics(agent.critics, agent.critic_optimizer, b, y)["critic_loss"])
        losses[dtype] = (curve[0], curve[-1])
    for dtype, (first, last) in losses.items():
        assert last < 1e-3 * first, (dtype, first, last)
    assert losses["bfloat16"][1] < 10 * losses["float32"][1] + 1.0


def test_a_step_inside_one_update_sees_the_weights_an_earlier_step_moved() -> None:
    """Autocast's cache of cast weights is off: SAC's actor step, in the same update as the critic step, must read
    the critics after their step (a cached bfloat16 copy would be the critics from before it)."""
    agent = _make("sac", "bfloat16")
    obs, act = agent.batch(_batch(4))["obs"], _t(_batch(4)["act"])
    with agent.update_precision():
        before = agent.critic(obs, act)
        with torch.no_grad():
            agent.critic.net[0].weight.add_(0.5)  # as an optimiser step would, in place
        after = agent.critic(obs, act)
    assert not torch.allclose(before, after)


def test_update_dtype_is_validated_and_tunable() -> None:
    with pytest.raises(ValueError, match="SACConfig.update_dtype must be one of float32, bfloat16, got 'float16'"):
        SACConfig(update_dtype="float16")
    with pytest.raises(ValueError, match="DDPGConfig.update_dtype must be one of"):
        DDPGConfig(update_dtype="bf16")
    assert SACConfig().update_dtype == DDPGConfig().update_dtype == TD3Config().update_dtype == "float32"
    assert "update_dtype" in SACConfig.TUNABLE  # a fork may switch it: no tensor depends on it
    cfg = SACConfig(update_dtype="bfloat16")
    assert SACConfig(**json.loads(json.dumps(dataclasses.asdict(cfg)))) == cfg


def test_a_bfloat16_training_run_resumed_equals_the_uninterrupted_one(tmp_path: Path) -> None:
    run_dir = resumed_equals_uninterrupted(tmp_path, dataclasses.replace(TINY, critic_norm="none",
                                                                         update_dtype="bfloat16"))
    assert json.loads((run_dir / "config.json").read_text())["sac"]["update_dtype"] == "bfloat16"
    weights = load_file(str(run_dir / "policy.safetensors"))
    layers = {k: t.dtype for k, t in weights.items() if not k.startswith("obs_norm.")}
    assert layers and set(layers.values()) == {torch.float32}  # the policy file is float32 whatever trained it


def test_a_config_json_written_before_update_dtype_reads_back_as_float32() -> None:
    """Run folders from before ``update_dtype`` trained in float32 and resume so; an unknown key is still refused."""
    from triplesumo.train.config import TrainConfig
    from triplesumo.train.run_folder import config_from_json

    data = json.loads(json.dumps(dataclasses.asdict(TrainConfig(learn=("bug=sac",)))))
    for algo in ("ddpg", "td3", "sac"):
        del data[algo]["update_dtype"]
    cfg = config_from_json(data)
    assert (cfg.ddpg.update_dtype, cfg.td3.update_dtype, cfg.sac.update_dtype) == ("float32",) * 3
    data["sac"]["update_dtpye"] = "bfloat16"
    with pytest.raises(ValueError, match="update_dtpye"):
        config_from_json(data, "old/config.json")
