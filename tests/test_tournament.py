"""``triplesumo tournament``: seats, schedule, ratings of real matches, determinism, resume, errors.

Real matches, kept short: a 1-vs-1 roster (two quadrupeds, passive against random, whose
random legs walk it off the ring) for the ratings, and the paper scenario over a tiny
trained zoo for seats and the command line.
"""

from __future__ import annotations

import csv
import dataclasses
import re
from pathlib import Path

import pytest

import triplesumo.agents.zoo
from conftest import TinyZoo, small_disk
from triplesumo.cli import main
from triplesumo.envs.match import Match
from triplesumo.evaluation.tournament import Tournament, TournamentConfig, run_tournament
from triplesumo.model.specs import AgentSpec, PhysicsConfig
from triplesumo.rules.config import MatchConfig

PNG = b"\x89PNG\r\n\x1a\n"
DUEL = MatchConfig(agents=(AgentSpec("a", "a", 0.2), AgentSpec("b", "b", 0.2)), max_steps=1000,
                   physics=PhysicsConfig(integrator="Euler"))
"""1-vs-1: two quadrupeds, one per team (Euler: about 4 x cheaper than RK4, and a match all the same;
at 1,000 steps the random quadruped leaves the ring in most matches, so few end drawn)."""


def duel_cfg(out: Path, **fields: object) -> TournamentConfig:
    base = TournamentConfig(policies=("passive=passive", "random=random"), rounds=24, steps_per_epoch=1000,
                            out=str(out), n_envs=8, n_threads=1, progress=False)
    return dataclasses.replace(base, **fields)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def duel(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("duel")
    return out, run_tournament(duel_cfg(out), DUEL)


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow  # 11 s alone on the shared 2-core box
def test_passive_ends_rated_above_random_with_non_overlapping_intervals(duel: tuple[Path, dict]) -> None:
    out, results = duel
    board = {e["policy"]: e for e in results["leaderboard"]}
    assert [e["policy"] for e in results["leaderboard"]] == ["passive", "random"]
    assert board["passive"]["lo"] > board["random"]["hi"]
    assert board["passive"]["elo"] > 1500.0 > board["random"]["elo"]  # 1-vs-1: plain Elo beside openskill
    assert board["passive"]["elo"] + board["random"]["elo"] == pytest.approx(3000.0)
    # Every lineup in every round: 2 lineups (each policy in each seat) x 24 rounds.
    table = rows(out / "matches.csv")
    assert len(table) == 48 == results["n_matches"]
    assert {(r["a"], r["b"]) for r in table} == {("passive", "random"), ("random", "passive")}
    # Win/loss/draw per seat adds up to the matches, and mirrors the opponent's.
    for e in results["leaderboard"]:
        assert sum(sum(s.values()) for s in e["seats"].values()) == e["matches"] == 48
    assert board["passive"]["n_win"] == board["random"]["n_loss"]
    assert board["passive"]["n_win"] > 36
    cross = {(c["row"], c["column"]): c for c in results["crossplay"]}
    pr = cross[("passive", "random")]
    assert pr["n"] == 48 and pr["wins"] == board["passive"]["n_win"]
    assert pr["lo"] <= pr["win_rate"] <= pr["hi"] and pr["lo"] > 0.5
    assert cross[("random", "passive")]["wins"] == board["random"]["n_win"]
    for name in ("leaderboard.png", "crossplay.png"):
        assert (out / name).read_bytes().startswith(PNG)
    lb = rows(out / "leaderboard.csv")
    assert [r["policy"] for r in lb] == ["passive", "random"]
    assert int(lb[0]["a_win"]) + int(lb[0]["b_win"]) == board["passive"]["n_win"]


def test_rating_by_seat_re_rates_a_finished_tournament_without_playing(duel: tuple[Path, dict]) -> None:
    out, by_policy = duel
    before = (out / "matches.csv").read_bytes()
    by_seat = run_tournament(duel_cfg(out, rate_by="seat", resume=True), DUEL)
    assert (out / "matches.csv").read_bytes() == before
    board = {e["policy"]: e for e in by_seat["leaderboard"]}
    assert set(board) == {"passive@a", "passive@b", "random@a", "random@b"}
    assert all(e["matches"] == 24 for e in board.values())
    assert board["passive@a"]["seats"]["b"] == {"win": 0, "loss": 0, "draw": 0, "error": 0}
    assert board["passive@a"]["elo"] is not None
    assert board["passive@a"]["n_win"] + board["passive@b"]["n_win"] == by_policy["leaderboard"][0]["n_win"]
    assert min(board["passive@a"]["mu"], board["passive@b"]["mu"]) > max(board["random@a"]["mu"],
                                                                          board["random@b"]["mu"])
    cross = {(c["row"], c["column"]): c["n"] for c in by_seat["crossplay"]}
    assert cross[("passive@a", "random@b")] == 24 and cross[("passive@a", "random@a")] == 0
    assert (out / "leaderboard_by_seat.png").read_bytes().startswith(PNG)
    assert [r["policy"] for r in rows(out / "leaderboard.csv")] == ["passive", "random"]  # kept


def test_frozen_policies_rated_without_drift_re_rate_with_narrower_intervals(duel: tuple[Path, dict]) -> None:
    out, default = duel
    before = (out / "matches.csv").read_bytes()
    frozen = run_tournament(duel_cfg(out, rating_tau=0.0, resume=True), DUEL)
    assert (out / "matches.csv").read_bytes() == before  # the same matches, only re-rated
    assert default["rating_tau"] == 25.0 / 300.0 and frozen["rating_tau"] == 0.0
    was = {e["policy"]: e for e in default["leaderboard"]}
    for e in frozen["leaderboard"]:
        assert e["sigma"] < was[e["policy"]]["sigma"]
        assert e["n_win"] == was[e["policy"]]["n_win"]
    assert [e["policy"] for e in frozen["leaderboard"]] == ["passive", "random"]
    run_tournament(duel_cfg(out, resume=True), DUEL)  # back to the default's table, for the other tests
    assert float(rows(out / "leaderboard.csv")[0]["sigma"]) == pytest.approx(was["passive"]["sigma"], abs=1e-4)


def test_same_seed_same_rows_whatever_the_batch(duel: tuple[Path, dict], tmp_path: Path) -> None:
    """The first 2 rounds again, one match at a time: the very same rows as 8 at once."""
    out, _ = duel
    run_tournament(duel_cfg(tmp_path, rounds=2, n_envs=1), DUEL)
    assert rows(tmp_path / "matches.csv") == rows(out / "matches.csv")[:4]
    other = tmp_path / "other-seed"
    run_tournament(duel_cfg(other, rounds=2, seed=7), DUEL)
    assert [r["steps"] for r in rows(other / "matches.csv")] != [r["steps"] for r in rows(tmp_path / "matches.csv")]


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_a_killed_tournament_resumes_to_the_rows_of_an_uninterrupted_one(duel: tuple[Path, dict],
                                                                       tmp_path: Path) -> None:
    out, _ = duel
    whole, part = tmp_path / "whole", tmp_path / "part"
    run_tournament(duel_cfg(whole, rounds=6, n_envs=1), DUEL)
    run_tournament(duel_cfg(part, rounds=3), DUEL)
    with (part / "matches.csv").open("a") as fh:
        fh.write("7,20003,passive,ran")  # a row torn by the kill
    run_tournament(duel_cfg(part, rounds=6, resume=True), DUEL)
    done = (part / "matches.csv").read_bytes()
    assert done == (whole / "matches.csv").read_bytes()
    assert done.splitlines() == (out / "matches.csv").read_bytes().splitlines()[:13]  # header + 12 matches
    for name in ("leaderboard.csv", "crossplay.csv"):
        assert (part / name).read_bytes() == (whole / name).read_bytes()
    # Resuming a finished tournament plays nothing and changes nothing.
    run_tournament(duel_cfg(part, rounds=6, resume=True), DUEL)
    assert (part / "matches.csv").read_bytes() == done


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_a_packed_tournament_resumes_to_the_rows_of_an_uninterrupted_one(tmp_path: Path) -> None:
    """Its tables gzipped (``triplesumo pack``), a killed tournament resumes as a plain one does."""
    import gzip

    from triplesumo.evaluation.metrics_csv import pack_tables

    whole, part = tmp_path / "whole", tmp_path / "part"
    run_tournament(duel_cfg(whole, rounds=4, n_envs=1), DUEL)
    run_tournament(duel_cfg(part, rounds=2), DUEL)
    assert "matches.csv.gz" in {p.name for p in pack_tables(part, min_bytes=0)}
    torn = gzip.decompress((part / "matches.csv.gz").read_bytes()) + b"7,20003,passive,ran"
    (part / "matches.csv.gz").write_bytes(gzip.compress(torn))  # and a row torn by the kill
    run_tournament(duel_cfg(part, rounds=4, resume=True), DUEL)
    assert (part / "matches.csv").read_bytes() == (whole / "matches.csv").read_bytes()
    assert not list(part.glob("*.csv.gz"))  # the tables written again replaced their packed copies
    for name in ("leaderboard.csv", "crossplay.csv"):
        assert (part / name).read_bytes() == (whole / name).read_bytes()


@pytest.mark.slow  # 4 s alone on the shared 2-core box
def test_a_tournament_killed_before_its_first_row_resumes_as_a_fresh_start(duel: tuple[Path, dict],
                                                                            tmp_path: Path) -> None:
    """Issue 39, item 16: killed before anything was written, a tournament leaves an empty record and an empty
    table; --resume starts it afresh (it refused the 0-byte files) and ends as an uninterrupted one."""
    out, _ = duel
    part = tmp_path / "part"
    part.mkdir()
    (part / "tournament.json").write_bytes(b"")
    (part / "matches.csv").write_bytes(b"")
    run_tournament(duel_cfg(part, rounds=6, resume=True), DUEL)
    assert (part / "matches.csv").read_bytes().splitlines() == (out / "matches.csv").read_bytes().splitlines()[:13]


def test_resume_refuses_what_changed(tmp_path: Path) -> None:
    part = tmp_path / "r"
    run_tournament(duel_cfg(part, rounds=2), DUEL)
    with pytest.raises(ValueError, match="seed was 20000, now 5"):
        run_tournament(duel_cfg(part, seed=5, resume=True), DUEL)
    with pytest.raises(ValueError, match="schedule was 'round-robin', now 'sampled'"):
        run_tournament(duel_cfg(part, schedule="sampled", resume=True), DUEL)
    with pytest.raises(ValueError, match=r"entries \['random', 'zero'\] changed"):
        run_tournament(duel_cfg(part, policies=("passive=passive", "zero=zero"), resume=True), DUEL)
    with pytest.raises(ValueError, match="cannot resume .*match was"):
        run_tournament(duel_cfg(part, resume=True), dataclasses.replace(DUEL, max_steps=999))
    with pytest.raises(ValueError, match="already holds 4 matches, more than matches of this schedule=2"):
        run_tournament(duel_cfg(part, rounds=1, resume=True), DUEL)
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        run_tournament(duel_cfg(tmp_path / "empty", resume=True), DUEL)


def test_the_ring_is_chosen_and_part_of_what_the_rows_depend_on(tmp_path: Path) -> None:
    from triplesumo.model import V0_PHYSICS

    assert TournamentConfig().match_config().physics.border_rim  # env v1: the paper's rim
    v0 = TournamentConfig(physics=V0_PHYSICS, out=str(tmp_path))
    assert v0.match_config().physics == V0_PHYSICS
    with pytest.raises(ValueError, match=r"zoo/ant\.json: the policy was trained on another ring"):
        Tournament(v0)  # the zoo's policies were trained on env v2's ring
    v0 = dataclasses.replace(v0, allow_other_ring=True)
    assert Tournament(v0).record()["rows_depend_on"]["match"]["physics"]["border_rim"] is False


def test_sampled_schedule_draws_lineups_from_the_seed(tmp_path: Path) -> None:
    cfg = duel_cfg(tmp_path, schedule="sampled", matches=40)
    t = Tournament(cfg, DUEL)
    drawn = [t.lineup_of(m) for m in range(40)]
    assert set(drawn) == set(t.lineups)
    assert drawn == [Tournament(cfg, DUEL).lineup_of(m) for m in range(40)]
    assert [t.seed_of(m) for m in range(3)] == [cfg.seed, cfg.seed + 1, cfg.seed + 2]


# ------------------------------------------------------------------- free-for-all: places


def ffa_cfg(out: Path, **fields: object) -> TournamentConfig:
    base = TournamentConfig(scenario="ffa", policies=("passive=passive", "random=random", "random2=random"), rounds=4,
                            steps_per_epoch=1000, physics=PhysicsConfig(integrator="Euler"), out=str(out), n_envs=8,
                            n_threads=1, progress=False)
    return dataclasses.replace(base, **fields)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def ffa(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("ffa")
    return out, run_tournament(ffa_cfg(out))


@pytest.mark.slow  # 10 s alone on the shared 2-core box
def test_free_for_all_by_name_records_places_and_rates_the_passive_quadruped_first(ffa: tuple[Path, dict]) -> None:
    out, results = ffa
    assert results["scenario"] == "ffa" and results["seats"] == ["ant", "bug", "spider"]
    table = rows(out / "matches.csv")
    assert len(table) == 4 * 6 == results["n_matches"]  # 3 entries in 3 seats: 6 lineups a round
    seats = ("ant", "bug", "spider")
    left = 0
    for r in table:
        places = sorted(int(r[f"{a}_place"]) for a in seats)
        for a in seats:  # place 1 is a win, or a draw shared by the quadrupeds still in at the limit
            assert (int(r[f"{a}_place"]) == 1) == (r[f"{a}_outcome"] in ("win", "draw"))
        if places == [1, 2, 3]:
            left += 1  # one out, then another: the order they left in is kept
        else:  # out on the same step: a shared place; in at the limit: place 1 shared
            assert places in ([1, 2, 2], [1, 1, 3], [1, 1, 1]), places
    assert left > 0
    board = {e["policy"]: e for e in results["leaderboard"]}
    assert results["leaderboard"][0]["policy"] == "passive"
    assert board["passive"]["lo"] > max(board["random"]["hi"], board["random2"]["hi"])
    assert board["passive"]["elo"] is None  # three teams: no 1-vs-1 Elo
    # Cross-play in a free-for-all: the matches the row placed better than the column.
    cross = {(c["row"], c["column"]): c for c in results["crossplay"]}
    better = sum(int(r[f"{_seat(r, 'passive')}_place"]) < int(r[f"{_seat(r, 'random')}_place"]) for r in table)
    assert cross[("passive", "random")]["wins"] == better and cross[("passive", "random")]["n"] == len(table)
    assert (out / "leaderboard.png").read_bytes().startswith(PNG)


def _seat(row: dict[str, str], name: str) -> str:
    return next(a for a in ("ant", "bug", "spider") if row[a] == name)


def test_free_for_all_rates_a_quadruped_out_second_above_one_out_first(tmp_path: Path) -> None:
    """The same matches told by outcome alone (both out: a loss each) would rate ``second`` and ``first``
    equal; the places say which one lasted longer."""
    from triplesumo.evaluation.tournament import tabulate

    cfg = ffa_cfg(tmp_path, policies=("last=passive", "second=random", "first=zero"))
    t = Tournament(cfg)
    table = []
    for m in range(30):
        seated = list(zip(t.agents, t.lineup_of(m), strict=True))
        place = {"last": 1, "second": 2, "first": 3}
        table.append({"match": str(m + 1), "seed": str(t.seed_of(m)), **dict(seated),
                      **{f"{a}_outcome": "win" if n == "last" else "loss" for a, n in seated},
                      **{f"{a}_place": str(place[n]) for a, n in seated}, "steps": "100"})
    assert all(t.valid_row(r, int(r["match"])) for r in table)
    board = [e["policy"] for e in tabulate(table, t, cfg)["leaderboard"]]
    assert board == ["last", "second", "first"]


@pytest.mark.slow  # 11 s alone on the shared 2-core box
def test_free_for_all_tournament_resumes_to_the_same_rows(ffa: tuple[Path, dict], tmp_path: Path) -> None:
    part = tmp_path / "part"
    run_tournament(ffa_cfg(part, rounds=2))
    run_tournament(ffa_cfg(part, rounds=4, resume=True))
    assert (part / "matches.csv").read_bytes() == (ffa[0] / "matches.csv").read_bytes()


@pytest.fixture
def tiny_zoo_dir(tiny_zoo: TinyZoo, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    return tiny_zoo.zoo_dir


@pytest.mark.slow  # 10 s alone on the shared 2-core box
def test_paper_seats_zoo_policies_where_they_were_trained_and_built_ins_anywhere(tiny_zoo_dir: Path) -> None:
    t = Tournament(TournamentConfig(progress=False))
    assert t.seats_of == {"ant": ["ant"], "bug": ["bug"], "spider": ["spider"],
                          "passive": ["ant", "bug", "spider"], "random": ["ant", "bug", "spider"]}
    assert ("ant", "bug", "spider") in t.lineups
    assert all(len(set(lineup)) == 3 for lineup in t.lineups)
    assert len(t.lineups) == 13  # 3 x 3 x 3 seatings, less those with a policy twice
    assert t.n_matches == 10 * 13
    with pytest.raises(ValueError, match=r"policies \['spider=zoo:spider'\] fit no seat"):
        Tournament(TournamentConfig(policies=("spider=zoo:spider", "p=passive"), obs_mode="egocentric"))


def test_tournament_command_in_the_paper_scenario(tiny_zoo_dir: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "t"
    assert main(["tournament", "--scenario", "paper", "--policies", "spider=zoo:spider", "passive=passive",
                 "random=random", "--rounds", "1", "--steps-per-epoch", "20", "--out", str(out),
                 "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "spider W/L/D" in printed and "passive" in printed
    table = rows(out / "matches.csv")
    assert [(r["ant"], r["bug"], r["spider"]) for r in table] == [("passive", "random", "spider"),
                                                                  ("random", "passive", "spider")]
    assert all(r["spider"] == "spider" for r in table)
    assert all(r["elo"] == "" for r in rows(out / "leaderboard.csv"))  # no Elo in a 2-vs-1
    assert (out / "crossplay.png").read_bytes().startswith(PNG)


@pytest.mark.parametrize(("fields", "message"), [
    ({"policies": ("ant",)}, "expected NAME=SPEC"),
    ({"policies": ("a=passive", "a=random")}, "entry 'a' given twice"),
    ({"policies": ("a=passive",)}, "at least 2 entries"),
    ({"policies": ("a b=passive", "c=random")}, "NAME may hold"),
    ({"scenario": "chess"}, r"scenario must be one of \['paper', 'ffa', 'pursuit'"),
    ({"schedule": "swiss"}, "schedule must be one of"),
    ({"rounds": 0}, "rounds must be an int >= 1"),
    ({"league_snapshots": 0}, "league_snapshots must be an int >= 1"),
    ({"league_until": -1, "league": "runs/x"}, "league_until must be an int >= 0"),
    ({"league_until": 100}, "league_until needs league"),
    ({"rating_model": "Glicko"}, "rating_model must be one of"),
    ({"rate_by": "team"}, "rate_by must be one of"),
    ({"confidence": 1.5}, "confidence must be in"),
    ({"rating_tau": -0.01}, "rating_tau must be a finite number >= 0"),
])
def test_bad_configs_name_the_field(fields: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TournamentConfig(**fields)


def test_a_corrupt_or_empty_league_is_named(tmp_path: Path) -> None:
    (tmp_path / "league").mkdir()
    pool = tmp_path / "league" / "pool.json"
    cfg = TournamentConfig(league=str(tmp_path), policies=("p=passive",))
    pool.write_text('{"format": "triplesumo-league/1", "pools": {"ffa": {"members": [{"id": "ffa-0001"')
    with pytest.raises(ValueError, match=r"league: .*pool.json is unreadable or corrupt"):
        cfg.resolved()
    pool.write_text('{"format": "other/2", "pools": {}}')
    with pytest.raises(ValueError, match="format 'other/2', expected 'triplesumo-league/1'"):
        cfg.resolved()
    pool.write_text('{"format": "triplesumo-league/1", "pools": {"ffa": {"members": [{"id": "ffa-0001", "source": '
                    '"zoo", "epoch": 0, "policies": {"ffa": "random"}}], "evicted": []}}}')
    with pytest.raises(ValueError, match="holds no snapshot of the run's own yet"):
        cfg.resolved()


def test_unknown_policies_and_rosters_without_a_lineup_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown policy 'runs/nowhere/policy'"):
        Tournament(TournamentConfig(policies=("x=runs/nowhere/policy", "p=passive")))
    with pytest.raises(ValueError, match="no lineup fills every seat"):
        Tournament(TournamentConfig(policies=("p=passive", "r=random")))  # 3 seats, 2 policies
    assert main(["tournament", "--policies", "bad", "--out", str(tmp_path)]) == 2
    assert Match(DUEL).agents == ("a", "b")


@pytest.mark.parametrize("size", ["4k", "12k", "40k"])  # full before the rows, the tables, the plots
def test_a_tournament_on_a_full_disk_names_the_file_it_could_not_write(
        tmp_path: Path, size: str, capsys: pytest.CaptureFixture[str]) -> None:
    with small_disk(tmp_path / "disk", size) as disk:
        out = disk / "t"
        assert main(["tournament", "--policies", "p=passive", "r=random", "s=random", "--rounds", "2",
                     "--steps-per-epoch", "100", "--no-progress", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert "No space left on device" in err, err
        named = re.search(rf"{re.escape(str(out))}/(\w+\.(csv|json|png))\b", err)
        assert named, err  # the file, in the tournament's folder
