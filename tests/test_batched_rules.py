"""The rules, written once over arrays (one match, the CPU vector env and MuJoCo Warp call the same functions),
equal an independent plain-Python reference (``tests/rules_reference.py``) and give the same on numpy and torch.

On numpy, for several rosters: ring exits and outcome codes against the reference ``judge``, every reward
term against its ``rows`` (bit for bit), elimination's places, codes and rewards against its
``judge_elimination`` and ``rows_in_play``; both observation modes of many matches stacked together against
each match's own ``ObservationBuilder.build`` over real rollouts.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import rules_reference as R
from triplesumo.envs.match import Match
from triplesumo.model import AgentSpec
from triplesumo.rules import MatchConfig, RewardConfig, Teams
from triplesumo.rules import batched as B
from triplesumo.rules import outcome as O
from triplesumo.rules.rewards import REPORTED

ROSTERS = {
    "paper": MatchConfig().agents,
    "3-vs-1": (AgentSpec("p0", "p", 0.2), AgentSpec("p1", "p", 0.2), AgentSpec("p2", "p", 0.2),
               AgentSpec("e", "e", 0.22)),
    "free-for-all": (AgentSpec("a", "a", 0.2), AgentSpec("b", "b", 0.2), AgentSpec("c", "c", 0.2)),
    "2-vs-2": (AgentSpec("a", "x", 0.2), AgentSpec("b", "x", 0.2), AgentSpec("c", "y", 0.2),
               AgentSpec("d", "y", 0.2)),
}


@pytest.mark.parametrize(("dead_zone", "opponents"), [(0.0, "mean"), (0.3, "mean"), (0.0, "sum")],
                         ids=["sign", "dead-zone", "sum"])
@pytest.mark.parametrize("roster", ROSTERS.values(), ids=list(ROSTERS))
def test_outcomes_and_reward_terms_equal_the_per_match_rules(roster, dead_zone: float, opponents: str) -> None:
    cfg = MatchConfig(agents=roster, reward=RewardConfig(win=500.0, loss=-400.0, draw=-7.0, axis_dead_zone=dead_zone,
                                                         opponents=opponents))
    rules = B.BatchedRules.build(cfg, half_size=2.0)
    teams = Teams.from_agents(roster)
    rule = R.ReferenceRewardRule(teams, cfg.reward)
    team_of = teams.team_of.tolist()
    rng = np.random.default_rng(7)
    e, n = 400, len(roster)
    pos = rng.uniform(-2.3, 2.3, (e, n, 3))
    pos[: e // 4] = np.clip(pos[: e // 4], -1.9, 1.9)  # a quarter with nobody out
    pos[5, :, :2] = 0.0  # equal coordinates: sign 0
    pos[6, :, 0] = pos[6, 0, 0] + rng.uniform(-0.25, 0.25, n)  # level within the dead zone in x
    vel = rng.normal(0.0, 1.0, (e, n, 3))
    timed_out = rng.uniform(size=e) < 0.3
    out = B.agents_out(pos, 2.0, np)
    code = B.judge(out, rules, np)
    terms = B.reward_terms(pos, vel, code, timed_out, rules, np)
    seen = set()
    for k in range(e):
        ref_out = R.agents_out(pos[k].tolist(), 2.0)
        assert out[k].tolist() == ref_out
        results = R.judge(ref_out, team_of, len(teams.names))
        expected = [O.PLAYING if results is None else O.OUTCOME_CODES[results[t]] for t in team_of]
        assert code[k].tolist() == expected
        seen.update(expected)
        rows = np.array(rule.rows(pos[k].tolist(), vel[k].tolist(), results, bool(timed_out[k])))
        for j, name in enumerate(REPORTED):  # bit for bit: vector_env's CPU results equal Match's
            np.testing.assert_array_equal(terms[name][k], rows[:, j], err_msg=name)
        np.testing.assert_array_equal(terms["reward"][k], rows[:, -2] + rows[:, -1])
    assert {0, 1, 2} <= seen  # the draw (3) needs every team out: reached with 2 teams only by chance
    assert 3 in seen or len(set(team_of)) > 2


@pytest.mark.parametrize("xp", [np, torch], ids=["numpy", "torch"])
def test_first_out_places_of_every_outcome_code(xp) -> None:
    """One definition of the place on every path (per match, vector, Warp): 1 for a win or a draw, 2 for a
    loss, 0 while playing and after a physics error -- an error decides nothing, the place of reset's infos
    (the batched copy once gave it place 1, the Warp copy 0)."""
    assert B.first_out_places is O.first_out_places
    codes = [O.OUTCOME_CODES[name] for name in ("playing", "win", "loss", "draw", "error")]
    places = O.first_out_places(xp.asarray([codes, codes[::-1]]), xp)
    assert places.tolist() == [[0, 1, 2, 1, 0], [0, 1, 2, 1, 0][::-1]]
    assert places.dtype == (np.int64 if xp is np else torch.int64)


def test_bad_state_flags_nan_inf_and_exploding_rows() -> None:
    ok = np.zeros((4, 5))
    bad = ok.copy()
    bad[1, 2], bad[2, 0], bad[3, 4] = np.nan, -np.inf, 2e10
    assert B.bad_state(np, ok, bad).tolist() == [False, True, True, True]
    assert B.bad_state(np, ok).tolist() == [False] * 4


@pytest.mark.parametrize("obs_mode", ["paper", "egocentric"])
@pytest.mark.parametrize("roster", [ROSTERS["paper"], ROSTERS["2-vs-2"]], ids=["paper", "2-vs-2"])
def test_observations_equal_the_observation_builder_over_rollouts(obs_mode: str, roster) -> None:
    cfg = MatchConfig(agents=roster, obs_mode=obs_mode, contact_force_clip=30.0)
    matches = [Match(cfg) for _ in range(3)]
    rules = B.BatchedRules.build(cfg, matches[0].half_size)
    rng = np.random.default_rng(3)
    for k, m in enumerate(matches):
        m.reset(seed=k)
    clipped = 0
    for _ in range(40):
        built = []
        for m in matches:
            if m.over:
                m.reset()
            m.step_array(rng.uniform(-1, 1, (m.n_agents, 8)))
            built.append(np.stack(m.observer.build()))
        sims = [m.sim for m in matches]
        pos = np.stack([s.torso_positions() for s in sims])
        vel = np.stack([s.torso_velocities() for s in sims])
        forces = np.stack([s.contact_forces() for s in sims])
        clipped += int((np.abs(forces) > cfg.contact_force_clip).sum())
        if obs_mode == "paper":
            qpos = np.stack([s.data.qpos for s in sims])
            qvel = np.stack([s.data.qvel for s in sims])
            got = B.paper_observation(pos, vel, forces, qpos, qvel, rules, np)[:, None, :].repeat(m.n_agents, 1)
        else:
            sim = sims[0]
            g = sim.geom_counts[0]
            args = (pos, vel, np.stack([s.torso_quaternions() for s in sims]),
                    np.stack([s.torso_angular_velocities() for s in sims]),
                    np.stack([s.data.qpos[np.stack([a.joint_qpos for a in sim.agents])] for s in sims]),
                    np.stack([s.data.qvel[np.stack([a.joint_qvel for a in sim.agents])] for s in sims]),
                    forces.reshape(len(sims), m.n_agents, g, 3))
            got = B.egocentric_observation(*args, rules, np)
            on_torch = B.egocentric_observation(*(torch.as_tensor(a) for a in args), rules.to(torch.as_tensor), torch)
            np.testing.assert_allclose(on_torch.numpy(), got, rtol=1e-12, atol=1e-12)  # one code, two namespaces
        assert got.shape == np.stack(built).shape
        np.testing.assert_allclose(got.astype(np.float32), np.stack(built), rtol=1e-6, atol=1e-5)
    assert clipped > 0  # the clip was exercised


def test_reward_terms_with_a_dead_zone_equal_on_torch_and_numpy() -> None:
    """The Warp backend judges on torch: the dead zone's band reads alike there (float64, bit for bit)."""
    cfg = MatchConfig(reward=RewardConfig(draw=-200.0, axis_dead_zone=0.25))
    rules = B.BatchedRules.build(cfg, half_size=2.0)
    rules_t = rules.to(lambda a: torch.as_tensor(a, dtype=torch.float64) if a.dtype != np.int64 else torch.as_tensor(a))
    rng = np.random.default_rng(11)
    pos, vel = rng.uniform(-1.9, 1.9, (64, 3, 3)), rng.normal(0.0, 1.0, (64, 3, 3))
    pos[:16, :, 1] = pos[:16, :1, 1] + rng.uniform(-0.3, 0.3, (16, 3))  # level in y, inside and outside the band
    code, timed_out = np.zeros((64, 3), dtype=np.int64), np.zeros(64, dtype=bool)
    ref = B.reward_terms(pos, vel, code, timed_out, rules, np)
    got = B.reward_terms(torch.as_tensor(pos), torch.as_tensor(vel), torch.as_tensor(code),
                         torch.as_tensor(timed_out), rules_t, torch)
    for name, value in ref.items():
        np.testing.assert_array_equal(got[name].numpy(), value, err_msg=name)
    plain = B.reward_terms(pos, vel, code, timed_out, B.BatchedRules.build(MatchConfig(), 2.0), np)
    assert not np.array_equal(plain["reward_self_velocity"], ref["reward_self_velocity"])  # the band acts


ELIMINATION_ROSTERS = {"free-for-all": ROSTERS["free-for-all"], "2-vs-2": ROSTERS["2-vs-2"],
                       "pursuit": ROSTERS["3-vs-1"],
                       "four-alone": tuple(AgentSpec(c, c, 0.2) for c in "abcd")}


@pytest.mark.parametrize("opponents", ["mean", "sum"])
@pytest.mark.parametrize("roster", ELIMINATION_ROSTERS.values(), ids=list(ELIMINATION_ROSTERS))
def test_elimination_equals_the_reference_and_torch(roster, opponents: str) -> None:
    """Elimination, once over arrays: who leaves, who plays on, the places each shares, the outcome codes, the
    placement rewards and every reward term (agents out of play get zeros) equal the plain-Python reference
    for random states of many matches at once; torch gives the same bits."""
    evader = roster[-1].name if len(roster) == 4 and roster[0].team == roster[1].team == roster[2].team else None
    cfg = MatchConfig(agents=roster, rules="elimination", evader=evader,
                      reward=RewardConfig(win=300.0, loss=-100.0, draw=0.0, opponents=opponents))
    rules = B.BatchedRules.build(cfg, half_size=2.0)
    teams = Teams.from_agents(roster)
    team_of = teams.team_of.tolist()
    timeout_team = team_of[cfg.agent_names.index(evader)] if evader else None
    rng = np.random.default_rng(5)
    e, n = 600, len(roster)
    alive = rng.uniform(size=(e, n)) < 0.75
    pos = rng.uniform(-2.4, 2.4, (e, n, 3))
    vel = rng.normal(0.0, 1.0, (e, n, 3))
    at_limit = rng.uniform(size=e) < 0.3
    out = B.agents_out(pos, 2.0, np)
    judged = B.judge_elimination(alive, out, at_limit, rules, np)
    sparse = B.place_values(judged.low, judged.high, rules, np)
    terms = B.reward_terms(pos, vel, None, None, rules, np, alive=alive, sparse=sparse)
    reference = R.ReferenceRewardRule(teams, cfg.reward)
    seen = set()
    for k in range(e):
        ref = R.judge_elimination(alive[k].tolist(), out[k].tolist(), team_of, bool(at_limit[k]), timeout_team)
        assert judged.leaving[k].tolist() == ref.leaving
        assert judged.alive[k].tolist() == ref.alive
        assert bool(judged.over[k]) == ref.over
        ends = (bool(judged.terminated[k]), bool(judged.truncated[k]))
        assert ends == (ref.terminated, ref.over and not ref.terminated)
        assert list(zip(judged.low[k].tolist(), judged.high[k].tolist(), strict=True)) == ref.spans
        codes = [O.PLAYING if o is None else O.OUTCOME_CODES[o] for o in ref.outcomes]
        assert judged.code[k].tolist() == codes
        seen.update(codes)
        ref_sparse = [R.place_value(300.0, -100.0, lo, hi, len(teams.names)) if lo else 0.0 for lo, hi in ref.spans]
        assert sparse[k].tolist() == ref_sparse  # the same formula, bit for bit
        rows = np.array(reference.rows_in_play(pos[k].tolist(), vel[k].tolist(), alive[k].tolist(), ref_sparse))
        for j, name in enumerate(REPORTED):  # the reference divides after the weight: equal to rounding
            np.testing.assert_allclose(terms[name][k], rows[:, j], rtol=1e-12, atol=1e-12, err_msg=name)
    assert {O.PLAYING, O.WIN_CODE, O.LOSS_CODE} <= seen
    on_torch = B.judge_elimination(torch.as_tensor(alive), torch.as_tensor(out), torch.as_tensor(at_limit),
                                   rules.to(torch.as_tensor), torch)
    for field in ("leaving", "alive", "over", "low", "high", "code", "terminated", "truncated"):
        np.testing.assert_array_equal(getattr(on_torch, field).numpy(), getattr(judged, field), err_msg=field)
    t_terms = B.reward_terms(torch.as_tensor(pos), torch.as_tensor(vel), None, None, rules.to(torch.as_tensor), torch,
                             alive=torch.as_tensor(alive), sparse=torch.as_tensor(sparse))
    for name, value in terms.items():
        np.testing.assert_array_equal(t_terms[name].numpy(), value, err_msg=name)


def test_one_match_calls_the_array_rules() -> None:
    """No second copy of a rule: the match core's step reads the functions of the rules' modules."""
    import inspect

    from triplesumo.envs import match

    source = inspect.getsource(match.Match)
    for used in ("rules_outcome.agents_out", "rules_outcome.judge(", "rules_rewards.reward_terms",
                 "rules_outcome.judge_elimination", "rules_outcome.place_values"):
        assert used in source, used
    assert B.reward_terms is __import__("triplesumo.rules.rewards", fromlist=["x"]).reward_terms
