"""The batched rules (rules/batched.py, over arrays) equal the per-match rules Match uses.

On numpy, for several rosters: ring exits and outcome codes against ``outcome.judge``,
every reward term against ``RewardRule.rows`` (bit for bit), and both observation modes against
``ObservationBuilder.build`` over real rollouts of several matches stacked together.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from triplesumo.envs.match import Match
from triplesumo.model import AgentSpec
from triplesumo.rules import MatchConfig, RewardConfig, Teams
from triplesumo.rules import batched as B
from triplesumo.rules import outcome as O
from triplesumo.rules.rewards import REPORTED, RewardRule

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
    rule = RewardRule(teams, cfg.reward)
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
        ref_out = O.agents_out(pos[k].tolist(), 2.0)
        assert out[k].tolist() == ref_out
        results = O.judge(ref_out, team_of, len(teams.names))
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
