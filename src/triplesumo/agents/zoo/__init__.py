"""The policy zoo: trained policies shipped in the package, loadable by name.

Each entry is ``NAME.safetensors`` + ``NAME.json`` in this folder (see
:mod:`triplesumo.agents.policy_file`); the manifest records the command and seed that
made it. An *alias* is a manifest alone, ``NAME.json`` holding ``{"alias_of": "OTHER"}``: ``zoo:NAME``
then loads ``zoo:OTHER``'s files, so weights shipped under two names are stored once
(:func:`alias_target`). :func:`make_policy` also resolves built-in policies and policy files, so one
string names any policy: ``"zero"`` / ``"passive"``, ``"random"``, ``"zoo:spider"``, or a
path to a policy file (``runs/x/policy`` or ``runs/x/policy.json``).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import re
from importlib import resources
from pathlib import Path
from typing import Any

from triplesumo.agents.builtin import ACTION_SIZE, BUILTIN
from triplesumo.agents.policy_file import (
    PolicyFileError,
    atomic_write_bytes,
    bare_stem,
    load_fixed_policy,
    load_json,
    load_policy,
    policy_paths,
    save_policy,
    seat_problem,
)

ZOO_DIR = Path(str(resources.files("triplesumo.agents.zoo")))

HISTORY = "docs/runs/zoo-history"
"""Where retired zoo policies live in the repository (not in the installed package), as policy files."""
RETIRED: dict[str, str] = {
    **{f"spider-selfplay-v{n}": f"{HISTORY}/spider-selfplay-v{n}" for n in (1, 2, 3, 4)},
    "spider-selfplay-v5": "zoo:spider-selfplay",
}
"""Zoo names no longer shipped -> the spec that now names the same weights: the zoo keeps one self-play Spider,
``zoo:spider-selfplay`` (the former ``spider-selfplay-v5``); the others, and the first ``zoo:spider-selfplay`` (now
``spider-selfplay-v0``), are policy files under :data:`HISTORY` (its README says what each was)."""


ALIAS = "alias_of"
"""The manifest key of an alias: ``NAME.json`` with ``{"alias_of": "OTHER", ...}`` and no ``NAME.safetensors`` names
``zoo:OTHER`` under a second name (``zoo:bug`` is the shipped Bug of the best algorithm, ``zoo:bug-sac``)."""


def available() -> list[str]:
    """Names of the shipped policies (aliases included)."""
    return sorted(p.stem for p in ZOO_DIR.glob("*.json"))


def _alias_of(zoo_dir: Path, name: str) -> str | None:
    """What ``NAME.json`` in ``zoo_dir`` is an alias of (:data:`ALIAS`), checked: the target ships its own weights;
    ``None`` for a policy with weights of its own. :class:`PolicyFileError` naming the manifest otherwise."""
    manifest_path = zoo_dir / f"{name}.json"
    target = load_json(manifest_path).get(ALIAS)
    if target is None:
        return None
    if not isinstance(target, str) or not target:
        raise PolicyFileError(f"{manifest_path}: {ALIAS} must be a zoo name, got {target!r}")
    if (zoo_dir / f"{name}.safetensors").exists():
        raise PolicyFileError(f"{manifest_path}: an alias (of zoo:{target}) ships no weights, but "
                              f"{name}.safetensors is there")
    if not (zoo_dir / f"{target}.json").is_file():
        shipped = sorted(p.stem for p in zoo_dir.glob("*.json"))
        raise PolicyFileError(f"{manifest_path}: zoo:{name} is an alias of zoo:{target}, which the zoo does not "
                              f"ship (shipped: {shipped})")
    if ALIAS in load_json(zoo_dir / f"{target}.json"):
        raise PolicyFileError(f"{manifest_path}: zoo:{name} is an alias of zoo:{target}, itself an alias: an alias "
                              "names a policy with weights")
    return target


def alias_target(name: str) -> str | None:
    """The zoo name that ``zoo:NAME`` is an alias of (:data:`ALIAS`), or ``None`` when NAME ships its own weights.
    An alias of a name the zoo does not ship, of another alias, or with weights of its own is refused
    (:class:`~triplesumo.agents.policy_file.PolicyFileError` naming the manifest)."""
    return _alias_of(ZOO_DIR, name)


def manifest_of(name: str) -> dict[str, Any]:
    """The manifest of ``zoo:NAME`` (of its target, for an alias), unchecked against the weights: what
    ``zoo list`` shows. :func:`load` checks both."""
    return load_json(policy_paths(policy_stem(f"zoo:{name}"))[0])


def retired_error(name: str) -> FileNotFoundError:
    """The error for ``zoo:NAME`` of a retired policy (:data:`RETIRED`): it names where the policy went."""
    where = RETIRED[name]
    hint = ("(a policy file in the TripleSumo repository, not in the installed package)"
            if not where.startswith("zoo:") else "(the same weights under the zoo's one self-play Spider name)")
    return FileNotFoundError(f"zoo:{name} is no longer shipped: it is {where} {hint}; see {HISTORY}/README.md")


def policy_stem(spec: str | Path) -> Path:
    """The policy-file stem (the path without ``.json``/``.safetensors``) that ``spec`` names:
    ``zoo:NAME`` a shipped policy, the one it names for an alias (:func:`alias_target`; ``FileNotFoundError``
    naming the shipped ones when there is no ``NAME``; for a retired ``NAME``, :data:`RETIRED`, one naming where it
    went), anything else a policy-file
    path, given with or without a suffix. Built-in policies (``passive``, ``random``, ...) have no file:
    ``ValueError``. Whether a path's files exist is for the loader to say."""
    if isinstance(spec, str) and spec in BUILTIN:
        raise ValueError(f"{spec!r} is a built-in policy: it has no policy file")
    if isinstance(spec, str) and spec.startswith("zoo:"):
        name = spec.removeprefix("zoo:")
        if name in RETIRED and name not in available():
            raise retired_error(name)
        if name not in available():
            raise FileNotFoundError(f"no policy {name!r} in the zoo ({ZOO_DIR}); shipped: {available()}")
        return ZOO_DIR / (alias_target(name) or name)
    return bare_stem(spec)


def find_policy_file(spec: str) -> Path:
    """The stem of the policy file pair that ``spec`` names, checked to be there: ``zoo:NAME`` or a path (with
    or without a suffix) whose manifest exists. The one answer to "is this spec a policy file" for everything
    that takes one (:func:`make_policy`, tournaments, league seeds). Errors: a built-in policy (it has no
    file) or a path where neither file is, ``ValueError`` ("unknown policy", naming the choices); an unknown
    ``zoo:NAME``, ``FileNotFoundError`` naming the shipped ones; weights without their manifest,
    :class:`~triplesumo.agents.policy_file.PolicyFileError` naming the missing file."""
    if spec in BUILTIN or spec.startswith("zoo:"):
        return policy_stem(spec)
    manifest, weights = policy_paths(spec)
    if manifest.is_file():
        return bare_stem(spec)
    if weights.exists():
        raise PolicyFileError(f"{manifest}: file not found (its weights {weights.name} are there)")
    raise ValueError(f"unknown policy {spec!r}: use one of {sorted(BUILTIN)}, 'zoo:NAME' "
                     f"(shipped: {available()}) or the path of a policy file")


def load(name: str, expect_obs_mode: str | None = None) -> tuple[Any, dict[str, Any]]:
    """Load a shipped policy (a numpy :class:`~triplesumo.agents.frozen.FrozenPolicy`: fork-safe)
    and its manifest by name (``"ant"``, ``"spider"``, ``"bug"``)."""
    return load_fixed_policy(policy_stem(f"zoo:{name}"), expect_obs_mode=expect_obs_mode)


def publish(policy_stem: Path, name: str, evaluation: dict[str, Any] | None = None,
            zoo_dir: Path | None = None, extra: dict[str, Any] | None = None) -> Path:
    """Copy a trained policy file pair into the zoo as ``name`` (``bug``, ``bug-sac``, ...), adding
    evaluation results and ``extra`` manifest entries (e.g. the code version).

    The manifest keeps the command, seed and epochs the training run recorded; nothing
    but the project's own training output can be published this way.
    """
    policy, manifest = load_policy(Path(policy_stem))
    for key in ("command", "seed", "epochs"):
        if key not in manifest:
            raise ValueError(f"{policy_stem}: manifest lacks {key!r}; only training runs' policies can be published")
    if not re.fullmatch(r"[a-z][a-z0-9_-]*", name):
        raise ValueError(f"zoo name must be lower-case letters, digits, - or _, got {name!r}")
    zoo_dir = Path(zoo_dir) if zoo_dir is not None else ZOO_DIR
    manifest = {**manifest, **(extra or {}), "zoo_name": name}
    if evaluation is not None:
        manifest["evaluation"] = evaluation
    save_policy(zoo_dir / name, policy.actor, {k: v for k, v in manifest.items()
                                               if k not in ("format", "obs_dim", "act_dim", "hidden", "obs_norm")},
                obs_norm=policy.obs_norm)
    return zoo_dir / f"{name}.json"


def publish_alias(name: str, target: str, zoo_dir: Path | None = None, extra: dict[str, Any] | None = None) -> Path:
    """Make ``zoo:NAME`` an alias of the shipped ``zoo:TARGET`` (:data:`ALIAS`): ``NAME.json`` holds the alias and
    ``extra`` entries (e.g. why it names that policy), and a ``NAME.safetensors`` of an earlier copy is removed, so
    the weights are stored once. ``TARGET`` must ship its own weights (``PolicyFileError`` otherwise)."""
    if not re.fullmatch(r"[a-z][a-z0-9_-]*", name):
        raise ValueError(f"zoo name must be lower-case letters, digits, - or _, got {name!r}")
    zoo_dir = Path(zoo_dir) if zoo_dir is not None else ZOO_DIR
    if name == target:
        raise ValueError(f"zoo:{name} cannot be an alias of itself")
    if not (zoo_dir / f"{target}.safetensors").is_file() or _alias_of(zoo_dir, target) is not None:
        raise PolicyFileError(f"cannot make zoo:{name} an alias of zoo:{target}: {zoo_dir} has no weights "
                              f"{target}.safetensors (an alias names a policy with weights)")
    path = zoo_dir / f"{name}.json"
    atomic_write_bytes(path, (json.dumps({**(extra or {}), ALIAS: target, "zoo_name": name}, indent=2,
                                         sort_keys=True) + "\n").encode())
    (zoo_dir / f"{name}.safetensors").unlink(missing_ok=True)
    return path


def make_policy(spec: str, seed: int | None = None, expect_obs_mode: str | None = None,
                action_size: int = ACTION_SIZE, expect_obs_dim: int | None = None,
                frozen: bool | None = None) -> Any:
    """A policy callable from its name: built-in, ``zoo:NAME`` or a policy-file path.

    ``action_size`` sizes a built-in policy's actions (the agent's motors); trained
    policies have theirs in their file. ``expect_obs_dim`` (the match's observation size for
    the agent) makes a policy file that expects another size fail here, with both sizes named.

    A trained policy comes as the torch actor (:func:`load_policy`, ``frozen=False``), whose float32 results the
    recorded trainings and evaluations replay bit for bit, or as the numpy
    :class:`~triplesumo.agents.frozen.FrozenPolicy` (:func:`load_fixed_policy`, ``frozen=True``: fork-safe, the
    same actions but for float rounding, ~1e-5), which the Gymnasium ids use. By default (``None``) it is the torch
    actor where torch is installed, else the numpy one: ``pip install triplesumo`` (no torch) plays every policy file.
    """
    if spec in BUILTIN:
        cls = BUILTIN[spec]
        return cls(seed, action_size=action_size) if spec == "random" else cls(action_size=action_size)
    if frozen is None:
        frozen = importlib.util.find_spec("torch") is None
    load = load_fixed_policy if frozen else load_policy
    return load(find_policy_file(spec), expect_obs_mode=expect_obs_mode, expect_obs_dim=expect_obs_dim)[0]


def policy_fingerprint(spec: str) -> str:
    """sha256 of the files behind a policy spec (``builtin:NAME`` for a built-in), to tell if it changed."""
    if spec in BUILTIN:
        return f"builtin:{spec}"
    digest = hashlib.sha256()
    for path in policy_paths(policy_stem(spec)):
        digest.update(path.read_bytes())
    return digest.hexdigest()


def check_policy_pairs(field: str, pairs: tuple[str, ...], learner: str | None = None,
                       agents: list[str] | None = None) -> None:
    """Validate ``AGENT=POLICY`` pairs of a config field; errors name ``field``."""
    for pair in pairs:
        if pair.count("=") != 1 or not all(pair.split("=")):
            raise ValueError(f"{field}: expected AGENT=POLICY, got {pair!r}")
        agent = pair.split("=")[0]
        if agent == "*":
            continue
        if agent == learner:
            raise ValueError(f"{field}: the learner {learner!r} cannot have a fixed policy")
        if agents is not None and agent not in agents:
            raise ValueError(f"{field}: unknown agent in {pair!r}; agents are {agents}")


def expand_pairs(pairs: tuple[str, ...], agents: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Replace a ``*=POLICY`` pair by one ``AGENT=POLICY`` pair per agent not named elsewhere,
    in roster order and in the wildcard's place (``("*=random",)`` for the paper's roster is
    ``("ant=random", "bug=random", "spider=random")``)."""
    named = {p.split("=")[0] for p in pairs if not p.startswith("*=")}
    out: list[str] = []
    for pair in pairs:
        if pair.startswith("*="):
            policy = pair.removeprefix("*=")
            out += [f"{a}={policy}" for a in agents if a not in named and f"{a}={policy}" not in out]
        else:
            out.append(pair)
    return tuple(out)


def check_seat(spec: str, seat: str, teams: dict[str, str]) -> None:
    """``ValueError`` naming the policy file unless the policy ``spec`` can drive ``seat`` of a match whose roster
    is ``teams`` (agent -> team label) (:func:`~triplesumo.agents.policy_file.seat_problem`; built-ins take any
    seat). The tournament, play, evaluate and train give one answer."""
    if spec in BUILTIN:
        return
    stem = find_policy_file(spec)
    problem = seat_problem(load_json(policy_paths(stem)[0]), seat, teams)
    if problem is not None:
        raise ValueError(f"policy {spec!r} ({policy_paths(stem)[0]}) cannot play {seat!r}: {problem}")


def policies_from_pairs(pairs: tuple[str, ...], seed: int, obs_mode: str,
                        action_sizes: dict[str, int] | None = None,
                        obs_dims: dict[str, int] | None = None,
                        teams: dict[str, str] | None = None) -> dict[str, Any]:
    """``("ant=zoo:ant", "spider=random")`` -> ``{"ant": policy, "spider": policy}``.

    ``action_sizes`` (agent -> motors, default 8 each) sizes built-in policies; ``obs_dims``
    (agent -> the match's observation size) checks every policy file against the roster; the
    error names the agent and both sizes. ``teams`` (agent -> team label, the roster) checks that each
    policy file can drive its seat (:func:`check_seat`).
    """
    out: dict[str, Any] = {}
    for k, pair in enumerate(pairs):
        agent, spec = pair.split("=")
        if agent in out:
            raise ValueError(f"policy for {agent!r} given twice")
        size = (action_sizes or {}).get(agent, ACTION_SIZE)
        expect = obs_dims.get(agent) if obs_dims is not None else None
        try:
            out[agent] = make_policy(spec, seed=seed * 1000 + k, expect_obs_mode=obs_mode, action_size=size,
                                     expect_obs_dim=expect)
        except ValueError as err:
            if expect is None:
                raise
            raise ValueError(f"policy {spec!r} for {agent!r} does not fit this roster: {err}") from None
        if teams is not None:  # (after the sizes: their error is the more concrete)
            check_seat(spec, agent, teams)
    return out
