"""Self-play leagues: admission threshold, sampling frequencies, size limit, exact resume, config
errors, and a tiny scripted 2-vs-1 league played through the match runner."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.stats import chisquare

from triplesumo.agents.frozen import FrozenPolicy
from triplesumo.agents.networks import Actor
from triplesumo.agents.policy_file import PolicyFileError, save_policy
from triplesumo.evaluation.ratings import Rating, RatingTable
from triplesumo.train.league import League
from triplesumo.train.league_config import LeagueConfig
from triplesumo.train.league_plots import (
    league_demo,
    league_figure,
    member_labels,
    member_ticks,
    plot_league,
    spec_label,
)

SIDES = {"team": ("ant", "bug"), "spider": ("spider",)}
SEEDED = ("ant=random", "bug=random", "spider=random")
TEAM = League.learner("team")
SPIDER = League.learner("spider")


def league(tmp_path: Path, **kw: object) -> League:
    cfg = LeagueConfig(**{"zoo": SEEDED, "snapshot_every": 1, **kw})  # type: ignore[arg-type]
    return League(tmp_path, cfg, SIDES, seed=7)


def play(lg: League, results: list[str]) -> None:
    """The team learner's matches against spider-0001, ``win``/``loss``/``draw`` from the team's side."""
    other = {"win": "loss", "loss": "win", "draw": "draw"}
    for r in results:
        lg.record_outcomes([[TEAM], ["spider-0001"]], [r, other[r]])


def as_json(state: dict[str, object]) -> object:
    return json.loads(json.dumps(state))


def write_actor(seed: int, obs_dim: int = 5, act_dim: int = 3):  # type: ignore[no-untyped-def]
    def write(stems: dict[str, Path]) -> None:
        for k, (role, stem) in enumerate(stems.items()):
            torch.manual_seed(seed + k)
            save_policy(stem, Actor(obs_dim, act_dim, (8,)), {"agent": role, "obs_mode": "paper"})
    return write


def test_a_snapshot_is_admitted_exactly_when_the_window_win_rate_passes_the_threshold(tmp_path: Path) -> None:
    lg = league(tmp_path, threshold=0.6, window=10)
    play(lg, ["win"] * 9)
    assert not lg.admit_due("team", 1)  # 9 of 9 but the window is not full
    lg.pools["team"].window.clear()
    play(lg, ["loss"] * 4 + ["win"] * 6)
    assert lg.pools["team"].win_rate == pytest.approx(0.6)
    assert not lg.admit_due("team", 1)  # 0.6 does not pass 0.6
    play(lg, ["win"])  # the oldest loss leaves the window: 0.7
    assert lg.pools["team"].win_rate == pytest.approx(0.7)
    assert lg.admit_due("team", 1)
    assert not lg.admit_due("spider", 1)  # the Spider learner has played nothing
    snap = lg.admit("team", 1, write=write_actor(3))
    assert snap.id == "team-0002" and snap.source == "self" and snap.epoch == 1
    assert [m.id for m in lg.pools["team"].members] == ["team-0001", "team-0002"]
    assert lg.ratings[snap.id] == lg.ratings[TEAM]  # a snapshot starts where its learner stands
    assert len(lg.pools["team"].window) == 0 and not lg.admit_due("team", 1)
    # its files are in the run folder, checksummed, and play as the actor that was written
    assert set(snap.sha256) == {f"members/team-0002/{r}.{s}" for r in ("ant", "bug") for s in ("json", "safetensors")}
    policies = lg.policies(snap)
    assert isinstance(policies["ant"], FrozenPolicy)
    torch.manual_seed(3)
    actor = Actor(5, 3, (8,))
    obs = np.linspace(-1, 1, 5).astype(np.float32)
    np.testing.assert_allclose(policies["ant"](obs), actor(torch.as_tensor(obs)).detach().numpy(), atol=1e-5)
    assert json.loads((tmp_path / "league" / "pool.json").read_text())["pools"]["team"]["members"][1]["id"] == snap.id


def test_a_draw_counts_draw_score_in_the_window_so_a_league_of_draws_can_start(tmp_path: Path) -> None:
    strict = league(tmp_path / "strict", threshold=0.4, window=10)
    play(strict, ["draw"] * 8 + ["win"] * 2)
    assert strict.pools["team"].win_rate == pytest.approx(0.2) and not strict.admit_due("team", 1)
    half = league(tmp_path / "half", threshold=0.4, window=10, draw_score=0.5)
    play(half, ["draw"] * 8 + ["win"] * 2)
    assert half.pools["team"].win_rate == pytest.approx(0.6) and half.admit_due("team", 1)
    play(half, ["loss"] * 10)
    assert half.pools["team"].win_rate == 0.0  # a loss adds nothing
    half.pools["team"].window.extend([0.5, 1, 0.5])
    again = league(tmp_path / "half", threshold=0.4, window=10, draw_score=0.5)
    again.load_state_dict(as_json(half.state_dict()))
    assert list(again.pools["team"].window) == list(half.pools["team"].window)


def test_a_side_can_score_its_draws_apart_from_the_others(tmp_path: Path) -> None:
    lg = league(tmp_path, threshold=0.4, window=10, draw_score=0.5, side_draw_score=("spider=0",))
    assert lg.pools["team"].draw_score == 0.5 and lg.pools["spider"].draw_score == 0.0
    for _ in range(8):  # live draws: the team scores them half, the Spider nothing
        lg.record_outcomes([[TEAM], [SPIDER]], ["draw", "draw"])
    for _ in range(2):
        lg.record_outcomes([[TEAM], [SPIDER]], ["loss", "win"])
    assert lg.pools["team"].win_rate == pytest.approx(0.4) and not lg.admit_due("team", 1)
    assert lg.pools["spider"].win_rate == pytest.approx(0.2) and not lg.admit_due("spider", 1)
    again = league(tmp_path, threshold=0.4, window=10, draw_score=0.5, side_draw_score=("team=1",))
    again.record_outcomes([[TEAM], [SPIDER]], ["draw", "draw"])
    assert list(again.pools["team"].window) == [1.0] and list(again.pools["spider"].window) == [0.5]
    with pytest.raises(ValueError, match="side_draw_score names sides this run has not"):
        League(tmp_path / "x", LeagueConfig(side_draw_score=("ffa=0",)), SIDES)
    lg.save()  # pool.json holds JSON lists; the config read back is the one saved
    assert League.load(tmp_path).config == lg.config and lg.config.draw_score_of("spider") == 0.0


def test_a_side_can_have_its_own_admission_threshold(tmp_path: Path) -> None:
    lg = league(tmp_path, threshold=0.5, window=10, side_threshold=("team=0.25",))
    assert lg.pools["team"].threshold == 0.25 and lg.pools["spider"].threshold == 0.5
    assert lg.config.threshold_of("team") == 0.25 and lg.config.threshold_of("spider") == 0.5
    play(lg, ["win"] * 3 + ["loss"] * 7)  # the team scores 0.3: above its own 0.25, below the others' 0.5
    assert lg.pools["team"].win_rate == pytest.approx(0.3) and lg.admit_due("team", 1)
    plain = league(tmp_path / "plain", threshold=0.5, window=10)
    play(plain, ["win"] * 3 + ["loss"] * 7)
    assert not plain.admit_due("team", 1)
    at = league(tmp_path / "at", threshold=0.5, window=10, side_threshold=("team=0.3",))
    play(at, ["win"] * 3 + ["loss"] * 7)
    assert not at.admit_due("team", 1)  # exactly at its threshold is not above it
    for _ in range(10):  # the Spider's window (its wins) is held to the run's threshold
        lg.record_outcomes([[TEAM], [SPIDER]], ["win", "loss"])
    assert lg.pools["spider"].win_rate == 0.0 and not lg.admit_due("spider", 1)
    with pytest.raises(ValueError, match="side_threshold names sides this run has not"):
        League(tmp_path / "x", LeagueConfig(side_threshold=("ffa=0.3",)), SIDES)
    lg.save()  # pool.json holds JSON lists; the config read back is the one saved
    back = League.load(tmp_path)
    assert back.config == lg.config and back.pools["team"].threshold == 0.25 and back.admit_due("team", 1)
    old = json.loads((tmp_path / "league" / "pool.json").read_text())
    del old["config"]["side_threshold"]  # a pool.json written before the option existed
    (tmp_path / "league" / "pool.json").write_text(json.dumps(old))
    assert League.load(tmp_path).config.side_threshold == ()


def test_admission_is_checked_only_every_snapshot_every_epochs(tmp_path: Path) -> None:
    lg = league(tmp_path, threshold=0.5, window=4, snapshot_every=5)
    play(lg, ["win"] * 4)
    assert [e for e in range(1, 16) if lg.admit_due("team", e)] == [5, 10, 15]


@pytest.mark.parametrize(("sampling", "weighting"), [("uniform", "hard"), ("latest", "hard"), ("pfsp", "hard"),
                                                      ("pfsp", "variance")])
def test_sampling_frequencies_follow_the_documented_weights(tmp_path: Path, sampling: str, weighting: str) -> None:
    lg = league(tmp_path, sampling=sampling, pfsp_weighting=weighting, pfsp_exponent=2.0)
    for k in range(3):
        lg.admit("spider", k + 1, builtin={"spider": "passive"})
    # the team learner's record against each Spider: (games, wins)
    record = [(10, 9), (10, 5), (10, 1), (0, 0)]
    for m, (games, wins) in zip(lg.pools["spider"].members, record, strict=True):
        m.games, m.wins = games, wins
    p = np.array([(w + 1) / (g + 2) for g, w in record])
    expected = {"uniform": np.full(4, 0.25), "latest": np.array([0.0, 0.0, 0.0, 1.0]),
                "pfsp": (1 - p) ** 2 if weighting == "hard" else p * (1 - p)}[sampling]
    expected = expected / expected.sum()
    np.testing.assert_allclose(lg.pools["spider"].weights(), expected)
    n = 8000
    ids = [m.id for m in lg.pools["spider"].members]
    draws = [ids.index(lg.sample("spider")[0].id) for _ in range(n)]
    counts = np.bincount(draws, minlength=4)
    if sampling == "latest":
        assert counts.tolist() == [0, 0, 0, n]
        return
    nonzero = expected > 0
    assert chisquare(counts[nonzero], n * expected[nonzero]).pvalue > 0.001
    if sampling == "pfsp" and weighting == "hard":
        assert counts[2] > counts[1] > counts[0]  # the Spider it loses to most is drawn most


@pytest.mark.parametrize("sampling", ["uniform", "latest", "pfsp"])
def test_zoo_share_gives_the_seeds_a_fixed_share_of_the_draws(tmp_path: Path, sampling: str) -> None:
    lg = league(tmp_path, sampling=sampling, zoo_share=0.4)  # spider-0001: the seeded random Spider
    lg.seed(("spider=passive",), epoch=0)  # spider-0002: a second seed
    for k in range(3):
        lg.admit("spider", k + 1, builtin={"spider": "zero"})  # spider-0003..0005: snapshots
    record = [(0, 0), (0, 0), (10, 9), (10, 5), (10, 1)]
    for m, (games, wins) in zip(lg.pools["spider"].members, record, strict=True):
        m.games, m.wins = games, wins
    p = np.array([(w + 1) / (g + 2) for g, w in record[2:]])
    rule = {"uniform": np.ones(3), "latest": np.array([0.0, 0.0, 1.0]), "pfsp": (1 - p) ** 2}[sampling]
    expected = np.concatenate([[0.2, 0.2], 0.6 * rule / rule.sum()])
    np.testing.assert_allclose(lg.pools["spider"].weights(), expected)
    n = 8000
    ids = [m.id for m in lg.pools["spider"].members]
    counts = np.bincount([ids.index(lg.sample("spider")[0].id) for _ in range(n)], minlength=5)
    nonzero = expected > 0
    assert chisquare(counts[nonzero], n * expected[nonzero]).pvalue > 0.001
    assert abs(counts[:2].sum() / n - 0.4) < 0.03
    # a pool of seeds only (the team's) ignores the share; so does zoo_share 0
    np.testing.assert_allclose(lg.pools["team"].weights(), [1.0])
    plain = league(tmp_path / "plain", sampling="uniform")
    plain.seed(("spider=passive",), epoch=0)
    plain.admit("spider", 1, builtin={"spider": "zero"})
    np.testing.assert_allclose(plain.pools["spider"].weights(), np.full(3, 1 / 3))
    with pytest.raises(ValueError, match="LeagueConfig.zoo_share must be a number in \\[0, 1\\], got 1.5"):
        LeagueConfig(zoo_share=1.5)


def test_sampling_several_seats_draws_distinct_members_while_the_pool_has_enough(tmp_path: Path) -> None:
    lg = league(tmp_path, sampling="uniform")
    lg.admit("spider", 1, builtin={"spider": "passive"})
    for _ in range(50):
        a, b = lg.sample("spider", 2)
        assert a.id != b.id
    assert len(lg.sample("spider", 3)) == 3  # more seats than members: drawn with replacement


def test_size_limit_evicts_fifo_but_keeps_the_first_and_the_best_rated(tmp_path: Path) -> None:
    lg = league(tmp_path, max_size=3)
    for e in (1, 2):
        lg.admit("team", e, write=write_actor(e))
    lg.ratings.set("team-0002", Rating(40.0, 2.0))  # the best-rated member
    assert [m.id for m in lg.pools["team"].members] == ["team-0001", "team-0002", "team-0003"]
    lg.admit("team", 3, write=write_actor(3))
    assert [m.id for m in lg.pools["team"].members] == ["team-0001", "team-0002", "team-0004"]
    lg.admit("team", 4, write=write_actor(4))
    assert [m.id for m in lg.pools["team"].members] == ["team-0001", "team-0002", "team-0005"]
    assert [m.id for m in lg.pools["team"].evicted] == ["team-0003", "team-0004"]
    assert (tmp_path / "league" / "members" / "team-0003" / "ant.safetensors").is_file()  # kept for old checkpoints
    lg.ratings.set("team-0005", Rating(50.0, 2.0))  # now team-0005 is best: team-0002 may go
    lg.admit("team", 5, write=write_actor(5))
    assert [m.id for m in lg.pools["team"].members] == ["team-0001", "team-0005", "team-0006"]


def test_keep_zoo_keeps_the_seeded_members_out_of_eviction_and_out_of_the_count(tmp_path: Path) -> None:
    for keep in (False, True):
        lg = league(tmp_path / str(keep), max_size=3, keep_zoo=keep)  # team-0001: the random team (zoo)
        added = lg.seed(("ant=passive", "bug=zero"), epoch=0)  # team-0002: a second seed, a still team
        assert [m.id for m in added] == ["team-0002"] and added[0].source == "zoo"
        for e in (1, 2, 3, 4):
            lg.admit("team", e, write=write_actor(e))
        ids = [m.id for m in lg.pools["team"].members]
        if keep:  # both seeds stay, and three snapshots beside them (the first snapshot is no longer "first")
            assert ids == ["team-0001", "team-0002", "team-0004", "team-0005", "team-0006"]
            assert [m.id for m in lg.pools["team"].evicted] == ["team-0003"]
        else:  # the still team is the oldest member but the first: it goes first
            assert ids == ["team-0001", "team-0005", "team-0006"]
            assert [m.id for m in lg.pools["team"].evicted] == ["team-0002", "team-0003", "team-0004"]
    with pytest.raises(ValueError, match=r"names roles \['ant'\] of side 'team' but not \['bug'\]"):
        lg.seed(("ant=passive",), epoch=5)
    with pytest.raises(ValueError, match="roles no side has"):
        lg.seed(("octopus=passive",), epoch=5)


def test_ratings_move_with_results_for_teams_and_free_for_all(tmp_path: Path) -> None:
    lg = league(tmp_path)
    play(lg, ["win"] * 20)
    assert lg.ratings[TEAM].mu > 25.0 > lg.ratings["spider-0001"].mu
    assert lg.pools["spider"].members[0].games == 20 and lg.pools["spider"].members[0].wins == 20
    ffa = League(tmp_path / "ffa", LeagueConfig(zoo=("agent=random",), sampling="uniform"), {"ffa": ("agent",)})
    for e in (1, 2):
        ffa.admit("ffa", e, builtin={"agent": "passive"})
    me = League.learner("ffa")
    for _ in range(10):
        ffa.record_match([[me], ["ffa-0001"], ["ffa-0002"]], [1, 2, 3])
    assert ffa.ratings[me].mu > ffa.ratings["ffa-0001"].mu > ffa.ratings["ffa-0002"].mu
    assert list(ffa.pools["ffa"].window) == [1] * 10
    # a member in two teams of one match is rated once, at its best place
    before = ffa.ratings["ffa-0003"]
    ffa.record_match([[me], ["ffa-0003"], ["ffa-0003"]], [2, 1, 3])
    assert ffa.ratings["ffa-0003"].mu > before.mu and ffa.ratings.matches["ffa-0003"] == 1
    assert ffa.pools["ffa"].window[-1] == 0
    # by seat: a team snapshot drives both its seats and is one player
    two = league(tmp_path / "seats")
    two.admit("team", 1, builtin={"ant": "passive", "bug": "passive"})
    one = league(tmp_path / "teams")
    one.admit("team", 1, builtin={"ant": "passive", "bug": "passive"})
    two.record_seat_outcomes(["team-0002", "team-0002", "spider:learner"], ["loss", "loss", "win"],
                             ["team", "team", "spider"])
    one.record_outcomes([["team-0002"], ["spider:learner"]], ["loss", "win"])
    assert two.state_dict()["ratings"] == one.state_dict()["ratings"]
    assert list(two.pools["spider"].window) == [1] and two.pools["team"].members[1].games == 1
    with pytest.raises(KeyError, match="ffa-0099"):
        ffa.record_match([[me], ["ffa-0099"]], [1, 2])


def test_ffa_seats_sharing_a_member_keep_their_own_places(tmp_path: Path) -> None:
    """Issue 39, item 1: a free-for-all pool of one member gives it both opponent seats. Seat 1 out first, the
    learner second, seat 2 survives: the learner finished second, not first. Merging the member's seats at its
    first seat made that a win in the admission window and rated the learner above the member."""
    ffa = League(tmp_path, LeagueConfig(zoo=("agent=random",), sampling="latest"), {"ffa": ("agent",)})
    member = ffa.pools["ffa"].members[0].id
    me = League.learner("ffa")
    ffa.record_seats([member, me, member], [3.0, 2.0, 1.0], ["ant", "bug", "spider"])
    assert list(ffa.pools["ffa"].window) == [0]  # not first: no win
    assert ffa.ratings[member].mu > ffa.ratings[me].mu  # rated at its best seat, ahead of the learner
    m = ffa.pools["ffa"].members[0]
    assert (m.games, m.wins, m.draws) == (2, 1, 0)  # the learner met both seats: beat one, lost to the other
    ffa.record_seats([member, me, member], [2.0, 1.0, 3.0], ["ant", "bug", "spider"])
    assert list(ffa.pools["ffa"].window) == [0, 1]  # first, alone: a win
    with pytest.raises(ValueError, match="one place and one team per seat"):
        ffa.record_seats([member, me], [1.0, 2.0], ["ant"])


def test_resume_restores_the_league_exactly(tmp_path: Path) -> None:
    lg = league(tmp_path, sampling="pfsp", threshold=0.5, window=4)
    lg.admit("spider", 0, builtin={"spider": "passive"})
    for epoch in range(1, 4):
        play(lg, ["win", "win", "win", "draw"])
        opponent = lg.sample("spider")[0]
        lg.record_outcomes([[TEAM], [opponent.id]], ["win", "loss"])
        if lg.admit_due("team", epoch):
            lg.admit("team", epoch, write=write_actor(epoch))
        lg.epoch_end(epoch)
    assert len(lg.pools["team"].members) > 1  # snapshots with policy files were admitted
    lg.save()
    lg.epoch_end(4)  # logged after the save: a resume from it drops this row
    back = League.load(tmp_path)
    assert as_json(back.state_dict()) == as_json(lg.state_dict() | {"epoch": 3})
    assert [back.sample("spider")[0].id for _ in range(40)] == [lg.sample("spider")[0].id for _ in range(40)]
    for name in lg.ratings.players:
        assert back.ratings[name] == lg.ratings[name]
    assert list(back.pools["team"].window) == list(lg.pools["team"].window)
    epochs = [ln.split(",")[0] for ln in (tmp_path / "league" / "league.csv").read_text().splitlines()[1:]]
    assert epochs == ["1", "1", "2", "2", "3", "3"]
    # state_dict / load_state_dict (what a checkpoint holds) give the same league
    other = League(tmp_path, lg.config, SIDES, seed=123)
    other.load_state_dict(json.loads(json.dumps(lg.state_dict())))
    assert [other.sample("spider")[0].id for _ in range(20)] == [lg.sample("spider")[0].id for _ in range(20)]
    # a damaged member file is named
    member = next(m for m in lg.pools["team"].members if m.sha256)
    damaged = tmp_path / "league" / next(iter(member.sha256))
    damaged.write_bytes(damaged.read_bytes() + b" ")
    with pytest.raises(PolicyFileError, match=str(damaged.name)):
        League.load(tmp_path)


def test_rating_table_round_trips_exactly() -> None:
    table = RatingTable("BradleyTerryFull")
    table.record([["a", "b"], ["c"]], [1, 2])
    back = RatingTable.from_state_dict(json.loads(json.dumps(table.state_dict())))
    assert back.players == table.players and back.matches == table.matches
    assert all(back[n] == table[n] for n in table.players)
    back.record([["a"], ["c"]], [2, 1])
    table.record([["a"], ["c"]], [2, 1])
    assert back["c"] == table["c"]


@pytest.mark.parametrize(("kw", "field"), [
    ({"threshold": 1.0}, "threshold"), ({"threshold": -0.1}, "threshold"), ({"window": 0}, "window"),
    ({"sampling": "best"}, "sampling"), ({"pfsp_weighting": "easy"}, "pfsp_weighting"),
    ({"pfsp_exponent": 0.0}, "pfsp_exponent"), ({"max_size": 2}, "max_size"),
    ({"snapshot_every": 0}, "snapshot_every"), ({"zoo": ("spider",)}, "zoo"),
    ({"zoo": ("spider=zoo:nobody",)}, "zoo"),
    ({"rating_model": "Glicko"}, "rating_model"), ({"draw_score": 1.5}, "draw_score"),
    ({"draw_score": True}, "draw_score"), ({"side_draw_score": ("spider",)}, "side_draw_score"),
    ({"side_draw_score": ("spider=2",)}, "side_draw_score"), ({"side_draw_score": ("spider=half",)}, "side_draw_score"),
    ({"side_draw_score": ("spider=0", "spider=1")}, "side_draw_score"),
    ({"side_threshold": ("team",)}, "side_threshold"), ({"side_threshold": ("team=1",)}, "side_threshold"),
    ({"side_threshold": ("team=-0.1",)}, "side_threshold"), ({"side_threshold": ("=0.3",)}, "side_threshold"),
    ({"side_threshold": ("team=0.3", "team=0.2")}, "side_threshold"),
    ({"side_threshold": ("team=nan",)}, "side_threshold"),
])
def test_bad_config_names_the_field(kw: dict[str, object], field: str) -> None:
    with pytest.raises(ValueError, match=f"LeagueConfig.{field}"):
        LeagueConfig(**kw)  # type: ignore[arg-type]


@pytest.mark.parametrize("n", [1, 5, 24, 25, 126, 1000])
def test_the_league_plot_labels_at_most_24_member_rows_first_and_last_included(n: int) -> None:
    shown = member_ticks(n)
    assert shown == sorted(set(shown)) and shown[0] == 0 and shown[-1] == n - 1
    assert len(shown) == n if n <= 24 else 2 <= len(shown) <= 24
    gaps = np.diff(shown)
    assert n <= 2 or gaps.min() >= gaps.max() / 2  # no two labels crowd each other (the last one included)
    assert n <= 24 or gaps[-1] >= gaps[0]  # the last row's label is a full step from the one before it


def test_bad_league_use_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="roles no side has"):
        League(tmp_path, LeagueConfig(zoo=("beetle=random",)), SIDES)
    lg = League(tmp_path, LeagueConfig(), SIDES)
    with pytest.raises(ValueError, match="pool 'spider' is empty"):
        lg.sample("spider")
    with pytest.raises(KeyError, match="no side 'ffa'"):
        lg.sample("ffa")
    with pytest.raises(ValueError, match="exactly one of write"):
        lg.admit("team", 1)
    with pytest.raises(FileNotFoundError, match="league.csv"):
        plot_league(tmp_path)


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_scripted_2v1_league_admits_stronger_snapshots_and_moves_ratings(tmp_path: Path) -> None:
    # draws count half: on the paper's rim a passive team often holds a random Spider to a draw
    cfg = LeagueConfig(threshold=0.5, window=6, snapshot_every=6, max_size=4, zoo=SEEDED, draw_score=0.5)
    lg = league_demo(tmp_path, epochs=24, max_steps=150, config=cfg)
    for side in ("team", "spider"):
        admitted = [m for m in lg.pools[side].members if m.source == "self"]
        assert admitted, f"no {side} snapshot was admitted"
        assert set(admitted[-1].policies.values()) == {"passive"}  # the stronger, later stage
        assert lg.ratings[League.learner(side)].mu > lg.ratings[f"{side}-0001"].mu  # beats the seeded random player
        assert lg.ratings[League.learner(side)].sigma < 25.0 / 3.0
    rows = (tmp_path / "league" / "league.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * 24
    assert (tmp_path / "plots" / "league.png").stat().st_size > 10_000
    assert as_json(League.load(tmp_path).state_dict()) == as_json(lg.state_dict())


def test_zoo_members_are_copied_into_the_run_folder_and_play_as_the_zoo_policy(tmp_path: Path) -> None:
    from triplesumo.agents.zoo import load as zoo_load

    lg = League(tmp_path, LeagueConfig(zoo=("spider=zoo:spider",)), SIDES)
    (snap,) = lg.pools["spider"].members
    assert snap.source == "zoo" and snap.policies == {"spider": "members/spider-0001/spider"}
    assert (tmp_path / "league" / "members" / "spider-0001" / "spider.safetensors").is_file()
    assert len(snap.sha256) == 2 and lg.pools["team"].members == []  # the team pool's roles were not named
    ours, theirs = lg.policies(snap)["spider"], zoo_load("spider")[0]
    obs = np.linspace(-1.0, 1.0, ours.obs_dim).astype(np.float32)
    np.testing.assert_array_equal(ours(obs), theirs(obs))


def test_a_role_named_k_times_seeds_k_members_in_order_and_a_side_pairs_its_roles_ith_with_ith(
        tmp_path: Path) -> None:
    from triplesumo.agents.zoo import load as zoo_load

    cfg = LeagueConfig(zoo=("spider=zoo:spider", "ant=random", "spider=passive", "bug=zero",
                            "spider=zoo:spider-selfplay", "ant=passive", "bug=random"))
    lg = League(tmp_path, cfg, SIDES)
    spiders, team = lg.pools["spider"].members, lg.pools["team"].members
    assert [m.id for m in spiders] == ["spider-0001", "spider-0002", "spider-0003"]
    assert [m.source for m in spiders] == ["zoo"] * 3 and spiders[1].policies == {"spider": "passive"}
    assert [m.policies for m in team] == [{"ant": "random", "bug": "zero"}, {"ant": "passive", "bug": "random"}]
    for snap, name in ((spiders[0], "spider"), (spiders[2], "spider-selfplay")):
        ours, theirs = lg.policies(snap)["spider"], zoo_load(name)[0]
        obs = np.linspace(-1.0, 1.0, ours.obs_dim).astype(np.float32)
        np.testing.assert_array_equal(ours(obs), theirs(obs))
    lg.save()
    assert len(spiders[2].sha256) == 2 and as_json(League.load(tmp_path).state_dict()) == as_json(lg.state_dict())
    with pytest.raises(ValueError, match=r"roles of side 'team' unequally often \{'ant': 2, 'bug': 1\}"):
        League(tmp_path / "bad", LeagueConfig(zoo=("ant=random", "bug=zero", "ant=passive")), SIDES)


def test_a_side_whose_learner_never_plays_logs_no_rating_and_the_plot_draws_none_for_it(tmp_path: Path) -> None:
    lg = league(tmp_path)  # only the team learns: it meets spider-0001, the Spider learner never plays
    play(lg, ["win", "loss", "draw"])
    scalars = lg.epoch_end(1)
    assert np.isfinite(scalars["league/team/learner_mu"]) and scalars["league/team/learner_sigma"] < 25.0 / 3.0
    assert np.isnan(scalars["league/spider/learner_mu"]) and np.isnan(scalars["league/spider/learner_sigma"])
    row = (tmp_path / "league" / "league.csv").read_text().splitlines()[-1].split(",")
    assert row[1] == "spider" and row[3] == row[4] == "nan"
    assert plot_league(tmp_path).stat().st_size > 10_000


def test_league_config_generates_cli_flags_and_back() -> None:
    import argparse

    from triplesumo import _dcargs

    parser = argparse.ArgumentParser()
    _dcargs.add_arguments(parser, LeagueConfig)
    cfg = _dcargs.build(LeagueConfig, parser.parse_args(
        ["--threshold", "0.7", "--sampling", "uniform", "--zoo", "spider=zoo:spider", "ant=passive"]))
    assert cfg == LeagueConfig(threshold=0.7, sampling="uniform", zoo=("spider=zoo:spider", "ant=passive"))
    assert _dcargs.build(LeagueConfig, parser.parse_args(_dcargs.to_argv(cfg))) == cfg


def test_seeded_members_are_labelled_with_their_policy_and_drawn_apart_in_the_league_plot(tmp_path: Path) -> None:
    # two Spider seeds (the second as a fork would append it) and a team of two built-ins
    zoo = ("ant=random", "bug=passive", "spider=passive", "spider=zoo:spider")
    lg = League(tmp_path, LeagueConfig(zoo=zoo, snapshot_every=1, threshold=0.0, window=1), SIDES, seed=7)
    for epoch in range(1, 31):
        lg.record_outcomes([[TEAM], ["spider-0001"]], ["win", "loss"])
        if lg.admit_due("team", epoch):
            lg.admit("team", epoch, write=write_actor(epoch))
        lg.epoch_end(epoch)
    lg.save()
    labels = member_labels(tmp_path)
    assert labels == {"team-0001": "team-0001 seed: random+passive", "spider-0001": "spider-0001 seed: passive",
                      "spider-0002": "spider-0002 seed: zoo:spider"}
    fig = league_figure(tmp_path)
    ticks = [t.get_text() for t in fig.axes[1].get_yticklabels()]
    assert set(labels.values()) <= {line for t in ticks for line in t.split("\n")}  # always, however many snapshots
    # the two Spider seeds sit in adjacent rows: one label of two lines between them, not two overlapping
    assert "spider-0001 seed: passive\nspider-0002 seed: zoo:spider" in ticks
    rows = dict(zip(ticks, fig.axes[1].get_yticks(), strict=True))
    assert rows["spider-0001 seed: passive\nspider-0002 seed: zoo:spider"] == 31.5  # team-0001..0031, then these
    sampled = [t for t in ticks if "seed" not in t]
    assert 0 < len(sampled) <= 24 and max(rows[t] for t in sampled) >= 28  # late snapshots too, clear of it
    assert all(abs(rows[t] - 31.5) >= 2 for t in sampled) and "team-0031" not in ticks  # (it would overlap)
    crosses = [c for c in fig.axes[1].collections if np.allclose(c.get_facecolor()[0][:3], 0.0)]
    assert len(crosses) == 3  # one row of black crosses per seed
    assert member_labels(tmp_path / "elsewhere") == {}
    # another run's member file is labelled by its last two parts; built-ins, zoo names and short paths as given
    assert spec_label("results/run-a/league/members/team-0120/ant") == ".../team-0120/ant"
    assert [spec_label(s) for s in ("passive", "zoo:spider", "pol/spider-0186")] == ["passive", "zoo:spider",
                                                                                    "pol/spider-0186"]


def test_a_torn_last_line_of_the_league_log_is_cut_on_resume(tmp_path: Path) -> None:
    """Issue 39, item 16 S: a kill while writing ``league.csv`` left a torn last line that the resumed run glued
    its next row onto (kept when its epoch was the resume point's); it now goes through the metrics CSVs' repair
    routine (torn tail cut, epochs past the resume point cut)."""
    lg = league(tmp_path)
    for epoch in (1, 2, 3):
        play(lg, ["win"])
        lg.epoch_end(epoch)
    log = lg.root / "league.csv"
    whole = log.read_text()
    log.write_text("".join(whole.splitlines(keepends=True)[:5]) + "3,spi")  # killed while writing epoch 3's rows
    lg.truncate_log(3)
    assert log.read_text() == "".join(whole.splitlines(keepends=True)[:5])
    lg.epoch_end(3)  # the rows of epoch 3 again, each on a line of its own
    assert all(len(r.split(",")) == 8 and r.split(",")[0] in "123" for r in log.read_text().splitlines()[1:])
    lg.truncate_log(1)  # a resume from epoch 1: later epochs cut
    assert [r.split(",")[0] for r in log.read_text().splitlines()[1:]] == ["1", "1"]
