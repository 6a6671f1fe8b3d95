"""Self-play training (``--self-play``): learners against pools of their own snapshots and the zoo.

Tiny runs (4 matches of 150 steps at once, 16-unit networks, a few seconds each): snapshots
are admitted and rated, seats are drawn from the pools, resume equals uninterrupted, and bad
self-play configs fail naming the field. Both sides of the 2-vs-1 learning in one run: 2
matches of 20 steps at once, started 1.7 m from the centre so that quadrupeds leave the ring
within 20 steps (wins, hence admissions, on both sides).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from triplesumo.agents.policy_file import load_policy
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.cli import main
from triplesumo.evaluation.tournament import TournamentConfig, league_entries, parse_entries, run_tournament
from triplesumo.model.specs import PhysicsConfig
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig
from triplesumo.train.league import League
from triplesumo.train.league_config import LeagueConfig
from triplesumo.train.loop import Trainer, train
from triplesumo.train.run_folder import config_from_json, config_to_json, run_id_of

SAC = SACConfig(hidden=(16, 16), buffer_size=4000, learning_starts=600, batch_size=16, learn_every=16)
LEAGUE = LeagueConfig(threshold=0.0, window=2, snapshot_every=2, max_size=3)
"""Admit at every even epoch whose last two matches hold a win: in 150 steps a random
quadruped often walks itself out of the ring, so a still learner wins."""


def tiny(out: Path, name: str, **fields: Any) -> TrainConfig:
    values: dict[str, Any] = {
        "name": name, "out": str(out), "epochs": 8, "steps_per_epoch": 150, "n_envs": 4,
        "checkpoint_every": 4, "seed": 3, "sac": SAC, "progress": False, "tensorboard": False,
        "self_play": True, "league": LEAGUE,
    }
    return TrainConfig(**(values | fields))


SPIDER = {"learn": ("spider=sac",), "policies": ("ant=random", "bug=random")}
FFA = {"scenario": "ffa", "learn": ("ant=sac",), "policies": ("*=random",), "obs_mode": "egocentric"}
"""One network takes every seat, so it reads each seat's own (egocentric) vector."""


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def assert_same_league(a: League, b: League) -> None:
    """``a`` and ``b`` hold the same league: members, ratings, windows, generator, and the same snapshot
    weights (by digest). A snapshot's manifest names the legs of the run so far (which session wrote it),
    so a resumed run's later snapshots name one leg more: the manifests are compared less ``legs``."""
    def weights_only(state: dict[str, Any]) -> dict[str, Any]:
        out = json.loads(json.dumps(state))
        for pool in out["pools"].values():
            for m in (*pool["members"], *pool["evicted"]):
                m["sha256"] = {f: d for f, d in m["sha256"].items() if not f.endswith(".json")}
        return out

    assert weights_only(a.state_dict()) == weights_only(b.state_dict())
    manifests = [rel for pool in a.pools.values() for m in (*pool.members, *pool.evicted)
                 for rel in m.sha256 if rel.endswith(".json")]
    assert manifests  # (the runs compared admit snapshots)
    for rel in manifests:
        x, y = (json.loads((league.root / rel).read_text()) for league in (a, b))
        assert {k: v for k, v in x.items() if k != "legs"} == {k: v for k, v in y.items() if k != "legs"}, rel


@pytest.mark.slow  # 13 s alone on the shared 2-core box
def test_spider_learns_against_the_team_pool_and_its_snapshots_join_its_own(tmp_path: Path) -> None:
    trainer = Trainer(tiny(tmp_path, "spider", **SPIDER))
    trainer.run()
    league = trainer.seats.league
    assert league is not None
    team, spider = league.pools["team"], league.pools["spider"]
    # the team seats come from the team pool, seeded from --policies (ant=random, bug=random)
    assert [m.policies for m in team.members] == [{"ant": "random", "bug": "random"}]
    assert {tuple(seats) for seats in trainer.seats.members} == {("team-0001", "team-0001", None)}
    assert team.members[0].games >= 8
    # the Spider learner's snapshots were admitted (its pool started empty) and are policy files
    assert len(spider) >= 2 and all(m.source == "self" for m in spider.members)
    snap = spider.members[-1]
    net, manifest = load_policy(league.root / snap.policies["spider"])
    assert manifest["algo"] == "sac" and manifest["seed"] == 3 and manifest["epochs"] == snap.epoch
    assert manifest["league_member"] == snap.id and "--self-play" in manifest["command"]
    # ratings moved: the learner's uncertainty shrank from the prior's
    me = league.ratings[League.learner("spider")]
    assert me.sigma < 25 / 3 - 1
    log = rows(league.root / "league.csv")
    assert [int(r["epoch"]) for r in log if r["side"] == "spider"] == list(range(1, trainer.collector.epochs_done + 1))
    assert sum(int(r["admitted"]) for r in log if r["side"] == "spider") == len(spider) + len(spider.evicted)
    assert (trainer.run_dir / "plots" / "league.png").stat().st_size > 10_000
    assert json.loads((league.root / "pool.json").read_text())["pools"]["spider"]["members"][-1]["id"] == snap.id


@pytest.mark.slow  # 27 s alone on the shared 2-core box
def test_ffa_learner_meets_its_own_snapshots_in_the_other_seats(tmp_path: Path) -> None:
    trainer = Trainer(tiny(tmp_path, "ffa", **FFA))
    trainer.run()
    league = trainer.seats.league
    assert league is not None and list(league.pools) == ["ffa"]
    pool = league.pools["ffa"]
    assert pool.members[0].source == "zoo" and pool.members[0].policies == {"ffa": "random"}
    assert len(pool) + len(pool.evicted) >= 2  # the seed and at least one snapshot
    assert len(pool) <= LEAGUE.max_size and pool.members[0].id == "ffa-0001"  # FIFO keeps the first
    met = [m for m in (*pool.members, *pool.evicted) if m.source == "self" and m.games > 0]
    assert met, "no admitted snapshot was ever drawn to play"
    for seats in trainer.seats.members:
        assert seats[0] is None and all(s is not None for s in seats[1:])
    assert league.ratings[League.learner("ffa")].mu != 25.0
    # The run's snapshots in a free-for-all tournament of their own (--league RUN): the first and the
    # last by epoch, named by member id, each in every seat, rated against the epochs they had trained.
    own = sorted((m for m in (*pool.members, *pool.evicted) if m.source == "self"), key=lambda m: m.epoch)
    cfg = TournamentConfig(scenario="ffa", obs_mode="egocentric", league=str(trainer.run_dir), league_snapshots=2,
                           policies=("passive=passive", "random=random", f"final={trainer.run_dir / 'policy'}"),
                           rounds=1, steps_per_epoch=60,
                           out=str(tmp_path / "ladder"), n_envs=6, n_threads=1, progress=False)
    entries = dict(p.split("=", 1) for p in cfg.resolved().policies)
    expected = sorted({own[0].id, own[-1].id, "passive", "random", "final"})
    assert sorted(entries) == expected and entries[own[-1].id] == str(league.root / own[-1].policies["ffa"])
    results = run_tournament(cfg)
    assert results["n_matches"] == len(expected) * (len(expected) - 1) * (len(expected) - 2)  # every seat
    board = {e["policy"]: e for e in results["leaderboard"]}
    assert board[own[-1].id]["epochs"] == own[-1].epoch and board[own[-1].id]["trained"] == "ant"
    assert board["passive"]["epochs"] is None and board["passive"]["run"] is None
    # one line on the ladder: the snapshots and the run's own policy
    assert board[own[0].id]["run"] == board[own[-1].id]["run"] == board["final"]["run"] == trainer.record.run_id
    # a copy of the run's policy outside the run folder still names the run (the run_id of its manifest)
    from triplesumo.evaluation.tournament import _run_of
    (tmp_path / "copied").mkdir()
    for suffix in (".json", ".safetensors"):
        shutil.copyfile(trainer.run_dir / f"policy{suffix}", tmp_path / "copied" / f"policy{suffix}")
    assert _run_of(str(tmp_path / "copied" / "policy"), load_policy(tmp_path / "copied" / "policy")[1]) \
        == trainer.record.run_id
    assert (tmp_path / "ladder" / "ladder.png").stat().st_size > 10_000
    with pytest.raises(ValueError, match=rf"entries \['{own[0].id}'\] clash with the snapshots"):
        dataclasses.replace(cfg, policies=(f"{own[0].id}=passive", "random=random")).resolved()
    with pytest.raises(FileNotFoundError, match="no self-play league in"):
        dataclasses.replace(cfg, league=str(tmp_path)).resolved()


def test_pursuit_evader_against_the_pursuers_pool(tmp_path: Path) -> None:
    cfg = tiny(tmp_path, "pursuit", scenario="pursuit", learn=("evader=sac",), epochs=4, tensorboard=True,
               policies=("*=random",), league=LeagueConfig(zoo=("pursuer_0=passive", "pursuer_1=random",
                                                                "pursuer_2=passive")))
    trainer = Trainer(cfg)
    trainer.run()
    league = trainer.seats.league
    assert league is not None
    assert [m.policies for m in league.pools["pursuers"].members] == [
        {"pursuer_0": "passive", "pursuer_1": "random", "pursuer_2": "passive"}]
    assert {tuple(s) for s in trainer.seats.members} == {("pursuers-0001",) * 3 + (None,)}
    assert league.pools["pursuers"].members[0].games == 4
    # the manifest names the pool's seeds, not the --policies they replaced
    assert load_policy(trainer.run_dir / "policy")[1]["trained_against"] == [
        "pursuer_0=passive", "pursuer_1=random", "pursuer_2=passive"]
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(trainer.run_dir / "tensorboard"))
    events.Reload()
    sizes = [e.value for e in events.Scalars("league/pursuers/pool_size")]
    assert len(sizes) == trainer.collector.epochs_done and set(sizes) == {1.0}
    assert len(events.Scalars("league/evader/learner_mu")) == trainer.collector.epochs_done


@pytest.mark.slow  # 50 s alone on the shared 2-core box
def test_resume_restores_the_league_exactly(tmp_path: Path) -> None:
    command = "triplesumo train --self-play"  # the same in both runs' manifests (it names --epochs otherwise)
    full = Trainer(tiny(tmp_path / "a", "run", **FFA), command=command)
    full.run()
    half_cfg = tiny(tmp_path / "b", "run", epochs=4, **FFA)
    half = Trainer(half_cfg, command=command)
    half.run()
    assert half.seats.league is not None and len(half.seats.league.pools["ffa"]) >= 2  # admitted before the checkpoint
    resumed = Trainer(dataclasses.replace(half_cfg, epochs=8), run_dir=tmp_path / "b/run", resume=True,
                      command=command)
    resumed.run()
    assert full.seats.league is not None and resumed.seats.league is not None
    assert_same_league(full.seats.league, resumed.seats.league)
    assert full.seats.members == resumed.seats.members
    assert (tmp_path / "a/run/league/league.csv").read_text() == (tmp_path / "b/run/league/league.csv").read_text()
    last = checkpoint.latest(tmp_path / "a/run")
    assert last.name == checkpoint.latest(tmp_path / "b/run").name
    with np.load(last / "arrays.npz") as x, np.load(tmp_path / "b/run/checkpoints" / last.name / "arrays.npz") as y:
        for key in x.files:
            assert np.array_equal(x[key], y[key]), key


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_resume_through_train_and_config_round_trip(tmp_path: Path) -> None:
    cfg = tiny(tmp_path, "rt", epochs=2, checkpoint_every=2, **SPIDER)
    assert config_from_json(config_to_json(cfg)) == cfg
    old = {k: v for k, v in config_to_json(cfg).items() if k not in ("self_play", "league")}
    assert config_from_json(old).self_play is False
    train(cfg)
    result = train(cfg, resume_dir=tmp_path / "rt", overrides={"epochs": 4})
    assert result.epochs >= 4
    assert int(rows(tmp_path / "rt/league/league.csv")[-1]["epoch"]) == result.epochs


@pytest.mark.parametrize(("fields", "message"), [
    ({"scenario": "ffa", "learn": ("ant=sac", "bug=sac")}, "free-for-all"),
    ({"scenario": "ffa", "learn": ("ant=sac",)}, "cannot tell which body it drives; use obs_mode 'egocentric'"),
    ({"learn": ("spider=sac",), "league": LeagueConfig(zoo=("ant=random",))},
     "TrainConfig.league: LeagueConfig.zoo names roles ['ant'] of side 'team' but not ['bug']"),
    ({"learn": ("spider=sac",), "league": LeagueConfig(zoo=("beetle=random",))}, "TrainConfig.league"),
])
def test_bad_self_play_configs_name_the_problem(tmp_path: Path, fields: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        Trainer(tiny(tmp_path, "bad", **({"policies": ("*=random",)} | fields)))


def test_league_options_without_self_play_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="TrainConfig.league is set .* add --self-play"):
        tiny(tmp_path, "off", self_play=False, **SPIDER)
    assert tiny(tmp_path, "off", self_play=False, league=LeagueConfig(), **SPIDER).self_play is False


def test_cli_parses_self_play_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "--self-play", "--league.threshold", "2", "--out", str(tmp_path)]) != 0
    assert "LeagueConfig.threshold" in capsys.readouterr().err
    assert main(["train", "--self-play", "--league.side-draw-score", "spider=2", "--out", str(tmp_path)]) != 0
    assert "LeagueConfig.side_draw_score" in capsys.readouterr().err
    cfg = tiny(tmp_path, "sides", league=LeagueConfig(draw_score=0.5, side_draw_score=("spider=0",)), **SPIDER)
    assert config_from_json(config_to_json(cfg)).league.side_draw_score == ("spider=0",)
    saved = config_to_json(cfg)
    del saved["league"]["side_draw_score"]  # a config.json written before the option existed
    assert config_from_json(saved).league.side_draw_score == ()
    assert main(["train", "--self-play", "--league.side-threshold", "team=1", "--out", str(tmp_path)]) != 0
    assert "LeagueConfig.side_threshold" in capsys.readouterr().err
    cfg = tiny(tmp_path, "own", league=LeagueConfig(side_threshold=("team=0.3",)), **SPIDER)
    assert config_from_json(config_to_json(cfg)).league.side_threshold == ("team=0.3",)
    saved = config_to_json(cfg)
    del saved["league"]["side_threshold"]
    assert config_from_json(saved).league.side_threshold == ()


# ------------------------------------------------------------- both sides learn in one run
BOTH_LEAGUE = LeagueConfig(threshold=0.0, window=2, snapshot_every=2, max_size=3, live_share=0.5)
DDPG = DDPGConfig(hidden=(16, 16), buffer_size=4000, learning_starts=40, batch_size=8, learn_every=8)
BOTH_COMMAND = ("triplesumo train --self-play --learn ant=ddpg bug=ddpg spider=ddpg --share team "
                "--obs-mode egocentric")


def both(out: Path, epochs: int = 16) -> TrainConfig:
    return TrainConfig(name="both", out=str(out), epochs=epochs, steps_per_epoch=20, n_envs=2, checkpoint_every=8,
                       seed=3, ddpg=DDPG, progress=False, tensorboard=False, self_play=True, league=BOTH_LEAGUE,
                       learn=("ant=ddpg", "bug=ddpg", "spider=ddpg"), share="team", obs_mode="egocentric",
                       physics=PhysicsConfig(layout="circle", start_radius=1.7))


@pytest.fixture(scope="module")
def both_run(tmp_path_factory: pytest.TempPathFactory) -> Trainer:
    trainer = Trainer(both(tmp_path_factory.mktemp("both")), command=BOTH_COMMAND)
    trainer.run()
    return trainer


@pytest.mark.slow  # 20 s alone on the shared 2-core box
def test_both_sides_learn_against_each_other_and_each_others_pools(both_run: Trainer) -> None:
    league, run = both_run.seats.league, both_run.run_dir
    assert league is not None and both_run.collector.epochs_done == 16
    for side, role in (("team", "ant"), ("spider", "spider")):
        pool = league.pools[side]
        assert pool.members and all(m.source == "self" for m in (*pool.members, *pool.evicted)), side
        _, manifest = load_policy(league.root / pool.members[0].policies[role])
        assert manifest["league_member"] == pool.members[0].id and manifest["side"] == side
        me = league.ratings[League.learner(side)]
        assert me.mu != 25.0 and me.sigma < 25 / 3 - 1, side
    # a match is live (both learners) or one learner against the other side's pool: every pool match is one
    # member's game, and the learner whose seats the member took wrote no metrics row for it
    pool_matches = sum(m.games for p in league.pools.values() for m in (*p.members, *p.evicted))
    team_rows, spider_rows = (rows(run / f"metrics-{a}.csv") for a in ("ant", "spider"))
    assert rows(run / "metrics-bug.csv") and len(rows(run / "metrics-bug.csv")) == len(team_rows)
    assert 0 < pool_matches < 16 and len(team_rows) < 16 and len(spider_rows) < 16
    assert len(team_rows) + len(spider_rows) == 16 + (16 - pool_matches)
    for table in (team_rows, spider_rows):  # each agent's own matches, in order
        assert [int(r["epoch"]) for r in table] == list(range(1, len(table) + 1))
        steps = [int(r["env_steps"]) for r in table]
        assert steps == sorted(steps)
    for learner in ("ant+bug", "spider"):  # learning rows: one per match of the run
        assert len(rows(run / f"learning-{learner}.csv")) == 16
    log = rows(league.root / "league.csv")
    assert [(int(r["epoch"]), r["side"]) for r in log] == [(e, s) for e in range(1, 17) for s in ("team", "spider")]
    assert (run / "plots" / "league.png").stat().st_size > 10_000


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_a_side_with_a_fixed_agent_learns_and_sits_out_only_its_learners_seats(tmp_path: Path) -> None:
    """The contest's stage 1 (docs/CONTEST.md): Ant and Spider learn, Bug stays passive, and each learner meets
    a still opponent (its pool's seed) in part of its matches. The team's pool holds Ant's role only; when the
    team sits a match out its member takes Ant's seat and Bug keeps its fixed policy (random here, so that it
    shows); a learner writes metrics
    rows only for the matches it played, and a snapshot of the team is Ant's actor."""
    league = LeagueConfig(threshold=0.0, window=2, snapshot_every=4, max_size=3, live_share=0.25, draw_score=0.5,
                          zoo=("ant=passive", "spider=passive"), keep_zoo=True, zoo_share=1.0)
    cfg = TrainConfig(name="stage1", out=str(tmp_path), epochs=16, steps_per_epoch=20, n_envs=2, checkpoint_every=8,
                      seed=5, ddpg=DDPG, progress=False, tensorboard=False, self_play=True, league=league,
                      learn=("ant=ddpg", "spider=ddpg"), policies=("bug=random",))
    trainer = Trainer(cfg)
    assert trainer.seats.sides == {"team": ["ant"], "spider": ["spider"]}
    assert trainer.seats.learning_sides == ["team", "spider"] and trainer.seats.opponent_sides == []
    seen: list[list[str | None]] = []
    draw = trainer.seats.draw

    def spy(k: int) -> None:
        draw(k)
        seen.append(list(trainer.seats.members[k]))
    trainer.seats.draw = spy  # type: ignore[method-assign]
    roster = list(trainer.seats.probe.agents)
    ant, bug, spider = (roster.index(a) for a in ("ant", "bug", "spider"))
    bug_acts: list[np.ndarray] = []
    env = trainer.collector.env
    step = env.step

    def record(actions: np.ndarray) -> Any:
        bug_acts.append(np.array(actions[:, bug]))
        return step(actions)
    env.step = record  # type: ignore[method-assign]
    trainer.run()
    assert seen and all(m[bug] is None for m in seen)  # Bug is never a member's seat: it plays its own policy
    assert all(np.abs(a).max() > 0.1 for a in bug_acts)  # (random, in every match: the league does not silence it)
    pool_ant = [m for m in seen if m[ant] is not None]
    pool_spider = [m for m in seen if m[spider] is not None]
    assert pool_ant and pool_spider and all(m[spider] is None for m in pool_ant)  # one side sits out at a time
    assert {m[ant] for m in pool_ant} <= {"team-0001"} and {m[spider] for m in pool_spider} <= {"spider-0001"}
    run = trainer.run_dir
    ant_rows, spider_rows = (rows(run / f"metrics-{a}.csv") for a in ("ant", "spider"))
    assert trainer.seats.league is not None
    pools = trainer.seats.league.pools
    pool_matches = sum(m.games for p in pools.values() for m in (*p.members, *p.evicted))
    assert 0 < pool_matches < 16 and len(ant_rows) + len(spider_rows) == 16 + (16 - pool_matches)
    assert len(ant_rows) < 16 and len(spider_rows) < 16
    team = pools["team"]
    assert team.roles == ("ant",) and pools["spider"].roles == ("spider",)
    snapshots = [m for m in team.members if m.source == "self"]
    assert snapshots and set(snapshots[0].policies) == {"ant"}
    _, manifest = load_policy(trainer.seats.league.root / snapshots[0].policies["ant"])  # (a snapshot: no zoo seeds)
    assert manifest["role"] == "ant" and manifest["side"] == "team"


def test_live_or_pool_draws_follow_live_share(tmp_path: Path) -> None:
    sides = {"team": ("ant", "bug"), "spider": ("spider",)}
    seeded = LeagueConfig(live_share=0.35, zoo=("ant=random", "bug=random", "spider=passive"))
    league = League(tmp_path / "a", seeded, sides, seed=1)
    n = 20_000
    draws = [tuple(league.draw_live(["team", "spider"])) for _ in range(n)]
    share = {d: draws.count(d) / n for d in set(draws)}
    assert set(share) == {("team", "spider"), ("team",), ("spider",)}
    tol = 4 * (0.25 / n) ** 0.5  # 4 binomial standard deviations at most
    assert abs(share[("team", "spider")] - 0.35) < tol
    assert abs(share[("team",)] - 0.325) < tol and abs(share[("spider",)] - 0.325) < tol
    # empty pools: live until a side has members; then only the other side plays against it
    fresh = League(tmp_path / "b", LeagueConfig(live_share=0.0), sides, seed=1)
    assert all(fresh.draw_live(["team", "spider"]) == ["team", "spider"] for _ in range(50))
    fresh.admit("spider", 1, builtin={"spider": "passive"})
    assert all(fresh.draw_live(["team", "spider"]) == ["team"] for _ in range(50))
    # one learning side: no draw (the league's generator is untouched)
    before = league.rng.bit_generator.state
    assert league.draw_live(["spider"]) == ["spider"] and league.rng.bit_generator.state == before
    with pytest.raises(ValueError, match="LeagueConfig.live_share"):
        LeagueConfig(live_share=1.5)
    # a config.json written before live_share existed reads with its default
    saved = config_to_json(tiny(tmp_path, "old", **SPIDER))
    del saved["league"]["live_share"]
    assert config_from_json(saved).league.live_share == LeagueConfig().live_share


@pytest.mark.slow  # 24 s alone on the shared 2-core box
def test_both_sides_resume_restores_both_pools_and_learners_exactly(both_run: Trainer, tmp_path: Path) -> None:
    half = Trainer(both(tmp_path, epochs=8), command=BOTH_COMMAND)
    half.run()
    assert half.seats.league is not None and half.seats.league.pools["spider"].members  # admitted before the checkpoint
    resumed = Trainer(both(tmp_path, epochs=16), run_dir=tmp_path / "both", resume=True, command=BOTH_COMMAND)
    resumed.run()
    assert both_run.seats.league is not None and resumed.seats.league is not None
    assert_same_league(both_run.seats.league, resumed.seats.league)
    assert both_run.seats.members == resumed.seats.members
    a, b = both_run.run_dir, resumed.run_dir
    assert (a / "league/league.csv").read_text() == (b / "league/league.csv").read_text()
    for name in ("metrics-ant.csv", "metrics-spider.csv", "learning-ant+bug.csv", "learning-spider.csv"):
        strip = [{k: v for k, v in r.items() if k != "wall_time"} for r in rows(a / name)]
        assert strip == [{k: v for k, v in r.items() if k != "wall_time"} for r in rows(b / name)], name
    last = checkpoint.latest(a)
    with np.load(last / "arrays.npz") as x, np.load(b / "checkpoints" / last.name / "arrays.npz") as y:
        for key in x.files:
            assert np.array_equal(x[key], y[key]), key
    for learner in ("ant+bug", "spider"):
        assert (a / f"policy-{learner}.safetensors").read_bytes() == (b / f"policy-{learner}.safetensors").read_bytes()
    # one run id: its policies and every league snapshot (admitted before the checkpoint or after the
    # resume) name the id the run started with, the uninterrupted run's (the same experiment); another seed
    # is another run
    ids = {load_policy(b / f"policy-{learner}")[1]["run_id"] for learner in ("ant+bug", "spider")}
    ids |= {load_policy(resumed.seats.league.root / stem)[1]["run_id"]
            for pool in resumed.seats.league.pools.values() for m in (*pool.members, *pool.evicted)
            for stem in m.policies.values()}
    assert ids == {half.record.run_id} == {resumed.record.run_id} == {both_run.record.run_id}
    assert run_id_of(dataclasses.replace(both_run.cfg, seed=1)) != both_run.record.run_id
    assert run_id_of(dataclasses.replace(both_run.cfg, epochs=99, out="elsewhere")) == both_run.record.run_id


@pytest.mark.slow  # uses the module's both_run fixture, 38 s to build
def test_league_entries_of_a_two_sided_run_name_each_role_of_a_team_snapshot(both_run: Trainer) -> None:
    """``--league RUN --league-snapshots 2``: each side's first and last own snapshot by epoch, a team
    member as one entry per role."""
    assert both_run.seats.league is not None
    expected: dict[str, str] = {}
    for side, pool in both_run.seats.league.pools.items():
        own = sorted((m for m in (*pool.members, *pool.evicted) if m.source == "self"), key=lambda m: m.epoch)
        assert own, side
        for m in {m.id: m for m in (own[0], own[-1])}.values():  # one snapshot: itself
            for role, stem in m.policies.items():
                expected[m.id if side == "spider" else f"{m.id}.{role}"] = str(both_run.seats.league.root / stem)
    assert league_entries(both_run.run_dir, 2) == expected
    assert league_entries(both_run.seats.league.root, 2) == expected  # the league folder itself works too
    assert any(n.endswith(".ant") for n in expected) and any(n.endswith(".bug") for n in expected)


@pytest.mark.slow  # uses the module's both_run fixture, 38 s to build
def test_league_until_picks_only_the_snapshots_that_joined_by_then(both_run: Trainer) -> None:
    """``--league-until EPOCH``: the picks of the run as it stood at EPOCH, so a table made before the run
    was resumed names the same snapshots after it; an epoch before the first snapshot is an error."""
    assert both_run.seats.league is not None
    firsts = {}
    for side, pool in both_run.seats.league.pools.items():
        own = sorted((m for m in (*pool.members, *pool.evicted) if m.source == "self"), key=lambda m: m.epoch)
        firsts[side] = own[0]
    until = min(m.epoch for m in firsts.values())
    picked = league_entries(both_run.run_dir, 8, until)
    assert picked and all(n.split(".")[0] in {m.id for m in firsts.values() if m.epoch <= until} for n in picked)
    assert league_entries(both_run.run_dir, 8, 10**9) == league_entries(both_run.run_dir, 8)
    assert len(league_entries(both_run.run_dir, 8)) > len(picked)
    assert until > 1
    with pytest.raises(ValueError, match=f"own yet that joined at or before epoch {until - 1}$"):
        league_entries(both_run.run_dir, 8, until - 1)
    cfg = TournamentConfig(league=str(both_run.run_dir), league_until=until, policies=("p=passive",)).resolved()
    assert cfg.league == "" and cfg.league_until == 0
    assert sorted(parse_entries(cfg.policies)) == sorted(["p", *picked])


@pytest.mark.slow  # uses the module's both_run fixture, 38 s to build
def test_tournament_seats_the_runs_egocentric_networks_and_snapshots_in_every_seat_they_fit(
        both_run: Trainer) -> None:
    """Egocentric vectors are the seat's own, so a network (the team's shared one, its snapshots, the
    Spider's) fits every seat of the same sizes and as many partners as it was trained with (their blocks
    come first: a team network would read the Spider's first opponent as its partner); with ``paper``
    ones it would not."""
    from triplesumo.evaluation.tournament import _manifest, eligible_seats

    assert both_run.seats.league is not None
    match = both_run.collector.batch.matches[0]
    member = both_run.seats.league.pools["team"].members[0]
    for stem, seats in ((both_run.run_dir / "policy-ant+bug", ["ant", "bug"]),
                        (both_run.seats.league.root / member.policies["bug"], ["ant", "bug"]),
                        (both_run.run_dir / "policy-spider", ["spider"])):
        manifest = _manifest(str(stem))
        assert manifest is not None and manifest["obs_mode"] == "egocentric"
        assert eligible_seats(str(stem), manifest, match) == seats, stem
        assert manifest["partners"] == len(seats) - 1  # the trained seat's partners, recorded at training
        other_roster = manifest | {"agents": ["a", "b", "c"]}  # the default roster no longer says; the key does
        assert eligible_seats(str(stem), other_roster, match) == seats, stem
        assert eligible_seats(str(stem), manifest | {"partners": 2}, match) == [], stem
        assert eligible_seats(str(stem), manifest | {"obs_mode": "paper"}, match) == [], stem  # another mode
