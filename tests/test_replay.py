"""ReplayBuffer: circular storage, vectorised adds across the wrap, seeded sampling, save/load."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from triplesumo.algos.replay import FIELDS, ReplayBuffer

torch.set_num_threads(1)

OBS_DIM, ACT_DIM = 3, 2


def _transition(i: int) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, float]:
    """Transition number ``i``: every field encodes ``i`` so rows can be identified."""
    obs = np.full(OBS_DIM, i, dtype=np.float32)
    act = np.full(ACT_DIM, -i, dtype=np.float32)
    return obs, act, float(i), obs + 0.5, float(i % 2)


def _batch(ids: range) -> tuple[np.ndarray, ...]:
    cols = list(zip(*(_transition(i) for i in ids), strict=True))
    return tuple(np.asarray(c, dtype=np.float32) for c in cols)


def test_len_saturates_and_wraparound_overwrites_oldest() -> None:
    buf = ReplayBuffer(4, OBS_DIM, ACT_DIM)
    assert len(buf) == 0 and buf.capacity == 4
    for i in range(6):
        buf.add(*_transition(i))
        assert len(buf) == min(i + 1, 4)
    # 0 and 1 were overwritten by 4 and 5, in their slots.
    np.testing.assert_array_equal(buf.rew, [4, 5, 2, 3])
    np.testing.assert_array_equal(buf.obs[:, 0], [4, 5, 2, 3])
    np.testing.assert_array_equal(buf.next_obs[:, 0], [4.5, 5.5, 2.5, 3.5])
    np.testing.assert_array_equal(buf.act[:, 0], [-4, -5, -2, -3])
    np.testing.assert_array_equal(buf.done, [0, 1, 0, 1])
    assert buf.pos == 2


@pytest.mark.parametrize("chunks", [(3, 4), (2, 2, 3), (7,), (1, 9), (12,)])
def test_add_batch_matches_sequential_adds_across_wrap(chunks: tuple[int, ...]) -> None:
    seq = ReplayBuffer(5, OBS_DIM, ACT_DIM)
    vec = ReplayBuffer(5, OBS_DIM, ACT_DIM)
    start = 0
    for n in chunks:
        ids = range(start, start + n)
        for i in ids:
            seq.add(*_transition(i))
        vec.add_batch(*_batch(ids))
        start += n
    assert len(vec) == len(seq) and vec.pos == seq.pos
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(vec, name), getattr(seq, name), err_msg=name)
    # The newest transitions are the ones kept.
    assert sorted(vec.rew[: len(vec)].tolist()) == list(range(start - len(vec), start))


def test_add_batch_rejects_bad_shapes() -> None:
    buf = ReplayBuffer(5, OBS_DIM, ACT_DIM)
    obs, act, rew, next_obs, done = _batch(range(3))
    with pytest.raises(ValueError, match="act"):
        buf.add_batch(obs, act[:, :1], rew, next_obs, done)
    with pytest.raises(ValueError, match="done"):
        buf.add_batch(obs, act, rew, next_obs, done[:2])
    assert len(buf) == 0


def test_sample_only_from_filled_part_and_seeded() -> None:
    buf = ReplayBuffer(100, OBS_DIM, ACT_DIM)
    buf.add_batch(*_batch(range(1, 8)))  # rewards 1..7; unfilled slots hold reward 0
    batch = buf.sample(500, np.random.default_rng(0))
    assert set(batch) == set(FIELDS)
    assert batch["obs"].shape == (500, OBS_DIM) and batch["act"].shape == (500, ACT_DIM)
    assert batch["rew"].shape == (500,) and batch["done"].shape == (500,)
    assert set(batch["rew"].tolist()) == set(range(1, 8))  # uniform over all 7, never a 0
    np.testing.assert_array_equal(batch["obs"][:, 0], batch["rew"])  # rows stay aligned
    again = buf.sample(500, np.random.default_rng(0))
    other = buf.sample(500, np.random.default_rng(1))
    for name in FIELDS:
        np.testing.assert_array_equal(batch[name], again[name])
    assert not np.array_equal(batch["rew"], other["rew"])
    batch["rew"][:] = -1  # a sample is a copy
    assert buf.rew.min() == 0


def test_sample_empty_raises() -> None:
    with pytest.raises(ValueError, match="empty"):
        ReplayBuffer(4, OBS_DIM, ACT_DIM).sample(2, np.random.default_rng(0))


@pytest.mark.parametrize("n", [3, 9])  # partly filled, and full after wrapping
def test_state_dict_round_trip_through_npz(tmp_path, n: int) -> None:
    buf = ReplayBuffer(5, OBS_DIM, ACT_DIM)
    buf.add_batch(*_batch(range(n)))
    path = tmp_path / "replay.npz"
    np.savez(path, **buf.state_dict())
    restored = ReplayBuffer(5, OBS_DIM, ACT_DIM)
    with np.load(path, allow_pickle=False) as data:
        restored.load_state_dict(data)
    assert len(restored) == len(buf) and restored.pos == buf.pos
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(restored, name), getattr(buf, name))
    # Resumed exactly: same samples, and the next add overwrites the same slot.
    for b in (buf, restored):
        b.add(*_transition(100))
    a = buf.sample(16, np.random.default_rng(3))
    b = restored.sample(16, np.random.default_rng(3))
    for name in FIELDS:
        np.testing.assert_array_equal(a[name], b[name])


def test_load_state_dict_validates() -> None:
    buf = ReplayBuffer(5, OBS_DIM, ACT_DIM)
    buf.add_batch(*_batch(range(3)))
    state = buf.state_dict()
    with pytest.raises(ValueError, match="capacity"):
        ReplayBuffer(6, OBS_DIM, ACT_DIM).load_state_dict(state)
    with pytest.raises(ValueError, match="obs"):
        ReplayBuffer(5, OBS_DIM + 1, ACT_DIM).load_state_dict(state)
    with pytest.raises(KeyError, match="done"):
        buf.load_state_dict({k: v for k, v in state.items() if k != "done"})
