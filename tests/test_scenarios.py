"""Named scenarios: the ecosystem's checkers on each, and scenario tests that put agents past the edge."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test
from pettingzoo.utils.conversions import parallel_to_aec

import triplesumo
from triplesumo.envs.parallel import TripleSumoParallelEnv
from triplesumo.registration import ENV_IDS
from triplesumo.rules import TERMS
from triplesumo.rules.config import ResetNoise, RewardConfig
from triplesumo.rules.outcome import DRAW_CODE as DRAW
from triplesumo.rules.outcome import LOSS_CODE as LOSS
from triplesumo.rules.outcome import WIN_CODE as WIN
from triplesumo.rules.outcome import place_value
from triplesumo.rules.scenarios import SCENARIOS, get_scenario

ALL = triplesumo.scenarios()
NO_NOISE = ResetNoise(position=0.0, yaw=0.0, joints=0.0, velocity=0.0)
ELIMINATION = ("ffa", "pursuit")


def make(scenario: str, **fields: object) -> TripleSumoParallelEnv:
    """A noise-free env of ``scenario``, reset with seed 0."""
    fields.setdefault("reset_noise", NO_NOISE)
    env = triplesumo.parallel_env(scenario=scenario, **fields)
    env.reset(seed=0)
    return env


def zero_actions(env: TripleSumoParallelEnv) -> dict[str, np.ndarray]:
    return {a: np.zeros(8, np.float32) for a in env.agents}


# ------------------------------------------------------------------------ names and checkers
def test_scenarios_are_named_and_registered() -> None:
    assert ALL[:4] == ("paper", "ffa", "pursuit", "2v2")
    for name in ALL:
        sc = get_scenario(name)
        assert sc.gym_id in ENV_IDS and sc.gym_id in gym.registry
        env = triplesumo.parallel_env(scenario=name)
        assert env.metadata["name"] == sc.pettingzoo_name
        assert sc.pettingzoo_name == ("triplesumo_v2" if name == "paper" else f"triplesumo_{name}_v2")
        assert f"### {name}" in (TripleSumoParallelEnv.__doc__ or "")
        for section in ("## Agents", "## Rules", "## Rewards", "## Episode End"):
            assert section in sc.doc
    assert triplesumo.parallel_env().config == triplesumo.parallel_env(scenario="paper").config


@pytest.mark.parametrize("scenario", ALL)
def test_pettingzoo_parallel_api_test(scenario: str) -> None:
    # long enough for random play to eliminate agents (ring exits after ~80-170 steps)
    parallel_api_test(triplesumo.parallel_env(scenario=scenario, max_steps=250), num_cycles=250)


@pytest.mark.parametrize("scenario", ALL)
def test_pettingzoo_parallel_seed_test(scenario: str) -> None:
    parallel_seed_test(lambda: triplesumo.parallel_env(scenario=scenario, max_steps=40))


@pytest.mark.parametrize("scenario", ALL)
def test_pettingzoo_aec_api_test(scenario: str) -> None:
    api_test(parallel_to_aec(triplesumo.parallel_env(scenario=scenario, max_steps=200)), num_cycles=200)


@pytest.mark.parametrize("scenario", ALL)
def test_gymnasium_check_env_on_each_scenario_id(scenario: str) -> None:
    env = gym.make(get_scenario(scenario).gym_id)
    assert env.unwrapped.scenario == scenario  # type: ignore[attr-defined]
    gym_check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("scenario", ALL)
def test_reward_is_sum_of_terms_and_infos_keep_their_keys(scenario: str) -> None:
    env = triplesumo.parallel_env(scenario=scenario, max_steps=300)
    rng = np.random.default_rng(5)
    _, infos = env.reset(seed=5)
    keys = None
    for info in infos.values():
        assert info["place"] == 0 and info["eliminated"] is False
    n_state = env.state_space.shape[0]
    left = 0
    while env.agents:
        actions = {a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents}
        obs, rewards, terms, truncs, infos = env.step(actions)
        assert env.state().shape == (n_state,)
        for agent, info in infos.items():
            assert rewards[agent] == sum(info[t] for t in TERMS)
            assert isinstance(info["place"], int) and isinstance(info["eliminated"], bool)
            keys = keys or set(info)
            assert set(info) == keys
            if terms[agent] or truncs[agent]:
                assert info["place"] >= 1
                left += 1
    assert left == len(env.possible_agents)


def test_scenario_options_are_checked() -> None:
    with pytest.raises(ValueError, match="unknown option.*n_pursuers"):
        triplesumo.parallel_env(scenario="ffa", n_pursuers=2)
    with pytest.raises(ValueError, match="n_agents must be an integer >= 2"):
        triplesumo.parallel_env(scenario="ffa", n_agents=1)
    with pytest.raises(ValueError, match="unknown scenario 'sumo'"):
        triplesumo.parallel_env(scenario="sumo")
    with pytest.raises(ValueError, match="team_sizes"):
        triplesumo.parallel_env(scenario="2v2", team_sizes=(3,))
    with pytest.raises(ValueError, match="evader_obs_noise needs an evader"):
        triplesumo.parallel_env(scenario="ffa", evader_obs_noise=0.1)
    with pytest.raises(ValueError, match="evader needs rules='elimination'"):
        triplesumo.parallel_env(scenario="paper", evader="spider")


def test_ffa_any_size_has_distinct_colours_and_one_team_each() -> None:
    env = triplesumo.parallel_env(scenario="ffa", n_agents=5)
    agents = env.config.agents
    assert len(agents) == 5 and len({a.team for a in agents}) == 5
    assert len({a.rgba for a in agents}) == 5
    geom_rgba = {tuple(np.round(env.match.model.geom_rgba[g], 3)) for g in env.match.sim.agent_geoms}
    assert len(geom_rgba) >= 5


# ------------------------------------------------------------------------ ffa: agents leave
def test_ffa_one_out_only_it_terminates_and_leaves(place) -> None:
    env = make("ffa")
    place(env.match, "bug", x=2.5)
    _, rewards, terms, truncs, infos = env.step(zero_actions(env))
    assert terms == {"ant": False, "bug": True, "spider": False}
    assert not any(truncs.values())
    assert infos["bug"]["place"] == 3 and infos["bug"]["outcome"] == LOSS and infos["bug"]["eliminated"]
    assert infos["bug"]["reward_outcome"] == -400.0
    assert infos["ant"]["place"] == 0 and infos["ant"]["reward_outcome"] == 0.0 and not infos["ant"]["eliminated"]
    assert env.agents == ["ant", "spider"]
    assert env.state()[-3:].tolist() == [0.0, 1.0, 0.0]
    with pytest.raises(ValueError, match="eliminated \\['bug'\\]"):
        env.step({a: np.zeros(8) for a in ("ant", "bug", "spider")})
    obs, rewards, terms, _, infos = env.step(zero_actions(env))
    assert set(obs) == set(rewards) == set(terms) == set(infos) == {"ant", "spider"}
    assert env.agents == ["ant", "spider"]


def test_ffa_eliminated_body_gets_zero_control(place) -> None:
    env = make("ffa")
    match = env.match
    place(match, "bug", x=2.5)
    env.step(zero_actions(env))
    match.step_array(np.ones((3, 8)))
    ctrl = match.data.ctrl[match.sim.actuator_ids]
    assert np.all(ctrl[1] == 0.0)
    assert np.all(ctrl[0] == pytest.approx(0.2)) and np.all(ctrl[2] == pytest.approx(0.2))


def test_ffa_two_out_together_share_a_place_and_the_last_one_wins(place) -> None:
    env = make("ffa")
    place(env.match, "ant", x=2.5)
    place(env.match, "bug", y=-2.5)
    _, rewards, terms, _, infos = env.step(zero_actions(env))
    shared = (50.0 + -400.0) / 2
    for agent in ("ant", "bug"):
        assert infos[agent]["place"] == 2 and infos[agent]["outcome"] == LOSS
        assert infos[agent]["reward_outcome"] == shared
    assert infos["spider"]["place"] == 1 and infos["spider"]["outcome"] == WIN
    assert infos["spider"]["reward_outcome"] == 500.0
    assert all(terms.values()) and env.agents == []


def test_ffa_places_in_order_of_exit(place) -> None:
    env = make("ffa")
    place(env.match, "ant", x=2.5)
    _, _, _, _, infos = env.step(zero_actions(env))
    assert infos["ant"]["place"] == 3 and infos["ant"]["reward_outcome"] == -400.0
    place(env.match, "spider", x=-2.5)
    _, rewards, terms, truncs, infos = env.step(zero_actions(env))
    assert set(infos) == {"bug", "spider"}
    assert infos["spider"]["place"] == 2 and infos["spider"]["reward_outcome"] == 50.0
    assert infos["bug"]["place"] == 1 and infos["bug"]["outcome"] == WIN and infos["bug"]["reward_outcome"] == 500.0
    assert terms == {"bug": True, "spider": True} and not any(truncs.values())
    assert env.agents == []


def test_ffa_step_limit_truncates_with_survivors_drawing(place) -> None:
    env = make("ffa", max_steps=3)
    place(env.match, "ant", x=2.5)
    env.step(zero_actions(env))
    env.step(zero_actions(env))
    _, rewards, terms, truncs, infos = env.step(zero_actions(env))
    assert truncs == {"bug": True, "spider": True} and not any(terms.values())
    for agent in ("bug", "spider"):
        assert infos[agent]["outcome"] == DRAW and infos[agent]["place"] == 1
        assert infos[agent]["reward_outcome"] == (500.0 + 50.0) / 2
    assert env.agents == []


def test_ffa_placement_rewards_follow_the_reward_config(place) -> None:
    reward = triplesumo.RewardConfig(win=100.0, loss=-100.0)
    env = make("ffa", n_agents=5, reward=reward)
    place(env.match, "beetle", x=2.5)
    _, _, _, _, infos = env.step(zero_actions(env))
    assert infos["beetle"]["place"] == 5 and infos["beetle"]["reward_outcome"] == -100.0
    place(env.match, "ant", x=2.5)
    _, _, _, _, infos = env.step(zero_actions(env))
    assert infos["ant"]["place"] == 4 and infos["ant"]["reward_outcome"] == pytest.approx(-50.0)
    assert place_value(100.0, -100.0, 2, 3, 5) == pytest.approx(25.0)


# ------------------------------------------------------------------------ pursuit
def test_pursuit_evader_out_pursuers_win(place) -> None:
    env = make("pursuit")
    place(env.match, "evader", x=2.5)
    _, rewards, terms, _, infos = env.step(zero_actions(env))
    assert all(terms.values()) and env.agents == []
    assert infos["evader"]["outcome"] == LOSS and infos["evader"]["reward_outcome"] == -400.0
    for k in range(3):
        assert infos[f"pursuer_{k}"]["outcome"] == WIN and infos[f"pursuer_{k}"]["place"] == 1
        assert infos[f"pursuer_{k}"]["reward_outcome"] == 500.0


def test_pursuit_pursuer_out_leaves_and_the_match_goes_on(place) -> None:
    env = make("pursuit")
    place(env.match, "pursuer_1", y=2.5)
    _, rewards, terms, truncs, infos = env.step(zero_actions(env))
    assert terms["pursuer_1"] and not any(t for a, t in terms.items() if a != "pursuer_1")
    assert infos["pursuer_1"]["reward_outcome"] == -400.0 and infos["pursuer_1"]["outcome"] == LOSS
    assert env.agents == ["pursuer_0", "pursuer_2", "evader"]
    env.step(zero_actions(env))
    assert env.agents == ["pursuer_0", "pursuer_2", "evader"]


def test_pursuit_evader_wins_by_pushing_every_pursuer_out_or_surviving(place) -> None:
    env = make("pursuit", n_pursuers=2)
    place(env.match, "pursuer_0", x=2.5)
    place(env.match, "pursuer_1", x=-2.5)
    _, _, terms, _, infos = env.step(zero_actions(env))
    assert all(terms.values()) and infos["evader"]["outcome"] == WIN and infos["evader"]["reward_outcome"] == 500.0
    env = make("pursuit", n_pursuers=2, max_steps=2)
    env.step(zero_actions(env))
    _, _, terms, truncs, infos = env.step(zero_actions(env))
    assert all(terms.values()) and not any(truncs.values())  # a decided result at the limit is terminal (issue 39)
    assert infos["evader"]["outcome"] == WIN and infos["evader"]["place"] == 1
    assert infos["pursuer_0"]["outcome"] == LOSS and infos["pursuer_0"]["reward_outcome"] == -400.0


@pytest.mark.parametrize("obs_mode", ["paper", "egocentric"])
def test_pursuit_evader_noise_is_seeded_and_only_on_the_evader(obs_mode: str) -> None:
    noisy = triplesumo.parallel_env(scenario="pursuit", evader_obs_noise=0.5, obs_mode=obs_mode)
    exact = triplesumo.parallel_env(scenario="pursuit", obs_mode=obs_mode)
    a, _ = noisy.reset(seed=3)
    b, _ = noisy.reset(seed=3)
    c, _ = noisy.reset(seed=4)
    ref, _ = exact.reset(seed=3)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["pursuer_0"], c["pursuer_0"])
    assert np.array_equal(a["evader"], ref["evader"])
    entries = noisy.match.observer.evader_entries[0]
    diff = np.flatnonzero(a["pursuer_0"] != ref["pursuer_0"])
    assert diff.tolist() == sorted(entries.tolist())
    assert len(entries) == (12 if obs_mode == "paper" else 6)
    noisy.reset(seed=3)
    assert np.array_equal(noisy.state(), exact.state())  # the state is exact


# ------------------------------------------------------------------------ teams
def test_2v2_uses_the_paper_rules_with_teams_of_two(place) -> None:
    env = make("2v2")
    assert [a.team for a in env.config.agents] == ["team_0", "team_0", "team_1", "team_1"]
    assert env.config.rules == "first_out"
    place(env.match, "beetle", x=2.5)
    _, _, terms, _, infos = env.step(zero_actions(env))
    assert all(terms.values()) and env.agents == []
    assert [infos[a]["outcome"] for a in env.possible_agents] == [WIN, WIN, LOSS, LOSS]
    assert [infos[a]["place"] for a in env.possible_agents] == [1, 1, 2, 2]


def test_n_vs_m_rosters_from_team_sizes() -> None:
    env = triplesumo.parallel_env(scenario="2v2", team_sizes=(3, 1))
    assert [a.team for a in env.config.agents] == ["team_0"] * 3 + ["team_1"]
    assert len({a.rgba for a in env.config.agents}) == 4


def test_gymnasium_view_ends_when_the_learner_is_eliminated(place) -> None:
    env = gym.make("TripleSumo-FFA-v2", reset_noise=NO_NOISE).unwrapped
    env.reset(seed=0)
    match = env.match  # type: ignore[attr-defined]
    place(match, "ant", x=2.5)
    _, reward, terminated, truncated, info = env.step(np.zeros(8, np.float32))
    assert not terminated and not truncated and match.agents_in_play == ["bug", "spider"]
    place(match, "bug", x=2.5)
    _, reward, terminated, truncated, info = env.step(np.zeros(8, np.float32))
    assert terminated and not truncated
    assert info["place"] == 2 and info["reward_outcome"] == 50.0


def test_every_scenario_id_is_documented_and_defaults_fit() -> None:
    for sc in SCENARIOS.values():
        assert sc.learner in sc.config().agent_names


def test_ffa_everyone_out_together_is_a_shared_draw(place) -> None:
    env = make("ffa")
    for agent, x in (("ant", 2.5), ("bug", -2.5), ("spider", 2.6)):
        place(env.match, agent, x=x)
    _, rewards, terms, _, infos = env.step(zero_actions(env))
    assert all(terms.values()) and env.agents == []
    for info in infos.values():
        assert info["place"] == 1 and info["outcome"] == DRAW
        assert info["reward_outcome"] == pytest.approx((500.0 + 50.0 - 400.0) / 3)


def test_ffa_of_two_is_a_duel(place) -> None:
    env = make("ffa", n_agents=2)
    assert env.possible_agents == ["ant", "bug"]
    place(env.match, "bug", y=2.5)
    _, rewards, terms, _, infos = env.step(zero_actions(env))
    assert all(terms.values())
    assert (infos["ant"]["outcome"], infos["ant"]["reward_outcome"]) == (WIN, 500.0)
    assert (infos["bug"]["outcome"], infos["bug"]["reward_outcome"]) == (LOSS, -400.0)


def test_an_agent_out_on_the_last_step_is_terminated_not_truncated(place) -> None:
    """Issue 39, item 2: leaving the ring on the step that reaches the limit ends that agent's episode by the
    rules (terminated, its outcome reward paid), in the PettingZoo view as in ``vector_env``; the agents the
    limit stopped are truncated."""
    env = make("ffa", max_steps=1)
    place(env.match, "bug", x=2.5)
    _, rewards, terms, truncs, infos = env.step(zero_actions(env))
    assert infos["bug"]["eliminated"] and rewards["bug"] < -390
    assert terms == {"ant": False, "bug": True, "spider": False}
    assert truncs == {"ant": True, "bug": False, "spider": True}
    assert env.agents == []

    vec = triplesumo.vector_env(1, scenario="ffa", max_steps=1, reset_noise=NO_NOISE)
    vec.reset(seed=0)
    place(vec.batch.matches[0], "bug", x=2.5)
    _, _, term, trunc, infos = vec.step(np.zeros((1, 3, 8), np.float32))
    assert infos["eliminated"][0].tolist() == [False, True, False]
    assert term[0].tolist() == [False, True, False] and trunc[0].tolist() == [True, False, True]


def test_survivors_sharing_a_draw_at_the_limit_are_truncated_and_draw_is_refused_under_elimination() -> None:
    """Issue 39, item 4: ``RewardConfig.draw`` is the first_out rules' draw; elimination rules pay survivors their
    shared places, so a draw other than 0 is refused by name instead of being ignored."""
    env = make("ffa", max_steps=1)
    _, rewards, terms, truncs, infos = env.step(zero_actions(env))
    assert all(truncs.values()) and not any(terms.values())
    assert all(info["outcome"] == DRAW for info in infos.values())
    assert {info["reward_outcome"] for info in infos.values()} == {50.0}  # places 1..3 of 3 shared
    with pytest.raises(ValueError, match=r"reward.draw is -7.0 but rules='elimination' never pays it"):
        triplesumo.parallel_env(scenario="ffa", reward=RewardConfig(draw=-7.0))
    with pytest.raises(ValueError, match="never pays it"):
        triplesumo.scenario_config("pursuit", reward=RewardConfig(draw=1.0))
    assert triplesumo.scenario_config("paper", reward=RewardConfig(draw=-7.0)).reward.draw == -7.0


@pytest.mark.parametrize(("sizes", "message"), [
    ({"scenario": "ffa", "n_agents": 100}, r"n_agents 100 makes a roster of 100 agents; at most 8"),
    ({"scenario": "pursuit", "n_pursuers": 100}, r"n_pursuers 100 makes a roster of 101 agents"),
    ({"scenario": "2v2", "team_sizes": (50, 50)}, r"team_sizes \(50, 50\) make a roster of 100 agents"),
])
def test_oversized_rosters_are_refused_by_their_size_before_any_model_is_built(sizes: dict, message: str) -> None:
    """Issue 39, item 16: ffa with 100 agents took 891 s to refuse (the layout searched first); the size is now
    checked before anything is built, and the error names the option."""
    with pytest.raises(ValueError, match=message):
        triplesumo.parallel_env(**sizes)


def test_complex_actions_and_overflowing_noise_are_refused() -> None:
    """Issue 39, item 16 S: complex actions lost their imaginary part in ``parallel_env`` and ``vector_env`` (the
    Gymnasium view refused them), and ``evader_obs_noise=1e308`` gave inf observations."""
    env = make("paper")
    with pytest.raises(ValueError, match="action of 'ant' must be real numbers, got complex"):
        env.step({a: np.zeros(8) + 0.5j for a in env.agents})
    vec = triplesumo.vector_env(2)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match="actions must be real numbers, got complex"):
        vec.step(np.zeros((2, 3, 8), np.complex64))
    with pytest.raises(ValueError, match=r"evader_obs_noise must be in \[0, 100\]"):
        triplesumo.parallel_env(scenario="pursuit", evader_obs_noise=1e308)
