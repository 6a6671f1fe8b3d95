"""Thousands of matches on one device: the MuJoCo Warp backend of the batched API.

:class:`WarpVectorMatches` steps ``num_envs`` matches of one :class:`MatchConfig` with
``mujoco_warp`` (one Warp *world* per match) on ``device`` (``"cuda"``, ``"cuda:1"`` or
Warp's ``"cpu"``), and computes their rules -- ring exits, outcome codes, reward terms,
observations with per-geom contact forces -- batched on the device with the very rule
functions (``xp=torch``; :mod:`triplesumo.rules.batched` lists them) that
:class:`~triplesumo.envs.match.Match` calls with numpy for one match. It is the Warp
counterpart of :class:`~triplesumo.envs.batch.VectorMatches` (one contract). Warp's arrays are read as
torch tensors without copies (``warp.to_torch``): the returned observations, rewards
and flags are torch tensors on ``device``.

The model is :class:`Match`'s own compiled ``MjModel`` (``mujoco_warp.put_model``), so
the physics is the CPU path's up to float32 rounding (Warp computes in float32): the
parity tests (``tests/test_warp_backend.py``, Warp's CPU device) hold qpos and qvel
within a stated tolerance of :class:`Match` over 120 steps.

Step: actions ``(num_envs, n_agents, 8)`` in [-1, 1] are clipped and scaled to each
motor's control range as :meth:`Match.prepare` does; ``frame_skip`` calls of
``mujoco_warp.step`` and one ``rne_postconstraint`` (for ``cfrc_ext``, whose force half
is the contact force on each agent geom's body, as on CPU) run -- on CUDA as one
captured CUDA graph, as are the resets' ``reset_data`` and ``forward`` --; then the rules.

Both rule sets play as on CPU. Under ``elimination`` rules (``ffa``, ``pursuit``) who is in play, and the
places and outcomes decided so far, are ``(num_envs, n_agents)`` tensors on the device: an eliminated agent's
motors get zero control, as :meth:`Match.prepare` gives them (its body stays in the physics, inert, as on CPU:
nothing in the model changes per world), and :func:`~triplesumo.rules.outcome.judge_elimination` judges every
match at once; an agent out terminates on that step while the rest play on. Pursuit's evader noise
(``evader_obs_noise > 0``) is drawn on the host from each match's own stream, the numbers the CPU backend draws
(a host loop over the matches on every step: the one part of a step that does not stay on the device).

Physics trouble is judged per match, as on CPU: a NaN, inf or entry beyond 1e10 in
qpos, qvel or qacc (MuJoCo's bad-qpos/qvel/qacc warnings), or a Warp overflow flag of
that world (contacts or constraints beyond ``nconmax``/``njmax``: MuJoCo's
contact-full/constraint-full), truncates that match with outcome code 4, zero reward
terms and the last trustworthy observation (``MatchConfig.on_physics_error="raise"``
raises :class:`~triplesumo.sim.physics.PhysicsError` instead).

Autoreset is Gymnasium 1.x SAME_STEP (the batched API contract): a finished match's
row of the returned observation is already its next match's first observation;
``infos["final_obs"]`` holds its last one (rows valid where ``infos["_final_obs"]``).
Start states are drawn on the host by :meth:`Match.start_state` from match ``k``'s own
stream, ``np.random.default_rng(match_seeds(seed, num_envs)[k])`` -- the streams of
:meth:`MatchBatch.reset_all` -- so starts are exactly the CPU backend's, whatever
``num_envs`` or device. A reset clears the match's Warp data (``reset_data`` on a
per-world mask), sets qpos and qvel and runs ``mujoco_warp.forward`` for its contacts
(on every world: it changes no state that the next step carries, only derived
quantities that the step recomputes).

``snapshot()``/``restore()`` carry every match across processes (the trainer's checkpoints):
each world's MuJoCo integration state (``mujoco_warp.get_state``/``set_state`` of :data:`STATE`,
the solver's warm start included), its step count and start stream; a restored batch steps on
bit for bit on Warp's CPU device (``tests/test_warp_backend.py``).

This module is the one place below ``agents`` that imports torch (``tests/test_layers.py``
names it): the backend's whole point is tensors shared with the GPU simulator. It is
imported only when ``backend="warp"`` is asked for.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import mujoco
import mujoco_warp as mjw
import numpy as np
import torch
import warp as wp
from gymnasium import spaces

from triplesumo.envs.match import Match
from triplesumo.envs.seeding import check_seed, match_seeds
from triplesumo.rules import batched as rules_batched
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.rewards import TERMS
from triplesumo.sim.physics import PhysicsError

STATE = int(mujoco.mjtState.mjSTATE_INTEGRATION) & ~int(mujoco.mjtState.mjSTATE_PLUGIN)
"""The state a world's next step depends on (``mujoco_warp.get_state``/``set_state`` signature): MuJoCo's
``mjSTATE_INTEGRATION`` -- time, qpos, qvel, act, history, plastic, the solver's warm start
``qacc_warmstart``, ctrl, applied forces, equality flags, mocap, userdata -- less plugin state,
which MuJoCo Warp does not hold (the model has no plugins)."""


class WarpVectorMatches:
    """``num_envs`` matches of one config stepped together by MuJoCo Warp on ``device``: the batched API
    of :class:`~triplesumo.envs.batch.VectorMatches` on the ``warp`` backend."""

    def __init__(self, config: MatchConfig | None = None, num_envs: int = 16, device: str = "cuda",
                 nconmax: int = 64, njmax: int = 320, graph: bool | None = None, seed: int | None = None,
                 verbose: bool = False) -> None:
        set_warp_verbose(verbose)
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        for name, value in (("nconmax", nconmax), ("njmax", njmax)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        self.match = Match(config)
        """The host match: compiled model, element indices, start states (never stepped)."""
        self.config = self.match.config
        self.elimination = self.match.elimination
        """Elimination rules (ffa, pursuit): an agent out leaves, its body gets zero control, the rest play on."""
        if len(set(self.match.action_sizes)) != 1:
            raise NotImplementedError("backend='warp' needs one body kind for every agent (the batched "
                                      f"observation stacks their joints); action sizes {self.match.action_sizes} "
                                      "run on backend='cpu'")
        self.num_envs = num_envs
        self.agents = self.match.agents
        self.n_agents = self.match.n_agents
        self.act_dim = self.match.action_width
        self.action_sizes = self.match.action_sizes
        self.obs_dim = self.match.observer.sizes[self.agents[0]]
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.act_dim,), np.float32)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (self.obs_dim,), np.float32)
        self._seed = seed
        try:
            self.wp_device = wp.get_device(device)
        except Exception as exc:  # warp raises a bare RuntimeError/ValueError for unknown devices
            raise ValueError(f"device {device!r} is not available to Warp ({exc}); Warp sees "
                             f"{[str(d) for d in wp.get_devices()]}") from None
        self.device = torch.device("cpu") if self.wp_device.is_cpu else torch.device(f"cuda:{self.wp_device.ordinal}")
        model = self.match.model
        with wp.ScopedDevice(self.wp_device):
            self.m = mjw.put_model(model)
            self.d = mjw.put_data(model, mujoco.MjData(model), nworld=num_envs, nconmax=nconmax, njmax=njmax)
        d = self.d
        self._qpos, self._qvel, self._qacc = wp.to_torch(d.qpos), wp.to_torch(d.qvel), wp.to_torch(d.qacc)
        self._ctrl = wp.to_torch(d.ctrl)
        self._cfrc = wp.to_torch(d.cfrc_ext)  # (E, nbody, 6): torque, force
        self._overflow = wp.to_torch(d.overflow)
        self._torch_stream = None if self.wp_device.is_cpu else wp.stream_to_torch(self.wp_device.stream)

        sim, dev = self.match.sim, self.device
        bodies = model.geom_bodyid[sim.agent_geoms]
        if len(set(bodies.tolist())) != len(bodies):
            raise NotImplementedError("backend='warp' reads contact forces from cfrc_ext and needs one body per "
                                      "agent geom (the quadruped has that)")

        def index(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(a), dtype=torch.long, device=dev)

        self._bodies = index(bodies)
        self._torso_qpos, self._torso_qvel = index(sim.torso_qpos), index(sim.torso_qvel)
        self._quat_qpos, self._angvel_qvel = index(sim.quat_qpos), index(sim.angvel_qvel)
        self._joint_qpos = index(np.stack([a.joint_qpos for a in sim.agents]))
        self._joint_qvel = index(np.stack([a.joint_qvel for a in sim.agents]))
        self._actuators = index(sim.actuator_ids.ravel())
        self._ctrl_mid = torch.as_tensor((sim.ctrl_high + sim.ctrl_low) / 2.0, dtype=torch.float32, device=dev)
        self._ctrl_half = torch.as_tensor((sim.ctrl_high - sim.ctrl_low) / 2.0, dtype=torch.float32, device=dev)
        host_rules = self.match.game  # the rules as arrays, copied to the device below
        self.rules = host_rules.to(lambda a: torch.as_tensor(
            a, dtype=torch.long if np.asarray(a).dtype.kind == "i" else torch.float32, device=dev))
        self.frame_skip = sim.frame_skip
        self._graphs: dict[str, Any] = {}
        self._reset_mask = torch.zeros(num_envs, dtype=torch.bool, device=dev)
        self._reset_mask_wp = wp.from_torch(self._reset_mask)
        self._use_graph = (not self.wp_device.is_cpu) if graph is None else bool(graph)
        if self._use_graph and self.wp_device.is_cpu:
            raise ValueError("graph=True needs a CUDA device (CUDA graphs)")
        self._rngs: list[np.random.Generator] = []
        self.steps = torch.zeros(num_envs, dtype=torch.long, device=dev)
        self._state_size = mujoco.mj_stateSize(model, STATE)
        self._last_obs = torch.zeros((num_envs, self.n_agents, self.obs_dim), dtype=torch.float32, device=dev)
        self._alive = torch.ones((num_envs, self.n_agents), dtype=torch.bool, device=dev)
        """Who is in play at the next step's start (elimination rules; all True under first-out rules)."""
        self._places = torch.zeros((num_envs, self.n_agents), dtype=torch.long, device=dev)
        """Each agent's place decided so far (elimination rules; 0 while it plays on)."""
        self._outcomes = torch.zeros((num_envs, self.n_agents), dtype=torch.long, device=dev)
        """Each agent's outcome code decided so far (elimination rules; 0 while it plays on)."""
        self._obs_noise = float(self.config.evader_obs_noise)
        self._noise_entries = [(i, index(idx)) for i, idx in self.match.observer.evader_entries.items()]
        """Pursuit's evader noise: per opponent of the evader, its observation's entries that hold the evader's torso
        position and velocity (what ``ObservationBuilder.add_evader_noise`` perturbs), in the order it draws them."""

    # ---------------------------------------------------------------- physics
    @contextlib.contextmanager
    def _on_stream(self) -> Iterator[None]:
        """Run torch and Warp work on Warp's stream of the device, ordered after the caller's stream."""
        if self._torch_stream is None:
            yield
            return
        caller = torch.cuda.current_stream(self.device)
        self._torch_stream.wait_stream(caller)
        with torch.cuda.stream(self._torch_stream), wp.ScopedDevice(self.wp_device):
            yield
        caller.wait_stream(self._torch_stream)

    def _physics(self) -> None:
        for _ in range(self.frame_skip):
            mjw.step(self.m, self.d)
        mjw.rne_postconstraint(self.m, self.d)

    def _clear(self) -> None:
        mjw.reset_data(self.m, self.d, reset=self._reset_mask_wp)

    def _derive(self) -> None:
        mjw.forward(self.m, self.d)
        mjw.rne_postconstraint(self.m, self.d)

    def _launch(self, name: str) -> None:
        """Run ``self._<name>`` (its Warp kernels). With graphs, the first call runs it eagerly (compiling
        and loading every kernel) and captures it; later calls replay the CUDA graph: mujoco_warp
        launches hundreds of kernels from Python per step, which a graph replays in one call."""
        work = getattr(self, f"_{name}")
        with wp.ScopedDevice(self.wp_device):
            if not self._use_graph:
                work()
            elif name in self._graphs:
                wp.capture_launch(self._graphs[name])
            else:
                work()
                with wp.ScopedCapture(device=self.wp_device) as capture:
                    work()
                self._graphs[name] = capture.graph

    def simulate(self) -> None:
        """``frame_skip`` physics steps of every match with the controls now in ``d.ctrl``, then
        ``cfrc_ext`` (a captured CUDA graph on CUDA)."""
        self._launch("physics")

    # ------------------------------------------------------------------ state
    def _state(self) -> dict[str, torch.Tensor]:
        qpos, qvel = self._qpos, self._qvel
        return {"pos": qpos[:, self._torso_qpos], "vel": qvel[:, self._torso_qvel],
                "forces": self._cfrc[:, self._bodies, 3:]}

    def _observe(self, state: dict[str, torch.Tensor]) -> torch.Tensor:
        rules, e, n = self.rules, self.num_envs, self.n_agents
        if self.config.obs_mode == "paper":
            obs = rules_batched.paper_observation(state["pos"], state["vel"], state["forces"], self._qpos,
                                                  self._qvel, rules, torch)
            return obs[:, None, :].expand(e, n, obs.shape[1]).contiguous()
        qpos, qvel = self._qpos, self._qvel
        forces = state["forces"].reshape(e, n, -1, 3)
        return rules_batched.egocentric_observation(
            state["pos"], state["vel"], qpos[:, self._quat_qpos], qvel[:, self._angvel_qvel],
            qpos[:, self._joint_qpos], qvel[:, self._joint_qvel], forces, rules, torch)

    def _restart(self, rows: np.ndarray) -> None:
        """Reset the matches ``rows`` (host indices) to fresh starts from their own streams."""
        starts = [self.match.start_state(self._rngs[k]) for k in rows.tolist()]
        qpos = torch.as_tensor(np.stack([s[0] for s in starts]), dtype=torch.float32, device=self.device)
        qvel = torch.as_tensor(np.stack([s[1] for s in starts]), dtype=torch.float32, device=self.device)
        index = torch.as_tensor(rows, device=self.device)
        self._reset_mask.zero_()
        self._reset_mask[index] = True
        self._launch("clear")
        self._qpos[index] = qpos
        self._qvel[index] = qvel
        self._launch("derive")
        self.steps[index] = 0
        self._alive[index] = True
        self._places[index] = 0
        self._outcomes[index] = 0

    def _add_noise(self, obs: torch.Tensor, rows: np.ndarray) -> torch.Tensor:
        """Pursuit's evader noise (``evader_obs_noise > 0``) on the observations of the matches ``rows`` (host
        indices), drawn on the host from each match's own stream as ``Match._observe`` draws it (the same numbers
        as on the CPU backend: a host loop over those matches, and a copy to the device, on every step)."""
        if self._obs_noise <= 0 or not len(rows):
            return obs
        widths = [len(idx) for _, idx in self._noise_entries]
        draws = np.stack([self._rngs[k].normal(0.0, self._obs_noise, sum(widths)) for k in rows.tolist()])
        noise = torch.as_tensor(draws.astype(np.float32), device=self.device)
        at = torch.as_tensor(rows, device=self.device)[:, None]
        obs = obs.clone()
        start = 0
        for (i, idx), width in zip(self._noise_entries, widths, strict=True):
            obs[at, i, idx] += noise[:, start:start + width]
            start += width
        return obs

    # -------------------------------------------------------------------- API
    reset_seed: Callable[[int], int | None] | None = None
    """Who seeds slot ``k``'s next match at an autoreset, as ``VectorMatches.reset_seed``:
    called for each finished slot in ascending ``k`` during :meth:`step`; the match then draws
    its start from ``np.random.default_rng(seed)`` as ``Match.reset(seed)`` does (``None``:
    continue the slot's stream)."""

    def reset(self, seed: int | Sequence[int | None] | None = None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Start every match: match ``k`` from ``match_seeds(seed, num_envs)[k]``'s stream (``seed + k``).

        ``infos`` has the keys of :meth:`step`'s (terms zero, outcome 0, no valid final_obs).

        ``seed=None`` keeps the streams of the last seeded reset (fresh entropy the first time,
        or the ``seed`` given at construction). A list of ``num_envs`` seeds seeds match ``k``
        as ``Match.reset(seed[k])`` does (as ``VectorMatches.reset``; ``None`` keeps its stream).
        """
        if isinstance(seed, Sequence):
            if len(seed) != self.num_envs or (None in seed and not self._rngs):
                raise ValueError(f"seed must be an int, None or a list of {self.num_envs} seeds, got {seed!r}")
            self._rngs = [self._rngs[k] if s is None else np.random.default_rng(check_seed(s))
                          for k, s in enumerate(seed)]
            seed = None
        if seed is None and not self._rngs:
            seed = self._seed if self._seed is not None else int(np.random.SeedSequence().generate_state(1)[0])
        if seed is not None:
            self._rngs = [np.random.default_rng(s) for s in match_seeds(seed, self.num_envs)]
        with self._on_stream():
            if self._use_graph and "physics" not in self._graphs:
                self.simulate()  # capture now, on the put_data state; the reset below overwrites it
            self._restart(np.arange(self.num_envs))
            obs = self._add_noise(self._observe(self._state()), np.arange(self.num_envs))
            self._last_obs = obs
            zeros = torch.zeros((self.num_envs, self.n_agents), device=self.device)
            infos = {name: zeros.clone() for name in (*TERMS, "dense_reward", "sparse_reward")}
            infos.update(step=self.steps.clone(), outcome=zeros.long(), place=zeros.long(), final_obs=obs.clone(),
                         out_of_ring=zeros.bool(), eliminated=zeros.bool(),
                         _final_obs=torch.zeros(self.num_envs, dtype=torch.bool, device=self.device))
        return obs, infos

    def step(self, actions: Any) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor,
                                          dict[str, torch.Tensor]]:
        """One env step of every match; see the module docstring for autoreset and errors."""
        if not self._rngs:
            raise RuntimeError("call reset() before step()")
        e, n = self.num_envs, self.n_agents
        with self._on_stream():
            act = torch.as_tensor(actions, dtype=torch.float32, device=self.device)
            if act.shape != (e, n, self.act_dim):
                raise ValueError(f"actions must have shape ({e}, {n}, {self.act_dim}), got {tuple(act.shape)}")
            finite = torch.isfinite(act).all(-1)
            if not bool(finite.all()):
                k, i = (int(v) for v in torch.nonzero(~finite)[0])
                raise ValueError(f"action of {self.agents[i]!r} in match {k} contains NaN or inf")
            ctrl = act.clamp(-1.0, 1.0) * self._ctrl_half + self._ctrl_mid
            if self.elimination:  # an eliminated body no longer acts
                ctrl = torch.where(self._alive[..., None], ctrl, 0.0)
            self._ctrl[:, self._actuators] = ctrl.reshape(e, -1)
            self.simulate()
            self.steps += 1
            rules = self.rules
            state = self._state()
            trouble = rules_batched.bad_state(torch, self._qpos, self._qvel, self._qacc) | (self._overflow != 0)
            error = trouble[:, None]
            out = rules_batched.agents_out(state["pos"], rules.half_size, torch)
            if self.elimination:
                before = self._alive
                judged = rules_batched.judge_elimination(before, out, self.steps >= rules.max_steps, rules, torch)
                sparse = rules_batched.place_values(judged.low, judged.high, rules, torch)
                terms = rules_batched.reward_terms(state["pos"], state["vel"], None, None, rules, torch, alive=before,
                                                   sparse=sparse)
                # an agent decided on an earlier step keeps its outcome and place
                code = torch.where(before, judged.code, self._outcomes)
                place = torch.where(before, judged.low, self._places)
                self._alive, self._places, self._outcomes = judged.alive, place, code
                ended, timed_out, over = judged.terminated, judged.truncated, judged.over
                left = judged.leaving & ~error  # out of the ring on this step: terminated, never truncated
                eliminated = torch.where(error, ~before, ~judged.alive)  # an error keeps who was in play
                place = torch.where(error, 0, place)
            else:
                ended = out.any(-1)
                timed_out = ~ended & (self.steps >= rules.max_steps)
                over = ended | timed_out
                code = rules_batched.judge(out, rules, torch)
                code = torch.where(timed_out[:, None], rules_batched.DRAW_CODE, code)
                terms = rules_batched.reward_terms(state["pos"], state["vel"], code, timed_out, rules, torch)
                place = rules_batched.first_out_places(torch.where(error, rules_batched.ERROR_CODE, code), torch)
                left = out & ~error  # first-out rules: out of the ring is eliminated, as on the CPU backend
                eliminated = left.clone()
            obs = self._observe(state)
            code = torch.where(error, rules_batched.ERROR_CODE, code)
            infos: dict[str, torch.Tensor] = {  # float64, as the CPU backend's (the terms of float32 physics)
                name: torch.where(error, 0.0, terms[name]).double() for name in (*TERMS, "dense_reward",
                                                                                 "sparse_reward")}
            reward = torch.where(error, 0.0, terms["reward"])
            # all agents of a match end together; under elimination rules an agent also terminates on the step it
            # leaves (as VectorMatches.step)
            terminated = (ended & ~trouble)[:, None] | left
            truncated = (timed_out | trouble)[:, None] & ~left
            done = over | trouble
            if self._obs_noise > 0:  # the evader noise draws on the host: which matches observe, which restart
                flags = torch.stack([done, trouble]).cpu().numpy()
                rows = np.flatnonzero(flags[0])
                obs = self._add_noise(obs, np.flatnonzero(~flags[1]))
            else:
                rows = torch.nonzero(done).flatten().cpu().numpy()  # the step's one host sync
            obs = torch.where(trouble[:, None, None], self._last_obs, obs)
            infos.update(outcome=code, place=place, step=self.steps.clone(), out_of_ring=left, eliminated=eliminated,
                         final_obs=obs, _final_obs=done)
            if len(rows) and self.config.on_physics_error == "raise" and bool(trouble.any()):
                k = int(torch.nonzero(trouble)[0])
                raise PhysicsError(f"MuJoCo Warp: bad state or overflow in match {k} at step {int(self.steps[k])}")
            if len(rows):
                if self.reset_seed is not None:
                    for k in rows.tolist():
                        if (chosen := self.reset_seed(k)) is not None:
                            self._rngs[k] = np.random.default_rng(chosen)
                self._restart(rows)
                obs = torch.where(done[:, None, None], self._add_noise(self._observe(self._state()), rows), obs)
            self._last_obs = obs
        return obs, reward, terminated, truncated, infos

    def restart(self, k: int, seed: int | None = None) -> torch.Tensor:
        """End slot ``k``'s match now and start its next one (from ``np.random.default_rng(seed)``, or its own
        stream with ``None``); returns its first observation ``(n_agents, obs_dim)``. As
        ``VectorMatches.restart``: for a caller whose episode ends before the match does (a trainer whose learning
        agents are all out under elimination rules)."""
        if not 0 <= k < self.num_envs:
            raise IndexError(f"match index must be in [0, {self.num_envs}), got {k}")
        if not self._rngs:
            raise RuntimeError("call reset() before restart()")
        if seed is not None:
            self._rngs[k] = np.random.default_rng(check_seed(seed))
        rows = np.array([k])
        with self._on_stream():
            self._restart(rows)
            first = self._add_noise(self._observe(self._state()), rows)[k]
            self._last_obs[k] = first
        return first.clone()

    def snapshot(self) -> list[dict[str, Any]]:
        """Every match's state, on the host, slot order: ``physics`` (float32, the world's
        :data:`STATE` from ``mujoco_warp.get_state``, warm start included), ``steps``, ``rng``
        (its start-state generator) and ``alive``, ``places`` and ``outcomes`` (elimination rules: who is in play,
        and what was decided so far, as ``Match.snapshot``). Arrays and JSON-able values only (no pickle). With the
        last returned observations, :meth:`restore` continues exactly (as ``VectorMatches.snapshot``)."""
        if not self._rngs:
            raise RuntimeError("call reset() before snapshot()")
        with self._on_stream(), wp.ScopedDevice(self.wp_device):
            state = wp.zeros((self.num_envs, self._state_size), dtype=wp.float32)
            mjw.get_state(self.m, self.d, state, STATE)
            physics = state.numpy()
        steps = self.steps.cpu().tolist()
        alive, places, outcomes = (t.cpu().tolist() for t in (self._alive, self._places, self._outcomes))
        return [{"physics": physics[k], "steps": int(steps[k]), "rng": self._rngs[k].bit_generator.state,
                 "alive": alive[k], "places": places[k], "outcomes": outcomes[k]} for k in range(self.num_envs)]

    def restore(self, snapshots: Sequence[dict[str, Any]], obs: Any) -> None:
        """Continue from :meth:`snapshot` and the observations ``(num_envs, n_agents, obs_dim)``
        returned with it (the last trustworthy observation of a match that meets physics trouble
        next): the next :meth:`step` is the one the snapshotted batch would have made, bit for
        bit on a deterministic device (Warp's CPU device; see docs/gpu.md on CUDA's contact order)."""
        if len(snapshots) != self.num_envs:
            raise ValueError(f"need {self.num_envs} match snapshots, got {len(snapshots)}")
        physics = np.stack([np.asarray(s["physics"], dtype=np.float32) for s in snapshots])
        if physics.shape != (self.num_envs, self._state_size):
            raise ValueError(f"match snapshots hold physics of shape {physics.shape[1:]}, this model's MuJoCo Warp "
                             f"state has ({self._state_size},) (another model or backend)")
        last = torch.as_tensor(obs, dtype=torch.float32, device=self.device)
        if last.shape != (self.num_envs, self.n_agents, self.obs_dim):
            raise ValueError(f"obs must have shape ({self.num_envs}, {self.n_agents}, {self.obs_dim}), "
                             f"got {tuple(last.shape)}")
        rngs = []
        for snap in snapshots:
            rng = np.random.default_rng()
            rng.bit_generator.state = snap["rng"]
            rngs.append(rng)
        with self._on_stream():
            if self._use_graph and "physics" not in self._graphs:
                self.simulate()  # capture now (as reset does); the state set below overwrites it
            with wp.ScopedDevice(self.wp_device):
                mjw.set_state(self.m, self.d, wp.array(physics, dtype=wp.float32), STATE)
            self._launch("derive")  # contacts and cfrc_ext of the restored state (no warm start is written)
            self.steps.copy_(torch.as_tensor([int(s["steps"]) for s in snapshots], device=self.device))
            every, none = [True] * self.n_agents, [0] * self.n_agents  # a snapshot of before elimination rules ran
            for name, default in (("alive", every), ("places", none), ("outcomes", none)):
                getattr(self, f"_{name}").copy_(torch.as_tensor([s.get(name, default) for s in snapshots],
                                                                device=self.device))
            self._last_obs = last.clone()
        self._rngs = rngs

    def close(self) -> None:
        """Drop the captured graphs."""
        self._graphs.clear()


def set_warp_verbose(verbose: bool) -> None:
    """Warp's info log (its banner and a ``Module ... load`` line per compiled module: about 47 lines on a
    cold compile) only when asked for; warnings and errors always. A cold compile of this env's kernels takes
    about 4 min on Warp's CPU device (seconds on a GPU) and is cached in ``~/.cache/warp``."""
    wp.config.log_level = wp.LOG_INFO if verbose else max(wp.config.log_level, wp.LOG_WARNING)


def make_warp_vector_env(config: MatchConfig | None, num_envs: int, device: str | None = None,
                         seed: int | None = None) -> WarpVectorMatches:
    """The ``backend="warp"`` env of ``triplesumo.vector_env``: ``device`` defaults to ``"cuda"``
    when Warp sees a GPU, else Warp's ``"cpu"``; ``seed`` seeds the first ``reset()``."""
    if device is None:
        device = "cuda" if wp.is_cuda_available() else "cpu"
    return WarpVectorMatches(config, num_envs, device=device, seed=seed)


def __getattr__(name: str) -> Any:
    if name == "WarpMatchBatch":
        import warnings

        warnings.warn("triplesumo.envs.warp.WarpMatchBatch is deprecated: it is WarpVectorMatches (the Warp backend "
                      "of the batched API, VectorMatches' counterpart)", DeprecationWarning, stacklevel=2)
        return WarpVectorMatches
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
