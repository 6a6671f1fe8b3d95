"""The MuJoCo Warp backend plays the CPU game: parity with :class:`Match` on Warp's CPU device.

One rollout (module fixture, about a minute on 2 cores: Warp's CPU device launches every
kernel serially; first kernel compile about 27 s, cached in ~/.cache/warp) of 3 seeded
matches, 110 env steps of uniform random actions, the paper's RK4 with 5 substeps,
start positions spread (noise 0.5 m) so that matches end by ring-out and restart.

Why teacher forcing: Warp computes in float32, MuJoCo in float64, and three walkers in
contact are chaotic: free-running, rounding differences grow to 1e-2 m within 40 steps
even with zero actions (measured). So before every step each Warp world is set to its
CPU match's state (qpos, qvel, solver warm start), and one env step is compared:

- qpos after the step within 2e-2 at every step, median within 1e-5; qvel median within 1e-3;
- outcome codes identical on every step where the CPU margins are clear (every torso
  farther than 1e-2 m from the ring's edge);
- the sparse term equal on clear steps, and the dense terms (5 x velocities, so qvel's
  one-step differences times 5) within 1e-3 median, 0.05 at the 98th percentile and 2
  at most, where no two torsos are within 1e-3 m along x or y (the terms' signs flip there);
- observations: the same layout and, block by block, positions within 2e-2, contact forces
  within 3 N median (contact forces from a stiff solver move most);
- starts: a restarted match's first observation equals the CPU match's reset
  observation (state blocks within float32 rounding, 1e-6; contact forces of the
  start pose, from Warp's float32 solver, within 1e-3 relative).
"""

from __future__ import annotations

import importlib.util
import json
import os

import numpy as np
import pytest

if importlib.util.find_spec("mujoco_warp") is None or importlib.util.find_spec("warp") is None:
    pytest.skip("mujoco-warp is not installed (pip install 'triplesumo[gpu]')", allow_module_level=True)

import torch  # noqa: E402
import warp as wp  # noqa: E402

from triplesumo.envs.match import Match  # noqa: E402
from triplesumo.envs.seeding import match_seeds  # noqa: E402
from triplesumo.envs.warp import WarpVectorMatches, make_warp_vector_env  # noqa: E402
from triplesumo.model import PhysicsConfig  # noqa: E402
from triplesumo.rules import MatchConfig, ResetNoise  # noqa: E402
from triplesumo.rules.outcome import OUTCOME_CODES  # noqa: E402
from triplesumo.rules.rewards import TERMS  # noqa: E402

pytestmark = pytest.mark.slow  # one minute: Warp's CPU device launches every kernel serially

N, T, SEED = 3, 110, 3
DEVICE = os.environ.get("TRIPLESUMO_WARP_TEST_DEVICE", "cpu")
"""Warp device of the parity rollout; CI has only ``cpu``, set ``cuda`` on a GPU machine."""
CONFIG = MatchConfig(reset_noise=ResetNoise(position=0.5), physics=PhysicsConfig(layout="circle"))
"""Env v1's circle start (the Ant 0.6 m from the edge behind it) on v2's box rim: ring-outs within the rollout."""


@pytest.fixture(scope="module")
def rollout() -> dict:
    env = WarpVectorMatches(CONFIG, N, device=DEVICE)
    obs, infos = env.reset(SEED)
    matches = [Match(CONFIG) for _ in range(N)]
    cpu_obs = [np.stack(m.reset(seed=s)[0]) for m, s in zip(matches, match_seeds(SEED, N), strict=True)]
    record: dict = {"reset_obs": (obs.cpu().numpy().copy(), np.stack(cpu_obs)), "steps": [], "restarts": [],
                    "structure": matches[0].observer.structure["ant"], "obs_shape": tuple(obs.shape)}
    warmstart = wp.to_torch(env.d.qacc_warmstart)
    actions = np.random.default_rng(0).uniform(-1, 1, (T, N, 3, 8)).astype(np.float32)
    for t in range(T):
        for k, m in enumerate(matches):
            env._qpos[k] = torch.as_tensor(m.data.qpos, dtype=torch.float32, device=env.device)
            env._qvel[k] = torch.as_tensor(m.data.qvel, dtype=torch.float32, device=env.device)
            warmstart[k] = torch.as_tensor(m.data.qacc_warmstart, dtype=torch.float32, device=env.device)
        obs, reward, terminated, truncated, infos = env.step(torch.as_tensor(actions[t], device=env.device))
        for k, m in enumerate(matches):
            r = m.step_array(actions[t, k])
            pos = m.sim.torso_positions()
            margin = float(np.min(np.abs(np.maximum(np.abs(pos[:, 0]), np.abs(pos[:, 1])) - m.half_size)))
            gaps = np.abs(pos[:, None, :2] - pos[None, :, :2])[~np.eye(len(pos), dtype=bool)]
            record["steps"].append({
                "k": k, "t": t, "margin": margin, "sign_margin": float(gaps.min()), "over": m.over,
                "warp_final_obs": infos["final_obs"][k].cpu().numpy().copy(), "cpu_obs": np.stack(r.observations),
                "warp_code": infos["outcome"][k].tolist(),
                "cpu_code": [int(i["outcome"]) for i in r.infos],
                "warp_terms": {n: infos[n][k].cpu().numpy().copy() for n in TERMS},
                "cpu_terms": {n: np.array([i[n] for i in r.infos]) for n in TERMS},
                "warp_reward": reward[k].cpu().numpy().copy(), "cpu_reward": r.rewards,
                "flags": (bool(terminated[k, 0]), bool(truncated[k, 0]), bool(infos["_final_obs"][k])),
                "cpu_flags": (r.terminated, r.truncated, m.over),
                "dq": None if m.over else np.abs(env._qpos[k].cpu().numpy() - m.data.qpos).max(),
                "dv": None if m.over else np.abs(env._qvel[k].cpu().numpy() - m.data.qvel).max(),
            })
            if m.over:
                first = np.stack(m.reset()[0])
                record["restarts"].append((obs[k].cpu().numpy().copy(), first))
    # physics trouble in match 1 only: a NaN velocity
    env._qvel[1, 0] = float("nan")
    before = obs.cpu().numpy().copy()
    obs, reward, terminated, truncated, infos = env.step(torch.zeros((N, 3, 8), device=env.device))
    flags = (terminated.cpu().numpy(), truncated.cpu().numpy(), infos["_final_obs"].cpu().numpy())
    record["error"] = {
        "code": infos["outcome"].cpu().numpy(), "place": infos["place"].cpu().numpy(),
        "reward": reward.cpu().numpy(), "flags": flags,
        "final_obs": infos["final_obs"].cpu().numpy(), "before": before,
        "obs_finite": bool(torch.isfinite(obs).all()), "step": infos["step"].cpu().numpy(),
        "terms": {n: infos[n].cpu().numpy() for n in TERMS}}
    record["env"] = env
    return record


def test_one_step_trajectories_stay_within_tolerance(rollout: dict) -> None:
    dq = np.array([s["dq"] for s in rollout["steps"] if s["dq"] is not None])
    dv = np.array([s["dv"] for s in rollout["steps"] if s["dv"] is not None])
    assert len(dq) >= 200
    assert dq.max() < 2e-2, dq.max()
    assert np.median(dq) < 1e-5, np.median(dq)
    assert np.median(dv) < 1e-3, np.median(dv)


def test_outcomes_flags_and_rewards_equal_where_margins_are_clear(rollout: dict) -> None:
    clear = [s for s in rollout["steps"] if s["margin"] > 1e-2]
    assert len(clear) > 0.9 * len(rollout["steps"])
    ended, errors = 0, []
    for s in clear:
        assert s["warp_code"] == s["cpu_code"], (s["t"], s["k"])
        assert s["flags"] == s["cpu_flags"], (s["t"], s["k"])
        ended += s["cpu_flags"][2]
        np.testing.assert_array_equal(s["warp_terms"]["reward_outcome"], s["cpu_terms"]["reward_outcome"])
        np.testing.assert_allclose(s["warp_reward"], sum(s["warp_terms"][n] for n in TERMS), rtol=1e-6, atol=1e-4)
        if s["sign_margin"] > 1e-3:  # s(a, b) = sign(p_b - p_a) flips closer: the velocity terms jump
            errors += [np.abs(s["warp_terms"][n] - s["cpu_terms"][n]) for n in TERMS]
    errors = np.concatenate(errors)
    assert np.median(errors) < 1e-3 and np.quantile(errors, 0.98) < 0.05 and errors.max() < 2.0, (
        np.median(errors), np.quantile(errors, 0.98), errors.max())
    assert ended >= 2  # ring-outs happened and were judged alike
    assert {1, 2} <= {c for s in clear for c in s["cpu_code"]}


def test_observation_layout_and_values_match(rollout: dict) -> None:
    structure = rollout["structure"]
    assert rollout["obs_shape"] == (N, 3, sum(structure.values()))
    bounds, at = {}, 0
    for name, size in structure.items():
        bounds[name] = slice(at, at + size)
        at += size
    force_errors = []
    for s in rollout["steps"]:
        w, c = s["warp_final_obs"], s["cpu_obs"]
        assert w.shape == c.shape and w.dtype == c.dtype == np.float32
        for name in ("torso_position", "qpos"):
            np.testing.assert_allclose(w[:, bounds[name]], c[:, bounds[name]], atol=2e-2)
        force_errors.append(np.abs(w[:, bounds["contact_force"]] - c[:, bounds["contact_force"]]).max())
    assert np.median(force_errors) < 3.0, np.median(force_errors)


def test_starts_are_exactly_the_cpu_starts(rollout: dict) -> None:
    structure = rollout["structure"]
    forces = slice(18, 18 + structure["contact_force"])
    state = np.ones(sum(structure.values()), dtype=bool)
    state[forces] = False
    pairs = [rollout["reset_obs"], *rollout["restarts"]]
    assert len(pairs) > 1, "no match restarted"
    for warp_obs, cpu_obs in pairs:
        np.testing.assert_allclose(warp_obs[..., state], cpu_obs[..., state], rtol=0, atol=1e-6)  # float32 rounding
        np.testing.assert_allclose(warp_obs[..., forces], cpu_obs[..., forces], rtol=1e-3, atol=1e-3)


def test_physics_error_truncates_only_that_match_and_restarts_it(rollout: dict) -> None:
    e = rollout["error"]
    terminated, truncated, final = e["flags"]
    assert e["code"][1].tolist() == [OUTCOME_CODES["error"]] * 3
    assert e["place"][1].tolist() == [0] * 3  # an error decides no place, as on the CPU backends
    assert truncated[1].all() and not terminated[1].any() and final[1]
    assert not (e["code"][[0, 2]] == OUTCOME_CODES["error"]).any()
    assert (e["reward"][1] == 0).all() and all((e["terms"][n][1] == 0).all() for n in TERMS)
    np.testing.assert_array_equal(e["final_obs"][1], e["before"][1])  # the last trustworthy observation
    assert e["obs_finite"]  # and the returned row is already the next match's start


def test_bad_actions_and_devices_are_refused(rollout: dict) -> None:
    env = rollout["env"]
    with pytest.raises(ValueError, match="shape"):
        env.step(torch.zeros((N, 3, 7)))
    bad = torch.zeros((N, 3, 8))
    bad[2, 1, 0] = float("nan")
    with pytest.raises(ValueError, match="'bug' in match 2"):
        env.step(bad)
    with pytest.raises(ValueError, match="num_envs"):
        make_warp_vector_env(CONFIG, 0, device="cpu")
    with pytest.raises(ValueError, match="not available"):
        WarpVectorMatches(CONFIG, 1, device="cuda:7")


def test_egocentric_observations_of_the_starts_and_one_step_match_the_cpu() -> None:
    cfg = MatchConfig(obs_mode="egocentric")
    env = WarpVectorMatches(cfg, 2, device=DEVICE)
    obs, _ = env.reset(5)
    matches = [Match(cfg) for _ in range(2)]
    first = np.stack([np.stack(m.reset(seed=s)[0]) for m, s in zip(matches, match_seeds(5, 2), strict=True)])
    assert tuple(obs.shape) == first.shape == (2, 3, 79)
    contact = slice(79 - 39, 79)
    np.testing.assert_allclose(obs.cpu().numpy()[..., :contact.start], first[..., :contact.start], atol=1e-5)
    np.testing.assert_allclose(obs.cpu().numpy()[..., contact], first[..., contact], rtol=1e-3, atol=1e-3)
    actions = np.random.default_rng(1).uniform(-1, 1, (2, 3, 8)).astype(np.float32)
    obs, *_ = env.step(torch.as_tensor(actions, device=env.device))
    after = np.stack([np.stack(m.step_array(a).observations) for m, a in zip(matches, actions, strict=True)])
    np.testing.assert_allclose(obs.cpu().numpy()[..., :contact.start], after[..., :contact.start], atol=1e-3)


def test_public_vector_env_reaches_the_warp_backend_and_refuses_mixed_bodies() -> None:
    import triplesumo

    env = triplesumo.vector_env(2, backend="warp", device="cpu", max_steps=3)
    assert isinstance(env, WarpVectorMatches)
    obs, infos = env.reset(seed=0)
    assert isinstance(obs, torch.Tensor) and tuple(obs.shape) == (2, 3, env.obs_dim)
    cpu = triplesumo.vector_env(2, max_steps=3)
    cpu_obs, _ = cpu.reset(seed=0)
    np.testing.assert_allclose(obs.numpy(), cpu_obs, atol=1e-3, rtol=1e-4)  # the same seeded starts
    for _ in range(3):
        obs, rewards, terminated, truncated, infos = env.step(torch.zeros((2, 3, env.act_dim)))
    assert tuple(rewards.shape) == (2, 3) and bool(truncated.all()) and bool(infos["_final_obs"].all())
    cpu.close()
    with pytest.raises(NotImplementedError, match="one body kind"):
        triplesumo.vector_env(2, scenario="bodies", backend="warp", device="cpu")
    with pytest.raises(ValueError, match="num_threads is for backend='cpu'"):
        triplesumo.vector_env(2, backend="warp", device="cpu", num_threads=2)


def test_the_border_rim_reaches_warp_with_the_compiled_model() -> None:
    """``PhysicsConfig.border_rim`` lives in the MjModel, which Warp takes as it is: its border
    geoms collide there too, and the agents' legs that land on the rim at a noise-free start on the
    v1 circle touch it in Warp as on the CPU."""
    from triplesumo.model import names

    cfg = MatchConfig(physics=PhysicsConfig(border_rim=True, layout="circle"), reset_noise=ResetNoise(0, 0, 0, 0))
    env = WarpVectorMatches(cfg, 1, device=DEVICE)
    rim = [env.match.model.geom(n).id for n in names.BORDER_GEOMS]
    assert (env.m.geom_contype.numpy()[rim] == 1).all() and (env.m.geom_conaffinity.numpy()[rim] == 1).all()
    env.reset(0)
    match = Match(cfg)
    match.reset(seed=0)
    for _ in range(5):
        env.step(torch.zeros((1, 3, 8), device=env.device))
        match.step_array(np.zeros((3, 8)))
    n = int(env.d.nacon.numpy()[0])
    on_warp = {tuple(sorted(map(int, p))) for p in env.d.contact.geom.numpy()[:n] if set(map(int, p)) & set(rim)}
    on_cpu = {tuple(sorted((int(c.geom1), int(c.geom2)))) for c in match.data.contact[:match.data.ncon]
              if {int(c.geom1), int(c.geom2)} & set(rim)}
    assert len(on_cpu) >= 2
    assert on_warp == on_cpu


@pytest.mark.parametrize("layout", ["fair", "circle"])
def test_the_box_rim_collides_alike_on_both_engines(layout: str) -> None:
    """Env v2's rim is four boxes because MuJoCo Warp collides them as MuJoCo does (on v1's cylinders the
    torsos part by 1 mm within 10 steps and by 8 mm within 15, measured): with zero actions from the same
    seeded starts, every torso agrees to 1 mm over the first 15 steps, at the fair start (no leg on the rim)
    and on the v1 circle, where legs land on the rim (which this checks)."""
    from triplesumo.model import names

    cfg = MatchConfig(physics=PhysicsConfig(layout=layout))
    n = 4
    env = WarpVectorMatches(cfg, n, device=DEVICE)
    env.reset([9 + k for k in range(n)])
    matches = []
    for k in range(n):
        matches.append(Match(cfg))
        matches[-1].reset(seed=9 + k)
    torso = [a.root_qpos + j for a in matches[0].sim.agents for j in range(3)]
    rim = {matches[0].model.geom(g).id for g in names.BORDER_GEOMS}
    on_rim = False
    for _ in range(15):
        env.step(torch.zeros((n, 3, 8), device=env.device))
        for m in matches:
            m.step_array(np.zeros((3, 8)))
            on_rim |= any({int(c.geom1), int(c.geom2)} & rim for c in m.data.contact[:m.data.ncon])
        warp_qpos = env.d.qpos.numpy()
        for k, m in enumerate(matches):
            np.testing.assert_allclose(warp_qpos[k][torso], m.data.qpos[torso], rtol=0, atol=1e-3)
    assert on_rim == (layout == "circle")


def test_a_snapshot_restored_into_a_fresh_batch_continues_bit_for_bit() -> None:
    """``snapshot``/``restore`` (exact resume of ``train --backend warp``): a fresh batch restored from a
    snapshot taken mid-match (the solver's warm start warm, one match about to end at ``max_steps``)
    makes the steps the original makes next, bit for bit on Warp's CPU device -- observations, rewards, flags, autoreset
    starts -- while a state of qpos and qvel only (no warm start) does not."""
    cfg = MatchConfig(max_steps=6, reset_noise=ResetNoise(position=0.5))
    actions = torch.as_tensor(np.random.default_rng(2).uniform(-1, 1, (9, 2, 3, 8)), dtype=torch.float32)
    env = WarpVectorMatches(cfg, 2, device=DEVICE)
    obs, _ = env.reset(7)
    for t in range(4):
        obs, *_ = env.step(actions[t].to(env.device))
    snap = [json.loads(json.dumps({k: v for k, v in s.items() if k != "physics"})) | {"physics": s["physics"]}
            for s in env.snapshot()]  # as a checkpoint holds it: state.json and arrays.npz
    saved_obs = obs.cpu().numpy().copy()
    ahead = [env.step(actions[t].to(env.device)) for t in range(4, 9)]
    again = WarpVectorMatches(cfg, 2, device=DEVICE)
    again.restore(snap, saved_obs)
    assert again.steps.tolist() == [4, 4]
    assert bool(ahead[1][4]["_final_obs"].all())  # the matches ended (step 6) and restarted from their streams
    cold = WarpVectorMatches(cfg, 2, device=DEVICE)
    cold.restore(snap, saved_obs)
    # Bit for bit only on Warp's CPU device: on CUDA, MuJoCo Warp gathers contacts with atomics (its
    # opt.deterministic is off), so two batches stepping one state may differ in rounding (an H200 did at
    # the first step after the restore: docs/bench/train_warp_h200.md).
    if DEVICE == "cpu":
        for t, expected in zip(range(4, 9), ahead, strict=True):
            got = again.step(actions[t].to(again.device))
            for a, b in zip(got[:4], expected[:4], strict=True):
                assert torch.equal(a, b), t
            assert all(torch.equal(got[4][k], expected[4][k]) for k in expected[4]), t
        wp.to_torch(cold.d.qacc_warmstart).zero_()
        assert not torch.equal(cold.step(actions[4].to(cold.device))[0], ahead[0][0])
    with pytest.raises(ValueError, match="physics of shape"):
        cold.restore([s | {"physics": s["physics"][:-1]} for s in snap], saved_obs)


def test_both_backends_give_the_same_info_keys_dtypes_and_shapes(capfd: pytest.CaptureFixture[str]) -> None:
    """Issue 39, item 10: code written against one backend runs on the other (``eliminated`` and ``out_of_ring``
    were missing on Warp, its reward terms float32), and Warp's module log stays quiet unless asked for."""
    import triplesumo

    capfd.readouterr()
    cpu = triplesumo.vector_env(2)
    gpu = triplesumo.vector_env(2, backend="warp", device=DEVICE)
    cpu.reset(seed=0)
    gpu.reset(seed=0)
    zeros = np.zeros((2, 3, 8), np.float32)
    for _ in range(3):
        *_, on_cpu = cpu.step(zeros)
        *_, on_warp = gpu.step(torch.as_tensor(zeros))
    assert set(on_cpu) == set(on_warp)
    for key, value in on_cpu.items():
        other = on_warp[key].cpu().numpy()
        assert (np.asarray(value).dtype, np.asarray(value).shape) == (other.dtype, other.shape), key
    assert "Module" not in capfd.readouterr().out  # no "Module ... load" lines without verbose


def test_the_old_class_name_is_a_deprecated_alias() -> None:
    """``WarpMatchBatch`` is ``WarpVectorMatches`` (the Warp backend of ``VectorMatches``' contract) for a release."""
    from triplesumo.envs import warp

    with pytest.warns(DeprecationWarning, match="WarpVectorMatches"):
        assert warp.WarpMatchBatch is WarpVectorMatches


ELIMINATION_CASES = {"ffa": ("ffa", {}), "pursuit": ("pursuit", {}),
                     "pursuit-noise": ("pursuit", {"evader_obs_noise": 0.2})}
"""Every elimination scenario, and pursuit's evader noise (drawn on the host from each match's stream)."""


@pytest.mark.parametrize("case", ELIMINATION_CASES.values(), ids=list(ELIMINATION_CASES))
def test_elimination_scenarios_play_as_on_the_cpu_vector_path(case: tuple) -> None:
    """Issue 54: Warp plays the elimination rules with the CPU's array rule. Teacher-forced as the rollout above
    (each world set to its CPU match's state, warm start, step count and standing -- who is in play, places and
    outcomes kept -- before every step), one step of ``VectorMatches`` and of Warp agree with the rollout's
    tolerances: on steps whose margins are clear, who leaves, who is eliminated, outcome codes, places, each
    agent's terminated and truncated flags, autoresets and the placement rewards exactly, the dense terms within
    the rollout's bounds; observations (evader noise included) within 2e-2 on every step; restarted matches start
    as the CPU's. An eliminated agent's motors get zero control on Warp as on the CPU."""
    import triplesumo
    from triplesumo.envs.batch import VectorMatches

    name, extra = case
    cfg = triplesumo.scenario_config(name, max_steps=30, reset_noise=ResetNoise(position=0.5),
                                     physics=PhysicsConfig(layout="circle"), **extra)
    n_envs, steps = 3, 60
    env = WarpVectorMatches(cfg, n_envs, device=DEVICE)
    cpu = VectorMatches(n_envs, cfg, 1)
    n, half = env.n_agents, env.match.half_size
    obs, _ = env.reset(SEED)
    cpu_obs, _ = cpu.reset(SEED)
    structure = cpu.matches[0].observer.structure[cpu.agents[0]]
    bounds, at = {}, 0
    for block, size in structure.items():
        bounds[block] = slice(at, at + size)
        at += size
    state = np.ones(at, dtype=bool)
    state[bounds["contact_force"]] = False
    starts = [(obs.cpu().numpy(), cpu_obs)]
    warmstart = wp.to_torch(env.d.qacc_warmstart)
    actions = np.random.default_rng(SEED).uniform(-1, 1, (steps, n_envs, n, 8)).astype(np.float32)
    clear = unclear = left = ended = truncated_ends = 0
    dq, errors = [], []
    for t in range(steps):
        before = []
        for k, m in enumerate(cpu.matches):
            env._qpos[k] = torch.as_tensor(m.data.qpos, dtype=torch.float32)
            env._qvel[k] = torch.as_tensor(m.data.qvel, dtype=torch.float32)
            warmstart[k] = torch.as_tensor(m.data.qacc_warmstart, dtype=torch.float32)
            alive, places, outcomes = m.standing
            env._alive[k], env._places[k], env._outcomes[k] = (torch.as_tensor(v) for v in (alive, places, outcomes))
            env.steps[k] = m.steps
            before.append(list(alive))
        w_obs, w_reward, w_term, w_trunc, w_infos = env.step(torch.as_tensor(actions[t], device=env.device))
        c_obs, c_reward, c_term, c_trunc, c_infos = cpu.step(actions[t])
        ctrl = env._ctrl[:, env._actuators].reshape(n_envs, n, 8).cpu().numpy()
        w_final = w_infos["final_obs"].cpu().numpy()
        for k, m in enumerate(cpu.matches):
            where = f"step {t}, match {k}"
            gone = ~np.array(before[k])
            assert (ctrl[k][gone] == 0).all(), where  # an eliminated body no longer acts
            c_done = bool(c_infos["_final_obs"][k])
            c_last = c_infos["final_obs"][k] if c_done else c_obs[k]
            pos = c_last[-1, bounds["torso_position"]].reshape(n, 3)  # the last agent's row: no evader noise on it
            margin = np.abs(np.maximum(np.abs(pos[:, 0]), np.abs(pos[:, 1])) - half)[~gone].min()
            for block in ("torso_position", "qpos"):
                np.testing.assert_allclose(w_final[k][:, bounds[block]], c_last[:, bounds[block]], atol=2e-2,
                                           err_msg=where)
            if not c_done:
                dq.append(np.abs(env._qpos[k].cpu().numpy() - m.data.qpos).max())
            if margin <= 1e-2:
                unclear += 1
                continue
            clear += 1
            for key in ("outcome", "place", "out_of_ring", "eliminated"):
                np.testing.assert_array_equal(w_infos[key][k].cpu().numpy(), c_infos[key][k], err_msg=f"{where} {key}")
            np.testing.assert_array_equal(w_term[k].cpu().numpy(), c_term[k], err_msg=where)
            np.testing.assert_array_equal(w_trunc[k].cpu().numpy(), c_trunc[k], err_msg=where)
            assert bool(w_infos["_final_obs"][k]) == c_done, where
            np.testing.assert_array_equal(w_infos["reward_outcome"][k].cpu().numpy(), c_infos["reward_outcome"][k])
            np.testing.assert_allclose(w_reward[k].cpu().numpy(), sum(w_infos[key][k].cpu().numpy() for key in TERMS),
                                       rtol=1e-6, atol=1e-4, err_msg=where)
            lead = np.sort(pos[:, :2], axis=0)
            if (np.diff(lead, axis=0) > 1e-3).all():  # s(a, b) flips closer: the velocity terms jump
                errors += [np.abs(w_infos[key][k].cpu().numpy() - c_infos[key][k]) for key in TERMS]
            left += int(c_infos["out_of_ring"][k].sum())
            ended += c_done
            truncated_ends += c_done and bool(c_trunc[k].any())
            if c_done:
                starts.append((w_obs[k].cpu().numpy(), c_obs[k]))
    assert clear > 0.9 * (clear + unclear) and left >= 2 and ended >= 2, (clear, unclear, left, ended)
    assert name != "ffa" or truncated_ends >= 1  # survivors sharing a draw at the step limit
    assert max(dq) < 2e-2, max(dq)
    errors = np.concatenate(errors)
    assert np.median(errors) < 1e-3 and np.quantile(errors, 0.98) < 0.05 and errors.max() < 2.0, (
        np.median(errors), np.quantile(errors, 0.98), errors.max())
    for warp_obs, cpu_start in starts:  # starts drawn from the same streams (and the same evader noise)
        np.testing.assert_allclose(warp_obs[..., state], cpu_start[..., state], rtol=0, atol=1e-5)
    # restart (a trainer whose learners are all out) and snapshot carry the standing too
    np.testing.assert_allclose(env.restart(1, 5).cpu().numpy()[..., state], cpu.restart(1, 5)[..., state], atol=1e-5)
    env._alive[2, 0] = False
    env._places[2, 0] = 3
    again = WarpVectorMatches(cfg, n_envs, device=DEVICE)
    again.restore(env.snapshot(), env._last_obs.cpu().numpy())
    for part in ("_alive", "_places", "_outcomes", "steps"):
        assert torch.equal(getattr(again, part), getattr(env, part)), part
    cpu.close()
