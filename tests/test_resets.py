"""Resets (``reset_every``, DDPG, TD3 and SAC; issue 53's "more updates per transition, with resets"): every
``reset_every`` updates the learner's networks, targets and optimisers are those a learner of the same config builds
under the reset's own seed; the normaliser and the update count are kept; resume equals uninterrupted."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from test_ddpg import ACT_DIM, BATCH, OBS_DIM
from test_sac_options import learn, reloaded, resumed_equals_uninterrupted
from triplesumo.algos.ddpg import DDPG, DDPGConfig
from triplesumo.algos.sac import SAC, SACConfig
from triplesumo.algos.td3 import TD3, TD3Config
from triplesumo.train.config import TrainConfig
from triplesumo.train.run_folder import config_from_json

torch.set_num_threads(1)

LEARNERS: dict[str, tuple[Any, Any]] = {
    "ddpg": (DDPG, DDPGConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100, reset_every=3)),
    "td3": (TD3, TD3Config(hidden=(32, 16), batch_size=BATCH, buffer_size=100, reset_every=3)),
    "sac": (SAC, SACConfig(hidden=(32, 16), batch_size=BATCH, buffer_size=100, n_step=1, reset_every=3)),
}


def _networks(agent: Any) -> dict[str, torch.Tensor]:
    return {k: v for k, v in agent.state_dict().items() if not k.startswith("obs_norm.")}


def _reset_seed(seed: int, index: int) -> int:
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


@pytest.mark.parametrize("algo", sorted(LEARNERS))
def test_a_reset_rebuilds_every_network_and_optimiser_in_place(algo: str) -> None:
    cls, config = LEARNERS[algo]
    agent = cls(OBS_DIM, ACT_DIM, config, seed=0)
    actor, policy_actor = agent.actor, agent.policy.actor
    learn(agent, range(2))
    first = cls(OBS_DIM, ACT_DIM, config, seed=_reset_seed(0, 1))
    assert any(not torch.equal(v, _networks(first)[k]) for k, v in _networks(agent).items())  # not yet
    assert any(getattr(agent, name).state_dict()["state"] for name in agent.optimizers)
    norm = agent.obs_norm.state_dict() if agent.obs_norm is not None else {}
    learn(agent, range(2, 3))  # update 3: then the reset
    assert agent.num_updates == 3
    built = _networks(first)
    assert _networks(agent).keys() == built.keys()
    for key, value in _networks(agent).items():  # every network and target, the temperature too
        assert torch.equal(value, built[key]), key
    assert all(not getattr(agent, name).state_dict()["state"] for name in agent.optimizers)  # Adam starts again
    for key, value in norm.items():  # the normaliser keeps what it has seen
        assert torch.equal(agent.obs_norm.state_dict()[key], value), key
    assert agent.actor is actor and agent.policy.actor is policy_actor  # in place: the policy follows
    # the next update learns from the fresh networks, as the fresh learner's own first update does
    stats = learn(agent, range(3, 4))[0]
    assert all(np.isfinite(v) for v in stats.values())
    learn(agent, range(4, 6))  # update 6: the second reset draws another seed than the first
    second = _networks(cls(OBS_DIM, ACT_DIM, config, seed=_reset_seed(0, 2)))
    for key, value in _networks(agent).items():
        assert torch.equal(value, second[key]), key
    assert any(not torch.equal(second[k], built[k]) for k in built)


def test_no_reset_by_default_and_the_field_is_validated() -> None:
    assert SACConfig().reset_every == DDPGConfig().reset_every == TD3Config().reset_every == 0
    _, config = LEARNERS["sac"]
    plain = dataclasses.replace(config, reset_every=0)
    agent, again = SAC(OBS_DIM, ACT_DIM, plain, seed=0), SAC(OBS_DIM, ACT_DIM, config, seed=0)
    learn(agent, range(6))
    learn(again, range(6))
    assert any(not torch.equal(v, _networks(again)[k]) for k, v in _networks(agent).items())
    with pytest.raises(ValueError, match="SACConfig.reset_every must be >= 0"):
        SACConfig(reset_every=-1)
    with pytest.raises(ValueError, match="TD3Config.reset_every"):
        TD3Config(reset_every=1.5)  # type: ignore[arg-type]


@pytest.mark.parametrize("algo", sorted(LEARNERS))
def test_a_learner_checkpointed_just_after_a_reset_resumes_bit_for_bit(tmp_path: Path, algo: str) -> None:
    """The checkpoint falls right after a reset (Adam's moments empty): the resumed learner resets again where the
    uninterrupted one does (at update 6) and ends with the same weights."""
    cls, config = LEARNERS[algo]
    uninterrupted = cls(OBS_DIM, ACT_DIM, config, seed=0)
    learn(uninterrupted, range(3))
    resumed = reloaded(uninterrupted, cls(OBS_DIM, ACT_DIM, config, seed=7), tmp_path)
    assert learn(uninterrupted, range(3, 8)) == learn(resumed, range(3, 8))
    for key, value in uninterrupted.state_dict().items():
        assert torch.equal(resumed.state_dict()[key], value), key


def test_a_training_run_with_resets_resumed_equals_the_uninterrupted_one(tmp_path: Path) -> None:
    """A tiny SAC run (about 40 updates by its checkpoint, 100 by its end) resetting every 25 updates: resets before
    and after the checkpoint, and the same policy bit for bit."""
    tiny = SACConfig(hidden=(16, 16), buffer_size=2000, learning_starts=40, batch_size=16, learn_every=2,
                     reset_every=25)
    run_dir = resumed_equals_uninterrupted(tmp_path, tiny)
    assert json.loads((run_dir / "config.json").read_text())["sac"]["reset_every"] == 25


def test_a_config_json_written_before_resets_reads_back_without_them() -> None:
    data = json.loads(json.dumps(dataclasses.asdict(TrainConfig(learn=("bug=sac", "ant=ddpg", "spider=td3")))))
    for algo in ("sac", "ddpg", "td3"):
        del data[algo]["reset_every"]
    cfg = config_from_json(data)
    assert (cfg.sac.reset_every, cfg.ddpg.reset_every, cfg.td3.reset_every) == (0, 0, 0)
