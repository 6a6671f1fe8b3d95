"""MatchBatch: many matches stepped together give exactly the trajectories of each match alone."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from triplesumo.envs.batch import MatchBatch, match_seeds
from triplesumo.envs.match import Match
from triplesumo.model import BODIES_AGENTS, AgentSpec
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.outcome import OUTCOME_CODES
from triplesumo.sim.physics import PhysicsError

N_MATCHES, N_STEPS = 3, 50
SHORT = MatchConfig(max_steps=20)
"""Episodes end by the step limit (a draw, truncated) at step 20, so 50 steps see resets."""

VARIANTS = [("mujoco", 1), ("mujoco", 2), ("threads", 2)]


def _actions(seed: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (N_STEPS, N_MATCHES, 3, 8))


def _record(results: list, matches: list[Match]) -> list[tuple]:
    return [(m.data.qpos.copy(), m.data.qvel.copy(), r.rewards.copy(), np.stack(r.observations), r.terminated,
             r.truncated, r.infos[0]["outcome"]) for r, m in zip(results, matches, strict=True)]


def _sequential(config: MatchConfig, actions: np.ndarray, seed: int) -> tuple[list, int]:
    """Each match stepped alone with Match.step_array: the reference."""
    matches = [Match(config) for _ in range(N_MATCHES)]
    for match, s in zip(matches, match_seeds(seed, N_MATCHES), strict=True):
        match.reset(s)
    log, resets = [], 0
    for t in range(N_STEPS):
        results = [m.step_array(a) for m, a in zip(matches, actions[t], strict=True)]
        log.append(_record(results, matches))
        for m in matches:
            if m.over:
                m.reset()
                resets += 1
    return log, resets


def _assert_same(expected: list, actual: list) -> None:
    for t, (rows_e, rows_a) in enumerate(zip(expected, actual, strict=True)):
        for k, (e, a) in enumerate(zip(rows_e, rows_a, strict=True)):
            for name, x, y in zip(("qpos", "qvel", "rewards", "observations"), e[:4], a[:4], strict=True):
                assert np.array_equal(x, y), f"step {t}, match {k}: {name} differs by {np.abs(x - y).max()}"
            assert e[4:] == a[4:], f"step {t}, match {k}: (terminated, truncated, outcome) differ"


@pytest.mark.parametrize(("backend", "n_threads"), VARIANTS)
def test_trajectories_equal_each_match_alone_bit_for_bit(backend: str, n_threads: int) -> None:
    actions = _actions()
    expected, expected_resets = _sequential(SHORT, actions, seed=11)
    assert expected_resets >= N_MATCHES  # every match ended and was reset at least once
    log, resets = [], 0
    with MatchBatch(SHORT, N_MATCHES, n_threads, stepper=backend) as batch:
        batch.reset_all(11)
        for t in range(N_STEPS):
            log.append(_record(batch.step(actions[t]), batch.matches))
            for k in np.flatnonzero(batch.over):
                batch.reset_one(int(k))
                resets += 1
    assert resets == expected_resets
    _assert_same(expected, log)


def test_reset_all_seeds_match_k_with_seed_plus_k() -> None:
    """As every vector view does: match k of ``reset(seed=s)`` is the match ``reset(seed=s + k)`` starts alone."""
    seeds = match_seeds(5, N_MATCHES)
    assert seeds == [5, 6, 7]
    with MatchBatch(None, N_MATCHES, 1) as batch:
        starts = [obs[0] for obs, _ in batch.reset_all(5)]
    for seed, obs in zip(seeds, starts, strict=True):
        alone = Match()
        np.testing.assert_array_equal(alone.reset(seed)[0][0], obs)


@pytest.mark.parametrize(("backend", "n_threads"), VARIANTS)
def test_a_finished_match_is_reported_over_until_reset(
        backend: str, n_threads: int, place: Callable[..., None]) -> None:
    with MatchBatch(None, N_MATCHES, n_threads, stepper=backend) as batch:
        batch.reset_all(0)
        assert not batch.over.any()
        place(batch.matches[1], "spider", x=3.0, y=0.0)  # Spider's torso past the edge
        batch.reload(1)
        results = batch.step(np.zeros((N_MATCHES, 3, 8)))
        assert results[1].terminated and not results[1].truncated
        assert [info["outcome"] for info in results[1].infos] == [OUTCOME_CODES[o] for o in ("win", "win", "loss")]
        assert not results[0].terminated and not results[2].terminated
        assert batch.over.tolist() == [False, True, False]
        with pytest.raises(RuntimeError, match=r"matches \[1\] are over"):
            batch.step(np.zeros((N_MATCHES, 3, 8)))
        batch.reset_one(1)
        assert not batch.over.any()
        batch.step(np.zeros((N_MATCHES, 3, 8)))


@pytest.mark.parametrize("shape", [(N_MATCHES, 3, 7), (N_MATCHES - 1, 3, 8), (3, 8), (N_MATCHES, 2, 8)])
def test_wrong_action_shape_is_a_value_error(shape: tuple[int, ...]) -> None:
    with MatchBatch(None, N_MATCHES, 1) as batch:
        batch.reset_all(0)
        with pytest.raises(ValueError, match=r"actions must have shape \(3, 3, 8\)"):
            batch.step(np.zeros(shape))


@pytest.mark.parametrize(("backend", "n_threads"), VARIANTS)
def test_nan_action_names_match_and_agent_and_steps_nothing(backend: str, n_threads: int) -> None:
    with MatchBatch(None, N_MATCHES, n_threads, stepper=backend) as batch:
        batch.reset_all(0)
        before = [m.data.qpos.copy() for m in batch.matches]
        actions = np.zeros((N_MATCHES, 3, 8))
        actions[2, 1, 4] = np.nan
        with pytest.raises(ValueError, match=r"match 2: action of 'bug' contains NaN or inf"):
            batch.step(actions)
        assert all(np.array_equal(b, m.data.qpos) for b, m in zip(before, batch.matches, strict=True))
        assert [m.steps for m in batch.matches] == [0, 0, 0]


@pytest.mark.parametrize(("backend", "n_threads"), VARIANTS)
def test_physics_blow_up_in_one_match_truncates_only_that_match(backend: str, n_threads: int) -> None:
    with MatchBatch(None, N_MATCHES, n_threads, stepper=backend) as batch:
        batch.reset_all(0)
        batch.matches[0].data.qvel[:] = 1e12  # MuJoCo's bad-qvel warning and auto-reset
        batch.reload(0)
        results = batch.step(np.zeros((N_MATCHES, 3, 8)))
    assert results[0].truncated and results[0].infos[0]["outcome"] == OUTCOME_CODES["error"]
    assert [info["place"] for info in results[0].infos] == [0, 0, 0]  # an error decides no place
    assert "bad_qvel" in (batch.matches[0].physics_error or "")
    assert all(np.isfinite(o).all() for o in results[0].observations)
    assert [r.infos[0]["outcome"] for r in results[1:]] == [0, 0]
    assert [m.physics_error for m in batch.matches[1:]] == [None, None]


def test_physics_error_raise_mode_finishes_every_match_then_names_the_match() -> None:
    with MatchBatch(MatchConfig(on_physics_error="raise"), N_MATCHES, 2) as batch:
        batch.reset_all(0)
        batch.matches[1].data.qvel[:] = 1e12
        batch.reload(1)
        with pytest.raises(PhysicsError, match="match 1: MuJoCo reported bad_qvel"):
            batch.step(np.zeros((N_MATCHES, 3, 8)))
        assert [m.steps for m in batch.matches] == [1, 1, 1]


def test_after_a_step_each_match_data_holds_its_state_with_current_contacts() -> None:
    """The mujoco backend copies the whole MjData back: contacts as after stepping the match alone."""
    with MatchBatch(None, 2, 2) as batch:
        batch.reset_all(0)
        for _ in range(30):  # the agents have landed on the tatami
            batch.step(np.zeros((2, 3, 8)))
        match = batch.matches[0]
        forces = match.sim.contact_forces()
        assert match.data.ncon > 0 and np.abs(forces).sum() > 0
        stepped = Match()  # the same contacts as stepping this match alone
        stepped.reset(match_seeds(0, 2)[0])
        for _ in range(30):
            stepped.step_array(np.zeros((3, 8)))
        assert stepped.data.ncon == match.data.ncon
        np.testing.assert_array_equal(stepped.sim.contact_forces(), forces)


def test_bad_arguments_and_closed_batch() -> None:
    with pytest.raises(ValueError, match="n_matches"):
        MatchBatch(None, 0)
    with pytest.raises(ValueError, match="n_threads"):
        MatchBatch(None, 2, 0)
    with pytest.raises(ValueError, match="stepper must be one of"):
        MatchBatch(None, 2, 1, stepper="rollout")
    batch = MatchBatch(None, 2, 2)
    with pytest.raises(RuntimeError, match="call reset_one"):  # never started
        batch.step(np.zeros((2, 3, 8)))
    with pytest.raises(IndexError):
        batch.reset_one(2)
    batch.close()
    with pytest.raises(RuntimeError, match="closed"):
        batch.reset_all(0)


# --------------------------------------------------------------- step_arrays
ARRAY_CONFIGS = {
    "paper": SHORT,
    "egocentric": MatchConfig(max_steps=20, obs_mode="egocentric"),
    "bodies": MatchConfig(max_steps=20, agents=BODIES_AGENTS),  # padded action columns
    "2-vs-2": MatchConfig(max_steps=20, agents=(AgentSpec("a", "x", 0.2), AgentSpec("b", "x", 0.2),
                                                AgentSpec("c", "y", 0.2), AgentSpec("d", "y", 0.2))),
    "ffa": MatchConfig(max_steps=20, rules="elimination", agents=(AgentSpec("a", "a", 0.2), AgentSpec("b", "b", 0.2),
                                                                   AgentSpec("c", "c", 0.2))),
}


def _step_arrays_against_alone(config: MatchConfig, backend: str, seed: int = 11,
                               action_seed: int = 4) -> dict[str, int]:
    """Step a MatchBatch with ``step_arrays`` and each match alone with ``Match.step_array``; assert every result
    equal, bit for bit, at every step; count the matches ended, the agents that left and the ends by truncation."""
    alone = [Match(config) for _ in range(N_MATCHES)]
    for match, s in zip(alone, match_seeds(seed, N_MATCHES), strict=True):
        match.reset(s)
    n, width = alone[0].n_agents, alone[0].action_width
    actions = np.random.default_rng(action_seed).uniform(-1.3, 1.3, (N_STEPS, N_MATCHES, n, width))
    seen = {"ends": 0, "left": 0, "truncated": 0}
    with MatchBatch(config, N_MATCHES, 2, stepper=backend) as batch:
        batch.reset_all(seed)
        for t in range(N_STEPS):
            got = batch.step_arrays(actions[t])
            for k, match in enumerate(alone):
                r = match.step_array(actions[t, k])
                where = f"step {t}, match {k}"
                assert np.array_equal(got.observations[k], np.stack(r.observations)), where
                assert got.observations.dtype == np.float32
                assert np.array_equal(got.rewards[k], r.rewards), where
                assert (got.terminated[k], got.truncated[k]) == (r.terminated, r.truncated), where
                assert got.leaving[k].tolist() == (r.eliminated or [False] * n), where
                for key, value in got.infos.items():
                    column = [info[key] for info in r.infos]
                    assert np.array_equal(value[k], column[0] if key == "step" else column), (where, key)
                assert np.array_equal(batch.matches[k].data.qpos, match.data.qpos), where
                assert batch.matches[k].over == match.over and batch.matches[k].steps == match.steps, where
                assert batch.matches[k].standing == match.standing, where
                assert np.array_equal(batch.matches[k].state(), match.state()), where
                seen["left"] += sum(r.eliminated or [])
                if match.over:
                    seen["truncated"] += r.truncated
                    match.reset()
                    batch.reset_one(k)
                    seen["ends"] += 1
    return seen


@pytest.mark.parametrize("backend", ["mujoco", "threads"])
@pytest.mark.parametrize("config", ARRAY_CONFIGS.values(), ids=list(ARRAY_CONFIGS))
def test_step_arrays_equal_each_match_alone_bit_for_bit(config: MatchConfig, backend: str) -> None:
    """The matches judged together give Match's results."""
    assert _step_arrays_against_alone(config, backend)["ends"] >= N_MATCHES


def _elimination_configs() -> dict[str, MatchConfig]:
    """Every elimination scenario, started on the v1 circle with spread positions so that agents leave within
    the steps (and the step limit cuts some matches), plus rosters and observations of other sizes."""
    from triplesumo.model import PhysicsConfig
    from triplesumo.registration import ELIMINATION_SCENARIOS
    from triplesumo.rules import ResetNoise
    from triplesumo.rules.scenarios import scenario_config

    spread = {"max_steps": 30, "reset_noise": ResetNoise(position=0.5), "physics": PhysicsConfig(layout="circle")}
    configs = {name: scenario_config(name, **spread) for name in ELIMINATION_SCENARIOS}
    configs |= {"ffa-4-egocentric": scenario_config("ffa", n_agents=4, obs_mode="egocentric", **spread),
                "pursuit-noise": scenario_config("pursuit", evader_obs_noise=0.2, **spread),
                "pursuit-2-noise-egocentric": scenario_config("pursuit", n_pursuers=2, evader_obs_noise=0.2,
                                                              obs_mode="egocentric", **spread)}
    return configs


ELIMINATION_CONFIGS = _elimination_configs()


@pytest.mark.parametrize("seed", [11, 23])
@pytest.mark.parametrize("backend", ["mujoco", "threads"])
@pytest.mark.parametrize("config", ELIMINATION_CONFIGS.values(), ids=list(ELIMINATION_CONFIGS))
def test_elimination_judged_together_equals_each_match_alone(config: MatchConfig, backend: str, seed: int) -> None:
    """Issue 54: elimination judged over the batch axis at once (who leaves, zero control for the bodies out of
    play, places kept, rewards over the agents in play, terminated or truncated, evader noise from each match's
    own generator) gives each match's own results bit for bit, step for step, for every elimination scenario."""
    seen = _step_arrays_against_alone(config, backend, seed, action_seed=seed)
    assert seen["left"] >= 2 and seen["ends"] >= 2, seen


def test_elimination_is_judged_over_the_batch_not_match_by_match(monkeypatch: pytest.MonkeyPatch) -> None:
    """No per-match judging is left on the batched path: with Match.finish_step out of reach, a batch of free-for-all
    matches still plays through eliminations and ends."""
    config = ELIMINATION_CONFIGS["ffa"]

    def alone(self: Match) -> None:
        raise AssertionError("a match was judged alone")

    monkeypatch.setattr(Match, "finish_step", alone)
    left = ends = 0
    with MatchBatch(config, N_MATCHES, 2, stepper="threads") as batch:
        batch.reset_all(11)
        actions = np.random.default_rng(11).uniform(-1.3, 1.3, (N_STEPS, N_MATCHES, 3, 8))
        for t in range(N_STEPS):
            got = batch.step_arrays(actions[t])
            left += int(got.leaving.sum())
            for k in np.flatnonzero(got.terminated | got.truncated).tolist():
                batch.reset_one(k)
                ends += 1
    assert left >= 2 and ends >= 2


@pytest.mark.parametrize("backend", ["mujoco", "threads"])
def test_step_arrays_with_a_physics_error_and_bad_actions(backend: str) -> None:
    with MatchBatch(None, N_MATCHES, 2, stepper=backend) as batch:
        batch.reset_all(0)
        actions = np.zeros((N_MATCHES, 3, 8))
        actions[1, 2, 0] = np.inf
        with pytest.raises(ValueError, match=r"match 1: action of 'spider' contains NaN or inf"):
            batch.step_arrays(actions)
        with pytest.raises(ValueError, match=r"actions must have shape \(3, 3, 8\)"):
            batch.step_arrays(np.zeros((N_MATCHES, 3, 7)))
        batch.matches[2].data.qvel[:] = 1e12  # MuJoCo's bad-qvel warning and auto-reset
        batch.reload(2)
        got = batch.step_arrays(np.zeros((N_MATCHES, 3, 8)))
        assert got.truncated.tolist() == [False, False, True] and not got.terminated.any()
        assert got.infos["outcome"].tolist() == [[0] * 3, [0] * 3, [OUTCOME_CODES["error"]] * 3]
        assert got.infos["place"].tolist() == [[0] * 3] * 3  # nothing decided: playing, and the error
        assert (got.rewards[2] == 0).all() and np.isfinite(got.observations).all()
        assert "bad_qvel" in (batch.matches[2].physics_error or "")
        assert got.infos["step"].tolist() == [1, 1, 1]
        with pytest.raises(RuntimeError, match=r"matches \[2\] are over"):
            batch.step_arrays(np.zeros((N_MATCHES, 3, 8)))
        batch.reset_one(2)
        assert batch.step_arrays(np.zeros((N_MATCHES, 3, 8))).infos["step"].tolist() == [2, 2, 1]
    with MatchBatch(MatchConfig(on_physics_error="raise"), N_MATCHES, 2, stepper=backend) as batch:
        batch.reset_all(0)
        batch.matches[1].data.qvel[:] = 1e12
        batch.reload(1)
        with pytest.raises(PhysicsError, match="match 1: MuJoCo reported bad_qvel"):
            batch.step_arrays(np.zeros((N_MATCHES, 3, 8)))
        assert [m.steps for m in batch.matches] == [1, 1, 1]


def test_old_names_still_work_with_a_deprecation_warning() -> None:
    """``MatchBatch(backend=...)`` became ``stepper`` (``backend`` names the simulator, cpu or warp, of
    ``vector_env``); the old spellings work for a release and warn."""
    import importlib

    from triplesumo.envs import batch as batch_module

    with pytest.warns(DeprecationWarning, match="stepper"):
        batch = MatchBatch(None, 2, 1, backend="threads")
    with batch:
        assert batch.stepper == "threads"
        with pytest.warns(DeprecationWarning, match="MatchBatch.stepper"):
            assert batch.backend == "threads"
    with pytest.warns(DeprecationWarning, match="STEPPERS"):
        assert batch_module.BACKENDS == batch_module.STEPPERS
    import sys

    sys.modules.pop("triplesumo.evaluation.league_plots", None)
    with pytest.warns(DeprecationWarning, match="tournament_plots"):
        old = importlib.import_module("triplesumo.evaluation.league_plots")
    from triplesumo.evaluation import tournament_plots

    assert old.plot_ladder is tournament_plots.plot_ladder
