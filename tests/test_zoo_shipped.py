"""The policies shipped in the package: manifests, safe loading, deterministic acting."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import triplesumo
from triplesumo.agents import zoo
from triplesumo.envs.match import Match
from triplesumo.evaluation.metrics_csv import open_table
from triplesumo.model import V0_PHYSICS, PhysicsConfig
from triplesumo.model.specs import physics_record
from triplesumo.rules.scenarios import scenario_config

SHIPPED = ("ant", "spider", "bug")
"""The paper roster that TripleSumo-Paper-v2 plays with: this env version's, built by ``triplesumo reproduce``."""


def test_the_zoo_ships_the_paper_roster_and_the_self_play_policies() -> None:
    assert set(zoo.available()) >= {*SHIPPED, "spider-selfplay", "ffa-selfplay", "ant-selfplay"}


def test_the_zoo_ships_one_self_play_spider() -> None:
    spiders = [n for n in zoo.available() if zoo.manifest_of(n)["agent"] == "spider"]
    assert spiders == ["spider", "spider-selfplay"]


@pytest.mark.parametrize("name", zoo.available())
def test_shipped_policy_manifest_says_how_it_was_made(name: str) -> None:
    manifest = zoo.manifest_of(name)  # (an alias's: its target's)
    scenario = manifest.get("scenario", "paper")
    if scenario == "paper":
        assert manifest["agent"] == name.split("-")[0]  # spider-selfplay plays the Spider
        assert manifest["obs_mode"] == "paper"
    else:  # e.g. ffa-selfplay: a free-for-all network, egocentric so that it takes any seat
        assert name.split("-")[0] == scenario and manifest["obs_mode"] == "egocentric"
        assert manifest["agent"] in scenario_config(scenario).agent_names
    assert manifest["command"].startswith("triplesumo train")
    assert isinstance(manifest["seed"], int)
    assert manifest["epochs"] > 0
    assert manifest["mujoco_version"] and manifest["env_version"] in ("v0", "v1", triplesumo.ENV_VERSION)
    # the simulation it was trained on: that of its env version (a manifest without physics: v0's)
    physics = PhysicsConfig(**physics_record(manifest["physics"])) if "physics" in manifest else V0_PHYSICS
    assert (physics == PhysicsConfig()) == (manifest["env_version"] == triplesumo.ENV_VERSION)
    if name in SHIPPED or name.startswith("bug-"):  # the paper roster of this env version (issue 38)
        assert manifest["env_version"] == triplesumo.ENV_VERSION
    assert "evaluation" in manifest


@pytest.mark.parametrize("name", zoo.available())
def test_shipped_policy_loads_by_name_and_acts_deterministically(name: str) -> None:
    policy, manifest = triplesumo.zoo.load(name)
    match = Match(scenario_config(manifest.get("scenario", "paper"), obs_mode=manifest["obs_mode"]))
    obs, _ = match.reset(seed=3)
    i = match.agents.index(manifest["agent"])
    a1, a2 = policy(obs[i]), policy(obs[i].copy())
    assert a1.shape == (8,) and a1.dtype == np.float32
    assert np.array_equal(a1, a2)
    assert np.all(np.abs(a1) <= 1.0)
    batch = policy(np.stack([obs[i], obs[i]]))
    assert np.allclose(batch[0], a1, atol=1e-6)
    assert manifest["obs_dim"] == obs[i].shape[0]


def test_paper_env_plays_the_shipped_pair_of_this_env_without_a_warning() -> None:
    import warnings

    import gymnasium as gym

    assert triplesumo.zoo.older_pair() == {}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning here fails the test
        gym.make("TripleSumo-Paper-v2").close()


def test_paper_env_names_a_pair_of_an_older_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A zoo whose Ant and Spider are env v1's (the history's copies): the env warns, naming each and its version."""
    import shutil

    import gymnasium as gym

    for name in ("ant", "spider"):
        for suffix in (".json", ".safetensors"):
            shutil.copy(HISTORY / f"{name}-v1{suffix}", tmp_path / f"{name}{suffix}")
    monkeypatch.setattr(zoo, "ZOO_DIR", tmp_path)
    assert triplesumo.zoo.older_pair() == {"zoo:ant": "v1", "zoo:spider": "v1"}
    with pytest.warns(UserWarning) as caught:
        gym.make("TripleSumo-Paper-v2").close()
    said = [str(w.message) for w in caught]
    for name in ("ant", "spider"):  # one warning each, naming the policy and both versions
        assert sum(f"zoo:{name} was trained on env v1, not {triplesumo.ENV_VERSION}" in m for m in said) == 1, said


def test_paper_env_uses_the_shipped_ant_and_spider() -> None:
    import gymnasium as gym

    env = gym.make("TripleSumo-Paper-v2")
    env.reset(seed=0)
    env.step(np.zeros(8, dtype=np.float32))
    data, match = env.unwrapped.data, env.unwrapped.match
    for agent in ("ant", "spider"):
        ids = match.sim.actuator_ids[match.agents.index(agent)]
        assert np.abs(data.ctrl[ids]).sum() > 0, agent
    assert np.abs(data.ctrl[match.sim.actuator_ids[match.agents.index("bug")]]).sum() == 0


ROOT = Path(__file__).resolve().parents[1]
HEAD_TO_HEAD = [n for n in zoo.available()
                if zoo.alias_target(n) is None and zoo.manifest_of(n)["evaluation"].get("kind") == "head_to_head"]


def test_some_shipped_policy_is_published_with_head_to_head_claims() -> None:
    assert {"ant-selfplay", "spider-selfplay"} <= set(HEAD_TO_HEAD)


# ------------------------------------------------------------------ the one self-play Spider and its history
HISTORY = ROOT / zoo.HISTORY
V5_SHA256 = "4f8fd1c0269514d8132cdaa2cdd54b066ed6bd4c3b84220d3a25cee26b15db34"
"""The weights' sha256 that ``spider-selfplay-v5.json`` recorded while it shipped under that name (commit 34c8bfd)."""


def test_the_self_play_spider_is_the_former_v5_bit_for_bit() -> None:
    from triplesumo.agents.policy_file import file_sha256

    manifest = json.loads((zoo.ZOO_DIR / "spider-selfplay.json").read_text())
    assert manifest["renamed_from"] == "spider-selfplay-v5" and manifest["zoo_name"] == "spider-selfplay"
    assert manifest["sha256"] == V5_SHA256 == file_sha256(zoo.ZOO_DIR / "spider-selfplay.safetensors")
    _, loaded = zoo.load("spider-selfplay")  # (the loader checks the weights against the manifest's sha256)
    assert loaded["league_member"] == "spider-0082" and loaded["epochs"] == 41000
    assert all(json.loads(p.read_text())["sha256"] != V5_SHA256 for p in HISTORY.glob("*.json"))


@pytest.mark.parametrize("name", sorted(zoo.RETIRED))
def test_a_retired_zoo_name_says_where_its_policy_went(name: str) -> None:
    where = zoo.RETIRED[name]
    with pytest.raises(FileNotFoundError, match=rf"zoo:{name} is no longer shipped: it is {re.escape(where)} "):
        zoo.make_policy(f"zoo:{name}")
    if where.startswith("zoo:"):
        assert where[4:] in zoo.available()
    else:
        assert (ROOT / f"{where}.json").is_file() and (ROOT / f"{where}.safetensors").is_file()
        assert json.loads((ROOT / f"{where}.json").read_text())["zoo_name"] == name  # its manifest, unchanged


V1_ROSTER = ("ant", "spider", "bug", "bug-sac")
"""Env v1's paper roster, shipped until the v2 contest's pair and Bugs replaced it (docs/CONTEST.md)."""


def test_the_history_holds_the_retired_spiders_the_first_self_play_spider_and_v1s_roster() -> None:
    assert sorted(p.stem for p in HISTORY.glob("*.json")) == sorted(
        [f"spider-selfplay-v{n}" for n in range(5)] + [f"{n}-v1" for n in V1_ROSTER])
    first = json.loads((HISTORY / "spider-selfplay-v0.json").read_text())
    assert first["zoo_name"] == "spider-selfplay" and first["env_version"] == "v0"  # the first zoo:spider-selfplay
    for name in V1_ROSTER:  # the manifest as it was shipped, under its zoo name
        manifest = json.loads((HISTORY / f"{name}-v1.json").read_text())
        assert manifest["env_version"] == "v1" and manifest.get("zoo_name", name) == name
    assert (HISTORY / "README.md").is_file()


@pytest.mark.parametrize("name", [f"spider-selfplay-v{n}" for n in range(5)] + [f"{n}-v1" for n in V1_ROSTER])
def test_a_history_policy_loads_by_path_without_a_suffix(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    spec = f"{zoo.HISTORY}/{name}"  # as a command line gives it: relative, no suffix
    assert zoo.find_policy_file(spec) == Path(spec)
    from triplesumo.agents.policy_file import load_policy

    _, manifest = load_policy(Path(spec))  # (checks the weights against the manifest's sha256)
    assert manifest["agent"] == name.split("-")[0] and manifest["command"].startswith("triplesumo train")
    obs = np.linspace(-1.0, 1.0, manifest["obs_dim"]).astype(np.float32)
    action = zoo.make_policy(spec, expect_obs_mode="paper")(obs)
    assert np.asarray(action).shape == (8,) and np.all(np.isfinite(action))


def _lwr(candidate: Path) -> np.ndarray:
    """Per-start local winning rate of an evaluation candidate's ``metrics.csv``: win +1, loss -1, draw 0."""
    with open_table(candidate / "metrics.csv") as fh:
        return np.array([{"win": 1.0, "loss": -1.0}.get(r["outcome"], 0.0) for r in csv.DictReader(fh)])


@pytest.mark.parametrize("name", HEAD_TO_HEAD)
def test_shipped_head_to_head_claims_match_the_published_matches(name: str) -> None:
    """Every row a manifest claims is its evaluation folder's ``summary.json`` row, and every paired
    difference is recomputed here from the per-start outcomes of the candidates' ``metrics.csv``
    (win +1, loss -1, draw 0; mean of this minus other, normal 95% interval)."""
    manifest = zoo.manifest_of(name)
    evaluation = manifest["evaluation"]
    assert evaluation["runs"] and evaluation["test_mwr"] == evaluation["runs"][0]["rows"][
        evaluation["runs"][0]["this"]]["mean_lwr"]
    for run in evaluation["runs"]:
        folder = ROOT / run["folder"]
        summary = json.loads((folder / "summary.json").read_text())
        assert run["learner"] == manifest["agent"] == summary["config"]["learner"]
        assert run["seed"] == summary["config"]["seed"] and run["epochs"] == summary["config"]["epochs"]
        assert f"--out {run['folder']}" in run["command"] and f"--epochs {run['epochs']}" in run["command"]
        for label, row in run["rows"].items():
            assert row == {k: summary["candidates"][label][k] for k in row}, (run["folder"], label)
            assert row["n"] == run["epochs"]

        mine = _lwr(folder / run["this"])
        assert mine.mean() == pytest.approx(run["rows"][run["this"]]["mean_lwr"], abs=1e-12)
        assert set(run["paired"]) == set(run["rows"]) - {run["this"]}
        for other, claim in run["paired"].items():
            d = mine - _lwr(folder / other)
            half = 1.959963984540054 * d.std(ddof=1) / np.sqrt(len(d))
            assert (claim["diff"], claim["lo"], claim["hi"]) == pytest.approx(
                (d.mean(), d.mean() - half, d.mean() + half), abs=1e-9), (run["folder"], other)


CONTEST = ROOT / "docs" / "runs" / "contest-v2" / "reproduce" / "contest"
"""The contest stage of env v2's reproduction (docs/CONTEST.md): ``contest.json`` and each check's per-match CSV."""


def test_the_contest_record_is_recomputed_from_its_matches() -> None:
    """Every count of the pair's contest record is the outcomes of its per-match ``metrics.csv`` (1,000 starts per
    check), the verdict is the contest rule's on those counts, and a shipped Ant or Spider of this env version
    carries this record in its manifest."""
    from triplesumo.reproduce.protocol import contest_verdict

    record = json.loads((CONTEST / "contest.json").read_text())
    counts = {}
    for check in ("ant-pushes", "spider-pushes", "match"):
        with open_table(CONTEST / check / "trained" / "metrics.csv") as fh:
            outcomes = [r["outcome"] for r in csv.DictReader(fh)]
        counts[check] = {"n": len(outcomes), **{f"n_{o}": outcomes.count(o) for o in ("win", "loss", "draw")}}
        summary = json.loads((CONTEST / check / "summary.json").read_text())
        assert summary["config"]["seed"] == 20_000 and summary["config"]["epochs"] == 1000
    assert counts == record["counts"] and record["matches"] == 1000
    assert contest_verdict(counts, record["ant"], record["spider"]) == record
    assert record["contest"] and -0.50 <= record["team_mwr"] <= -0.10
    for name in ("ant", "spider"):
        manifest = zoo.load(name)[1]
        assert manifest["evaluation"]["contest"] == record


REPRODUCE = ROOT / "docs" / "runs" / "contest-v2" / "reproduce"
"""Env v2's reproduction (docs/CONTEST.md): the Bug trials' ``metrics.csv`` and the 2,000-start test's per-match
CSVs that the shipped Bugs' manifests are recomputed from."""
BUGS = [n for n in zoo.available() if n == "bug" or n.startswith("bug-")]


def _test_rows() -> list[dict[str, str]]:
    with open_table(REPRODUCE / "evaluation" / "per_seed.csv") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("name", BUGS)
def test_a_shipped_bug_is_its_trial_and_its_figures_are_recomputed_from_the_matches(name: str) -> None:
    """A shipped Bug's weights are its trial's final policy; its test MWR, interval and counts are the outcomes of its
    2,000 test matches; its pick is the seed with the highest training MWR over its last 200 training matches, and
    ``zoo:bug`` is that Bug of the algorithm with the highest IQM test MWR across seeds (the rules fixed beforehand in
    docs/CONTEST.md), every figure read back from the CSVs."""
    from triplesumo.agents.policy_file import file_sha256
    from triplesumo.evaluation.compare import iqm
    from triplesumo.evaluation.metrics import summarize

    manifest = zoo.load(name)[1]
    assert manifest["env_version"] == triplesumo.ENV_VERSION and manifest["reproduction"] == str(
        REPRODUCE.relative_to(ROOT))
    ev, algo = manifest["evaluation"], manifest["algo"]
    trial = REPRODUCE / "bug" / f"learn=bug={algo},seed={manifest['seed']}"
    assert manifest["sha256"] == file_sha256(trial / "policy.safetensors")
    rows = [r for r in _test_rows() if "/bug/learn=bug=" in r["policy"]]
    row = next(r for r in rows if r["algo"] == algo and int(r["train_seed"]) == manifest["seed"])
    with open_table(REPRODUCE / "evaluation" / row["candidate"] / "metrics.csv") as fh:
        matches = list(csv.DictReader(fh))
    s = summarize([m["outcome"] for m in matches], [float(m["steps"]) for m in matches])
    assert s["n"] == ev["test_matches"] == 2000 and ev["eval_seed"] == 10_000
    assert (s["n_win"], s["n_loss"], s["n_draw"]) == (ev["n_win"], ev["n_loss"], ev["n_draw"])
    assert (s["mean_lwr"], s["mean_lwr_lo"], s["mean_lwr_hi"]) == pytest.approx(
        (ev["test_mwr"], ev["test_mwr_lo"], ev["test_mwr_hi"]), abs=1e-12)

    def train_mwr(seed: str) -> float:
        with open_table(REPRODUCE / "bug" / f"learn=bug={algo},seed={seed}" / "metrics.csv") as fh:
            lwr = [float(r["local_winning_rate"]) for r in csv.DictReader(fh)][-200:]
        return sum(lwr) / len(lwr)

    mine = {r["train_seed"]: train_mwr(r["train_seed"]) for r in rows if r["algo"] == algo}
    assert len(mine) == ev["selection"]["seeds"] == 3
    assert ev["selection"]["train_mwr"] == pytest.approx(mine[str(manifest["seed"])], abs=1e-12)
    assert max(mine, key=lambda k: (mine[k], -int(k))) == str(manifest["seed"])  # lower seed on a tie
    algos = {r["algo"] for r in rows}
    by_algo = {a: iqm(np.array([float(r["test_mwr"]) for r in rows if r["algo"] == a])) for a in algos}
    assert ev["selection"]["algo_iqm_test_mwr"] == pytest.approx(by_algo[algo], abs=1e-12)
    if name == "bug":  # an alias of that Bug (zoo:bug-ALGO), its weights stored once
        assert algo == max(by_algo, key=lambda a: (by_algo[a], a == "ddpg"))
        assert zoo.alias_target("bug") == f"bug-{algo}" and manifest["zoo_name"] == f"bug-{algo}"
    else:
        assert name == f"bug-{algo}"


def test_the_headline_table_is_recomputed_from_the_committed_matches() -> None:
    """The table of the result in the README and on the contest page (the site's home page states the result in
    prose and links there): every per-seed test MWR of the SAC and DDPG Bugs, their mean, and the passive and random
    baselines, each recomputed from its 2,000 per-match rows."""
    from triplesumo.evaluation.metrics import summarize

    def mwr(row: dict[str, str]) -> float:
        with open_table(REPRODUCE / "evaluation" / row["candidate"] / "metrics.csv") as fh:
            matches = list(csv.DictReader(fh))
        assert len(matches) == 2000
        return float(summarize([m["outcome"] for m in matches], [float(m["steps"]) for m in matches])["mean_lwr"])

    rows = _test_rows()
    seeds = {algo: [mwr(r) for r in sorted((r for r in rows if r["algo"] == algo and "/bug/learn=bug=" in r["policy"]),
                                             key=lambda r: int(r["train_seed"]))] for algo in ("sac", "ddpg")}
    baseline = {g: mwr(next(r for r in rows if r["group"] == g)) for g in ("passive", "random")}
    assert [len(v) for v in seeds.values()] == [3, 3]
    for page in (ROOT / "README.md", ROOT / "docs" / "CONTEST.md"):
        text = page.read_text()
        for algo, label in (("sac", "| **SAC** |"), ("ddpg", "| DDPG (paper preset) |")):
            values = " ".join(f"{v:+.3f}" for v in seeds[algo])
            mean = f"{np.mean(seeds[algo]):+.3f}"
            line = next(x for x in text.splitlines() if x.startswith(label))
            assert values in line and mean in line, (page.name, line, values, mean)
        assert f"| passive / random | {baseline['passive']:+.3f} / {baseline['random']:+.3f} |" in text, page.name


# ------------------------------------------------------------------ aliases: one copy of each weights file
TIME_FOLDERS = ("docs/runs/scratch-v2/seed-3", "docs/runs/scratch-v2/seed-1", "docs/runs/scratch-v3/seed-3",
                "docs/runs/scratch-v3/seed-1", "docs/runs/scratch-v4/seed-3", "docs/runs/scratch-v4/seed-1")


def test_where_a_pairs_time_goes_is_recomputed_from_the_committed_records(tmp_path: Path) -> None:
    """docs/reproduce.md's table of item 4's levers is what benchmarks/reproduce_time.py prints from the committed
    folders' records; a folder that is no reproduction is refused by name."""
    script = ROOT / "benchmarks" / "reproduce_time.py"
    facts = tmp_path / "time.json"
    done = subprocess.run([sys.executable, str(script), *TIME_FOLDERS, "--json", str(facts)], cwd=ROOT,
                          capture_output=True, text=True, check=True)
    assert done.stdout.strip() in (ROOT / "docs" / "reproduce.md").read_text()
    rows = {Path(f["folder"]).parent.name + "/" + Path(f["folder"]).name: f for f in json.loads(facts.read_text())}
    # pair 3 from scratch: the sides' own legs and screens, against stage 1's recorded wall time
    s1 = rows["scratch-v2/seed-3"]["stage1"]
    own = sum(s["train_seconds"] + s["screen_seconds"] for s in s1["sides"].values())
    assert s1["wall_seconds"] == json.loads((ROOT / TIME_FOLDERS[0] / "reproduce.json").read_text())["stages"][
        "ant"]["seconds"] and s1["side_by_side_speedup"] == round(own / s1["wall_seconds"], 2) > 1
    assert rows["scratch-v2/seed-1"]["bug"]["wall_seconds"] is None  # (a record before stage legs: not recorded)
    assert rows["scratch-v3/seed-3"]["stage1"] is None and len(rows["scratch-v3/seed-3"]["bug"]["runs"]) == 5
    refused = subprocess.run([sys.executable, str(script), str(tmp_path)], capture_output=True, text=True)
    assert refused.returncode == 2 and f"{tmp_path}: no reproduce.json" in refused.stderr


def test_every_shipped_weights_file_is_stored_once_and_zoo_bug_is_an_alias() -> None:
    from triplesumo.agents.policy_file import file_sha256

    weights = sorted(zoo.ZOO_DIR.glob("*.safetensors"))
    digests = [file_sha256(p) for p in weights]
    assert len(set(digests)) == len(digests), [p.name for p in weights]
    aliases = {n: zoo.alias_target(n) for n in zoo.available() if zoo.alias_target(n)}
    assert aliases == {"bug": zoo.manifest_of("bug")["zoo_name"]} and aliases["bug"].startswith("bug-")
    assert sorted(p.stem for p in weights) == sorted(set(zoo.available()) - set(aliases))
    assert json.loads((zoo.ZOO_DIR / "bug.json").read_text())["alias_of"] == aliases["bug"]


def test_an_alias_loads_the_weights_of_its_target() -> None:
    from triplesumo.agents.policy_file import load_policy

    target = zoo.alias_target("bug")
    assert target is not None and zoo.policy_stem("zoo:bug") == zoo.ZOO_DIR / target
    (alias, alias_manifest), (same, manifest) = zoo.load("bug"), zoo.load(target)
    assert alias_manifest == manifest  # the loader checked the weights against the target's sha256
    obs = np.linspace(-1.0, 1.0, manifest["obs_dim"] * 4).astype(np.float32).reshape(4, -1)
    assert np.array_equal(alias(obs), same(obs))
    torch_alias, torch_target = zoo.make_policy("zoo:bug"), load_policy(zoo.ZOO_DIR / target)[0]
    for (k, a), (_, b) in zip(torch_alias.actor.state_dict().items(), torch_target.actor.state_dict().items(),
                              strict=True):
        assert a.equal(b), k
    assert zoo.policy_fingerprint("zoo:bug") == zoo.policy_fingerprint(f"zoo:{target}")
    assert zoo.find_policy_file("zoo:bug") == zoo.ZOO_DIR / target


def _tiny_zoo(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A zoo of one shipped policy (``spider``, copied) pointed at by ``ZOO_DIR``."""
    import shutil

    for suffix in (".json", ".safetensors"):
        shutil.copy(zoo.ZOO_DIR / f"spider{suffix}", tmp_path / f"spider{suffix}")
    monkeypatch.setattr(zoo, "ZOO_DIR", tmp_path)
    return tmp_path


def test_publish_alias_writes_a_manifest_alone_and_replaces_an_earlier_copy(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    tiny = _tiny_zoo(tmp_path, monkeypatch)
    for suffix in (".json", ".safetensors"):  # an earlier full copy under the alias's name
        (tiny / f"arachne{suffix}").write_bytes((tiny / f"spider{suffix}").read_bytes())
    path = zoo.publish_alias("arachne", "spider", extra={"rule": "why"})
    assert json.loads(path.read_text()) == {"alias_of": "spider", "zoo_name": "arachne", "rule": "why"}
    assert not (tiny / "arachne.safetensors").exists() and zoo.available() == ["arachne", "spider"]
    assert zoo.load("arachne")[1]["zoo_name"] == "spider"
    with pytest.raises(zoo.PolicyFileError, match=r"cannot make zoo:x an alias of zoo:beetle: .* no weights"):
        zoo.publish_alias("x", "beetle")
    with pytest.raises(zoo.PolicyFileError, match=r"cannot make zoo:x an alias of zoo:arachne"):
        zoo.publish_alias("x", "arachne")  # an alias of an alias
    with pytest.raises(ValueError, match="of itself"):
        zoo.publish_alias("spider", "spider")


@pytest.mark.parametrize(("alias", "error"), [
    ({"alias_of": "beetle"}, r"moth\.json: zoo:moth is an alias of zoo:beetle, which the zoo does not ship "
                             r"\(shipped: \['moth', 'spider'\]\)"),
    ({"alias_of": 3}, r"moth\.json: alias_of must be a zoo name, got 3"),
])
def test_an_alias_of_a_name_the_zoo_lacks_is_refused_naming_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, alias: dict[str, object], error: str) -> None:
    tiny = _tiny_zoo(tmp_path, monkeypatch)
    (tiny / "moth.json").write_text(json.dumps(alias))
    for load in (lambda: zoo.load("moth"), lambda: zoo.make_policy("zoo:moth"),
                 lambda: zoo.policy_fingerprint("zoo:moth")):
        with pytest.raises(zoo.PolicyFileError, match=error):
            load()


def test_an_alias_of_an_alias_or_with_weights_of_its_own_is_refused(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    tiny = _tiny_zoo(tmp_path, monkeypatch)
    (tiny / "moth.json").write_text(json.dumps({"alias_of": "spider"}))
    (tiny / "gnat.json").write_text(json.dumps({"alias_of": "moth"}))
    with pytest.raises(zoo.PolicyFileError, match=r"zoo:gnat is an alias of zoo:moth, itself an alias"):
        zoo.load("gnat")
    (tiny / "moth.safetensors").write_bytes((tiny / "spider.safetensors").read_bytes())
    with pytest.raises(zoo.PolicyFileError, match=r"an alias \(of zoo:spider\) ships no weights"):
        zoo.load("moth")


RUNS = ROOT / "docs" / "runs"
SCRATCH: dict[str, dict[int, dict[str, int]]] = {
    "scratch-v2": {1: {"sac": 5, "ddpg": 3, "passive": 1, "random": 1}, 3: {"sac": 5, "passive": 1, "random": 1}},
    "scratch-v3": {1: {"sac": 5, "passive": 1, "random": 1}, 3: {"sac": 5, "passive": 1, "random": 1}},
    "scratch-v4": {1: {"sac": 5, "passive": 1, "random": 1}, 3: {"sac": 5, "passive": 1, "random": 1}}}
"""Per protocol version (its folder under docs/runs): the from-scratch pair seeds that made a contest, and the runs
of each algorithm and baseline on their test. ``scratch-v3`` reruns the Bugs under protocol change 1, ``scratch-v4``
under protocol change 2."""
SECTION = {"scratch-v2": "**Pair seed {}:", "scratch-v3": "**Protocol change 1, pair seed {}:",
           "scratch-v4": "**Protocol change 2, pair seed {}:"}
"""How docs/reproduce.md opens a version's section on one pair seed."""
SCRATCH_PAIRS = [(version, seed) for version, pairs in SCRATCH.items() for seed in sorted(pairs)]
HEADLINES = ("scratch-v2", "scratch-v3", "scratch-v4")
"""The protocol versions whose every contest pair has its Bugs tested: each has a headline over all its runs."""


def _scratch_scores(pair_seed: int, version: str) -> dict[str, list[float]]:
    """Each Bug's and baseline's test MWR on a from-scratch pair, recomputed from its 2,000 per-match rows (and
    held to its per_seed.csv row), by algorithm (SAC, DDPG) or baseline, in training-seed order."""
    from triplesumo.evaluation.metrics import summarize

    folder = RUNS / version / f"seed-{pair_seed}"
    with open(folder / "evaluation" / "per_seed.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    score: dict[str, list[float]] = {}
    for row in sorted(rows, key=lambda r: (r["algo"] or r["group"], int(r["train_seed"] or 0))):
        with open_table(folder / "evaluation" / row["candidate"] / "metrics.csv") as fh:
            matches = list(csv.DictReader(fh))
        assert len(matches) == 2000 and row["eval_seed"] == "10000"
        mwr = float(summarize([m["outcome"] for m in matches], [float(m["steps"]) for m in matches])["mean_lwr"])
        assert mwr == pytest.approx(float(row["test_mwr"]), abs=1e-12)
        score.setdefault(row["algo"] or row["group"], []).append(mwr)
    assert {k: len(v) for k, v in score.items()} == SCRATCH[version][pair_seed]
    return score


def _pair_section(page: str, pair_seed: int, version: str) -> str:
    """docs/reproduce.md's section on one from-scratch pair seed of one protocol version: from its bold paragraph
    to the next of that version (or to the next heading)."""
    opening = SECTION[version]
    start = page.index(opening.format(pair_seed))
    ends = [i for i in (page.find(opening.split("{}")[0], start + 1), page.find("\n### ", start)) if i > 0]
    return page[start:min(ends)]


def _signed(values: list[float]) -> str:
    return ", ".join(f"{v:+.3f}" for v in values)


@pytest.mark.parametrize(("version", "pair_seed"), SCRATCH_PAIRS)
def test_a_from_scratch_reproductions_table_is_recomputed_from_its_committed_matches(version: str,
                                                                                      pair_seed: int) -> None:
    """A from-scratch pair's 2,000-start test: every Bug's and baseline's MWR from its per-match rows, the IQM and
    the rliable interval of the SAC runs from those, and the pair's table on docs/reproduce.md."""
    from rliable import library as rly
    from rliable import metrics as rly_metrics
    from scipy.stats import trim_mean

    score = _scratch_scores(pair_seed, version)
    sac = np.asarray(score["sac"])
    iqm = trim_mean(sac, 0.25)
    compare = json.loads((RUNS / version / f"seed-{pair_seed}" / "compare" / "compare.json").read_text())
    group = next(g for g in compare["groups"] if g["group"] == "sac")
    assert group["iqm"] == pytest.approx(iqm, abs=1e-12)
    estimates, intervals = rly.get_interval_estimates({"sac": sac[:, None]}, lambda x: np.array(
        [rly_metrics.aggregate_iqm(x)]), reps=2000, confidence_interval_size=0.95)
    assert estimates["sac"][0] == pytest.approx(iqm)
    assert abs(intervals["sac"][0, 0] - group["lo"]) < 0.05 and abs(intervals["sac"][1, 0] - group["hi"]) < 0.05

    section = _pair_section((ROOT / "docs" / "reproduce.md").read_text(), pair_seed, version)
    sac_line = next(x for x in section.splitlines() if x.strip().startswith("| SAC, seeds 0-4 |"))
    assert _signed(score["sac"]) in sac_line
    assert f"IQM {iqm:+.3f} [{group['lo']:+.3f}, {group['hi']:+.3f}]" in sac_line
    if "ddpg" in score:
        ddpg_line = next(x for x in section.splitlines() if x.strip().startswith("| DDPG (paper preset), seeds 0-2 |"))
        assert _signed(score["ddpg"]) in ddpg_line and f"mean {np.mean(score['ddpg']):+.3f}" in ddpg_line
    for baseline in ("passive", "random"):
        assert f"| {baseline} | {score[baseline][0]:+.3f} |" in section


@pytest.mark.parametrize("version", HEADLINES)
def test_the_from_scratch_headline_is_recomputed_from_every_pairs_committed_matches(version: str) -> None:
    """The headline over the (pair, seed) runs of every pair that made a contest: SAC's IQM over the runs as a
    (seeds, pairs) matrix, its stratified-bootstrap interval (rliable's, drawing seeds within each pair), the
    share of runs at +0.15 or more, each pair's passive baseline, and the figures on docs/reproduce.md and the
    README."""
    from rliable import library as rly
    from rliable import metrics as rly_metrics

    pairs = sorted(SCRATCH[version])
    scores = {seed: _scratch_scores(seed, version) for seed in pairs}
    matrix = np.array([scores[seed]["sac"] for seed in pairs]).T
    assert matrix.shape == (5, len(pairs)) and matrix.size >= 10
    iqm = float(rly_metrics.aggregate_iqm(matrix))
    headline = json.loads((RUNS / version / "headline" / "compare.json").read_text())
    assert headline["tasks"] == "folder" and headline["by"] == "algo"
    assert [Path(f).parent.name for f in headline["config"]["folders"]] == [f"seed-{s}" for s in pairs]
    sac = next(g for g in headline["groups"] if g["group"] == "sac")
    assert sac["iqm"] == pytest.approx(iqm, abs=1e-12) and sac["n_seeds"] == matrix.size
    np.random.seed(0)  # noqa: NPY002 (rliable's bootstrap draws from numpy's global generator)
    _, ci = rly.get_interval_estimates({"sac": matrix}, lambda x: np.array([rly_metrics.aggregate_iqm(x)]),
                                       reps=5000)
    assert abs(ci["sac"][0, 0] - sac["lo"]) < 0.03 and abs(ci["sac"][1, 0] - sac["hi"]) < 0.03
    passive = next(g for g in headline["groups"] if g["group"] == "passive")
    assert passive["scores"] == pytest.approx([scores[s]["passive"][0] for s in pairs])
    share = float(np.mean(matrix >= 0.15))
    figures = f"IQM {iqm:+.3f} [{sac['lo']:+.3f}, {sac['hi']:+.3f}]"
    for page in (ROOT / "docs" / "reproduce.md", ROOT / "README.md"):
        text = " ".join(page.read_text().split())
        assert f"{figures} over the {matrix.size} (pair, seed) runs" in text, page
        assert f"{round(100 * share)}% of runs at +0.15 or more" in text, page
        for seed in pairs:
            assert f"pair {seed}: passive Bug {scores[seed]['passive'][0]:+.3f}" in text, page
