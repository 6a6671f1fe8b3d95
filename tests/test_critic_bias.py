"""benchmarks/critic_bias.py: the n-step soft returns it compares SAC's critics with, its table, and a run read end
to end."""
from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from conftest import module_from_file
from triplesumo.algos.sac import SACConfig
from triplesumo.train.config import TrainConfig
from triplesumo.train.loop import train
from triplesumo.train.run_folder import write_run_config

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "critic_bias.py"


def _module() -> ModuleType:
    return module_from_file(SCRIPT)


def test_soft_returns_add_the_entropy_term_where_an_n_step_target_bootstraps() -> None:
    soft_returns = _module().soft_returns
    r, lp, a, g = np.array([1.0, 2.0, 3.0, 4.0]), np.array([10.0, 20.0, 30.0, 40.0]), 0.5, 0.9
    discounted = [1 + g * 2 + g**2 * 3 + g**3 * 4, 2 + g * 3 + g**2 * 4, 3 + g * 4, 4]
    one = [discounted[0] - a * (g * 20 + g**2 * 30 + g**3 * 40), discounted[1] - a * (g * 30 + g**2 * 40),
           discounted[2] - a * g * 40, 4]
    two = [discounted[0] - a * g**2 * 30, discounted[1] - a * g**2 * 40, discounted[2], 4]
    np.testing.assert_allclose(soft_returns(r, lp, a, g), one)
    np.testing.assert_allclose(soft_returns(r, lp, a, g, n_step=2), two)
    np.testing.assert_allclose(soft_returns(r, lp, 0.0, g, n_step=5), discounted)  # no temperature: the return
    with pytest.raises(ValueError, match="two 1-D arrays of one length"):
        soft_returns(r, lp[:3], a, g)
    with pytest.raises(ValueError, match="n_step must be >= 1"):
        soft_returns(r, lp, a, g, n_step=0)


def test_the_table_averages_per_match_and_the_minimum_is_never_above_the_mean() -> None:
    rng = np.random.default_rng(0)
    matches = [{"q1": rng.normal(size=n), "q2": rng.normal(size=n), "g": rng.normal(size=n)} for n in (40, 10, 25)]
    table = _module().bias_table(matches, early=5)
    whole, first = table["all_steps"], table["first_5_steps"]
    assert (whole["matches"], whole["states"], first["states"]) == (3, 75, 15)
    per_match = [((m["q1"] + m["q2"]) / 2 - m["g"]).mean() for m in matches]
    assert whole["bias_mean"] == pytest.approx(np.mean(per_match), abs=0.006)  # each match counts once
    assert whole["bias_mean_se"] == pytest.approx(np.std(per_match, ddof=1) / np.sqrt(3), abs=0.006)
    for t in (whole, first):
        assert t["bias_min"] <= t["bias_mean"]
        assert t["bias_mean"] - t["bias_min"] == pytest.approx(t["half_gap"], abs=0.011)  # mean - min = |gap| / 2


@pytest.mark.slow  # a tiny SAC run, then its critics read on 4 matches
def test_a_sac_run_is_read_end_to_end(tmp_path: Path) -> None:
    sac = SACConfig(hidden=(16, 16), buffer_size=2000, learning_starts=40, batch_size=16, learn_every=4)
    cfg = TrainConfig(name="run", out=str(tmp_path), learn=("bug=sac",), policies=("ant=zoo:ant", "spider=zoo:spider"),
                      epochs=2, steps_per_epoch=200, n_envs=2, checkpoint_every=2, seed=0, sac=sac, progress=False,
                      tensorboard=False)
    train(cfg)
    out = tmp_path / "bias.json"
    assert _module().main([str(tmp_path / "run"), "--matches", "4", "--early", "10", "--json", str(out)]) == 0
    table = json.loads(out.read_text())
    assert table["checkpoint"] == "epoch-000002" and table["n_step"] == 5 and table["pessimism"] == 1.0
    whole = table["all_steps"]
    assert whole["matches"] + table["time_limit_left_out"] == 4 and whole["matches"] >= 2
    assert whole["bias_min"] <= whole["bias_mean"] and np.isfinite(whole["return"])
    ppo = TrainConfig(name="ppo", out=str(tmp_path), learn=("bug=ppo",), epochs=1, steps_per_epoch=20, progress=False,
                      tensorboard=False)
    (tmp_path / "ppo").mkdir()
    write_run_config(tmp_path / "ppo", ppo)
    with pytest.raises(SystemExit, match="one SAC learner, this one learns"):
        _module().main([str(tmp_path / "ppo")])
