"""A policy knows the ring it was trained on (its manifest's ``physics``) and is refused on another one, by every
way of loading it into a match, unless that is allowed explicitly (``--allow-other-ring``, ``allow_other_ring``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
import torch

from triplesumo import zoo
from triplesumo.agents.networks import Actor
from triplesumo.agents.policy_file import policy_paths, save_policy
from triplesumo.cli import main
from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate
from triplesumo.evaluation.tournament import Tournament, TournamentConfig
from triplesumo.model.specs import RINGS, V0_PHYSICS, V1_PHYSICS, PhysicsConfig, RingError, recorded_physics
from triplesumo.reproduce.config import ReproduceConfig
from triplesumo.reproduce.run import run_reproduce
from triplesumo.train.checkpoint import CheckpointError
from triplesumo.train.loop import train

ROOT = Path(__file__).resolve().parents[1]
V2 = dataclasses.asdict(PhysicsConfig())
V1_RECORD = {k: v for k, v in dataclasses.asdict(V1_PHYSICS).items() if k not in ("layout", "start_edge", "rim_shape")}
"""The physics record as env v1's trainer wrote it (before the layout and the rim's shape were fields)."""
OTHER_RINGS: dict[str, dict[str, Any]] = {
    "env-v1": {"env_version": "v1", "physics": V1_RECORD},
    "circle": {"physics": {**V2, "layout": "circle"}},
    "no-rim": {"physics": {**V2, "border_rim": False}},
    "cylinder": {"physics": {**V2, "rim_shape": "cylinder"}},
}
"""Manifests of an Ant trained on another ring than env v2's default one."""
TINY_TRAIN = ["--epochs", "1", "--steps-per-epoch", "10", "--n-envs", "1", "--ddpg.hidden", "16", "16",
              "--ddpg.learning-starts", "5", "--ddpg.batch-size", "4", "--checkpoint-every", "1", "--no-progress",
              "--no-tensorboard", "--no-save-replay"]


def craft(folder: Path, name: str, **manifest: Any) -> str:
    """An Ant policy file (a tiny real actor of the paper's observation size) whose manifest is zoo:ant's with
    ``manifest``'s entries (``None`` removes one)."""
    base = zoo.load("ant")[1]
    torch.manual_seed(0)
    actor = Actor(int(base["obs_dim"]), int(base["act_dim"]), (16, 16))
    keep = {k: v for k, v in base.items() if k not in ("format", "obs_dim", "act_dim", "hidden", "obs_norm", "sha256",
                                                       "evaluation", "reproduction")}
    fields = {k: v for k, v in {**keep, **manifest}.items() if v is not None}
    save_policy(folder / name, actor, fields)
    return str(folder / name)


@pytest.fixture
def other(tmp_path: Path) -> dict[str, str]:
    return {label: craft(tmp_path, label, **fields) for label, fields in OTHER_RINGS.items()}


@pytest.mark.parametrize("label", OTHER_RINGS)
def test_make_policy_refuses_a_policy_of_another_ring_naming_both_rings_and_the_file(
        tmp_path: Path, label: str) -> None:
    spec = craft(tmp_path, label, **OTHER_RINGS[label])
    with pytest.raises(RingError, match="trained on another ring") as caught:
        zoo.make_policy(spec, expect_physics=PhysicsConfig())
    said = str(caught.value)
    assert str(policy_paths(spec)[0]) in said and "this match is on a box rim, the fair start" in said
    assert said.count(" rim") >= 2 and "--allow-other-ring" in said
    own = zoo.policy_ring(spec)
    assert own != PhysicsConfig()
    zoo.make_policy(spec, expect_physics=own)  # on its own ring
    zoo.make_policy(spec, expect_physics=PhysicsConfig(), allow_other_ring=True)  # said explicitly
    with pytest.raises(RingError):
        zoo.policies_from_pairs((f"ant={spec}",), 0, "paper", physics=PhysicsConfig())
    assert set(zoo.policies_from_pairs((f"ant={spec}",), 0, "paper", physics=PhysicsConfig(),
                                       allow_other_ring=True)) == {"ant"}


def test_an_env_v1_manifest_is_on_v1s_ring_and_one_without_physics_on_its_env_versions() -> None:
    assert recorded_physics({"env_version": "v1", "physics": V1_RECORD}) == V1_PHYSICS
    # made before physics was recorded: env v0's
    assert recorded_physics({"env_version": "v0"}) == recorded_physics({}) == V0_PHYSICS
    assert recorded_physics({"env_version": "v1"}) == V1_PHYSICS
    assert recorded_physics({"env_version": "v2"}) == PhysicsConfig()
    with pytest.raises(RingError, match=r"m\.json: env_version 'v9' is none of"):
        recorded_physics({"env_version": "v9"}, "m.json")
    # a v2 manifest relabelled v1: v1 had no fair layout nor box rim
    with pytest.raises(RingError, match=r"env_version 'v1' contradicts its physics: physics.layout 'fair'"):
        recorded_physics({"env_version": "v1", "physics": V2})
    with pytest.raises(RingError, match=r"physics: PhysicsConfig.layout must be one of"):
        recorded_physics({"physics": {**V2, "layout": "zigzag"}})
    with pytest.raises(RingError, match=r"physics has unknown field\(s\) \['rim_height'\]"):
        recorded_physics({"physics": {**V2, "rim_height": 0.1}})


def test_the_shipped_zoo_and_the_policies_of_docs_runs_load_on_their_own_ring() -> None:
    """Every policy file shipped or kept beside the docs records the ring of its env version, and loads on it."""
    manifests = [*zoo.ZOO_DIR.glob("*.json"), *(ROOT / "docs" / "runs").rglob("*.json")]
    checked = 0
    for path in manifests:
        manifest = json.loads(path.read_text())
        if not isinstance(manifest, dict) or manifest.get("format") != "triplesumo-policy/1":
            continue
        ring = recorded_physics(manifest, str(path))
        assert ring == RINGS[manifest.get("env_version", "v0")], path
        zoo.make_policy(str(path), expect_physics=ring)
        if ring != PhysicsConfig():
            with pytest.raises(RingError):
                zoo.make_policy(str(path), expect_physics=PhysicsConfig())
        checked += 1
    assert checked >= 40
    zoo.load("ant-selfplay", expect_physics=V1_PHYSICS)  # the shipped self-play policies are env v1's
    with pytest.raises(RingError, match=r"ant-selfplay\.json: the policy was trained on another ring: a cylinder rim"):
        zoo.load("ant-selfplay", expect_physics=PhysicsConfig())


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_play_evaluate_and_train_refuse_another_ring_unless_allowed(tmp_path: Path, other: dict[str, str],
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    for label, spec in other.items():
        assert main(["play", "--policies", f"ant={spec}", "--max-steps", "3"]) == 2, label
        assert "trained on another ring" in capsys.readouterr().err
    spec = other["env-v1"]
    assert main(["play", "--policies", f"ant={spec}", "--max-steps", "3", "--allow-other-ring"]) == 0
    assert main(["play", "--policies", f"ant={spec}", "--max-steps", "3", "--physics.layout", "circle",
                 "--physics.rim-shape", "cylinder"]) == 0  # on its own ring
    capsys.readouterr()

    out = tmp_path / "evaluation"
    tiny_eval = ["--learner", "bug", "--policy", "passive", "--baselines", "--epochs", "1", "--steps-per-epoch", "3",
                 "--n-envs", "1", "--no-progress", "--out", str(out)]
    assert main(["evaluate", *tiny_eval, "--policies", f"ant={spec}", "spider=passive"]) == 2
    assert "trained on another ring" in capsys.readouterr().err and not (out / "evaluation.json").exists()
    assert main(["evaluate", *tiny_eval, "--compare", spec, "--learner", "ant", "--policies", "bug=passive",
                 "spider=passive"]) == 2  # a candidate too
    assert "trained on another ring" in capsys.readouterr().err and not (out / "evaluation.json").exists()
    assert main(["evaluate", *tiny_eval, "--policies", f"ant={spec}", "spider=passive", "--allow-other-ring"]) == 0

    runs = tmp_path / "runs"
    assert main(["train", "--out", str(runs), "--name", "r", "--policies", f"ant={spec}", "spider=passive",
                 *TINY_TRAIN]) == 2
    assert "trained on another ring" in capsys.readouterr().err and not (runs / "r" / "config.json").exists()
    assert main(["train", "--out", str(runs), "--name", "r", "--policies", f"ant={spec}", "spider=passive",
                 "--allow-other-ring", *TINY_TRAIN]) == 0
    assert json.loads((runs / "r" / "config.json").read_text())["allow_other_ring"] is True


def test_a_league_seed_of_another_ring_is_refused_unless_allowed_and_so_is_one_a_fork_adds(
        tmp_path: Path, other: dict[str, str]) -> None:
    from conftest import tiny
    from triplesumo.train.fork import fork_run

    base = tiny(tmp_path, learn=("spider=ddpg",), policies=("ant=passive", "bug=passive"), self_play=True, epochs=2)
    seeds = (f"ant={other['circle']}", "bug=passive")
    refused = r"LeagueConfig.zoo: .*circle.json: the policy was trained on another ring"
    with pytest.raises(ValueError, match=refused):
        train(dataclasses.replace(base, league=dataclasses.replace(base.league, zoo=seeds)))
    parent = train(base).run_dir  # seeds nothing
    fork = dataclasses.replace(base, name="fork", league=dataclasses.replace(base.league, zoo=seeds))
    with pytest.raises(ValueError, match=refused):
        fork_run(parent, fork)
    assert not (tmp_path / "fork").exists()
    assert fork_run(parent, dataclasses.replace(fork, allow_other_ring=True)).is_dir()


@pytest.mark.slow  # 4 s alone on the shared 2-core box
def test_evaluate_and_tournament_configs_take_the_flag(tmp_path: Path, other: dict[str, str]) -> None:
    spec = other["no-rim"]
    ecfg = EvaluateConfig(learner="ant", policy=(spec,), policies=("bug=passive", "spider=passive"), baselines=(),
                          epochs=1, steps_per_epoch=3, n_envs=1, progress=False, out=str(tmp_path / "e"))
    with pytest.raises(ValueError, match=r"no-rim\.json: the policy was trained on another ring: no rim"):
        evaluate(ecfg)
    evaluate(dataclasses.replace(ecfg, physics=PhysicsConfig(border_rim=False), out=str(tmp_path / "own")))
    evaluate(dataclasses.replace(ecfg, allow_other_ring=True, out=str(tmp_path / "allowed")))
    tcfg = TournamentConfig(policies=(f"a={spec}", "p=passive", "r=random"), rounds=1, steps_per_epoch=3, n_envs=1,
                            progress=False, out=str(tmp_path / "t"))
    with pytest.raises(RingError, match=r"no-rim\.json: the policy was trained on another ring"):
        Tournament(tcfg)
    assert Tournament(dataclasses.replace(tcfg, allow_other_ring=True)).seats_of["a"] == ["ant"]
    assert main(["tournament", "--policies", f"a={spec}", "p=passive", "r=random", "--rounds", "1",
                 "--steps-per-epoch", "3", "--n-envs", "1", "--no-progress", "--out", str(tmp_path / "t")]) == 2


def test_reproduce_pair_of_another_ring_is_refused_unless_allowed(tmp_path: Path, other: dict[str, str]) -> None:
    cfg = ReproduceConfig(out=str(tmp_path / "rep"), pair=(other["cylinder"], "zoo:spider"), tiny=True,
                          progress=False, algos=("ddpg",), seeds=(0,))
    with pytest.raises(ValueError, match=r"cylinder\.json: the policy was trained on another ring"):
        run_reproduce(cfg)  # at the contest stage, before its first match
    assert not (tmp_path / "rep" / "contest" / "contest.json").exists()
    from triplesumo.reproduce.protocol import Protocol

    allowed = Protocol(dataclasses.replace(cfg, allow_other_ring=True))
    assert all(c.allow_other_ring for c in allowed.contest_configs().values())
    assert allowed.bug_base().allow_other_ring and allowed.evaluation_config().allow_other_ring
    evaluate(allowed.contest_configs()["ant-pushes"])  # plays


def test_zoo_publish_refuses_an_invalid_layout_naming_the_field(tmp_path: Path) -> None:
    bad = craft(tmp_path, "bad", physics={**V2, "layout": "zigzag"})
    with pytest.raises(RingError, match=r"bad\.json: physics: PhysicsConfig.layout must be one of"):
        zoo.publish(Path(bad), "ant", zoo_dir=tmp_path / "zoo")
    good = craft(tmp_path, "good")
    with pytest.raises(RingError, match=r"physics: PhysicsConfig.rim_shape must be one of"):
        zoo.publish(Path(good), "ant", zoo_dir=tmp_path / "zoo", extra={"physics": {**V2, "rim_shape": "round"}})
    assert not (tmp_path / "zoo").exists() or not any((tmp_path / "zoo").iterdir())
    assert zoo.publish(Path(good), "ant", zoo_dir=tmp_path / "zoo").is_file()


@pytest.mark.slow  # 4 s alone on the shared 2-core box
def test_resume_of_a_config_without_physics_refuses_the_checkpoints_other_physics(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """config.json without ``physics`` reads as env v0's; a checkpoint made on v2 is not trained on v0 physics."""
    from conftest import tiny

    run = train(tiny(tmp_path, epochs=2, checkpoint_every=2)).run_dir
    config = json.loads((run / "config.json").read_text())
    del config["physics"]
    (run / "config.json").write_text(json.dumps(config))
    before = sorted(p.name for p in (run / "checkpoints").iterdir())
    with pytest.raises(CheckpointError, match=r"config.json records no physics, which reads as env v0's") as caught:
        train(tiny(tmp_path), resume_dir=run, overrides={"epochs": 4})
    assert "physics.layout 'fair' there, 'circle' here" in str(caught.value)
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == before  # nothing trained
    assert main(["train", "--resume", str(run), "--epochs", "4"]) == 2
    assert "records no physics" in capsys.readouterr().err
    config["physics"] = dataclasses.asdict(V1_PHYSICS)  # written by hand: other physics than its checkpoints'
    (run / "config.json").write_text(json.dumps(config))
    with pytest.raises(CheckpointError, match=r"config.json records other physics: a cylinder rim"):
        train(tiny(tmp_path), resume_dir=run, overrides={"epochs": 4})
    config["physics"] = V2  # the checkpoint's
    (run / "config.json").write_text(json.dumps(config))
    assert train(tiny(tmp_path), resume_dir=run, overrides={"epochs": 4}).epochs >= 4
