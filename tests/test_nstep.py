"""n-step returns (issue 53): the windows against a per-row reference, the ends of a match, the TD target's γ^m,
the replay's discount field, and a training run resumed equals the uninterrupted one."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from test_ddpg import ACT_DIM, OBS_DIM, _batch
from test_sac_options import resumed_equals_uninterrupted
from triplesumo.algos.ddpg import DDPG, DDPGConfig
from triplesumo.algos.nstep import NStepReturns
from triplesumo.algos.replay import ReplayBuffer
from triplesumo.algos.sac import SACConfig
from triplesumo.train.config import TrainConfig

torch.set_num_threads(1)
G = 0.9


def _step(rows: int, t: int, rew: list[float] | None = None, terminated: tuple[int, ...] = (),
          truncated: tuple[int, ...] = (), broken: tuple[int, ...] = (), out: tuple[int, ...] = ()) -> dict:
    """Step ``t`` of ``rows`` rows: observation ``[t, row]`` (next ``[t + 1, row]``), action ``[row, t]``."""
    obs = np.array([[t, r] for r in range(rows)], np.float32)
    return {"obs": obs, "act": obs[:, ::-1].copy(), "rew": np.asarray(rew if rew is not None else [1.0] * rows),
            "next_obs": obs + np.array([1.0, 0.0], np.float32),
            "terminated": np.isin(np.arange(rows), terminated), "truncated": np.isin(np.arange(rows), truncated),
            "valid": ~np.isin(np.arange(rows), broken), "played": ~np.isin(np.arange(rows), out)}


def _transitions(out: dict[str, np.ndarray]) -> list[tuple]:
    return [(tuple(out["obs"][i]), round(float(out["rew"][i]), 5), tuple(out["next_obs"][i]), float(out["done"][i]),
             round(float(out["discount"][i]), 5)) for i in range(len(out["rew"]))]


def test_a_window_of_three_fills_moves_on_and_flushes_at_a_win() -> None:
    q = NStepReturns(3, G, 1, 2, 2)
    seen = [_transitions(q.push(**_step(1, t, [t + 1.0]))) for t in range(4)]
    assert seen[:2] == [[], []]  # nothing is complete before three steps
    assert seen[2] == [((0, 0), round(1 + G * 2 + G * G * 3, 5), (3, 0), 0.0, round(G ** 3, 5))]
    assert seen[3] == [((1, 0), round(2 + G * 3 + G * G * 4, 5), (4, 0), 0.0, round(G ** 3, 5))]
    assert len(q) == 2
    end = _transitions(q.push(**_step(1, 4, [5.0], terminated=(0,))))  # a win: every pending one, no bootstrap
    assert end == [((2, 0), round(3 + G * 4 + G * G * 5, 5), (5, 0), 1.0, round(G ** 3, 5)),
                   ((3, 0), round(4 + G * 5, 5), (5, 0), 1.0, round(G ** 2, 5)),
                   ((4, 0), 5.0, (5, 0), 1.0, round(G, 5))]
    assert len(q) == 0


def test_a_draw_bootstraps_each_pending_transition_with_its_own_discount() -> None:
    q = NStepReturns(4, G, 1, 2, 2)
    for t in range(2):
        assert not _transitions(q.push(**_step(1, t, [1.0])))
    end = _transitions(q.push(**_step(1, 2, [1.0], truncated=(0,))))
    assert [(o, d, disc) for o, _, _, d, disc in end] == [
        ((0, 0), 0.0, round(G ** 3, 5)), ((1, 0), 0.0, round(G ** 2, 5)), ((2, 0), 0.0, round(G, 5))]
    assert [n for _, _, n, _, _ in end] == [(3, 0)] * 3  # all bootstrap from the last observation


def test_a_physics_error_is_never_stored_and_the_pending_ones_bootstrap_from_before_it() -> None:
    q = NStepReturns(3, G, 1, 2, 2)
    q.push(**_step(1, 0, [1.0]))
    q.push(**_step(1, 1, [2.0]))
    out = _transitions(q.push(**_step(1, 2, [100.0], broken=(0,))))
    assert out == [((0, 0), round(1 + G * 2, 5), (2, 0), 0.0, round(G ** 2, 5)),
                   ((1, 0), 2.0, (2, 0), 0.0, round(G, 5))]
    assert len(q) == 0


def _reference(n: int, steps: list[dict]) -> list[list[tuple]]:
    """One row at a time, with Python lists: what each step completes (row by row, oldest first)."""
    rows = len(steps[0]["rew"])
    pending: list[list[tuple]] = [[] for _ in range(rows)]
    done_at: list[list[tuple]] = []
    for s in steps:
        now = []
        for r in range(rows):
            if not s["played"][r]:
                continue
            if not s["valid"][r]:
                now += [(o, ret, tuple(s["obs"][r]), 0.0, G ** m) for o, ret, m in pending[r]]
                pending[r] = []
                continue
            pending[r] = [(o, ret + G ** m * s["rew"][r], m + 1) for o, ret, m in pending[r]]
            pending[r].append((tuple(s["obs"][r]), float(s["rew"][r]), 1))
            nxt = tuple(s["next_obs"][r])
            if s["terminated"][r] or s["truncated"][r]:
                now += [(o, ret, nxt, float(s["terminated"][r]), G ** m) for o, ret, m in pending[r]]
                pending[r] = []
            elif len(pending[r]) == n:
                o, ret, m = pending[r].pop(0)
                now.append((o, ret, nxt, 0.0, G ** m))
        done_at.append([(o, round(ret, 4), nxt, d, round(disc, 4)) for o, ret, nxt, d, disc in now])
    return done_at


def _rounded(out: dict[str, np.ndarray]) -> list[tuple]:
    return [(tuple(out["obs"][i]), round(float(out["rew"][i]), 4), tuple(out["next_obs"][i]), float(out["done"][i]),
             round(float(out["discount"][i]), 4)) for i in range(len(out["rew"]))]


@pytest.mark.parametrize("n", [1, 2, 5])
def test_random_matches_of_many_rows_agree_with_the_per_row_reference(n: int) -> None:
    rng = np.random.default_rng(n)
    rows, steps = 5, []
    for t in range(60):
        kind = rng.choice(["plain", "terminated", "truncated", "broken", "out"], size=rows, p=[.7, .1, .08, .04, .08])
        s = _step(rows, t, list(rng.normal(size=rows)), tuple(np.flatnonzero(kind == "terminated")),
                  tuple(np.flatnonzero(kind == "truncated")), tuple(np.flatnonzero(kind == "broken")),
                  tuple(np.flatnonzero(kind == "out")))
        steps.append(s)
    q = NStepReturns(n, G, rows, 2, 2)
    got = [_rounded(q.push(**s)) for s in steps]
    assert got == _reference(n, steps)
    assert sum(map(len, got)) > 100  # the matches did store transitions


def test_the_windows_resume_from_their_state_as_if_never_stopped() -> None:
    rng = np.random.default_rng(0)
    steps = [_step(3, t, list(rng.normal(size=3)), terminated=(t % 7 == 6) * (1,)) for t in range(30)]
    whole = NStepReturns(4, G, 3, 2, 2)
    first = [_rounded(whole.push(**s)) for s in steps]
    half = NStepReturns(4, G, 3, 2, 2)
    for s in steps[:13]:
        half.push(**s)
    state = json.loads(json.dumps({k: v.tolist() for k, v in half.state_dict().items()}))
    resumed = NStepReturns(4, G, 3, 2, 2)
    resumed.load_state_dict({k: np.asarray(v) for k, v in state.items()})
    assert [_rounded(resumed.push(**s)) for s in steps[13:]] == first[13:]
    with pytest.raises(ValueError, match=r"n-step state 'obs' has shape \(4, 3, 2\), this learner's is \(3, 3, 2\)"):
        NStepReturns(3, G, 3, 2, 2).load_state_dict(half.state_dict())
    with pytest.raises(ValueError, match="n >= 1"):
        NStepReturns(0, G, 3, 2, 2)


def test_the_replay_keeps_discounts_only_when_made_to() -> None:
    buf = ReplayBuffer(10, 2, 2, discount=True)
    one = {"obs": np.zeros((3, 2)), "act": np.zeros((3, 2)), "rew": np.arange(3.0), "next_obs": np.ones((3, 2)),
           "done": np.zeros(3)}
    buf.add_batch(**one, discount=np.array([0.9, 0.81, 0.729]))
    batch = buf.sample(50, np.random.default_rng(0))
    assert set(batch) == {"obs", "act", "rew", "next_obs", "done", "discount"}
    assert np.allclose(batch["discount"], 0.9 ** (batch["rew"] + 1))  # each row kept its own factor
    with pytest.raises(ValueError, match="discount must be given exactly when the buffer keeps it"):
        buf.add_batch(**one)
    with pytest.raises(ValueError, match="discount must be given exactly when the buffer keeps it"):
        ReplayBuffer(10, 2, 2).add_batch(**one, discount=np.ones(3))
    restored = ReplayBuffer(10, 2, 2, discount=True)
    restored.load_state_dict(buf.state_dict())
    assert np.array_equal(restored.discount[:3], buf.discount[:3])
    with pytest.raises(KeyError, match="'discount'"):
        restored.load_state_dict(ReplayBuffer(10, 2, 2).state_dict())
    plain = ReplayBuffer(10, 2, 2)
    plain.add_batch(**one)
    assert set(plain.sample(4, np.random.default_rng(0))) == {"obs", "act", "rew", "next_obs", "done"}


def test_the_td_target_bootstraps_with_the_batchs_discount() -> None:
    agent = DDPG(OBS_DIM, ACT_DIM, DDPGConfig(hidden=(16, 16), gamma=G), seed=0)
    batch = _batch(0)
    plain = agent.td_target(batch)
    same = agent.td_target({**batch, "discount": np.full(len(batch["rew"]), G, np.float32)})
    torch.testing.assert_close(same, plain)  # discount γ is one-step TD
    discount = np.linspace(G ** 5, G, len(batch["rew"])).astype(np.float32)
    y = agent.td_target({**batch, "discount": discount})
    rew, done = (torch.as_tensor(np.asarray(batch[k], np.float32).reshape(-1)) for k in ("rew", "done"))
    live = done == 0
    assert live.any() and (~live).any()
    torch.testing.assert_close((y - rew)[live] * G, (plain - rew)[live] * torch.as_tensor(discount)[live])
    torch.testing.assert_close(y[~live], rew[~live])  # no bootstrap after a win or a loss


TINY = SACConfig(hidden=(16, 16), buffer_size=2000, learning_starts=40, batch_size=16, learn_every=2, n_step=3)


def test_an_n_step_training_run_resumed_equals_the_uninterrupted_one(tmp_path: Path) -> None:
    run_dir = resumed_equals_uninterrupted(tmp_path, TINY)
    assert json.loads((run_dir / "config.json").read_text())["sac"]["n_step"] == 3
    checkpoint = sorted((run_dir / "checkpoints").glob("epoch-*"))[0]
    with np.load(checkpoint / "replay.npz") as replay, np.load(checkpoint / "arrays.npz") as arrays:
        spans = np.round(np.log(replay["bug.discount"].astype(np.float64)) / np.log(0.99)).astype(int)
        assert np.allclose(replay["bug.discount"], 0.99 ** spans)  # γ^m, m steps spanned
        assert set(spans) <= {1, 2, 3} and np.mean(spans == 3) > 0.8  # mostly whole windows
        assert {"bug.nstep.obs", "bug.nstep.count"} <= set(arrays.files)


def test_n_step_is_validated_and_on_by_default_in_sac_only() -> None:
    """SAC's default schedule is the measured recipe (5-step returns, one update per 8 transitions); DDPG's paper
    preset and TD3 keep one-step targets."""
    from triplesumo.algos.td3 import TD3Config

    assert (SACConfig().n_step, SACConfig().learn_every) == (5, 8)
    assert DDPGConfig().n_step == TD3Config().n_step == 1
    with pytest.raises(ValueError, match="SACConfig.n_step must be >= 1"):
        SACConfig(n_step=0)
    assert dataclasses.replace(TINY, n_step=2).n_step == 2


def test_a_config_json_written_before_n_step_reads_back_with_one_step_targets() -> None:
    from triplesumo.train.run_folder import config_from_json

    data = json.loads(json.dumps(dataclasses.asdict(TrainConfig(learn=("bug=sac", "ant=ddpg", "spider=td3")))))
    for algo in ("sac", "ddpg", "td3"):
        del data[algo]["n_step"]
    cfg = config_from_json(data)
    assert (cfg.sac.n_step, cfg.ddpg.n_step, cfg.td3.n_step) == (1, 1, 1)


@pytest.mark.parametrize("n", [2, 5])
def test_the_device_windows_give_the_host_windows_transitions_and_checkpoint(n: int) -> None:
    """:class:`TorchNStepReturns` (a device-resident collection's windows; torch's CPU device here) stores the same
    transitions in the same order as the numpy windows over random matches with every kind of end, and its
    checkpoint arrays are the numpy windows', loadable either way."""
    from triplesumo.algos.nstep import TorchNStepReturns

    rng = np.random.default_rng(10 + n)
    rows = 6
    host, device = NStepReturns(n, G, rows, 2, 2), TorchNStepReturns(n, G, rows, 2, 2, "cpu")
    stored = 0
    for t in range(80):
        kind = rng.choice(["plain", "terminated", "truncated", "broken", "out"], size=rows, p=[.7, .1, .08, .04, .08])
        s = _step(rows, t, list(rng.normal(size=rows)), tuple(np.flatnonzero(kind == "terminated")),
                  tuple(np.flatnonzero(kind == "truncated")), tuple(np.flatnonzero(kind == "broken")),
                  tuple(np.flatnonzero(kind == "out")))
        want = host.push(**s)
        got = device.push(**{k: torch.as_tensor(v) for k, v in s.items()})
        assert set(got) == set(want) and all(isinstance(v, torch.Tensor) and v.dtype == torch.float32
                                             for v in got.values())
        for name in want:
            np.testing.assert_allclose(got[name].numpy(), want[name], rtol=0, atol=1e-6, err_msg=f"{name} at {t}")
        stored += len(want["rew"])
        assert len(device) == len(host)
        if t == 40:  # a checkpoint each way: the arrays are the same, and each loads the other's
            a, b = host.state_dict(), device.state_dict()
            assert all(np.array_equal(a[k], b[k]) and a[k].dtype == b[k].dtype for k in a)
            host.load_state_dict(b)
            device.load_state_dict(a)
    assert stored > 150
    with pytest.raises(ValueError, match="n-step state 'obs' has shape"):
        device.load_state_dict({**host.state_dict(), "obs": np.zeros((n + 1, rows, 2), np.float32)})


def test_a_device_resident_collection_keeps_its_windows_and_discounts_on_the_device() -> None:
    from triplesumo.algos.nstep import TorchNStepReturns
    from triplesumo.algos.replay import TorchReplayBuffer
    from triplesumo.train.learners import learner_specs, make_learner

    cfg = TrainConfig(learn=("bug=sac",), policies=("ant=zero", "spider=random"), sac=TINY, n_envs=2)
    spec = learner_specs(cfg, ("ant", "bug", "spider"), {"ant": "team", "bug": "team", "spider": "spider"})[0]
    learner = make_learner(spec, [1], 0, cfg, 8, 2, device=torch.device("cpu"))
    assert isinstance(learner.nstep, TorchNStepReturns) and isinstance(learner.replay, TorchReplayBuffer)
    assert learner.nstep.obs.shape == (3, 2, 8) and "discount" in learner.replay.fields
    learner = make_learner(spec, [1], 0, cfg, 8, 2)  # on the host the numpy windows
    assert type(learner.nstep) is NStepReturns and learner.nstep.obs.shape == (3, 2, 8)
    assert "discount" in learner.replay.fields


def test_an_n_step_learner_refuses_one_step_batches_by_name() -> None:
    """A learner made with ``n_step`` above 1 (SAC's default) fed a batch without ``discount`` (one-step transitions
    from a loop of one's own) says so instead of learning from them as if they were n-step ones; with n_step 1, or
    with the discounts, it updates."""
    from triplesumo.algos.sac import SAC

    batch = _batch(0)
    sac = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(SACConfig(), hidden=(16, 16), batch_size=len(batch["rew"])), 0)
    with pytest.raises(ValueError, match=r"SACConfig.n_step is 5 but the batch has no 'discount'.*\(n_step=1\)"):
        sac.update(batch)
    assert sac.num_updates == 0
    sac.update({**batch, "discount": np.full(len(batch["rew"]), G**5, np.float32)})
    one_step = SAC(OBS_DIM, ACT_DIM, dataclasses.replace(SACConfig(), hidden=(16, 16), n_step=1), 0)
    one_step.update(batch)
    assert sac.num_updates == one_step.num_updates == 1
