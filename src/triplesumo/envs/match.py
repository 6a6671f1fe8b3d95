"""The match core: one TripleSumo match, free of any RL framework.

:class:`Match` ties the simulation to the rules: it validates and scales actions,
steps the physics, judges ring exits, computes every agent's reward terms and
observation, and watches MuJoCo for trouble. Under ``elimination`` rules
(:mod:`triplesumo.rules.outcome`) it keeps who is still in play: an eliminated agent's
body gets zero control and its rows of a step are zeros. The PettingZoo and Gymnasium views
wrap it; batch runners and benchmarks use it directly through :meth:`Match.step_array`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from triplesumo.envs.seeding import check_seed
from triplesumo.model import build_model, ring_half_size
from triplesumo.rules import outcome as rules_outcome
from triplesumo.rules import rewards as rules_rewards
from triplesumo.rules.batched import BatchedRules
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.observations import ObservationBuilder
from triplesumo.rules.teams import Teams
from triplesumo.sim.physics import PhysicsError, Simulation


@dataclass
class StepResult:
    """What one env step returns, per agent in roster order."""

    observations: list[np.ndarray]
    rewards: np.ndarray
    terminated: bool
    truncated: bool
    infos: list[dict[str, Any]]
    eliminated: list[bool] | None = None
    """Per agent: eliminated on this step (``None`` if nobody was: the match went on, or it
    ended under ``first_out`` rules, where ``terminated`` covers everyone)."""


class Match:
    """One match between the agents of a :class:`MatchConfig`."""

    def __init__(self, config: MatchConfig | None = None) -> None:
        self.config = config or MatchConfig()
        self.agents = self.config.agent_names
        self.n_agents = len(self.agents)
        self.model = build_model(self.config.agents, self.config.physics)
        self.sim = Simulation(self.model, self.agents, self.config.physics.frame_skip)
        self.data = self.sim.data
        self.teams = Teams.from_agents(self.config.agents)
        self.half_size = ring_half_size(self.model)
        self.game = BatchedRules.build(self.config, self.half_size)
        """The game as arrays: every rule of a step is :mod:`triplesumo.rules`' array function on ``E = 1``."""
        self._playing_codes = np.full((1, self.n_agents), rules_outcome.PLAYING)
        self._draw_codes = np.full((1, self.n_agents), rules_outcome.DRAW_CODE)
        self._no_sparse = np.zeros((1, self.n_agents))
        self.observer = ObservationBuilder(
            self.sim, self.teams, self.config.obs_mode, self.half_size, self.config.contact_force_clip
        )
        self.action_sizes = self.sim.action_sizes
        """Each agent's action size (its motors: 8 ant, 12 bug, 16 spider), roster order."""
        self.action_width = self.sim.action_width
        """Columns of the ``(n_agents, action_width)`` action arrays; an agent with fewer motors
        ignores the columns past its own action size."""
        self._pad = self.sim.action_mask
        self._ctrl_mid = (self.sim.ctrl_high + self.sim.ctrl_low) / 2.0
        self._ctrl_half = (self.sim.ctrl_high - self.sim.ctrl_low) / 2.0
        self.elimination = self.config.rules == "elimination"
        self.alive = [True] * self.n_agents
        """Who is in play (always everyone under ``first_out`` rules)."""
        self._places = [0] * self.n_agents
        self._outcomes: list[int] = [rules_outcome.PLAYING] * self.n_agents
        self._evader = self.agents.index(self.config.evader) if self.config.evader is not None else None
        if self._evader is not None:
            self.observer.set_evader(self._evader)
        self._obs_noise = float(self.config.evader_obs_noise)
        self.np_random = np.random.default_rng()
        self.steps = 0
        self.started = False
        """Whether :meth:`reset` (or :meth:`restore`) has started a match yet."""
        self.over = True
        self.physics_error: str | None = None
        """What MuJoCo reported when a physics error truncated the current match, else ``None``."""
        self._last_obs: list[np.ndarray] = []

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | None = None) -> tuple[list[np.ndarray], list[dict[str, Any]]]:
        """Start a new match from the start pose plus seeded noise.

        ``seed`` re-seeds the match's only random generator; ``None`` keeps drawing
        from the current one.
        """
        if seed is not None:
            self.np_random = np.random.default_rng(check_seed(seed))
        qpos, qvel = self.start_state(self.np_random)
        self.sim.reset(qpos, qvel)
        self.steps = 0
        self.started = True
        self.over = False
        self.physics_error = None
        self.alive = [True] * self.n_agents
        self._places = [0] * self.n_agents
        self._outcomes = [rules_outcome.PLAYING] * self.n_agents
        self._last_obs = self._observe()
        return self._last_obs, self.reset_infos()

    def reset_infos(self) -> list[dict[str, Any]]:
        """Infos with every term zero and no outcome: those of reset (and of a physics error).

        Every info has the same keys and numeric types at reset and every step: the reward
        terms, ``outcome`` (an int code, :data:`~triplesumo.rules.outcome.OUTCOME_CODES`),
        ``out_of_ring`` (this agent left the ring on this step), ``step``, ``place`` (1 = winner,
        0 until decided) and ``eliminated`` (no longer in play)."""
        info: dict[str, Any] = dict.fromkeys(rules_rewards.REPORTED, 0.0)
        info.update(outcome=rules_outcome.PLAYING, out_of_ring=False, step=self.steps, place=0)
        return [dict(info, eliminated=not playing) for playing in self.alive]

    @property
    def agents_in_play(self) -> list[str]:
        """Names of the agents still in play, roster order."""
        return [a for a, playing in zip(self.agents, self.alive, strict=True) if playing]

    def _observe(self) -> list[np.ndarray]:
        obs = self.observer.build()
        if self._obs_noise > 0:
            self.observer.add_evader_noise(obs, self.np_random, self._obs_noise)
        return obs

    def start_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Start pose (``model.qpos0``) with the configured noise drawn from ``rng``."""
        noise = self.config.reset_noise
        qpos = self.model.qpos0.copy()
        for a in self.sim.agents:
            r = a.root_qpos
            qpos[r:r + 2] += rng.uniform(-noise.position, noise.position, 2)
            half = rng.uniform(-noise.yaw, noise.yaw) / 2.0
            turn = np.array([math.cos(half), 0.0, 0.0, math.sin(half)])
            qpos[r + 3:r + 7] = _quat_mul(turn, qpos[r + 3:r + 7])
            qpos[a.joint_qpos] += rng.uniform(-noise.joints, noise.joints, len(a.joint_qpos))
        qvel = rng.normal(0.0, noise.velocity, self.model.nv) if noise.velocity > 0 else np.zeros(self.model.nv)
        return qpos, qvel

    # ------------------------------------------------------------------- step
    def actions_from_dict(self, actions: Mapping[str, Any]) -> np.ndarray:
        """Validate a ``{agent: action}`` mapping and stack it in roster order (a copy), padded with
        zeros to ``action_width`` columns where bodies differ (zeros too for agents no longer in play)."""
        if not all(self.alive):
            return self._actions_in_play(actions)
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions must be a dict {{agent: action}} for agents {list(self.agents)}, "
                             f"got {type(actions).__name__}")
        agents = self.agents
        if len(actions) != self.n_agents or not all(a in actions for a in agents):
            missing = [a for a in agents if a not in actions]
            unknown = [a for a in actions if a not in agents]
            raise ValueError(f"actions must have exactly the keys {list(agents)}; "
                             f"missing {missing}, unknown {unknown}")
        if self._pad is not None:
            padded = np.zeros((self.n_agents, self.action_width))
            for i, a in enumerate(agents):
                padded[i, :self.action_sizes[i]] = self.check_action(a, actions[a])
            return padded
        try:
            if any(np.iscomplexobj(actions[a]) or _object_array(actions[a]) for a in agents):
                raise TypeError("complex or object")  # numpy could drop imaginary parts: check_action refuses them
            stacked = np.array([actions[a] for a in agents], dtype=np.float64)
        except (TypeError, ValueError):  # ragged, complex or not numbers: let check_action name the agent
            stacked = None
        if stacked is None or stacked.shape != (self.n_agents, self.action_width):
            for a in agents:
                self.check_action(a, actions[a])
            raise ValueError(f"actions must stack to shape ({self.n_agents}, {self.action_width})")
        return stacked

    def _actions_in_play(self, actions: Mapping[str, Any]) -> np.ndarray:
        playing = self.agents_in_play
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions must be a dict {{agent: action}} for agents {playing}, "
                             f"got {type(actions).__name__}")
        if set(actions) != set(playing):
            gone = [a for a in actions if a in self.agents and a not in playing]
            raise ValueError(f"actions must have exactly the keys of the agents in play {playing}; "
                             f"missing {[a for a in playing if a not in actions]}, "
                             f"unknown {[a for a in actions if a not in self.agents]}, eliminated {gone}")
        stacked = np.zeros((self.n_agents, self.action_width))
        for i, name in enumerate(self.agents):
            if name in actions:
                stacked[i, :self.action_sizes[i]] = self.check_action(name, actions[name])
        return stacked

    def check_action(self, agent: str, action: Any) -> np.ndarray:
        """One agent's action as a float64 copy, or ``ValueError`` naming the agent."""
        size = self.action_sizes[self.agents.index(agent)]
        arr = real_array(action, f"action of {agent!r}", f"{size} real numbers, shape ({size},)")
        if arr.shape != (size,):
            raise ValueError(f"action of {agent!r} must have shape ({size},), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"action of {agent!r} contains NaN or inf: {arr.tolist()}")
        return arr

    def step_array(self, actions: np.ndarray) -> StepResult:
        """One env step with ``(n_agents, action_width)`` normalised actions in roster order.

        Finite values beyond [-1, 1] are clipped; each agent's action is scaled to its
        motors' control range. NaN or inf raises ``ValueError`` naming the agent.
        It is :meth:`prepare`, the physics step, then :meth:`finish_step`.
        """
        ctrl = self.prepare(actions)
        self.sim.step(ctrl)
        return self.finish_step()

    def prepare(self, actions: np.ndarray) -> np.ndarray:
        """Check ``(n_agents, action_width)`` normalised actions and return the controls (same shape).

        The first half of :meth:`step_array`, with its errors; it changes nothing, so a
        runner that steps the physics of many matches together
        (:class:`triplesumo.envs.batch.MatchBatch`) can check every match first.
        """
        if self.over:
            raise RuntimeError(self.why_not_playing())
        actions = real_array(actions, "actions", f"real numbers of shape ({self.n_agents}, {self.action_width})",
                             copy=False)
        if actions.shape != (self.n_agents, self.action_width):
            raise ValueError(f"actions must have shape ({self.n_agents}, {self.action_width}), got {actions.shape}")
        if self._pad is not None:  # columns past an agent's motors are ignored, whatever they hold
            actions = np.where(self._pad, actions, 0.0)
        if not math.isfinite(actions.sum()):  # NaN or inf somewhere (or an overflowing sum: look closer)
            bad = ~np.isfinite(actions).all(axis=1)
            if bad.any():
                raise ValueError(f"action of {self.agents[int(np.argmax(bad))]!r} contains NaN or inf")
        ctrl = scale_actions(actions, self._ctrl_half, self._ctrl_mid)
        if not all(self.alive):  # an eliminated body no longer acts
            ctrl[[not playing for playing in self.alive]] = 0.0
        return ctrl

    def why_not_playing(self) -> str:
        """Why this match cannot step now: never started, or over."""
        if not self.started:
            return "the match was never started: call reset() before the first step()"
        return "the match is over: call reset() before step()"

    def finish_step(self) -> StepResult:
        """Judge the physics step just taken: outcome, rewards, observations, MuJoCo warnings.

        The second half of :meth:`step_array`: call it exactly once after ``sim.step(ctrl)``
        (or an equivalent ``frame_skip`` substeps on this match's ``data``) with the
        controls :meth:`prepare` returned.
        """
        self.steps += 1
        trouble = self.sim.new_warnings()
        if trouble:
            return self._physics_error(trouble)
        pos, vel = self.sim.torso_positions()[None], self.sim.torso_velocities()[None]
        rules = self.game
        out = rules_outcome.agents_out(pos, rules.half_size, np)  # (1, n)
        if self.elimination:
            return self._finish_elimination(pos, vel, out)
        ended = bool(out.any())
        timed_out = not ended and self.steps >= self.config.max_steps
        if ended or timed_out:
            code = rules_outcome.judge(out, rules, np) if ended else self._draw_codes
            terms = rules_rewards.reward_terms(pos, vel, code, np.array([timed_out]), rules, np)
        else:  # nobody out (most steps): what judge() gives then, and no sparse reward (the table's 0)
            code = self._playing_codes
            terms = rules_rewards.reward_terms(pos, vel, code, None, rules, np, sparse=self._no_sparse)
        if ended or timed_out:  # decided: once per match, off the per-step path
            places = rules_outcome.first_out_places(code[0], np).tolist()
        else:
            places = [0] * self.n_agents  # nothing decided yet
        infos = self._infos(terms, code[0].tolist(), places, out[0].tolist(), out[0].tolist())
        self.over = ended or timed_out
        self._last_obs = self._observe()
        return StepResult(self._last_obs, terms["reward"][0], ended, timed_out, infos)

    def _infos(self, terms: dict[str, np.ndarray], outcomes: list[int], places: list[int], out: list[bool],
               eliminated: list[bool]) -> list[dict[str, Any]]:
        """Every agent's info of a step from the ``(1, n)`` arrays of :func:`~triplesumo.rules.rewards.reward_terms`
        (plain Python numbers, the same types at reset and every step)."""
        keys, step = rules_rewards.REPORTED, self.steps
        infos = []
        rows = zip(*(terms[k][0].tolist() for k in keys), strict=True)
        for row, outcome, place, is_out, gone in zip(rows, outcomes, places, out, eliminated, strict=True):
            info: dict[str, Any] = dict(zip(keys, row, strict=True))
            info["outcome"] = outcome
            info["out_of_ring"] = is_out
            info["step"] = step
            info["place"] = place
            info["eliminated"] = gone
            infos.append(info)
        return infos

    def record_judged(self, over: bool, observations: list[np.ndarray],
                      standing: tuple[list[bool], list[int], list[int]] | None = None) -> None:
        """Take the result of a step judged outside the match: the batched rules of
        :meth:`MatchBatch.step_arrays <triplesumo.envs.batch.MatchBatch.step_arrays>`, which
        increment :attr:`steps` and judge many matches at once (what :meth:`finish_step`
        does for one): whether the match ended, its observations and, under ``elimination``
        rules, ``standing``: who is still in play, and every agent's place and outcome code so far."""
        self.over = over
        self._last_obs = observations
        if standing is not None:
            self.alive, self._places, self._outcomes = standing

    @property
    def standing(self) -> tuple[list[bool], list[int], list[int]]:
        """Under ``elimination`` rules, where the match stands: who is in play, and every agent's place and
        outcome code decided so far (0 while it plays on); :meth:`record_judged` takes it back."""
        return self.alive, self._places, self._outcomes

    def _finish_elimination(self, pos: np.ndarray, vel: np.ndarray, out: np.ndarray) -> StepResult:
        """:meth:`finish_step` under ``elimination`` rules."""
        rules, before = self.game, np.array([self.alive])
        judged = rules_outcome.judge_elimination(before, out, np.array([self.steps >= self.config.max_steps]),
                                                 rules, np)
        sparse = rules_outcome.place_values(judged.low, judged.high, rules, np)
        terms = rules_rewards.reward_terms(pos, vel, None, None, rules, np, alive=before, sparse=sparse)
        decided, places = judged.code[0].tolist(), judged.low[0].tolist()
        # an agent decided on an earlier step keeps its outcome and place
        outcomes = [decided[i] if self.alive[i] else self._outcomes[i] for i in range(self.n_agents)]
        places = [places[i] if self.alive[i] else self._places[i] for i in range(self.n_agents)]
        leaving, alive = judged.leaving[0].tolist(), judged.alive[0].tolist()
        infos = self._infos(terms, outcomes, places, leaving, [not a for a in alive])
        self._places, self._outcomes = places, outcomes
        self.alive = alive
        self.over = over = bool(judged.over[0])
        terminated = bool(judged.terminated[0])
        truncated = over and not terminated  # judged.truncated, without two array operations on one match
        self._last_obs = self._observe()
        return StepResult(self._last_obs, terms["reward"][0], terminated, truncated, infos,
                          leaving if any(leaving) else None)

    def _physics_error(self, trouble: list[str]) -> StepResult:
        message = (f"MuJoCo reported {', '.join(trouble)} at step {self.steps}; "
                   "the simulation can no longer be trusted")
        self.over = True
        if self.config.on_physics_error == "raise":
            raise PhysicsError(message)
        self.physics_error = message
        infos = self.reset_infos()
        for info in infos:
            info["outcome"] = rules_outcome.ERROR_CODE
        # The last trustworthy observation: never the NaN or auto-reset state.
        return StepResult(self._last_obs, np.zeros(self.n_agents), False, True, infos)

    def snapshot(self) -> dict[str, Any]:
        """Everything needed to continue this match exactly: physics integration state
        (incl. warm start), step count, last observations, warning counters and the
        random generator's state. Arrays and JSON-able values only (no pickle)."""
        import mujoco

        size = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_INTEGRATION)
        physics = np.empty(size)
        mujoco.mj_getState(self.model, self.data, physics, mujoco.mjtState.mjSTATE_INTEGRATION)
        return {
            "physics": physics,
            "last_obs": np.stack(self._last_obs) if self._last_obs else np.zeros((0,)),
            "warnings": self.sim.warnings_seen(),
            "steps": self.steps,
            "over": self.over,
            "rng": self.np_random.bit_generator.state,
            "alive": list(self.alive),
            "places": list(self._places),
            "outcomes": list(self._outcomes),
        }

    def restore(self, snap: dict[str, Any]) -> None:
        """Continue from :meth:`snapshot` (the same config is assumed)."""
        import mujoco

        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_setState(self.model, self.data, np.asarray(snap["physics"], dtype=np.float64),
                           mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(self.model, self.data)
        self.sim.set_warnings_seen(snap["warnings"])
        self.steps = int(snap["steps"])
        self.started = True
        self.over = bool(snap["over"])
        self._last_obs = list(np.asarray(snap["last_obs"], dtype=np.float32)) if len(snap["last_obs"]) else []
        self.np_random = np.random.default_rng()
        self.np_random.bit_generator.state = snap["rng"]
        self.alive = [bool(a) for a in snap.get("alive", [True] * self.n_agents)]
        self._places = [int(p) for p in snap.get("places", [0] * self.n_agents)]
        self._outcomes = [rules_outcome.PLAYING if o is None else int(o)
                          for o in snap.get("outcomes", [None] * self.n_agents)]

    def state(self) -> np.ndarray:
        """Global state: the ``paper`` observation vector (torso states, contact forces, qpos, qvel),
        exact (no evader noise); under ``elimination`` rules followed by one flag per agent,
        1.0 once it is eliminated, so the size stays fixed for the whole match."""
        state = self.observer.global_state()
        if self.elimination:
            flags = np.array([0.0 if playing else 1.0 for playing in self.alive], dtype=np.float32)
            return np.concatenate([state, flags])
        return state


def real_array(values: Any, what: str, expected: str, copy: bool = True) -> np.ndarray:
    """``values`` as a float64 array (a copy unless ``copy=False`` and it already is one), or ``ValueError``
    saying that ``what`` must be ``expected``: complex values (numpy would drop their imaginary parts with a
    warning), a torch tensor that requires grad, and values that are not numbers are refused. The one check of
    actions in every view."""
    if getattr(values, "requires_grad", False):  # a torch tensor still in an autograd graph
        raise ValueError(f"{what} is a tensor that requires grad: pass .detach()")
    complex_values = f"{what} must be real numbers, got complex values (their imaginary parts would be dropped)"
    if np.iscomplexobj(values) or getattr(values, "is_complex", lambda: False)():
        raise ValueError(complex_values)
    try:
        if not _object_array(values):
            return np.array(values, dtype=np.float64, copy=copy or None)
        with warnings.catch_warnings():  # numpy complex scalars in an object array: cast with only a warning
            warnings.simplefilter("error", np.exceptions.ComplexWarning)
            return np.array(values, dtype=np.float64)
    except np.exceptions.ComplexWarning:
        raise ValueError(complex_values) from None
    except (TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(f"{what} must be {expected}; {_not_a_number(values) or exc}") from None


def _object_array(values: Any) -> bool:
    """Whether ``values`` is a numpy array of Python objects."""
    return isinstance(values, np.ndarray) and values.dtype.kind == "O"


def _not_a_number(values: Any) -> str | None:
    """The first element of ``values`` that is no number, as "got 'x' (str) at [0, 3]" (``None`` if none is found:
    a ragged nesting, say)."""
    try:
        cells = np.array(values, dtype=object)
    except (TypeError, ValueError, RuntimeError):
        return None
    for index in np.ndindex(cells.shape):
        item = cells[index]
        try:
            np.array(item, dtype=np.float64)
        except (TypeError, ValueError, RuntimeError):
            where = f" at {list(index)}" if index else ""
            if isinstance(item, complex | np.complexfloating):
                return f"got the complex value {item!r}{where} (its imaginary part would be dropped)"
            return f"got {item!r} ({type(item).__name__}){where}, which is not a number"
    return None


def scale_actions(actions: np.ndarray, half_range: np.ndarray, mid: np.ndarray) -> np.ndarray:
    """Finite normalised actions ``(..., n_agents, action_width)`` to controls (a new array):
    clipped to [-1, 1], then ``mid + action * half_range`` per column (``Match.prepare``)."""
    ctrl = np.maximum(actions, -1.0)  # a clip; np.clip's dispatch costs several times more
    np.minimum(ctrl, 1.0, out=ctrl)
    ctrl *= half_range
    ctrl += mid
    return ctrl


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])
