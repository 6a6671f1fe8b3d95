"""Ratings on synthetic results: openskill teams, free-for-all places, intervals; plain Elo."""

from __future__ import annotations

import numpy as np
import pytest

from triplesumo.evaluation.ratings import Elo, Rating, RatingTable


def test_a_player_that_always_wins_ends_higher_with_non_overlapping_intervals() -> None:
    table = RatingTable()
    for _ in range(30):
        table.record([["strong"], ["weak"]], [1, 2])
    strong, weak = table["strong"], table["weak"]
    assert strong.mu > 25.0 > weak.mu
    assert strong.interval()[0] > weak.interval()[1]
    assert strong.sigma < 25.0 / 3.0 and weak.sigma < 25.0 / 3.0  # uncertainty shrank
    assert table.ranking() == ["strong", "weak"]
    assert table.matches == {"strong": 30, "weak": 30}
    assert table.win_probability([["strong"], ["weak"]])[0] > 0.9


def test_few_results_leave_intervals_overlapping() -> None:
    table = RatingTable()
    table.record([["a"], ["b"]], [1, 2])
    assert table["a"].mu > table["b"].mu
    assert table["a"].interval()[0] < table["b"].interval()[1]


def test_interval_is_mu_plus_minus_z_sigma_and_ordinal_is_mu_minus_3_sigma() -> None:
    r = Rating(30.0, 2.0)
    lo, hi = r.interval(0.95)
    assert lo == pytest.approx(30.0 - 1.959964 * 2.0, abs=1e-5)
    assert hi == pytest.approx(30.0 + 1.959964 * 2.0, abs=1e-5)
    assert r.ordinal == 24.0
    assert r.interval(0.5)[1] - r.interval(0.5)[0] < hi - lo


@pytest.mark.parametrize("model", ["PlackettLuce", "BradleyTerryFull", "ThurstoneMostellerFull"])
def test_teams_winning_together_rise_together(model: str) -> None:
    """2-vs-1: partners who always win end level with each other and above their opponent (one
    fixed lineup cannot tell the partners' skills apart, so the intervals stay wide)."""
    table = RatingTable(model)
    for _ in range(20):
        table.record_outcomes([["ant", "bug"], ["spider"]], ["win", "loss"])
    assert table["ant"].mu == pytest.approx(table["bug"].mu)
    assert table["ant"].mu > 25.0 > table["spider"].mu
    assert table["ant"].sigma < 25.0 / 3.0


def test_a_good_player_lifts_whoever_it_partners() -> None:
    """Rotating partners: the player whose teams always win is rated above everyone else."""
    table = RatingTable()
    for _ in range(15):
        table.record_outcomes([["star", "x"], ["y"]], ["win", "loss"])
        table.record_outcomes([["star", "y"], ["x"]], ["win", "loss"])
        table.record_outcomes([["x", "y"], ["star"]], ["loss", "win"])
    assert table.ranking()[0] == "star"
    others = max(table["x"].interval()[1], table["y"].interval()[1])
    assert table["star"].interval()[0] > others


def test_free_for_all_places_order_the_ratings() -> None:
    table = RatingTable()
    for _ in range(25):
        table.record([["first"], ["second"], ["third"], ["fourth"]], [1, 2, 3, 4])
    assert table.ranking() == ["first", "second", "third", "fourth"]
    mus = [table[n].mu for n in table.ranking()]
    assert all(a > b for a, b in zip(mus, mus[1:], strict=False))


def test_draws_between_equal_players_keep_them_equal() -> None:
    table = RatingTable()
    for _ in range(10):
        table.record_outcomes([["a"], ["b"]], ["draw", "draw"])
    assert table["a"].mu == pytest.approx(table["b"].mu)
    assert table["a"].mu == pytest.approx(25.0)
    assert table["a"].sigma < 25.0 / 3.0


def test_same_results_in_the_same_order_give_the_same_ratings() -> None:
    def run() -> list[Rating]:
        t = RatingTable("BradleyTerryFull")
        for k in range(12):
            t.record([["a", "b"], ["c"]], [1, 2] if k % 3 else [2, 1])
        return [t[n] for n in "abc"]

    assert run() == run()


def frozen_duel(tau: float | None, matches: int, seed: int = 0) -> list[Rating]:
    """``a`` beats ``b`` with probability 0.6, whatever it has played: frozen policies. Returns a's
    rating after every 750 matches."""
    table, rng, seen = RatingTable(players=["a", "b"], tau=tau), np.random.default_rng(seed), []
    for m in range(1, matches + 1):
        table.record([["a"], ["b"]], [1, 2] if rng.random() < 0.6 else [2, 1])
        if m % 750 == 0:
            seen.append(table["a"])
    return seen


def test_without_drift_intervals_keep_narrowing_with_openskills_default_they_floor() -> None:
    default, frozen = frozen_duel(None, 3000), frozen_duel(0.0, 3000)
    # openskill's default tau (25/300) adds back what a match takes away: sigma stops at about 1.5.
    assert RatingTable().model.tau == 25.0 / 300.0 and RatingTable(tau=0.0).model.tau == 0.0
    assert default[-1].sigma > 0.95 * default[0].sigma > 1.3
    # tau = 0: 4 x the matches, about half the sigma (0.61 x here), and narrower than the default's.
    assert frozen[-1].sigma < 0.7 * frozen[0].sigma
    assert all(f.sigma < d.sigma for f, d in zip(frozen, default, strict=True))
    assert frozen[-1].mu > 25.0  # the better player stays on top


def test_tau_round_trips_through_the_state_dict_and_bad_values_are_named() -> None:
    table = RatingTable(tau=0.0)
    table.record([["a"], ["b"]], [1, 2])
    state = table.state_dict()
    assert state["tau"] == 0.0
    again = RatingTable.from_state_dict(state)
    assert again.tau == 0.0 and again.model.tau == 0.0 and again["a"] == table["a"]
    assert "tau" not in RatingTable().state_dict()  # openskill's default: older states read the same
    assert RatingTable.from_state_dict(RatingTable().state_dict()).tau is None
    for bad in (-0.1, float("nan"), float("inf"), True):
        with pytest.raises(ValueError, match="rating tau must be a finite number >= 0"):
            RatingTable(tau=bad)  # type: ignore[arg-type]


def test_bad_input_gives_clear_errors() -> None:
    with pytest.raises(ValueError, match="rating model must be one of"):
        RatingTable("Glicko")
    table = RatingTable()
    with pytest.raises(ValueError, match="only once in a match"):
        table.record([["a"], ["a"]], [1, 2])
    with pytest.raises(ValueError, match=">= 2 teams"):
        table.record([["a"]], [1])
    with pytest.raises(ValueError, match="one place per team"):
        table.record([["a"], ["b"]], [1])
    with pytest.raises(ValueError, match="outcomes must be among"):
        table.record_outcomes([["a"], ["b"]], ["won", "lost"])
    with pytest.raises(KeyError, match="no rating for 'zz'"):
        table["zz"]


def test_elo_is_the_textbook_update() -> None:
    elo = Elo(k=32)
    assert elo.expected("a", "b") == 0.5
    elo.record("a", "b", 1)
    assert elo.ratings == {"a": 1516.0, "b": 1484.0}
    assert elo.expected("a", "b") == pytest.approx(1 / (1 + 10 ** (-32 / 400)))
    elo.record("a", "b", 0.5)  # a draw moves the favourite down
    assert elo.ratings["a"] < 1516.0
    assert sum(elo.ratings.values()) == pytest.approx(3000.0)
    with pytest.raises(ValueError, match="score_a must be"):
        elo.record("a", "b", 2)
    with pytest.raises(ValueError, match="two different players"):
        elo.record("a", "a", 1)
