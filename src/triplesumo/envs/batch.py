"""Many independent matches whose physics steps together, so that every core works.

:class:`MatchBatch` holds ``n_matches`` :class:`~triplesumo.envs.match.Match` objects of
one :class:`~triplesumo.rules.MatchConfig`. A step checks every match's actions
(:meth:`Match.prepare`), advances all the physics on ``n_threads`` threads with the GIL
released, then judges each match in Python (:meth:`Match.finish_step`: outcome,
rewards, observations, MuJoCo warnings).

Exactness: the trajectories are bit for bit those of stepping each match alone with
:meth:`Match.step_array` (same qpos, qvel, observations and rewards; checked with
``np.array_equal`` in ``tests/test_batch.py``), at any thread count, with either *stepper* (how the
physics of the matches is spread over threads; ``backend`` is the word for the simulator, ``cpu`` or ``warp``,
of :func:`~triplesumo.envs.backends.vector_env`):

``stepper="mujoco"`` (default)
    ``mujoco.batch.Batch(model, n_matches, nthread=n_threads, persistent=True)``, MuJoCo
    4's native threaded stepping. Its state rows are ``mjSTATE_INTEGRATION`` (qpos, qvel,
    controls *and* the solver warm start) and a persistent batch keeps one ``MjData`` per
    simulation, so after a step ``Batch.get_data(k, match.data)`` hands match ``k`` its
    complete ``MjData``: contacts for the contact forces, warning counters, warm start;
    no ``mj_forward`` is needed.
``stepper="threads"``
    A Python thread pool (the calling thread and ``n_threads - 1`` others) in which each
    thread runs whole steps (``sim.step`` then ``finish_step``) on the matches' own
    ``MjData``, taking the next match not yet taken until none is left (matches with more
    contacts cost more; fixed blocks per thread left one thread waiting). ``mj_step``
    releases the GIL, so one thread's physics overlaps another's Python rules.

Why not ``mujoco.rollout``: its persistent pool steps *scratch* ``MjData`` (one per
thread, any of which may run any match) and returns only the ``mjSTATE_FULLPHYSICS``
state, without the final ``qacc_warmstart``. Each match's data must then be set from that
state and ``mj_forward`` run for its contacts, which is not exact twice over: the lost warm
start moves the solver's result, and ``mj_forward`` gives the contacts of the new state
where ``mj_step`` leaves those of the last substep's start, so the observed contact forces
change. Rollout also clears the warning counters and stops a trajectory at its first
warning. How much each stepper gains, and the measurements behind this paragraph, are in
``docs/bench/index.md``.

Finished matches are not reset here: after a step in which ``results[k]`` is terminated
or truncated, call :meth:`reset_one` for ``k`` before the next :meth:`step`.

:meth:`MatchBatch.step_arrays` is the same step with its results as arrays over the
matches (:class:`BatchStep`), the path of :class:`VectorMatches`. Under either rule set
it judges the matches together, with the very rule functions one match calls (on ``E = 1``) and MuJoCo
Warp calls (with torch; :mod:`triplesumo.rules.batched` lists them): controls of all actions in one array
operation; qpos, qvel and warning counters in ``(n_matches, ...)`` rows (the batch's own
rows with ``mujoco``; with ``threads`` each thread copies its matches' states into them
after their physics, and computes their contact forces); outcome, rewards, places, infos
and ``paper`` observations over ``(n_matches, n_agents, ...)`` arrays. Per match there
remain a few attribute updates, with ``mujoco`` the copy of its ``MjData`` out of the batch
and its ``mj_rnePostConstraint``, and under ``egocentric`` observations the match's own
:class:`~triplesumo.rules.observations.ObservationBuilder`. Results are bit for bit those
of :meth:`step` (``tests/test_batch.py``): the reward sums run in one order for any number of matches
(:func:`~triplesumo.rules.rewards.ordered_sum`). A match with a new MuJoCo warning, a
failed ``mj_step`` or a non-finite state is finished by :meth:`Match.finish_step` (its
physics error). Under elimination rules the batch carries where each match stands in
``(n_matches, n_agents)`` arrays (who is in play, the places and outcomes decided so far): an agent
out of play gets zero control in the one array operation, and
:func:`~triplesumo.rules.outcome.judge_elimination` judges every match at once; each match takes
its row back (:meth:`Match.record_judged`), as it takes its observations (and pursuit's evader
noise, drawn from its own generator). ``triplesumo bench env`` measures ``vector_env`` against raw
``mujoco.batch`` physics of the same matches (``docs/bench/env_vector_cpu.md``).

:class:`VectorMatches` (made by ``triplesumo.vector_env``) is the public face of a
MatchBatch: arrays ``(num_envs, n_agents, ...)`` in and out, Gymnasium-style autoreset,
seeds that depend only on ``(seed, k)``.
"""

from __future__ import annotations

import math
import operator
import os
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import mujoco.batch
import numpy as np
from gymnasium import spaces

from triplesumo.envs.match import Match, StepResult, real_array, scale_actions
from triplesumo.envs.seeding import check_seed, match_seeds
from triplesumo.rules import batched as rules_batched
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.rewards import REPORTED
from triplesumo.sim.physics import PhysicsError

STEPPERS = ("mujoco", "threads")
"""How :class:`MatchBatch` spreads the physics over threads: ``mujoco.batch``'s own pool, or Python threads."""
_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_NO_STAGE = int(mujoco.mjtStage.mjSTAGE_NONE)


UNCOUNTED_BYTES = 512 * 1024
"""Bytes per match that MuJoCo's buffer sizes leave out, counted by :func:`match_bytes`: the part of the
``MjData`` arena a step uses and the match's Python objects (measured: a paper match takes about 1.1 MB of
resident memory, 0.38 MB of it its ``MjModel`` and ``MjData`` buffers; so the estimate stays below the truth)."""


def match_bytes(match: Match, stepper: str = "threads") -> int:
    """Bytes one more match like ``match`` takes in a :class:`MatchBatch`: its own ``MjModel`` and ``MjData``
    buffers, :data:`UNCOUNTED_BYTES`, and with ``stepper="mujoco"`` the batch's own ``MjData`` of it."""
    data = match.data.nbuffer * (2 if stepper == "mujoco" else 1)
    return match.model.nbuffer + data + UNCOUNTED_BYTES


def available_memory() -> int | None:
    """Bytes this process could still get: ``MemAvailable`` plus free swap from ``/proc/meminfo`` (else
    ``os.sysconf``'s available pages), no more than a cgroup v2 memory limit leaves; ``None`` if unknown."""
    have: int | None = None
    try:
        info = {k: int(v.split()[0]) * 1024 for k, v in
                (line.split(":", 1) for line in Path("/proc/meminfo").read_text().splitlines() if ":" in line)}
        if "MemAvailable" in info:
            have = info["MemAvailable"] + info.get("SwapFree", 0)
    except (OSError, ValueError):
        pass
    if have is None:
        try:
            have = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return None
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            have = min(have, int(limit) - int(Path("/sys/fs/cgroup/memory.current").read_text()))
    except (OSError, ValueError):
        pass
    return have


def check_memory(first: Match, n_matches: int, stepper: str = "threads") -> None:
    """``MemoryError`` (a ``ValueError`` too) naming ``n_matches`` and the estimate when ``n_matches`` matches
    like ``first`` would take more memory than this machine has available: checked before they are built, so
    that a batch too big for the machine is refused at once instead of filling memory for minutes."""
    per_match = match_bytes(first, stepper)
    need, have = n_matches * per_match, available_memory()
    if have is not None and need > have:
        raise BatchMemoryError(
            f"n_matches={n_matches:,} matches need about {need / 2**30:,.1f} GiB ({per_match / 2**20:.2f} MiB each: "
            f"MuJoCo model and data, arena and Python objects), more than the {have / 2**30:,.1f} GiB this machine "
            f"has available; at most about {max(1, have // per_match):,} fit")


class BatchMemoryError(MemoryError, ValueError):
    """A batch of matches that this machine's memory cannot hold (a ``ValueError`` too: the size was a bad
    argument here, and the commands report it as one)."""


class MatchBatch:
    """``n_matches`` independent matches of one config, their physics stepped on ``n_threads`` threads."""

    def __init__(self, config: MatchConfig | None = None, n_matches: int = 16, n_threads: int = 2,
                 stepper: str = "mujoco", *, backend: str | None = None) -> None:
        if isinstance(n_matches, bool) or not isinstance(n_matches, int) or n_matches < 1:
            raise ValueError(f"n_matches must be an integer >= 1, got {n_matches!r}")
        if isinstance(n_threads, bool) or not isinstance(n_threads, int) or n_threads < 1:
            raise ValueError(f"n_threads must be an integer >= 1, got {n_threads!r}")
        if backend is not None:
            warnings.warn("MatchBatch(backend=...) is deprecated: it is MatchBatch(stepper=...) (``backend`` names the "
                          "simulator, cpu or warp, of triplesumo.vector_env)", DeprecationWarning, stacklevel=2)
            stepper = backend
        if stepper not in STEPPERS:
            raise ValueError(f"stepper must be one of {STEPPERS}, got {stepper!r}")
        first = Match(config)
        check_memory(first, n_matches, stepper)
        self.matches = [first, *(Match(config) for _ in range(n_matches - 1))]
        self.config = first.config
        self.agents = first.agents
        self.n_agents = first.n_agents
        self.action_width = first.action_width
        """Columns of each match's action array (see :attr:`Match.action_width`)."""
        self.n_matches = n_matches
        self.n_threads = n_threads
        self.stepper = stepper
        """How the physics is spread over threads: ``"mujoco"`` (``mujoco.batch``) or ``"threads"`` (Python)."""
        self._frame_skip = first.sim.frame_skip
        motors = first.sim.actuator_ids >= 0  # padding columns of smaller bodies drive nothing
        self._motor_columns = None if motors.all() else motors.ravel()
        self._actuators = first.sim.actuator_ids[motors]
        self._batch: mujoco.batch.Batch | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._closed = False
        if stepper == "mujoco":
            # Every match compiles the same config to the same model; the batch steps a copy of it.
            self._batch = mujoco.batch.Batch(first.model, n_matches, nthread=n_threads, persistent=True)
            self._ctrl = self._batch.bind("ctrl")
            self._qpos, self._qvel = self._batch.bind("qpos"), self._batch.bind("qvel")
            self._warnings_seen = self._batch.warning.copy()
            """Every simulation's MuJoCo warning counters as of its last judged step."""
        elif n_threads > 1:
            self._pool = ThreadPoolExecutor(n_threads - 1, thread_name_prefix="MatchBatch")
        self._rules = first.game  # the rules as arrays, as each match holds them
        self._elimination = first.elimination
        """Elimination rules: :meth:`step_arrays` carries where each match stands in the arrays below."""
        self._alive = np.ones((n_matches, first.n_agents), bool)
        """``(n_matches, n_agents)``: who is in play at the next step's start (elimination rules; each match's
        ``alive``, read by :meth:`reload` and written back after every step)."""
        self._places = np.zeros((n_matches, first.n_agents), np.int64)
        """Each agent's place decided so far (0 while it plays on): an agent out keeps it in later infos."""
        self._outcomes = np.zeros((n_matches, first.n_agents), np.int64)
        """Each agent's outcome code decided so far (0 while it plays on)."""
        self._obs_noise = float(self.config.evader_obs_noise)
        """Pursuit's evader noise: each match draws it from its own generator after its observation is built."""
        sim = first.sim
        self._torso_qpos, self._torso_qvel = sim.torso_qpos, sim.torso_qvel
        paper = self.config.obs_mode == "paper"
        self._forces = np.empty((n_matches, len(sim.agent_geoms), 3)) if paper else None
        """Contact forces of the step's ``paper`` observations (egocentric: each match builds its own)."""
        # Simulation.contact_forces without its method calls: each match's cfrc_ext rows after
        # mj_rnePostConstraint, minus its xfrc_applied rows.
        rows = sim.body_force_rows
        self._body_forces = [(m.data.cfrc_ext[rows, 3:], m.data.xfrc_applied[rows, :3])
                             if paper and rows is not None else None for m in self.matches]
        """Per match: the views ``Simulation.contact_forces`` subtracts (``None``: call it)."""
        if self._batch is None:  # the threads stepper: each match's state gathered into rows after its step
            self._qpos, self._qvel = np.empty((n_matches, first.model.nq)), np.empty((n_matches, first.model.nv))
            self._warnings_now = np.zeros((n_matches, *first.data.warning.number.shape), np.int32)
            self._warnings_seen = self._warnings_now.copy()
            self._contacts = [0] * n_matches
        self._pad = first.sim.action_mask
        self._ctrl_mid = (sim.ctrl_high + sim.ctrl_low) / 2.0
        self._ctrl_half = (sim.ctrl_high - sim.ctrl_low) / 2.0

    # ------------------------------------------------------------------ reset
    def reset_all(self, seed: int) -> list[tuple[list[np.ndarray], list[dict[str, Any]]]]:
        """Reset every match; match ``k`` is seeded with ``match_seeds(seed, n_matches)[k]``, ``seed + k``."""
        return [self.reset_one(k, s) for k, s in enumerate(match_seeds(seed, self.n_matches))]

    def reset_one(self, k: int, seed: int | None = None) -> tuple[list[np.ndarray], list[dict[str, Any]]]:
        """Reset match ``k`` (``Match.reset``: ``None`` keeps drawing from its generator)."""
        self._check_index(k)
        observations, infos = self.matches[k].reset(seed)
        self.reload(k)
        return observations, infos

    def reload(self, k: int) -> None:
        """Continue match ``k`` from its ``MjData`` as it is now.

        :meth:`reset_one` calls it; call it yourself after editing ``matches[k].data`` by
        hand (a scenario test placing an agent), since the ``mujoco`` stepper steps its own
        copy of each match's state and would otherwise overwrite the edit.
        """
        self._check_index(k)
        match = self.matches[k]
        if self._batch is not None:
            # Clear the simulation's MjData (warning counters included), then load the match's state.
            self._batch.reset(ids=[k], stage=_NO_STAGE)
            mujoco.mj_getState(match.model, match.data, self._batch.state[k], _INTEGRATION)
            self._warnings_seen[k] = self._batch.warning[k]
        else:
            self._warnings_seen[k] = match.data.warning.number
        if self._elimination:
            self._alive[k], self._places[k], self._outcomes[k] = match.standing

    @property
    def over(self) -> np.ndarray:
        """``(n_matches,)`` bool: which matches have ended (or were never started)."""
        return np.array([m.over for m in self.matches])

    # ------------------------------------------------------------------- step
    def step(self, actions: np.ndarray) -> list[StepResult]:
        """One env step of every match with ``(n_matches, n_agents, action_width)`` normalised actions.

        Raises before any physics runs: ``ValueError`` for a wrong shape, or for NaN or inf
        (naming the match and the agent); ``RuntimeError`` if a match is over. With
        ``on_physics_error="raise"``, every match finishes its step and then the first
        ``PhysicsError`` is raised, naming its match.
        """
        self._check_open()
        actions = self._checked_shape(actions)
        ctrls = []
        for k, (match, action) in enumerate(zip(self.matches, actions, strict=True)):
            try:
                ctrls.append(match.prepare(action))
            except ValueError as err:
                raise ValueError(f"match {k}: {err}") from err
        if self._batch is not None:
            outcomes = self._step_batch(ctrls)
        else:  # as step_arrays: every thread takes the next match from one shared iterator
            todo = iter(range(self.n_matches))
            found: list[Any] = [None] * self.n_matches
            others = [] if self._pool is None else [self._pool.submit(self._run_block, todo, ctrls, found)
                                                     for _ in range(self.n_threads - 1)]
            self._run_block(todo, ctrls, found)
            for future in others:
                future.result()
            outcomes = found
        if self._elimination:  # each match judged itself: take where it stands for step_arrays
            for k, match in enumerate(self.matches):
                self._alive[k], self._places[k], self._outcomes[k] = match.standing
        for k, outcome in enumerate(outcomes):
            if isinstance(outcome, PhysicsError):
                raise PhysicsError(f"match {k}: {outcome}") from outcome
        return outcomes  # type: ignore[return-value]  # no PhysicsError left

    def step_arrays(self, actions: np.ndarray) -> BatchStep:
        """:meth:`step` with its results as arrays over the matches (:class:`BatchStep`), bit for bit.

        The matches are judged together (see the module docstring): controls from all actions
        at once, states and warnings read from ``(n_matches, ...)`` rows, outcome (under
        elimination rules who leaves, who plays on, the places each shares), rewards and places
        by :mod:`triplesumo.rules.batched`, ``paper`` observations stacked over the matches. A
        match with a new MuJoCo warning, a failed ``mj_step`` or a non-finite state takes
        :meth:`Match.finish_step` (its physics error). Every agent's observation must have one size.
        """
        self._check_open()
        ctrl = self._controls(actions)
        if self._batch is not None:
            flat = ctrl.reshape(self.n_matches, -1)
            self._ctrl[:, self._actuators] = flat if self._motor_columns is None else flat[:, self._motor_columns]
            self._batch.step(nstep=self._frame_skip)
            return self._judge_together(self._batch.warning)
        # Every thread (the calling one too, as mujoco.batch's caller) takes the next match not yet
        # taken from one shared iterator (next() of a range iterator is atomic under the GIL): the
        # matches' physics costs differ with their contacts, and fixed blocks of matches per thread
        # left one thread idle while the other finished its block (docs/bench/index.md). The matches with
        # the most contacts at their last step go first, so the last ones taken are short. Which thread
        # steps a match changes nothing in it.
        todo = iter(range(self.n_matches) if self._pool is None else
                    sorted(range(self.n_matches), key=self._contacts.__getitem__, reverse=True))
        others = [] if self._pool is None else [self._pool.submit(self._physics_block, todo, ctrl)
                                                 for _ in range(self.n_threads - 1)]
        self._physics_block(todo, ctrl)
        for future in others:
            future.result()
        return self._judge_together(self._warnings_now)

    def _physics_block(self, block: Any, ctrl: np.ndarray) -> None:
        """The ``threads`` stepper: step matches of ``block`` (an iterator shared by the pool's threads)
        on their own ``MjData``, then copy each one's state into the rows :meth:`_judge_together`
        reads, and compute the contact forces of ``paper`` observations (``mj_rnePostConstraint``
        releases the GIL too)."""
        for k in block:
            sim = self.matches[k].sim
            sim.step(ctrl[k])
            data = sim.data
            self._qpos[k], self._qvel[k], self._warnings_now[k] = data.qpos, data.qvel, data.warning.number
            self._contacts[k] = data.ncon
            if sim.step_failed:
                self._warnings_now[k] = -1  # a new "warning": the match is judged alone (its arena_overflow)
            views = self._body_forces[k]
            if self._forces is None:
                continue
            if views is not None:  # Simulation.contact_forces, without its method calls
                mujoco.mj_rnePostConstraint(sim.model, data)
                np.subtract(views[0], views[1], out=self._forces[k])
            else:
                self._forces[k] = sim.contact_forces()

    def _checked_shape(self, actions: np.ndarray) -> np.ndarray:
        """``actions`` as float64 ``(n_matches, n_agents, action_width)``; ``ValueError`` for another shape or
        values that are not real numbers (naming the match and agent), ``RuntimeError`` if a match is over or
        was never started."""
        expected = (self.n_matches, self.n_agents, self.action_width)
        try:
            actions = real_array(actions, "actions", f"real numbers of shape {expected}", copy=False)
        except ValueError:
            self._name_bad_action(actions)
            raise
        if actions.shape != expected:
            raise ValueError(f"actions must have shape {expected}, got {actions.shape}")
        if any(m.over for m in self.matches):
            never = [k for k, m in enumerate(self.matches) if not m.started]
            if never:
                raise RuntimeError(f"matches {never} were never started: call reset_one(k) before the first step")
            finished = [k for k, m in enumerate(self.matches) if m.over]
            raise RuntimeError(f"matches {finished} are over: call reset_one(k) first")
        return actions

    def _name_bad_action(self, actions: Any) -> None:
        """``ValueError`` naming the match and agent whose action row holds something that is not a real
        number, if ``actions`` has the batch's shape (``Match.check_action``'s message); else nothing."""
        if np.iscomplexobj(actions):  # refused as a whole already ("real numbers, got complex values")
            return
        try:
            cells = np.array(actions, dtype=object)
        except (TypeError, ValueError, RuntimeError):
            return
        if cells.shape != (self.n_matches, self.n_agents, self.action_width):
            return
        for k, match in enumerate(self.matches):
            for i, agent in enumerate(self.agents):
                try:
                    match.check_action(agent, cells[k, i, :match.action_sizes[i]])
                except ValueError as err:
                    raise ValueError(f"match {k}: {err}") from None

    def _controls(self, actions: np.ndarray) -> np.ndarray:
        """:meth:`Match.prepare` of every match at once: an agent out of play (elimination rules) gets zero control."""
        actions = self._checked_shape(actions)
        if self._pad is not None:  # columns past an agent's motors are ignored, whatever they hold
            actions = np.where(self._pad, actions, 0.0)
        if not math.isfinite(actions.sum()):  # NaN or inf somewhere (or an overflowing sum: look closer)
            bad = ~np.isfinite(actions).all(axis=2)
            if bad.any():
                k, i = (int(x) for x in np.argwhere(bad)[0])
                raise ValueError(f"match {k}: action of {self.agents[i]!r} contains NaN or inf")
        ctrl = scale_actions(actions, self._ctrl_half, self._ctrl_mid)
        if self._elimination and not self._alive.all():  # an eliminated body no longer acts
            ctrl[~self._alive] = 0.0
        return ctrl

    def _judge_together(self, warnings: np.ndarray) -> BatchStep:
        """The second half of :meth:`step_arrays`: every match's step judged over arrays."""
        n, a = self.n_matches, self.n_agents
        qpos, qvel = self._qpos, self._qvel
        trouble = np.zeros(n, bool)
        if warnings.tobytes() != self._warnings_seen.tobytes():  # rare: find the matches with new warnings
            trouble = (warnings != self._warnings_seen).reshape(n, -1).any(axis=1)
            self._warnings_seen[trouble] = warnings[trouble]
        if not math.isfinite(qpos.sum() + qvel.sum()):  # NaN or inf somewhere (or an overflowing sum)
            trouble |= ~(np.isfinite(qpos.sum(axis=1)) & np.isfinite(qvel.sum(axis=1)))
        forces = self._forces
        own_obs: list[Any] = [None] * n
        """Observations built by each match itself (egocentric); the results of troubled matches."""
        steps = np.empty(n, np.int64)
        if self._batch is None and forces is not None and not trouble.any():  # the threads stepper's usual step
            for match in self.matches:
                match.steps += 1
            steps[:] = [match.steps for match in self.matches]
        else:
            self._count_steps(trouble, own_obs, steps)
        rules, xp = self._rules, np
        with np.errstate(all="ignore") if trouble.any() else nullcontext():  # troubled rows are replaced below
            pos, vel = qpos[:, self._torso_qpos], qvel[:, self._torso_qvel]
            out = rules_batched.agents_out(pos, rules.half_size, xp)
            if self._elimination:
                before = self._alive
                judged = rules_batched.judge_elimination(before, out, steps >= rules.max_steps, rules, xp)
                sparse = rules_batched.place_values(judged.low, judged.high, rules, xp)
                terms = rules_batched.reward_terms(pos, vel, None, None, rules, xp, alive=before, sparse=sparse)
                # an agent decided on an earlier step keeps its outcome and place
                code = xp.where(before, judged.code, self._outcomes)
                places = xp.where(before, judged.low, self._places)
                ended, timed_out, leaving, over = judged.terminated, judged.truncated, judged.leaving, judged.over
                out, gone = leaving.copy(), ~judged.alive
            else:
                ended = out.any(axis=1)
                timed_out = ~ended & (steps >= rules.max_steps)
                if ended.any() or timed_out.any():
                    code = xp.where(timed_out[:, None], rules_batched.DRAW_CODE, rules_batched.judge(out, rules, xp))
                else:  # every match goes on (most steps): what judge() gives then
                    code = np.full((n, a), rules_batched.GOES_ON, np.int64)
                terms = rules_batched.reward_terms(pos, vel, code, timed_out, rules, xp)
                places, leaving, over, gone = rules_batched.first_out_places(code, xp), np.zeros((n, a), bool), \
                    ended | timed_out, out.copy()
            if forces is not None:
                obs = rules_batched.paper_observation(pos, vel, forces, qpos, qvel, rules, xp).astype(np.float32)
                obs = np.repeat(obs[:, None], a, axis=1)
            else:
                obs = np.empty((n, a, self.matches[0].observer.sizes[self.agents[0]]), np.float32)
        infos: dict[str, np.ndarray] = {key: terms[key] for key in REPORTED}
        infos["sparse_reward"] = infos["sparse_reward"].copy()  # reward_terms gives reward_outcome the same array
        infos.update(outcome=code, out_of_ring=out, place=places, eliminated=gone, step=steps)
        rewards = terms["reward"]
        truncated = timed_out
        errors = []
        standing = None
        if self._elimination:  # where each match stands after the step (a troubled match's row is its own, below)
            self._alive, self._places, self._outcomes = judged.alive, places.copy(), code.copy()
            standing = zip(judged.alive.tolist(), places.tolist(), code.tolist(), strict=True)
        noise, over = self._obs_noise, over.tolist()
        for k, (match, own, bad) in enumerate(zip(self.matches, own_obs, trouble.tolist(), strict=True)):
            where = None if standing is None else next(standing)
            if not bad:
                if own is not None:
                    obs[k] = own
                rows = list(obs[k])
                if noise > 0:  # pursuit's evader noise, from the match's own generator, as Match._observe draws it
                    match.observer.add_evader_noise(rows, match.np_random, noise)
                match.record_judged(over[k], rows, where)
                continue
            if isinstance(own, PhysicsError):
                errors.append((k, own))
                continue
            result: StepResult = own
            obs[k], rewards[k], ended[k], truncated[k] = result.observations, result.rewards, \
                result.terminated, result.truncated
            leaving[k] = result.eliminated or False
            for key, column in zip(_ARRAY_INFOS, zip(*(_array_infos(info) for info in result.infos),
                                                     strict=True), strict=True):
                infos[key][k] = column
            if self._elimination:
                self._alive[k], self._places[k], self._outcomes[k] = match.standing
        if errors:
            k, err = errors[0]
            raise PhysicsError(f"match {k}: {err}") from err
        return BatchStep(obs, rewards, ended, truncated, leaving, infos)

    def _count_steps(self, trouble: np.ndarray, own_obs: list[Any], steps: np.ndarray) -> None:
        """The general first half of :meth:`_judge_together`, match by match: a troubled match is
        finished alone (its result into ``own_obs``); the others count their step, take their state
        from the ``mujoco`` stepper's batch and their contact forces, or build their own
        (``egocentric``) observations into ``own_obs``."""
        forces = self._forces
        get_data = None if self._batch is None else self._batch.get_data
        post_constraint = mujoco.mj_rnePostConstraint
        for k, (match, bad, views) in enumerate(zip(self.matches, trouble.tolist(), self._body_forces, strict=True)):
            if get_data is not None:
                get_data(k, match.data)
            if bad:
                own_obs[k] = _finish(match)
            else:
                match.steps += 1
                if forces is None:
                    own_obs[k] = match.observer.build()
                elif get_data is None:
                    pass  # contact forces computed by _physics_block
                elif views is not None:  # Simulation.contact_forces, without its method calls
                    post_constraint(match.model, match.data)
                    np.subtract(views[0], views[1], out=forces[k])
                else:
                    forces[k] = match.sim.contact_forces()
            steps[k] = match.steps

    def _step_batch(self, ctrls: list[np.ndarray]) -> list[StepResult | PhysicsError]:
        assert self._batch is not None
        flat = np.reshape(ctrls, (self.n_matches, -1))
        self._ctrl[:, self._actuators] = flat if self._motor_columns is None else flat[:, self._motor_columns]
        self._batch.step(nstep=self._frame_skip)
        outcomes = []
        for k, match in enumerate(self.matches):
            self._batch.get_data(k, match.data)
            outcomes.append(_finish(match))
        return outcomes

    def _run_block(self, block: Any, ctrls: list[np.ndarray], outcomes: list[Any]) -> None:
        """Whole steps of the matches of ``block`` (an iterator shared by the pool's threads), each on
        its own MjData, their results into ``outcomes[k]``."""
        for k in block:
            self.matches[k].sim.step(ctrls[k])
            outcomes[k] = _finish(self.matches[k])

    # ---------------------------------------------------------------- closing
    def close(self) -> None:
        """Stop the threads and free the batch; it cannot step or reset afterwards."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        self._batch = None
        self._closed = True

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("the MatchBatch is closed")

    def _check_index(self, k: int) -> None:
        self._check_open()
        if not 0 <= k < self.n_matches:
            raise IndexError(f"match index must be in [0, {self.n_matches}), got {k}")

    @property
    def backend(self) -> str:
        """Deprecated: :attr:`stepper`."""
        warnings.warn("MatchBatch.backend is deprecated: it is MatchBatch.stepper", DeprecationWarning, stacklevel=2)
        return self.stepper

    def __enter__(self) -> MatchBatch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class BatchStep:
    """One step of every match of a :class:`MatchBatch`, as arrays (``N`` matches, ``A`` agents).

    What :meth:`MatchBatch.step` returns as a list of :class:`StepResult`, bit for bit."""

    observations: np.ndarray
    """``(N, A, obs_dim)`` float32."""
    rewards: np.ndarray
    """``(N, A)`` float64: ``dense + sparse``."""
    terminated: np.ndarray
    """``(N,)`` bool: the match ended by its rules."""
    truncated: np.ndarray
    """``(N,)`` bool: the match hit its step limit or a physics error."""
    leaving: np.ndarray
    """``(N, A)`` bool: eliminated on this step (elimination rules; all False under first_out)."""
    infos: dict[str, np.ndarray]
    """Every :data:`REPORTED` term ``(N, A)`` float64, ``outcome`` and ``place`` ``(N, A)`` int64,
    ``out_of_ring`` and ``eliminated`` ``(N, A)`` bool, ``step`` ``(N,)`` int64."""


def _infos(per_match: list[list[dict[str, Any]]], steps: list[int], n_agents: int) -> dict[str, np.ndarray]:
    """Per-match info dicts as the arrays of :attr:`BatchStep.infos`."""
    rows = [_array_infos(info) for infos in per_match for info in infos]
    table = np.array(rows, np.float64).reshape(len(per_match), n_agents, len(_ARRAY_INFOS))
    infos: dict[str, np.ndarray] = {key: table[..., j] for j, key in enumerate(REPORTED)}
    infos["outcome"] = table[..., len(REPORTED)].astype(np.int64)
    infos["out_of_ring"] = table[..., len(REPORTED) + 1].astype(bool)
    infos["place"] = table[..., len(REPORTED) + 2].astype(np.int64)
    infos["eliminated"] = table[..., len(REPORTED) + 3].astype(bool)
    infos["step"] = np.array(steps, np.int64)
    return infos


_ARRAY_INFOS = (*REPORTED, "outcome", "out_of_ring", "place", "eliminated")
_array_infos = operator.itemgetter(*_ARRAY_INFOS)


def _finish(match: Match) -> StepResult | PhysicsError:
    """``match.finish_step()``, with a raised ``PhysicsError`` returned so the other matches still finish."""
    try:
        return match.finish_step()
    except PhysicsError as err:
        return err


class VectorMatches:
    """Many matches as arrays: TripleSumo's public batched API on the CPU
    (:func:`~triplesumo.envs.backends.vector_env`).

    It grows :class:`MatchBatch` (threaded physics, bit for bit the trajectories of single
    matches) into the batched contract that the ``warp`` backend shares: arrays in, arrays
    out, autoreset. Each step is :meth:`MatchBatch.step_arrays` on the ``threads`` stepper:
    each thread steps its block of matches on their own ``MjData`` (``mj_step`` and
    ``mj_rnePostConstraint`` release the GIL) and copies their states into rows, then the
    rules judge all matches over arrays. The ``mujoco`` stepper (``mujoco.batch``) would
    have to copy every match's whole ``MjData`` out of the batch after each step for its
    contact forces, which doubles the memory the physics runs through and slows it
    (``docs/bench/index.md``).

    Shapes (``N = num_envs``, ``A = n_agents``): observations ``(N, A, obs_dim)`` float32;
    actions ``(N, A, act_dim)`` in [-1, 1], scaled to each agent's control range as
    :class:`Match` does; rewards ``(N, A)`` float32; terminations and truncations
    ``(N, A)`` bool. ``infos`` is a dict of arrays: every reward term and
    ``dense_reward``/``sparse_reward`` ``(N, A)`` float64 (the reward is exactly
    ``dense + sparse`` before its cast to float32), ``outcome`` ``(N, A)`` int64
    (:data:`triplesumo.rules.outcome.OUTCOME_CODES`: 0 goes on, 1 win, 2 loss, 3 draw,
    4 physics error), ``out_of_ring`` ``(N, A)`` bool, ``step`` ``(N,)`` int64.

    Autoreset (Gymnasium 1.x ``SAME_STEP``): on a step where match ``k`` ends, ``obs[k]``
    is already the first observation of its next match; ``infos["final_obs"][k]`` is the
    last observation of the finished match (rows of unfinished matches are unspecified)
    and ``infos["_final_obs"]`` ``(N,)`` says which rows hold one. Rewards, flags,
    outcome, terms and ``step`` returned for that step are the finished match's.

    Seeding: ``reset(seed)`` gives match ``k`` the seed ``seed + k`` (``match_seeds``), the
    match ``parallel_env().reset(seed=seed + k)`` starts, as Gymnasium's vector envs seed
    their slots; each later match of slot ``k`` draws its start from that match's own
    generator. So match ``k``'s run of matches depends only on ``(seed, k)``: never on
    ``N`` nor on the thread count. ``reset(seed=[s_0, ...])`` seeds each match as
    ``Match.reset(s_k)`` (``None`` keeps its generator going). A seed must be an integer >= 0.
    """

    def __init__(self, num_envs: int, config: MatchConfig | None = None, num_threads: int | None = None) -> None:
        if num_threads is None and isinstance(num_envs, int):
            usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
            num_threads = max(1, min(num_envs, usable))
        try:
            self.batch = MatchBatch(config, num_envs, num_threads or 1, stepper="threads")
        except ValueError as err:  # the same error (a BatchMemoryError stays one), in this class's words
            raise type(err)(str(err).replace("n_matches", "num_envs").replace("n_threads", "num_threads")) from None
        first = self.batch.matches[0]
        sizes = sorted({first.observer.sizes[a] for a in first.agents})
        if len(sizes) != 1:
            self.batch.close()
            raise ValueError(f"every agent's observation must have one size to stack them, got {first.observer.sizes}")
        self.config = first.config
        self.num_envs = num_envs
        self.num_threads = self.batch.n_threads
        self.agents = first.agents
        self.n_agents = first.n_agents
        self.obs_dim = sizes[0]
        self.action_sizes = first.action_sizes
        """Each agent's own action size (8 ant, 12 bug, 16 spider body), roster order."""
        self.act_dim = first.action_width
        """Columns of the action array: the largest action size; an agent with a smaller body
        ignores the columns past its own size."""
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (self.obs_dim,), np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.act_dim,), np.float32)
        self._obs = np.zeros((num_envs, self.n_agents, self.obs_dim), np.float32)
        self._seeded = False

    @property
    def matches(self) -> list[Match]:
        """The matches themselves (for rendering, or a scenario test placing an agent:
        call ``batch.reload(k)`` after editing ``matches[k].data``)."""
        return self.batch.matches

    def reset(self, seed: int | Sequence[int | None] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Start a match in every slot; see the class docstring for the seeds."""
        if seed is None:
            seeds: Sequence[int | None] = ([None] * self.num_envs if self._seeded else
                                           match_seeds(int(np.random.default_rng().integers(2**63)), self.num_envs))
        elif isinstance(seed, Sequence) and not isinstance(seed, str):
            if len(seed) != self.num_envs:
                raise ValueError(f"seed must be an int, None or a list of {self.num_envs} seeds, got {seed!r}")
            seeds = [None if s is None else check_seed(s) for s in seed]
        else:
            seeds = match_seeds(check_seed(seed), self.num_envs)
        for k, s in enumerate(seeds):
            self._obs[k] = self.batch.reset_one(k, s)[0]
        self._seeded = True
        infos = _infos([m.reset_infos() for m in self.batch.matches], [0] * self.num_envs, self.n_agents)
        infos["final_obs"], infos["_final_obs"] = np.zeros_like(self._obs), np.zeros(self.num_envs, bool)
        return self._obs.copy(), infos

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """One step of every match with ``(num_envs, n_agents, act_dim)`` actions; autoreset."""
        if not self._seeded:
            raise RuntimeError("call reset() before step()")
        result = self.batch.step_arrays(actions)
        obs, terminated, truncated = result.observations, result.terminated, result.truncated
        final = terminated | truncated
        final_obs = np.zeros_like(obs)
        for k in np.flatnonzero(final).tolist():
            final_obs[k] = obs[k]
            obs[k] = self.batch.reset_one(k, self._next_seed(k))[0]
        self._obs = obs
        infos = result.infos
        infos["final_obs"], infos["_final_obs"] = final_obs, final
        # All agents of a match end together; under elimination rules an agent also terminates
        # on the step it is eliminated (and its rows stay in the arrays, flagged by
        # infos["eliminated"], until its match ends).
        a = self.n_agents
        term = np.repeat(terminated[:, None], a, 1) | result.leaving
        trunc = np.repeat(truncated[:, None], a, 1) & ~result.leaving  # an agent out is terminated, never truncated
        return obs.copy(), result.rewards.astype(np.float32), term, trunc, infos

    reset_seed: Callable[[int], int | None] | None = None
    """Who seeds slot ``k``'s next match at an autoreset: ``reset_seed(k)`` is called for each
    finished slot in ascending ``k`` during :meth:`step` (a trainer that draws every match's
    seed from its own generator sets it); ``None`` (default) continues each match's generator."""

    def _next_seed(self, k: int) -> int | None:
        """Seed of slot ``k``'s next match at an autoreset: ``None`` continues its generator."""
        return None if self.reset_seed is None else self.reset_seed(k)

    def restart(self, k: int, seed: int | None = None) -> np.ndarray:
        """End slot ``k``'s match now and start its next one (``Match.reset(seed)``); returns its
        first observation ``(n_agents, obs_dim)``. For a caller whose episode ends before the
        match does (a trainer whose learning agents are all out under elimination rules)."""
        self._obs[k] = self.batch.reset_one(k, seed)[0]
        return self._obs[k].copy()

    def snapshot(self) -> list[dict[str, Any]]:
        """Every match's :meth:`Match.snapshot` (physics incl. warm start, step, generator, who
        is in play), slot order: with the last returned observations, an exact resume."""
        return [m.snapshot() for m in self.batch.matches]

    def restore(self, snapshots: Sequence[dict[str, Any]], obs: np.ndarray) -> None:
        """Continue from :meth:`snapshot` and the observations ``(num_envs, n_agents, obs_dim)``
        returned with it; the next :meth:`step` goes on exactly."""
        if len(snapshots) != self.num_envs:
            raise ValueError(f"need {self.num_envs} match snapshots, got {len(snapshots)}")
        for k, (match, snap) in enumerate(zip(self.batch.matches, snapshots, strict=True)):
            match.restore(snap)
            self.batch.reload(k)
        self._obs[:] = obs
        self._seeded = True

    def close(self) -> None:
        """Free the matches' threads and batch."""
        self.batch.close()

    def __enter__(self) -> VectorMatches:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def __getattr__(name: str) -> Any:
    if name == "BACKENDS":
        warnings.warn("triplesumo.envs.batch.BACKENDS is deprecated: it is STEPPERS (MatchBatch's steppers)",
                      DeprecationWarning, stacklevel=2)
        return STEPPERS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
