"""The game's rules: ring exits, outcomes, sparse and dense reward terms.

Scenario tests put torsos where they need to be (``place`` writes the free joint of an agent
and calls ``mj_forward``), step once with zero action and check what the rules make of it.
"""

from __future__ import annotations

import numpy as np
import pytest

from triplesumo.model import PAPER_AGENTS, AgentSpec, PhysicsConfig
from triplesumo.rules import DENSE_TERMS, DRAW, LOSS, TERMS, WIN, MatchConfig, ResetNoise, RewardConfig, Teams
from triplesumo.rules.batched import BatchedRules
from triplesumo.rules.outcome import OUTCOME_CODES, agents_out, judge, outcome_name
from triplesumo.rules.rewards import REPORTED, RewardRule, dense_terms, reward_terms

ANT, BUG, SPIDER = 0, 1, 2


def reference_dense(pos: np.ndarray, vel: np.ndarray, agents: tuple[AgentSpec, ...],
                    cfg: RewardConfig) -> dict[str, np.ndarray]:
    """The formulas of the rules/rewards.py docstring, written out with plain loops."""
    n = len(agents)
    s = np.sign
    opp, slf, par = np.zeros(n), np.zeros(n), np.zeros(n)
    for i in range(n):
        opponents = [o for o in range(n) if agents[o].team != agents[i].team]
        partners = [j for j in range(n) if j != i and agents[j].team == agents[i].team]
        opp[i] = np.mean([sum(s(pos[o, k] - pos[i, k]) * vel[o, k] for k in range(2)) for o in opponents])
        slf[i] = np.mean([sum(s(pos[o, k] - pos[i, k]) * vel[i, k] for k in range(2)) for o in opponents])
        if partners:
            par[i] = np.mean([np.mean([sum(s(pos[o, k] - pos[j, k]) * vel[j, k] for k in range(2))
                                       for o in opponents]) for j in partners])
    return {
        "reward_opponent_velocity": cfg.opponent_velocity * opp,
        "reward_self_velocity": cfg.self_velocity * slf,
        "reward_partner_velocity": cfg.partner_velocity * par,
        "reward_still": np.full(n, cfg.still),
    }


# ------------------------------------------------------------------------ ring exits
@pytest.mark.parametrize(
    ("who", "coords", "expected"),
    [
        ("spider", {"x": 2.5}, {"ant": WIN, "bug": WIN, "spider": LOSS}),
        ("spider", {"y": -2.5}, {"ant": WIN, "bug": WIN, "spider": LOSS}),
        ("ant", {"x": 2.5}, {"ant": LOSS, "bug": LOSS, "spider": WIN}),
        ("bug", {"y": 2.5}, {"ant": LOSS, "bug": LOSS, "spider": WIN}),
        ("bug", {"x": -2.5}, {"ant": LOSS, "bug": LOSS, "spider": WIN}),
    ],
)
def test_one_agent_out_ends_the_match(make_match, place, zeros, who, coords, expected) -> None:
    match = make_match()
    place(match, who, **coords)
    result = match.step_array(zeros(match))
    assert result.terminated is True
    assert result.truncated is False
    sparse = {WIN: 500.0, LOSS: -400.0}
    for i, agent in enumerate(match.agents):
        info = result.infos[i]
        assert info["outcome"] == OUTCOME_CODES[expected[agent]]
        assert info["reward_outcome"] == sparse[expected[agent]]
        assert info["sparse_reward"] == sparse[expected[agent]]
        assert info["out_of_ring"] is (agent == who)
        assert info["step"] == 1
    assert match.over
    with pytest.raises(RuntimeError):
        match.step_array(zeros(match))


def test_nobody_is_judged_before_a_step(make_match, place) -> None:
    match = make_match()
    place(match, "spider", x=2.5)
    assert match.steps == 0
    assert not match.over


def test_spider_and_bug_out_together_is_a_terminated_draw(make_match, place, zeros) -> None:
    match = make_match()
    place(match, "spider", y=-2.5)
    place(match, "bug", y=2.5)
    result = match.step_array(zeros(match))
    assert result.terminated is True
    assert result.truncated is False
    assert [outcome_name(info["outcome"]) for info in result.infos] == [DRAW, DRAW, DRAW]
    assert [info["reward_outcome"] for info in result.infos] == [0.0, 0.0, 0.0]
    assert [info["out_of_ring"] for info in result.infos] == [False, True, True]


def test_ant_and_bug_out_together_is_still_a_team_loss(make_match, place, zeros) -> None:
    match = make_match()
    place(match, "ant", x=2.5)
    place(match, "bug", y=2.5)
    result = match.step_array(zeros(match))
    assert result.terminated
    assert [outcome_name(info["outcome"]) for info in result.infos] == [LOSS, LOSS, WIN]
    assert result.infos[SPIDER]["reward_outcome"] == 500.0


def test_exit_is_judged_on_the_free_joint_after_the_step_not_stale_xpos(make_match, place, zeros) -> None:
    """Ant flies out along +x; after the step its free joint is past the edge, its xpos is not yet.

    With Euler, ``xpos`` after ``mj_step`` is one substep stale (with RK4 the last stage nearly
    matches the final state, so only Euler tells the two readings apart).
    """
    physics = PhysicsConfig(integrator="Euler")
    trial = make_match(physics=physics)
    place(trial, "ant", x=1.5, vx=3.0)
    trial.step_array(zeros(trial))
    a = trial.sim.agents[ANT]
    after_qpos, after_xpos = trial.data.qpos[a.root_qpos], trial.data.xpos[a.torso_body, 0]
    gap = after_qpos - after_xpos
    assert gap > 0.01  # the flight is fast enough to tell the two apart
    # Motion in the air is translation-invariant: shift the start so that 2 lies mid-gap.
    match = make_match(physics=physics)
    place(match, "ant", x=1.5 + 2.0 - (after_qpos + after_xpos) / 2, vx=3.0)
    result = match.step_array(zeros(match))
    assert match.data.qpos[a.root_qpos] > 2.0 > match.data.xpos[a.torso_body, 0]
    assert result.terminated
    assert outcome_name(result.infos[SPIDER]["outcome"]) == WIN


def test_step_limit_is_a_truncated_draw(make_match, zeros) -> None:
    match = make_match(max_steps=5)
    for _ in range(4):
        result = match.step_array(zeros(match))
        assert not (result.terminated or result.truncated)
        assert all(info["outcome"] == OUTCOME_CODES["playing"] == 0 for info in result.infos)
    result = match.step_array(zeros(match))
    assert result.truncated is True
    assert result.terminated is False
    assert [outcome_name(info["outcome"]) for info in result.infos] == [DRAW] * 3
    assert [info["reward_outcome"] for info in result.infos] == [0.0] * 3
    assert match.over


def test_exit_on_the_last_step_wins_over_the_step_limit(make_match, place, zeros) -> None:
    match = make_match(max_steps=1)
    place(match, "spider", x=2.5)
    result = match.step_array(zeros(match))
    assert result.terminated is True
    assert result.truncated is False
    assert outcome_name(result.infos[BUG]["outcome"]) == WIN


def test_sparse_rewards_come_from_the_config(make_match, place, zeros) -> None:
    cfg = RewardConfig(win=7.0, loss=-3.0)
    match = make_match(reward=cfg)
    place(match, "spider", x=2.5)
    result = match.step_array(zeros(match))
    assert [info["reward_outcome"] for info in result.infos] == [7.0, 7.0, -3.0]
    timed = make_match(max_steps=1, reward=RewardConfig(draw=-1.5))
    result = timed.step_array(zeros(timed))
    assert [info["reward_outcome"] for info in result.infos] == [-1.5] * 3


# ------------------------------------------------------------------ reward invariants
def test_reward_is_the_exact_sum_of_its_terms_over_a_random_rollout(make_match) -> None:
    match = make_match(reset_noise=ResetNoise(), max_steps=150)
    match.reset(seed=3)
    rng = np.random.default_rng(3)
    still = match.config.reward.still
    ended = False
    for _ in range(150):
        result = match.step_array(rng.uniform(-1, 1, (3, 8)))
        for i, info in enumerate(result.infos):
            assert sorted(k for k in info if k.startswith("reward_")) == sorted(TERMS)
            terms_sum = 0.0
            for name in TERMS:
                terms_sum += info[name]
            assert result.rewards[i] == terms_sum
            assert info["dense_reward"] + info["sparse_reward"] == result.rewards[i]
            dense = 0.0
            for name in DENSE_TERMS:
                dense += info[name]
            assert info["dense_reward"] == dense
            assert info["reward_still"] == still
        if result.terminated or result.truncated:
            ended = True
            break
    assert ended


def test_match_terms_follow_the_docstring_formulas(make_match, place, zeros) -> None:
    """Spider flies away from Bug; the terms equal the written-out formulas on the post-step state."""
    match = make_match()
    place(match, "ant", x=1.5, y=1.5)
    place(match, "bug", x=-1.5, y=1.5)
    place(match, "spider", x=0.5, y=-1.5, vx=1.0, vy=-0.5)
    result = match.step_array(zeros(match))
    pos, vel = match.sim.torso_positions(), match.sim.torso_velocities()
    # the hand-built velocities survive the step (agents in the air, no contacts)
    assert vel[SPIDER, 0] > 0.5 and vel[SPIDER, 1] < -0.2
    assert result.infos[BUG]["reward_opponent_velocity"] > 0
    expected = reference_dense(pos, vel, PAPER_AGENTS, RewardConfig())
    c1 = RewardConfig().opponent_velocity
    bug_opp = c1 * (abs(vel[SPIDER, 0]) + np.sign(pos[SPIDER, 1] - pos[BUG, 1]) * vel[SPIDER, 1])
    assert result.infos[BUG]["reward_opponent_velocity"] == pytest.approx(bug_opp, rel=1e-12)
    for i in range(3):
        for name, values in expected.items():
            assert result.infos[i][name] == pytest.approx(values[i], rel=1e-12, abs=1e-12), (i, name)
    assert result.infos[SPIDER]["reward_partner_velocity"] == 0.0


def test_dense_terms_on_hand_made_arrays_spider_moves() -> None:
    teams = Teams.from_agents(PAPER_AGENTS)
    cfg = RewardConfig()
    pos = np.array([[1.0, 1.0], [-1.0, 1.0], [0.5, -1.0]])
    vel = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, -0.5]])
    terms = dense_terms(pos, vel, teams, cfg)
    # Spider moves away from Bug in x and y: +5 * (1 + 0.5); toward Ant in x, away in y: 5 * (-1 + 0.5).
    np.testing.assert_array_equal(terms["reward_opponent_velocity"], [-2.5, 7.5, 0.0])
    # Spider's self term: mean over Ant (1 - 0.5) and Bug (-1 - 0.5), times 5.
    np.testing.assert_array_equal(terms["reward_self_velocity"], [0.0, 0.0, -2.5])
    np.testing.assert_array_equal(terms["reward_partner_velocity"], [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(terms["reward_still"], [-4.0, -4.0, -4.0])


def test_dense_terms_on_hand_made_arrays_bug_moves_toward_spider() -> None:
    teams = Teams.from_agents(PAPER_AGENTS)
    cfg = RewardConfig()
    pos = np.array([[1.0, 1.0], [-1.0, 1.0], [0.5, -1.0]])
    vel = np.array([[0.0, 0.0], [0.6, -0.8], [0.0, 0.0]])
    terms = dense_terms(pos, vel, teams, cfg)
    # Bug toward Spider: 5 * (0.6 + 0.8); Ant's partner term sees the same; Spider's opponent
    # term is the mean over Ant (still, 0) and Bug (coming closer, -1.4).
    np.testing.assert_allclose(terms["reward_self_velocity"], [0.0, 7.0, 0.0], rtol=1e-12)
    np.testing.assert_allclose(terms["reward_partner_velocity"], [7.0, 0.0, 0.0], rtol=1e-12)
    np.testing.assert_allclose(terms["reward_opponent_velocity"], [0.0, 0.0, -3.5], rtol=1e-12)
    # moving away flips every sign
    flipped = dense_terms(pos, -vel, teams, cfg)
    for name in ("reward_self_velocity", "reward_partner_velocity", "reward_opponent_velocity"):
        np.testing.assert_allclose(flipped[name], -terms[name], rtol=1e-12)


@pytest.mark.parametrize(
    "agents",
    [
        PAPER_AGENTS,
        (AgentSpec("p0", "p", 0.2), AgentSpec("p1", "p", 0.2), AgentSpec("p2", "p", 0.2), AgentSpec("e", "e", 0.2)),
        (AgentSpec("a", "a", 0.2), AgentSpec("b", "b", 0.2), AgentSpec("c", "c", 0.2)),
    ],
    ids=["paper", "3-vs-1", "free-for-all"],
)
def test_dense_terms_equal_reference_on_random_arrays(agents) -> None:
    rng = np.random.default_rng(7)
    cfg = RewardConfig(opponent_velocity=1.5, self_velocity=2.0, partner_velocity=3.0, still=-0.5)
    teams = Teams.from_agents(agents)
    for _ in range(20):
        pos = rng.uniform(-2, 2, (len(agents), 3))
        vel = rng.normal(size=(len(agents), 3))
        got = dense_terms(pos, vel, teams, cfg)
        want = reference_dense(pos, vel, agents, cfg)
        for name in want:
            np.testing.assert_allclose(got[name], want[name], rtol=1e-12, atol=1e-12, err_msg=name)


def test_reward_weights_flow_through(make_match) -> None:
    base = make_match(reset_noise=ResetNoise())
    double = make_match(reset_noise=ResetNoise(),
                        reward=RewardConfig(opponent_velocity=10.0, self_velocity=0.0, still=-1.0))
    base.reset(seed=11)
    double.reset(seed=11)
    rng = np.random.default_rng(11)
    for _ in range(10):
        action = rng.uniform(-1, 1, (3, 8))
        a, b = base.step_array(action), double.step_array(action)
        for ia, ib in zip(a.infos, b.infos, strict=True):
            assert ib["reward_opponent_velocity"] == 2 * ia["reward_opponent_velocity"]
            assert ib["reward_self_velocity"] == 0.0
            assert ib["reward_partner_velocity"] == ia["reward_partner_velocity"]
            assert ib["reward_still"] == -1.0
    assert any(info["reward_opponent_velocity"] != 0.0 for info in a.infos)


def test_reward_rows_and_their_sums() -> None:
    """Rows are TERMS then dense and sparse; dense + sparse is the TERMS sum in order, bit for bit."""
    rule = RewardRule(Teams.from_agents(PAPER_AGENTS), RewardConfig(still=-0.3))
    rng = np.random.default_rng(5)
    assert REPORTED == (*TERMS, "dense_reward", "sparse_reward")
    for results, timed_out in [(None, False), (None, True), ([WIN, LOSS], False), ([DRAW, DRAW], False)]:
        pos, vel = rng.uniform(-2, 2, (3, 3)).tolist(), rng.normal(size=(3, 3)).tolist()
        rows = rule.rows(pos, vel, results, timed_out)
        assert len(rows) == 3
        for row, dense, sparse in zip(rows, rule.dense(pos, vel), rule.outcome(results, timed_out), strict=True):
            assert len(row) == len(REPORTED)
            assert row[:3] == dense and row[3] == -0.3 and row[4] == sparse == row[6]
            assert row[5] == row[0] + row[1] + row[2] + row[3]
            in_order = 0.0
            for value in row[:5]:
                in_order += value
            assert row[5] + row[6] == in_order


# -------------------------------------------------------------------------- judging
@pytest.mark.parametrize(
    ("team_of", "out", "expected"),
    [
        # the paper's roster: ant, bug (team 0), spider (team 1)
        ([0, 0, 1], [False, False, False], None),
        ([0, 0, 1], [False, False, True], [WIN, LOSS]),
        ([0, 0, 1], [True, False, False], [LOSS, WIN]),
        ([0, 0, 1], [False, True, False], [LOSS, WIN]),
        ([0, 0, 1], [True, True, False], [LOSS, WIN]),
        ([0, 0, 1], [False, True, True], [DRAW, DRAW]),
        ([0, 0, 1], [True, True, True], [DRAW, DRAW]),
        # 3 pursuers (team 0) against 1 evader (team 1)
        ([0, 0, 0, 1], [False, True, False, False], [LOSS, WIN]),
        ([0, 0, 0, 1], [False, False, False, True], [WIN, LOSS]),
        ([0, 0, 0, 1], [True, False, True, True], [DRAW, DRAW]),
        # free-for-all: three one-agent teams
        ([0, 1, 2], [True, False, False], [LOSS, WIN, WIN]),
        ([0, 1, 2], [True, False, True], [LOSS, WIN, LOSS]),
        ([0, 1, 2], [True, True, True], [DRAW, DRAW, DRAW]),
    ],
)
def test_judge_precedence(team_of, out, expected) -> None:
    roster = tuple(AgentSpec(f"a{i}", f"t{t}", 0.2) for i, t in enumerate(team_of))
    rules = BatchedRules.build(MatchConfig(agents=roster), half_size=2.0)
    codes = judge(np.array([out]), rules, np)[0].tolist()
    want = [OUTCOME_CODES["playing"]] * len(team_of) if expected is None else [OUTCOME_CODES[expected[t]]
                                                                                 for t in team_of]
    assert codes == want


def test_agents_out_is_strict_and_uses_both_axes() -> None:
    xy = np.array([[2.0, 0.0], [2.0001, 0.0], [0.0, -2.0001], [-1.9, 1.9], [-2.5, 3.0]])
    assert agents_out(xy, 2.0, np).tolist() == [False, True, True, False, True]


def test_outcome_term() -> None:
    teams = Teams.from_agents(PAPER_AGENTS)
    rule = RewardRule(teams, RewardConfig())
    assert rule.outcome(None, timed_out=False) == [0, 0, 0]
    assert RewardRule(teams, RewardConfig(draw=-2.0)).outcome(None, timed_out=True) == [-2] * 3
    assert rule.outcome([WIN, LOSS], timed_out=False) == [500, 500, -400]
    assert rule.outcome([DRAW, DRAW], timed_out=False) == [0, 0, 0]


def _walk_at_pays(agents: list[str], pos: np.ndarray, rule: RewardRule, who: str, target: str,
                  speed: float = 0.3) -> float:
    """The self-velocity term of ``who`` walking straight at ``target`` at ``speed`` m/s, everyone else still."""
    i, j = agents.index(who), agents.index(target)
    direction = (pos[j] - pos[i]) / np.linalg.norm(pos[j] - pos[i])
    vel = np.zeros((len(agents), 3))
    vel[i, :2] = speed * direction
    return rule.dense(pos.tolist(), vel.tolist())[i][1]


def test_axis_dead_zone_pays_spider_for_walking_at_ant_on_every_fair_start() -> None:
    """On env v2's fair start Spider stands level with Ant in y and with Bug in x, so with the paper's sign
    the 2 cm reset noise decides whether walking at Ant pays Spider twice the one-opponent term or nothing
    (the other opponent's axis sign); Ant is paid alike on every start. A dead zone wider than the noise pays
    Spider half (its mean over two opponents) on every start."""
    import triplesumo

    env = triplesumo.parallel_env()
    c2, speed = RewardConfig().self_velocity, 0.3
    paid: dict[float, set[float]] = {0.0: set(), 0.25: set()}
    ant_paid = set()
    for seed in range(40):
        env.reset(seed=seed)
        match = env.match
        agents = list(match.agents)
        pos = match.sim.torso_positions()[:, :2].astype(np.float64)
        for dead in paid:
            rule = RewardRule(Teams.from_agents(PAPER_AGENTS), RewardConfig(axis_dead_zone=dead))
            paid[dead].add(round(_walk_at_pays(agents, pos, rule, "spider", "ant", speed) / (c2 * speed), 1))
            ant_paid.add(round(_walk_at_pays(agents, pos, rule, "ant", "spider", speed) / (c2 * speed), 1))
    assert paid[0.0] == {0.0, 1.0}  # the coin flip of the paper's sign: nothing or double the half share
    assert paid[0.25] == {0.5}  # half (two opponents), every start
    assert ant_paid == {1.0}  # one opponent: the whole term, on every start, with or without the band


def test_axis_dead_zone_zero_is_the_paper_sign_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    teams = Teams.from_agents(PAPER_AGENTS)
    default, zero = RewardRule(teams, RewardConfig()), RewardRule(teams, RewardConfig(axis_dead_zone=0.0))
    for _ in range(50):
        pos, vel = rng.uniform(-2, 2, (3, 3)).tolist(), rng.normal(size=(3, 3)).tolist()
        assert default.dense(pos, vel) == zero.dense(pos, vel)
    wide = RewardRule(teams, RewardConfig(axis_dead_zone=10.0))  # every axis inside the band: no velocity terms
    assert wide.dense(pos, vel) == [(0.0, 0.0, 0.0)] * 3


def test_opponents_sum_pays_spider_each_opponent_at_full_weight() -> None:
    """``RewardConfig.opponents``: ``mean`` (default) averages Spider's per-opponent velocity terms over Ant and
    Bug, ``sum`` adds them, so Spider's terms double and Ant's and Bug's (one opponent each) stay bit for bit."""
    rng = np.random.default_rng(5)
    teams = Teams.from_agents(PAPER_AGENTS)
    mean, total = RewardRule(teams, RewardConfig()), RewardRule(teams, RewardConfig(opponents="sum"))
    sum_rules = BatchedRules.from_roster(teams, RewardConfig(opponents="sum"), 2.0, 0, 1.0)
    mean_rules = BatchedRules.from_roster(teams, RewardConfig(), 2.0, 0, 1.0)
    spider = [a.name for a in PAPER_AGENTS].index("spider")
    for _ in range(50):
        pos, vel = rng.uniform(-2, 2, (3, 3)).tolist(), rng.normal(size=(3, 3)).tolist()
        m, t = mean.dense(pos, vel), total.dense(pos, vel)
        for i in range(3):
            if i == spider:
                assert t[i][:2] == pytest.approx((2 * m[i][0], 2 * m[i][1])) and t[i][2] == m[i][2] == 0.0
            else:
                assert t[i] == m[i]
        in_play = reward_terms(np.array([pos]), np.array([vel]), None, None, sum_rules, np,
                               alive=np.ones((1, 3), bool), sparse=np.zeros((1, 3)))  # elimination, all in play
        assert np.stack([in_play[k][0] for k in DENSE_TERMS[:3]], axis=1).tolist() == [list(row) for row in t]
        alive = [True] * 3
        alive[int(rng.integers(3))] = False  # one out: nobody has two opponents in play, so sum is mean
        in_play = [reward_terms(np.array([pos]), np.array([vel]), None, None, r, np, alive=np.array([alive]),
                                sparse=np.zeros((1, 3))) for r in (sum_rules, mean_rules)]
        for name in DENSE_TERMS:
            assert in_play[0][name].tolist() == in_play[1][name].tolist()
    with pytest.raises(ValueError, match=r"RewardConfig.opponents must be one of \('mean', 'sum'\), got 'max'"):
        RewardConfig(opponents="max")
