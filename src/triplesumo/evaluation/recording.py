"""Replayable match files: a match's seed, config, actions and MuJoCo states in one ``.npz``.

``triplesumo play --record match.npz`` (and ``evaluate --record K``) write a
:class:`MatchFile`: the seed, the full :class:`MatchConfig` (JSON), the policies' names,
and per env step the normalised actions given to the match and the MuJoCo integration
state after it (``mj_getState(..., mjSTATE_INTEGRATION)``: qpos, qvel, controls, warm
start, ...), plus the state right after the reset. Only arrays and JSON text are stored;
files are read with ``allow_pickle=False``.

``triplesumo replay match.npz --video out.mp4`` renders the recorded states, without the
policies. :func:`verify` re-simulates the match from its seed and recorded actions and
checks that every state comes out bit for bit as recorded.
"""

from __future__ import annotations

import dataclasses
import io
import json
import typing
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.envs.match import Match, StepResult
from triplesumo.envs.seeding import check_seed
from triplesumo.model.specs import PhysicsConfig, physics_record
from triplesumo.rules.config import MatchConfig

FORMAT = "triplesumo-match-1"
"""Format tag stored in every match file."""
STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
"""The MuJoCo state recorded at every step: everything ``mj_step`` reads."""
_KEYS = ("format", "meta", "config", "actions", "states")


class MatchFileError(ValueError):
    """A match file is unreadable, corrupt, or does not fit this version of TripleSumo."""


@dataclass
class MatchFile:
    """One recorded match."""

    seed: int
    """Seed of ``Match.reset``."""
    config: MatchConfig
    """The match's full configuration."""
    actions: np.ndarray
    """``(steps, n_agents, action_width)`` float64 normalised actions, as given to ``step_array``."""
    states: np.ndarray
    """``(steps + 1, n_state)`` float64 MuJoCo integration states: after the reset, then after each step."""
    policies: dict[str, str] = field(default_factory=dict)
    """Agent -> policy name that played it (for the record; replay does not need them)."""
    outcomes: dict[str, str | None] = field(default_factory=dict)
    """Agent -> its side's result at the end."""

    @property
    def steps(self) -> int:
        """Env steps in the match."""
        return len(self.actions)

    def save(self, path: Path) -> Path:
        """Write the match to ``path`` (``.npz``, compressed) atomically (a temp file in the same folder, fsync,
        rename, as checkpoints are): a full disk or a kill leaves any earlier file at ``path`` as it was, and the
        ``OSError`` names the file. Returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = {"seed": self.seed, "policies": self.policies, "outcomes": self.outcomes,
                "state_spec": int(STATE_SPEC), "mujoco": mujoco.__version__}
        buffer = io.BytesIO()
        np.savez_compressed(buffer, format=np.array(FORMAT), meta=np.array(json.dumps(meta)),
                            config=np.array(json.dumps(dataclasses.asdict(self.config))),
                            actions=np.asarray(self.actions, np.float64),
                            states=np.asarray(self.states, np.float64))
        try:
            atomic_write_bytes(path, buffer.getvalue())
        except OSError as exc:
            raise OSError(exc.errno, f"{path}: the match file was not written ({exc.strerror or exc}); any earlier "
                                     "file there is unchanged") from exc
        return path

    @classmethod
    def load(cls, path: Path) -> MatchFile:
        """Read a match file; :class:`MatchFileError` says what is wrong with a bad one."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no match file {path}")
        _check_members(path)
        try:
            with np.load(path, allow_pickle=False) as npz:
                missing = [k for k in _KEYS if k not in npz.files]
                if missing:
                    raise MatchFileError(f"{path}: not a TripleSumo match file (missing {missing})")
                arrays = {k: npz[k] for k in _KEYS}
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError) as exc:
            if isinstance(exc, MatchFileError):
                raise
            raise MatchFileError(f"{path}: not a readable .npz match file ({exc})") from None
        if str(arrays["format"]) != FORMAT:
            raise MatchFileError(f"{path}: format {str(arrays['format'])!r}, this version reads {FORMAT!r}")
        try:
            meta = json.loads(str(arrays["meta"]))
            config = _dataclass_from_json(MatchConfig, json.loads(str(arrays["config"])), "config")
        except (json.JSONDecodeError, TypeError, KeyError) as exc:
            raise MatchFileError(f"{path}: corrupt config or metadata ({exc})") from None
        except ValueError as exc:
            raise MatchFileError(f"{path}: recorded config is not valid here: {exc}") from None
        problem = _meta_problem(meta)
        if problem is not None:
            raise MatchFileError(f"{path}: corrupt metadata: {problem}")
        if meta.get("state_spec") != int(STATE_SPEC):
            raise MatchFileError(f"{path}: states were recorded with MuJoCo state spec {meta.get('state_spec')}, "
                                 f"this version records {int(STATE_SPEC)}")
        actions, states = arrays["actions"], arrays["states"]
        record = cls(seed=int(meta["seed"]), config=config, actions=actions, states=states,
                     policies=dict(meta.get("policies", {})), outcomes=dict(meta.get("outcomes", {})))
        record.check(path)
        return record

    def check(self, where: object = "match file") -> None:
        """Raise :class:`MatchFileError` unless the arrays' shapes fit the config's compiled model."""
        match = Match(self.config)
        n_state = mujoco.mj_stateSize(match.model, STATE_SPEC)
        want_actions = (match.n_agents, match.action_width)
        if self.actions.ndim != 3 or self.actions.shape[1:] != want_actions or self.actions.dtype != np.float64:
            raise MatchFileError(f"{where}: actions must be float64 of shape (steps, {want_actions[0]}, "
                                 f"{want_actions[1]}) for this roster, got {self.actions.dtype} {self.actions.shape}")
        if self.states.shape != (self.steps + 1, n_state) or self.states.dtype != np.float64:
            raise MatchFileError(f"{where}: states must be float64 of shape ({self.steps + 1}, {n_state}) "
                                 f"(one per step plus the start), got {self.states.dtype} {self.states.shape}")
        if not (np.isfinite(self.actions).all() and np.isfinite(self.states).all()):
            raise MatchFileError(f"{where}: actions or states hold NaN or inf")


class MatchRecorder:
    """Collects a :class:`MatchFile` while a :class:`Match` is played.

    Call :meth:`start` right after ``match.reset(seed)``, :meth:`step` after every
    ``step_array(actions)`` with those actions, then :meth:`finish`.
    """

    def __init__(self, match: Match, seed: int, policies: dict[str, str] | None = None) -> None:
        self.match, self.seed, self.policies = match, seed, dict(policies or {})
        self._actions: list[np.ndarray] = []
        self._states = [get_state(match)]

    def step(self, actions: np.ndarray) -> None:
        """Record the actions of the step just taken and the state after it."""
        self._actions.append(np.array(actions, dtype=np.float64))
        self._states.append(get_state(self.match))

    def finish(self, outcomes: Mapping[str, str | None] | None = None) -> MatchFile:
        """The recorded match."""
        width = (self.match.n_agents, self.match.action_width)
        actions = np.stack(self._actions) if self._actions else np.zeros((0, *width))
        return MatchFile(self.seed, self.match.config, actions, np.stack(self._states), self.policies,
                         dict(outcomes or {}))


def get_state(match: Match) -> np.ndarray:
    """The match's MuJoCo integration state (float64 copy)."""
    state = np.empty(mujoco.mj_stateSize(match.model, STATE_SPEC))
    mujoco.mj_getState(match.model, match.data, state, STATE_SPEC)
    return state


def set_state(match: Match, state: np.ndarray) -> None:
    """Put the match's physics in a recorded state (and recompute what rendering reads)."""
    mujoco.mj_setState(match.model, match.data, np.asarray(state, dtype=np.float64), STATE_SPEC)
    mujoco.mj_forward(match.model, match.data)


def resimulate(record: MatchFile) -> typing.Iterator[Match]:
    """Play ``record`` again from its seed and recorded actions, yielding the match after the reset
    and after each step; ``MatchFileError`` at the first state that differs by even one bit."""
    for match, _ in resimulate_steps(record):
        yield match


def resimulate_steps(record: MatchFile) -> typing.Iterator[tuple[Match, StepResult | None]]:
    """:func:`resimulate`, with what each step returned (its rewards and infos; ``None`` for the reset)."""
    match = Match(record.config)
    match.reset(seed=record.seed)
    _same(get_state(match), record.states[0], 0)
    yield match, None
    for t, actions in enumerate(record.actions):
        if match.over:
            raise MatchFileError(f"the re-simulated match ended after {t} steps, the recording has {record.steps}")
        result = match.step_array(actions)
        _same(get_state(match), record.states[t + 1], t + 1)
        yield match, result


def verify(record: MatchFile) -> int:
    """Check that ``record`` re-simulates bit for bit (see :func:`resimulate`); returns the steps checked."""
    for _ in resimulate(record):
        pass
    return record.steps


def render_frames(record: MatchFile, width: int = 480, height: int = 480,
                  exact: bool = True) -> typing.Iterator[np.ndarray]:
    """Frames of the match (start, then one per step) from the overview camera.

    ``exact``: from the verified re-simulation, so each frame is the one ``play --video`` rendered
    (MuJoCo's derived positions lag the state by a substep after ``mj_step``); otherwise from the
    recorded states alone (``mj_setState`` + ``mj_forward``), e.g. for a file from another machine
    that no longer re-simulates bit for bit.
    """
    from triplesumo.sim.render import FrameRenderer

    matches = resimulate(record) if exact else recorded_matches(record)
    renderer: FrameRenderer | None = None
    try:
        for match in matches:
            renderer = renderer or FrameRenderer(match.model, width, height)
            yield renderer.render(match.data)
    finally:
        if renderer is not None:
            renderer.close()


def recorded_matches(record: MatchFile) -> typing.Iterator[Match]:
    """The match put in each recorded state in turn (``mj_setState`` + ``mj_forward``), without re-simulating."""
    match = Match(record.config)
    for state in record.states:
        set_state(match, state)
        yield match


def _same(got: np.ndarray, want: np.ndarray, step: int) -> None:
    if not np.array_equal(got, want):
        worst = float(np.max(np.abs(got - want)))
        raise MatchFileError(f"replay differs from the recording at step {step} (largest difference {worst:.3g}): "
                             "recorded with another config, MuJoCo version or machine, or the file was altered")


MAX_MEMBER_BYTES = 1 << 30
"""Largest array a match file may hold (1 GiB: a 500-step match of 8 agents is a few MB); checked from the zip's
and the arrays' headers before anything is read, so a zip bomb or a lying header allocates nothing."""


def _check_members(path: Path) -> None:
    """:class:`MatchFileError` unless every array of the npz at ``path`` declares a sane size: its uncompressed size
    at most :data:`MAX_MEMBER_BYTES`, and its header's shape and dtype no larger than that."""
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                if info.file_size > MAX_MEMBER_BYTES:
                    raise MatchFileError(f"{path}: {info.filename} would unpack to {info.file_size:,} bytes, more "
                                         f"than a match file holds ({MAX_MEMBER_BYTES:,}); not read")
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                              else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = header(fh, max_header_size=10_000)
                declared = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
                if declared > info.file_size:
                    raise MatchFileError(f"{path}: {info.filename}'s header declares {declared:,} bytes of {dtype} "
                                         f"{shape}, more than its {info.file_size:,}; not read")
    except MatchFileError:
        raise
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError, TypeError) as exc:
        raise MatchFileError(f"{path}: not a readable .npz match file ({exc})") from None


def _meta_problem(meta: Any) -> str | None:
    """Why a match file's metadata is not what :meth:`MatchFile.save` writes (None if it is)."""
    if not isinstance(meta, dict):
        return f"expected a JSON object, got {type(meta).__name__}"
    seed = meta.get("seed")
    if not isinstance(seed, int) or isinstance(seed, bool):
        return f"seed must be an integer, got {seed!r}"
    try:
        check_seed(seed)
    except ValueError as exc:
        return str(exc)
    for key in ("policies", "outcomes"):
        if not isinstance(meta.get(key, {}), dict):
            return f"{key} must be a JSON object, got {meta[key]!r}"
    return None


def _dataclass_from_json(cls: type, data: Any, where: str) -> Any:
    """Rebuild dataclass ``cls`` from ``dataclasses.asdict`` output; unknown fields are errors."""
    if not isinstance(data, dict):
        raise MatchFileError(f"{where} must be a JSON object, got {type(data).__name__}")
    if cls is PhysicsConfig:  # recorded before a field existed: as those versions ran (v1's circle and cylinders)
        data = physics_record(data)
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise MatchFileError(f"{where} has fields {unknown} unknown to {cls.__name__} in this version")
    return cls(**{k: _value(hints[k], v, f"{where}.{k}") for k, v in data.items()})


def _value(hint: Any, value: Any, where: str) -> Any:
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return _dataclass_from_json(hint, value, where)
    origin = typing.get_origin(hint)
    if origin is tuple:
        args = typing.get_args(hint)
        inner = args[0] if len(args) == 2 and args[1] is Ellipsis else None
        if not isinstance(value, list):
            raise MatchFileError(f"{where} must be a list, got {type(value).__name__}")
        if inner is not None:
            return tuple(_value(inner, v, f"{where}[{i}]") for i, v in enumerate(value))
        return tuple(_value(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True)))
    return value
