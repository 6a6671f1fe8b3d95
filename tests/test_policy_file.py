"""Policy files (safetensors + JSON manifest) and the zoo's policy names."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from triplesumo.agents import policy_file
from triplesumo.agents.builtin import RandomPolicy, ZeroPolicy
from triplesumo.agents.frozen import FrozenPolicy
from triplesumo.agents.networks import Actor, ActorPolicy
from triplesumo.agents.policy_file import PolicyFileError, load_fixed_policy, load_policy, save_policy
from triplesumo.agents.zoo import (
    ZOO_DIR,
    find_policy_file,
    load,
    make_policy,
    policies_from_pairs,
    policy_fingerprint,
    policy_stem,
)

OBS_DIM = 12


@pytest.fixture
def actor() -> Actor:
    torch.manual_seed(3)
    return Actor(OBS_DIM, 8, (16, 16))


@pytest.fixture
def stem(tmp_path: Path, actor: Actor) -> Path:
    stem = tmp_path / "pol"
    save_policy(stem, actor, {"agent": "bug", "obs_mode": "paper", "seed": 7, "epochs": 42})
    return stem


def observations(n: int = 5) -> np.ndarray:
    return np.random.default_rng(0).normal(size=(n, OBS_DIM)).astype(np.float32)


def test_round_trip_gives_the_same_actions(stem: Path, actor: Actor) -> None:
    assert sorted(p.name for p in stem.parent.iterdir()) == ["pol.json", "pol.safetensors"]  # no temp files left
    expected = ActorPolicy(actor)(observations())
    for name in (stem, stem.with_suffix(".json"), stem.with_suffix(".safetensors")):
        policy, manifest = load_policy(name, expect_obs_mode="paper", expect_obs_dim=OBS_DIM)
        assert np.array_equal(policy(observations()), expected)
        assert policy(observations()[0]).shape == (8,)
    assert manifest["format"] == policy_file.FORMAT
    assert (manifest["agent"], manifest["obs_mode"], manifest["obs_dim"], manifest["act_dim"]) == ("bug", "paper",
                                                                                                    OBS_DIM, 8)
    assert manifest["hidden"] == [16, 16] and manifest["seed"] == 7 and manifest["epochs"] == 42


def test_save_policy_needs_agent_and_obs_mode(tmp_path: Path, actor: Actor) -> None:
    with pytest.raises(ValueError, match="lacks.*agent"):
        save_policy(tmp_path / "pol", actor, {"obs_mode": "paper"})


def test_failed_save_keeps_the_previous_file(stem: Path, actor: Actor, monkeypatch: pytest.MonkeyPatch) -> None:
    weights = stem.with_suffix(".safetensors")
    before = weights.read_bytes()

    def dies(tensors: object, path: str, metadata: object = None) -> None:
        Path(path).write_bytes(b"half")
        raise OSError("disk full")

    import safetensors.torch

    monkeypatch.setattr(safetensors.torch, "save_file", dies)  # (imported where tensors are saved)
    with torch.no_grad():
        actor.net[0].weight.add_(1.0)
    with pytest.raises(OSError, match="disk full"):
        save_policy(stem, actor, {"agent": "bug", "obs_mode": "paper"})
    assert weights.read_bytes() == before
    assert sorted(p.name for p in stem.parent.iterdir()) == ["pol.json", "pol.safetensors"]


def _edit_manifest(**changes: object) -> Callable[[Path], None]:
    def edit(stem: Path) -> None:
        path = stem.with_suffix(".json")
        data = json.loads(path.read_text())
        for key, value in changes.items():
            if value is None:
                del data[key]
            else:
                data[key] = value
        path.write_text(json.dumps(data))
    return edit


def _truncate(stem: Path) -> None:
    path = stem.with_suffix(".safetensors")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _not_an_actor(stem: Path) -> None:
    save_file({"critic.net.0.weight": torch.zeros(3, 3)}, str(stem.with_suffix(".safetensors")))


def _flip_data_byte(stem: Path) -> None:
    """Flip one byte in the tensor data (past the safetensors header): still a valid file."""
    path = stem.with_suffix(".safetensors")
    data = bytearray(path.read_bytes())
    data[-5] ^= 0x40
    path.write_bytes(bytes(data))


def _rewrite_weights(change: Callable[[str, torch.Tensor], torch.Tensor]) -> Callable[[Path], None]:
    """Weights rewritten tensor by tensor (a valid safetensors file, other contents)."""
    def rewrite(stem: Path) -> None:
        path = stem.with_suffix(".safetensors")
        tensors = load_file(str(path))
        save_file({k: change(k, v) for k, v in tensors.items()}, str(path))
    return rewrite


def _nan_weight(key: str, value: torch.Tensor) -> torch.Tensor:
    if key == "actor.net.0.weight":
        value = value.clone()
        value[0, 0] = float("nan")
    return value


def _json_null(**fields: object) -> Callable[[Path], None]:
    def edit(stem: Path) -> None:
        path = stem.with_suffix(".json")
        path.write_text(json.dumps({**json.loads(path.read_text()), **fields}))
    return edit


def _unchecked(*damages: Callable[[Path], None]) -> Callable[[Path], None]:
    """A file written before the sha256 was recorded: damage it, and take the checksum away."""
    def damage(stem: Path) -> None:
        _edit_manifest(sha256=None)(stem)
        for d in damages:
            d(stem)
    return damage


BROKEN = {
    "missing-json": (lambda s: s.with_suffix(".json").unlink(), ".json", {}, "file not found"),
    "missing-safetensors": (lambda s: s.with_suffix(".safetensors").unlink(), ".safetensors", {}, "file not found"),
    "truncated-safetensors": (_truncate, ".safetensors", {}, "sha256 differs"),
    "garbage-safetensors": (lambda s: s.with_suffix(".safetensors").write_bytes(b"\xff" * 64), ".safetensors", {},
                            "sha256 differs"),
    "flipped-data-byte": (_flip_data_byte, ".safetensors", {}, "sha256 differs"),
    "truncated-unchecked": (_unchecked(_truncate), ".safetensors", {}, "truncated or corrupt"),
    "garbage-unchecked": (_unchecked(lambda s: s.with_suffix(".safetensors").write_bytes(b"\xff" * 64)),
                          ".safetensors", {}, "truncated or corrupt"),
    "corrupt-json": (lambda s: s.with_suffix(".json").write_text('{"agent": "bug",'), ".json", {}, "corrupt JSON"),
    "json-not-an-object": (lambda s: s.with_suffix(".json").write_text("[1, 2]"), ".json", {},
                           "expected a JSON object"),
    "wrong-format": (_edit_manifest(format="other/9"), ".json", {}, "format 'other/9'"),
    "manifest-lacks-key": (_edit_manifest(obs_dim=None), ".json", {}, "lacks ['obs_dim']"),
    "obs-mode-mismatch": (lambda s: None, ".json", {"expect_obs_mode": "egocentric"}, "obs_mode 'paper'"),
    "obs-dim-mismatch": (lambda s: None, ".json", {"expect_obs_dim": OBS_DIM + 1}, f"expects {OBS_DIM} observation"),
    "manifest-disagrees-with-weights": (_edit_manifest(obs_dim=OBS_DIM + 1), ".safetensors", {},
                                        f"weights are {OBS_DIM}->8, manifest says {OBS_DIM + 1}->8"),
    "weights-not-an-actor": (_unchecked(_not_an_actor), ".safetensors", {}, "not an actor"),
    # issue 39, item 16: these were accepted (and published, averaged, or failed at the first step)
    "nan-weights": (_unchecked(_rewrite_weights(_nan_weight)), ".safetensors", {},
                    "actor.net.0.weight holds NaN or inf"),
    "int32-weights": (_unchecked(_rewrite_weights(lambda k, v: v.to(torch.int32))), ".safetensors", {},
                      "is int32, expected float32"),
    "hidden-disagrees-with-weights": (_edit_manifest(hidden=[16, 99]), ".safetensors", {},
                                      "hidden widths are [16, 16], its manifest says [16, 99]"),
    "obs-dim-null": (_json_null(obs_dim=None), ".json", {}, "obs_dim must be a positive integer, got None"),
    "obs-dim-list": (_json_null(obs_dim=[OBS_DIM]), ".json", {}, "obs_dim must be a positive integer"),
    "hidden-not-a-list": (_json_null(hidden=16), ".json", {}, "hidden must be a list of positive integers"),
}


@pytest.mark.parametrize("loader", [load_policy, load_fixed_policy])
@pytest.mark.parametrize("case", list(BROKEN))
def test_broken_policy_file_error_names_the_file(stem: Path, case: str, loader: Callable[..., object]) -> None:
    damage, suffix, expect, reason = BROKEN[case]
    damage(stem)
    pattern = f"{re.escape(str(stem.with_suffix(suffix)))}.*{re.escape(reason)}"
    with pytest.raises(PolicyFileError, match=pattern):
        loader(stem, **expect)


def test_fixed_policy_acts_as_the_torch_actor_and_alike_alone_or_batched(stem: Path, actor: Actor) -> None:
    fixed, manifest = load_fixed_policy(stem, expect_obs_mode="paper")
    assert isinstance(fixed, FrozenPolicy) and (fixed.obs_dim, fixed.act_dim) == (OBS_DIM, 8)
    obs = observations(64) * 50.0  # large inputs: tanh saturates for some rows, not all
    batched = fixed(obs)
    assert batched.dtype == np.float32 and batched.shape == (64, 8)
    np.testing.assert_allclose(batched, ActorPolicy(actor)(obs), atol=1e-5)
    assert np.array_equal(np.stack([fixed(o) for o in obs]), batched)  # no dependence on the batch
    assert np.array_equal(fixed(obs[:5]), batched[:5])
    with pytest.raises(ValueError, match=rf"obs must have shape \({OBS_DIM},\)"):
        fixed(np.zeros(OBS_DIM + 1))


def test_zoo_load_gives_the_fork_safe_policy_and_make_policy_the_torch_actor() -> None:
    assert isinstance(load("spider")[0], FrozenPolicy)
    assert isinstance(make_policy("zoo:spider"), ActorPolicy)


# --------------------------------------------------------------------------- zoo


def test_make_policy_builtins() -> None:
    obs = observations()[0]
    for name in ("zero", "passive"):
        policy = make_policy(name)
        assert isinstance(policy, ZeroPolicy)
        assert np.array_equal(policy(obs), np.zeros(8))
    a, b, c = make_policy("random", seed=5), make_policy("random", seed=5), make_policy("random", seed=6)
    assert isinstance(a, RandomPolicy)
    first = np.stack([a(obs) for _ in range(4)])
    assert first.shape == (4, 8) and np.abs(first).max() <= 1.0 and len(np.unique(first)) == first.size
    assert np.array_equal(first, np.stack([b(obs) for _ in range(4)]))
    assert not np.array_equal(first, np.stack([c(obs) for _ in range(4)]))


def test_make_policy_from_a_policy_file(stem: Path, actor: Actor) -> None:
    expected = ActorPolicy(actor)(observations())
    for spec in (str(stem), str(stem.with_suffix(".json")), str(stem.with_suffix(".safetensors"))):
        assert np.array_equal(make_policy(spec, expect_obs_mode="paper")(observations()), expected)
    with pytest.raises(PolicyFileError, match="obs_mode"):
        make_policy(str(stem), expect_obs_mode="egocentric")


def test_make_policy_unknown_name_lists_the_choices(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown policy 'telepathy'.*'passive', 'random', 'zero'.*zoo:NAME"):
        make_policy("telepathy")
    with pytest.raises(ValueError, match="unknown policy"):
        make_policy(str(tmp_path / "no-such-policy"))


def test_find_policy_file_is_the_one_answer_to_is_this_spec_a_policy_file(stem: Path, tmp_path: Path) -> None:
    """make_policy, the tournament and a league's seeds ask :func:`find_policy_file`: a pair (with or without a
    suffix) is one, a path where neither file is is an unknown policy, and weights without their
    manifest are a broken policy file named as such (the loader's words), not an unknown name."""
    from triplesumo.evaluation.tournament import _manifest
    from triplesumo.train.league_config import check_seeds

    for spec in (str(stem), str(stem.with_suffix(".json")), str(stem.with_suffix(".safetensors"))):
        assert find_policy_file(spec) == stem
    assert find_policy_file("zoo:spider") == ZOO_DIR / "spider"
    with pytest.raises(ValueError, match="'passive' is a built-in policy"):
        find_policy_file("passive")
    stem.with_suffix(".json").unlink()
    missing = re.escape(f"{stem.with_suffix('.json')}: file not found (its weights")
    with pytest.raises(PolicyFileError, match=missing):
        make_policy(str(stem))
    with pytest.raises(PolicyFileError, match=missing):
        _manifest(str(stem), "paper")
    with pytest.raises(ValueError, match=r"LeagueConfig.zoo: " + missing):
        check_seeds((f"spider={stem}",))
    gone = str(tmp_path / "gone")
    for call in (lambda: make_policy(gone), lambda: _manifest(gone, "paper"),
                 lambda: check_seeds((f"spider={gone}",))):
        with pytest.raises(ValueError, match=f"unknown policy '{re.escape(gone)}'"):
            call()


def test_zoo_load_unknown_name() -> None:
    with pytest.raises(FileNotFoundError, match="no policy 'nonexistent' in the zoo"):
        load("nonexistent")
    with pytest.raises(FileNotFoundError, match="nonexistent"):
        make_policy("zoo:nonexistent")


def test_policy_stem_one_lookup_for_every_spec(tmp_path: Path) -> None:
    """zoo:NAME, a path with or without its suffix (dots in the name kept): one stem, the one the
    fingerprint hashes; built-ins have no file and unknown zoo names list the shipped ones."""
    assert policy_stem("zoo:spider") == ZOO_DIR / "spider"
    for spec in ("runs/a10000.v2-spider", "runs/a10000.v2-spider.json", "runs/a10000.v2-spider.safetensors"):
        assert policy_stem(spec) == Path("runs/a10000.v2-spider")
    assert policy_stem(Path("runs/x/policy.json")) == Path("runs/x/policy")
    with pytest.raises(FileNotFoundError, match=r"no policy 'beetle' in the zoo.*shipped: \[.*'spider'"):
        policy_stem("zoo:beetle")
    with pytest.raises(ValueError, match="'passive' is a built-in policy"):
        policy_stem("passive")
    stem = tmp_path / "copy.v1"
    for suffix in (".json", ".safetensors"):
        stem.with_name(stem.name + suffix).write_bytes((ZOO_DIR / f"spider{suffix}").read_bytes())
    assert policy_fingerprint(str(stem) + ".json") == policy_fingerprint("zoo:spider") != policy_fingerprint("zoo:ant")
    # the loader and the writer keep the dot too: the copy loads, and a save under a dotted stem writes that name
    assert policy_file.policy_paths(str(stem) + ".safetensors") == (tmp_path / "copy.v1.json",
                                                                  tmp_path / "copy.v1.safetensors")
    copy = make_policy(str(stem))
    _, manifest = load_policy(stem)
    assert manifest["agent"] == "spider" and copy.obs_dim == manifest["obs_dim"]
    written = save_policy(tmp_path / "again.v2", copy.actor, {k: manifest[k] for k in ("agent", "obs_mode")})
    assert written == (tmp_path / "again.v2.safetensors", tmp_path / "again.v2.json")


def test_policies_from_pairs_seeds_each_policy_apart() -> None:
    policies = policies_from_pairs(("spider=random", "ant=random", "bug=zero"), seed=1, obs_mode="paper")
    assert list(policies) == ["spider", "ant", "bug"]
    obs = observations()[0]
    assert not np.array_equal(policies["spider"](obs), policies["ant"](obs))
    again = policies_from_pairs(("spider=random", "ant=random", "bug=zero"), seed=1, obs_mode="paper")
    assert np.array_equal(again["spider"](obs), make_policy("random", seed=1000)(obs))
    with pytest.raises(ValueError, match="'ant' given twice"):
        policies_from_pairs(("ant=zero", "ant=random"), seed=0, obs_mode="paper")
