"""Averaging the actor weights of snapshots of one run (``triplesumo average``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.numpy import load_file

from triplesumo.agents.average import average_policies
from triplesumo.agents.networks import Actor
from triplesumo.agents.normalizer import ObsNormalizer
from triplesumo.agents.policy_file import PolicyFileError, file_sha256, load_fixed_policy, save_policy
from triplesumo.cli import main

OBS_DIM = 10


def snapshot(folder: Path, name: str, seed: int, epochs: int, run_id: str = "run-a",
             hidden: tuple[int, ...] = (16, 8), obs_norm: ObsNormalizer | None = None) -> Path:
    torch.manual_seed(seed)
    stem = folder / name / "spider"
    save_policy(stem, Actor(OBS_DIM, 4, hidden),
                {"agent": "spider", "obs_mode": "paper", "algo": "ddpg", "epochs": epochs, "seed": 3,
                 "command": "triplesumo train --learn spider=ddpg", "league_member": name,
                 "legs": [{"kind": "start", "epoch": 0, "run_id": run_id}]}, obs_norm=obs_norm)
    return stem


def test_average_is_the_parameter_mean_and_names_its_sources(tmp_path: Path) -> None:
    stems = [snapshot(tmp_path, f"spider-000{i}", seed=i, epochs=500 * i) for i in (1, 2, 3)]
    made = average_policies(stems, tmp_path / "swa" / "spider", command="triplesumo average ...")
    got = load_file(str(tmp_path / "swa" / "spider.safetensors"))
    parts = [load_file(str(s.with_suffix(".safetensors"))) for s in stems]
    assert set(got) == set(parts[0]) and len(got) == 6
    for key, value in got.items():
        np.testing.assert_allclose(value, sum(p[key] for p in parts) / 3, rtol=0, atol=1e-6)
        assert not np.allclose(value, parts[0][key])  # a real mean, not a copy of the first
    assert made["average"]["sources"] == [
        {"policy": str(s), "sha256": file_sha256(s.with_suffix(".safetensors")), "epochs": 500 * i,
         "league_member": f"spider-000{i}"} for i, s in zip((1, 2, 3), stems, strict=True)]
    assert made["average"]["command"] == "triplesumo average ..."
    assert made["epochs"] == 1500 and "league_member" not in made  # the newest source's provenance, no member id
    assert made["command"] == "triplesumo train --learn spider=ddpg"
    policy, manifest = load_fixed_policy(tmp_path / "swa" / "spider", expect_obs_mode="paper", expect_obs_dim=OBS_DIM)
    assert manifest["sha256"] == file_sha256(tmp_path / "swa" / "spider.safetensors")
    assert policy(np.zeros((2, OBS_DIM), np.float32)).shape == (2, 4)


@pytest.mark.parametrize("problem, match", [
    ("one", "at least two"),
    ("twice", "named twice"),
    ("hidden", "hidden is"),
    ("run", "from run 'run-b'"),
    ("norms", "different observation normalisers"),
    ("overwrite", "would overwrite"),
    ("corrupt", "sha256 differs"),
    ("missing", "not found"),
])
def test_average_refuses_what_is_not_one_run(tmp_path: Path, problem: str, match: str) -> None:
    a = snapshot(tmp_path, "a", seed=1, epochs=500)
    b = snapshot(tmp_path, "b", seed=2, epochs=1000)
    sources = [a, b]
    out = tmp_path / "out" / "spider"
    if problem == "one":
        sources = [a]
    elif problem == "twice":
        sources = [a, a.with_suffix(".json")]
    elif problem == "hidden":
        sources = [a, snapshot(tmp_path, "c", seed=2, epochs=1000, hidden=(16, 16))]
    elif problem == "run":
        sources = [a, snapshot(tmp_path, "c", seed=2, epochs=1000, run_id="run-b")]
    elif problem == "norms":
        norms = [ObsNormalizer(OBS_DIM), ObsNormalizer(OBS_DIM)]
        norms[1].update(np.ones((4, OBS_DIM), np.float32))
        sources = [snapshot(tmp_path, f"n{i}", seed=i, epochs=500, obs_norm=n) for i, n in enumerate(norms)]
    elif problem == "overwrite":
        out = b
    elif problem == "corrupt":
        b.with_suffix(".safetensors").write_bytes(b.with_suffix(".safetensors").read_bytes()[:-8] + b"\0" * 8)
    elif problem == "missing":
        sources = [a, tmp_path / "nowhere" / "spider"]
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    with pytest.raises((ValueError, PolicyFileError, FileNotFoundError), match=match):
        average_policies(sources, out)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before  # nothing written or lost


def test_identical_normalisers_are_kept(tmp_path: Path) -> None:
    norm = ObsNormalizer(OBS_DIM)
    norm.update(np.arange(3 * OBS_DIM, dtype=np.float32).reshape(3, OBS_DIM))
    stems = [snapshot(tmp_path, f"n{i}", seed=i, epochs=500 * i, obs_norm=norm) for i in (1, 2)]
    made = average_policies(stems, tmp_path / "swa")
    assert made["obs_norm"] is True
    got, first = load_file(str(tmp_path / "swa.safetensors")), load_file(str(stems[0].with_suffix(".safetensors")))
    assert all(np.array_equal(got[k], first[k]) for k in first if k.startswith("obs_norm."))


def test_cli_average(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = snapshot(tmp_path, "a", seed=1, epochs=500)
    b = snapshot(tmp_path, "b", seed=2, epochs=1000)
    assert main(["average", str(a), str(b), "--out", str(tmp_path / "swa")]) == 0
    assert "the mean of 2 spider policies (epochs [500, 1000])" in capsys.readouterr().out
    made = json.loads((tmp_path / "swa.json").read_text())
    assert made["average"]["command"] == f"triplesumo average {a} {b} --out {tmp_path / 'swa'}"
    assert main(["average", str(a), "zoo:spider", "--out", str(tmp_path / "x")]) == 2
    assert "only snapshots of one run average" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()
