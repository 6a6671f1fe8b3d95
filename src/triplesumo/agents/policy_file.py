"""Policy files: an actor's weights as safetensors beside a JSON manifest.

``NAME.safetensors`` holds the actor's tensors (keys ``actor.*``) and, for a learner that
normalises its observations, the frozen normaliser (keys ``obs_norm.*``, manifest entry
``"obs_norm": true``); ``NAME.json`` says
what they are: agent, observation mode and size, action size, hidden sizes, env and
mujoco versions, how they were made (command, seed, epochs, evaluation), and the sha256
of the weights file, checked on load (files written before it was recorded load
unchecked). Loading never unpickles anything.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load_file as load_numpy

from triplesumo.agents.frozen import FrozenPolicy

if TYPE_CHECKING:  # torch is imported where torch tensors are made: playing a policy file needs numpy only
    import torch

    from triplesumo.agents.networks import Actor, ActorPolicy
    from triplesumo.agents.normalizer import ObsNormalizer

FORMAT = "triplesumo-policy/1"
LEAGUE_FORMAT = "triplesumo-league/1"
"""Format of a self-play league's pool file (``RUN/league/pool.json``, written by
:mod:`triplesumo.train.league`, read also by ``tournament --league``): members that are policy files."""
REQUIRED = ("format", "agent", "obs_mode", "obs_dim", "act_dim", "hidden")


class PolicyFileError(ValueError):
    """A policy or checkpoint file is missing, truncated, corrupt or incompatible."""


class CheckpointWriteError(OSError):
    """Writing a run file failed (disk full, read-only, no permission); names the file and cause."""

    def __str__(self) -> str:
        return str(self.strerror)


@contextmanager
def writing(path: Path | str, last_good: str = "") -> Iterator[None]:
    """Turn a failed write of ``path`` into a :class:`CheckpointWriteError` naming it and the cause."""
    try:
        yield
    except CheckpointWriteError:
        raise
    except (OSError, SafetensorError) as exc:
        code = getattr(exc, "errno", None)
        if code is None:  # safetensors reports io errors as text: "IoError(Os { code: 28, ..." or "(os error 28)"
            found = re.search(r"code: (\d+)|os error (\d+)", str(exc))
            code = int(found.group(1) or found.group(2)) if found else None
        cause = os.strerror(code) if code else str(exc)
        detail = "" if code is None or cause in str(exc) else f" ({exc})"
        raise CheckpointWriteError(code or errno.EIO, f"cannot write {path}: {cause}{detail}{last_good}") from exc


def atomic_write_bytes(path: Path, payload: bytes) -> None:
    """Write ``payload`` to ``path`` via a temp file, fsync and ``os.replace``. A failed write (a full disk, a
    read-only folder) leaves ``path`` as it was and raises an ``OSError`` of the same kind naming ``path``."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise _naming(path, exc) from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise _naming(path, exc) from exc
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _naming(path: Path, exc: OSError) -> OSError:
    """``exc`` as an ``OSError`` of the same kind (errno) and cause (``strerror``) whose ``filename`` is ``path``
    (its message then names it: ``[Errno 28] No space left on device: 'OUT/results.json'``)."""
    if str(path) in str(exc):
        return exc
    if not exc.errno:
        return OSError(f"cannot write {path}: {exc}")
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(path))


def atomic_save_tensors(tensors: dict[str, torch.Tensor], path: Path, metadata: dict[str, str] | None = None) -> None:
    """safetensors ``save_file`` made atomic (temp file in the same folder, then replace)."""
    from safetensors.torch import save_file

    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        save_file({k: v.detach().contiguous().cpu() for k, v in tensors.items()}, tmp, metadata=metadata)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def file_sha256(path: Path) -> str:
    """The sha256 of a file's bytes (hex), read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def load_tensors(path: Path) -> dict[str, torch.Tensor]:
    """Load a safetensors file, or :class:`PolicyFileError` naming the file and the reason."""
    from safetensors.torch import load_file

    path = Path(path)
    if not path.is_file():
        raise PolicyFileError(f"{path}: file not found")
    try:
        return load_file(str(path))
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise PolicyFileError(f"{path}: not a readable safetensors file (truncated or corrupt?): {exc}") from exc


def load_json(path: Path) -> dict[str, Any]:
    """Load a JSON object, or :class:`PolicyFileError` naming the file and the reason."""
    path = Path(path)
    if not path.is_file():
        raise PolicyFileError(f"{path}: file not found")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PolicyFileError(f"{path}: corrupt JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise PolicyFileError(f"{path}: expected a JSON object")
    return data


def bare_stem(path: Path | str) -> Path:
    """The stem of a policy file pair given with or without either suffix; a dot inside the name is kept
    (``a10000.v2-spider`` is not cut at ``.v2``)."""
    path = Path(path)
    return path.with_suffix("") if path.suffix in (".json", ".safetensors") else path


def policy_paths(stem: Path | str) -> tuple[Path, Path]:
    """The ``.json`` manifest and ``.safetensors`` weights of the pair ``stem`` names (:func:`bare_stem`)."""
    stem = bare_stem(stem)
    return stem.with_name(stem.name + ".json"), stem.with_name(stem.name + ".safetensors")


def save_policy(stem: Path, actor: Actor, manifest: dict[str, Any],
                obs_norm: ObsNormalizer | None = None) -> tuple[Path, Path]:
    """Write ``stem.safetensors`` and ``stem.json`` (with the normaliser, if any); returns both paths."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    full = {"format": FORMAT, "obs_dim": actor.obs_dim, "act_dim": actor.act_dim,
            "hidden": list(actor.hidden), **manifest, "obs_norm": obs_norm is not None}
    missing = [k for k in REQUIRED if k not in full]
    if missing:
        raise ValueError(f"policy manifest lacks {missing}")
    meta, weights = policy_paths(stem)
    tensors = {f"actor.{k}": v for k, v in actor.state_dict().items()}
    if obs_norm is not None:
        tensors |= {f"obs_norm.{k}": v for k, v in obs_norm.state_dict().items()}
    atomic_save_tensors(tensors, weights)
    full["sha256"] = file_sha256(weights)
    atomic_write_bytes(meta, (json.dumps(full, indent=2, sort_keys=True) + "\n").encode())
    return weights, meta


def _read_manifest(stem: Path, expect_obs_mode: str | None,
                   expect_obs_dim: int | None) -> tuple[dict[str, Any], Path]:
    """The checked manifest of a policy file pair and the path of its weights."""
    meta_path, weights_path = policy_paths(stem)
    manifest = load_json(meta_path)
    missing = [k for k in REQUIRED if k not in manifest]
    if missing:
        raise PolicyFileError(f"{meta_path}: manifest lacks {missing}")
    if manifest["format"] != FORMAT:
        raise PolicyFileError(f"{meta_path}: format {manifest['format']!r}, expected {FORMAT!r}")
    for key in ("obs_dim", "act_dim"):
        if not _positive_int(manifest[key]):
            raise PolicyFileError(f"{meta_path}: {key} must be a positive integer, got {manifest[key]!r}")
    hidden = manifest["hidden"]
    if not (isinstance(hidden, list) and hidden and all(_positive_int(h) for h in hidden)):
        raise PolicyFileError(f"{meta_path}: hidden must be a list of positive integers, got {hidden!r}")
    roster = manifest.get("agents")
    if isinstance(roster, list):  # the seats it was trained for must be seats of the roster it was trained in
        seats = [*str(manifest["agent"]).split("+"), *(manifest.get("plays") or [])]  # (a shared net: "ant+bug")
        for seat in seats:
            if seat not in roster:
                raise PolicyFileError(f"{meta_path}: agent {seat!r} is not in the roster it records {roster}")
    if expect_obs_mode is not None and manifest["obs_mode"] != expect_obs_mode:
        raise PolicyFileError(f"{meta_path}: policy was trained with obs_mode {manifest['obs_mode']!r}, "
                              f"the match uses {expect_obs_mode!r}")
    if expect_obs_dim is not None and int(manifest["obs_dim"]) != expect_obs_dim:
        raise PolicyFileError(f"{meta_path}: policy expects {manifest['obs_dim']} observation values, "
                              f"the match gives {expect_obs_dim}")
    if "sha256" in manifest and weights_path.is_file() and file_sha256(weights_path) != manifest["sha256"]:
        raise PolicyFileError(f"{weights_path}: sha256 differs from the one {meta_path} records "
                              "(damaged, or replaced by other weights)")
    return manifest, weights_path


def seat_problem(manifest: dict[str, Any], seat: str, teams: dict[str, str],
                 trained_with: int | None = None) -> str | None:
    """Why the policy file of ``manifest`` cannot drive ``seat`` of a match whose roster is ``teams`` (agent ->
    team label, roster order), or ``None`` if it can. With ``paper`` observations (one global vector, nothing in
    it says which body the network drives) only the seats it was trained for (``plays``, else ``agent``), in the
    roster it was trained in; with ``egocentric`` ones any seat with as many partners as it was trained with
    (``trained_with``, default the manifest's ``partners``; files older than that key say nothing here)."""
    roster = list(teams)
    if manifest.get("obs_mode") == "paper":
        trained = manifest.get("agents")
        if trained is not None and list(trained) != roster:
            return f"it was trained in the roster {list(trained)}, this match's is {roster}"
        plays = list(manifest.get("plays") or [manifest.get("agent")])
        if seat not in plays:
            return (f"it was trained to drive {plays} and reads the paper's global observations, which do not say "
                    f"which body it drives, so it cannot drive {seat!r}")
        return None
    partners = sum(1 for a, t in teams.items() if t == teams[seat] and a != seat)
    if trained_with is None and isinstance(manifest.get("partners"), int):
        trained_with = int(manifest["partners"])
    if trained_with is not None and trained_with != partners:
        return (f"it was trained in a seat with {trained_with} partner(s); {seat!r} has {partners} (egocentric "
                "observations list partners before opponents)")
    return None


def _positive_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


def check_weights(weights_path: Path, tensors: dict[str, Any], manifest: dict[str, Any]) -> None:
    """``PolicyFileError`` naming the file unless every actor tensor is finite float32 and the actor's hidden
    widths are the manifest's ``hidden`` (NaN, inf or int32 weights, or a manifest that lies about the widths,
    fail here, on loading, not at the first step or in a published copy)."""
    widths = []
    for key, value in tensors.items():
        array = value.detach().cpu().numpy() if hasattr(value, "detach") else np.asarray(value)
        if key.startswith("actor."):
            if array.dtype != np.float32:
                raise PolicyFileError(f"{weights_path}: {key} is {array.dtype}, expected float32")
            if key.endswith(".weight") and array.ndim == 2:
                widths.append(int(array.shape[0]))
        if not np.isfinite(array).all():
            raise PolicyFileError(f"{weights_path}: {key} holds NaN or inf values")
    if widths and widths[:-1] != list(manifest["hidden"]):  # (no actor weights at all: the loader says so)
        raise PolicyFileError(f"{weights_path}: the actor's hidden widths are {widths[:-1]}, its manifest says "
                              f"{manifest['hidden']}")


def _check_sizes(weights_path: Path, manifest: dict[str, Any], obs_dim: int, act_dim: int) -> None:
    if obs_dim != int(manifest["obs_dim"]) or act_dim != int(manifest["act_dim"]):
        raise PolicyFileError(f"{weights_path}: weights are {obs_dim}->{act_dim}, "
                              f"manifest says {manifest['obs_dim']}->{manifest['act_dim']}")


def load_policy(stem: Path, expect_obs_mode: str | None = None,
                expect_obs_dim: int | None = None) -> tuple[ActorPolicy, dict[str, Any]]:
    """Load a policy file pair as a torch actor (to train on, or to publish); checks the
    manifest against the weights and expectations. To drive an agent, prefer
    :func:`load_fixed_policy`."""
    from triplesumo.agents.networks import Actor, ActorPolicy
    from triplesumo.agents.normalizer import ObsNormalizer

    manifest, weights_path = _read_manifest(stem, expect_obs_mode, expect_obs_dim)
    tensors = load_tensors(weights_path)
    check_weights(weights_path, tensors, manifest)
    try:
        actor = Actor.from_state_dict(tensors, prefix="actor.")
    except (KeyError, ValueError, RuntimeError) as exc:
        raise PolicyFileError(f"{weights_path}: not an actor: {exc}") from exc
    _check_sizes(weights_path, manifest, actor.obs_dim, actor.act_dim)
    obs_norm = None
    if manifest.get("obs_norm", False):
        try:
            obs_norm = ObsNormalizer.from_state_dict(tensors, prefix="obs_norm.")
        except (KeyError, ValueError, RuntimeError) as exc:
            raise PolicyFileError(f"{weights_path}: manifest says obs_norm, the weights lack it: {exc}") from exc
        if obs_norm.obs_dim != actor.obs_dim:
            raise PolicyFileError(f"{weights_path}: normaliser is for {obs_norm.obs_dim} values, "
                                  f"the actor takes {actor.obs_dim}")
        obs_norm.eval()
    actor.eval()
    return ActorPolicy(actor, obs_norm), manifest


def load_fixed_policy(stem: Path, expect_obs_mode: str | None = None,
                      expect_obs_dim: int | None = None) -> tuple[FrozenPolicy, dict[str, Any]]:
    """Load a policy file pair as a :class:`FrozenPolicy` (numpy, no torch: fork-safe and
    cheap), the way fixed opponents and the zoo are played; same checks as :func:`load_policy`
    (the frozen observation normaliser included)."""
    manifest, weights_path = _read_manifest(stem, expect_obs_mode, expect_obs_dim)
    if not weights_path.is_file():
        raise PolicyFileError(f"{weights_path}: file not found")
    try:
        tensors = load_numpy(str(weights_path))
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise PolicyFileError(f"{weights_path}: not a readable safetensors file (truncated or corrupt?): "
                              f"{exc}") from exc
    check_weights(weights_path, tensors, manifest)
    try:
        policy = FrozenPolicy.from_tensors(tensors, prefix="actor.",
                                           obs_norm_prefix="obs_norm." if manifest.get("obs_norm", False) else None)
    except (KeyError, ValueError) as exc:
        raise PolicyFileError(f"{weights_path}: not an actor (or its normaliser is missing): {exc}") from exc
    _check_sizes(weights_path, manifest, policy.obs_dim, policy.act_dim)
    return policy, manifest
