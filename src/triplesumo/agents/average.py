"""Weight averaging of policy snapshots of one run (stochastic weight averaging).

A deterministic actor trained by DDPG moves a long way between snapshots a few hundred
epochs apart, and so does its skill. The equal-weight mean of the actor parameters of
several snapshots of the *same* run (Izmailov et al. 2018, "Averaging weights leads to
wider optima and better generalization"; in RL, Nikishin et al. 2018) is a policy of its
own, often steadier than any one of them. It is computed by PyTorch's
:class:`torch.optim.swa_utils.AveragedModel`, and written as an ordinary policy file whose
manifest names its sources (path, sha256, epochs) beside the training provenance of the
newest one.

Only snapshots of one training run average meaningfully (networks from different starts
do not share a basin), so the sources must agree on agent, observation mode and sizes,
hidden widths and algorithm, and on the run id their manifests record. Policies with an
observation normaliser average only if their normalisers are identical: the mean of
normalised actors under different normalisers is not an actor of any of them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch.optim.swa_utils import AveragedModel

from triplesumo.agents.networks import Actor
from triplesumo.agents.policy_file import PolicyFileError, file_sha256, load_policy, policy_paths, save_policy
from triplesumo.agents.zoo import policy_stem

AGREE = ("agent", "obs_mode", "obs_dim", "act_dim", "hidden", "algo")
"""Manifest entries every averaged source must share."""


def run_id_of(manifest: dict[str, Any]) -> str | None:
    """The training run a policy file comes from (its first leg's ``run_id``), if the manifest records it."""
    legs = manifest.get("legs")
    if isinstance(legs, list) and legs and isinstance(legs[0], dict):
        value = legs[0].get("run_id")
        return str(value) if value else None
    return None


def average_policies(sources: list[Path | str], out: Path | str, command: str = "") -> dict[str, Any]:
    """Write the equal-weight average of the actors of ``sources`` (policy files of one run) to
    ``out`` (``out.safetensors`` and ``out.json``); returns the written manifest.

    ``ValueError`` (a :class:`PolicyFileError` for a bad file) names the problem: fewer than two
    sources, one named twice, a source that does not load, sources that disagree on an
    :data:`AGREE` entry or on their run, or that hold different observation normalisers.
    """
    stems = [policy_stem(s) for s in sources]
    if len(stems) < 2:
        raise ValueError(f"averaging needs at least two policy files, got {len(stems)}")
    if len({s.resolve() for s in stems}) < len(stems):
        raise ValueError(f"a policy file is named twice among {[str(s) for s in stems]}")
    loaded = [load_policy(s) for s in stems]
    first = loaded[0][1]
    for stem, (_, manifest) in zip(stems, loaded, strict=True):
        for key in AGREE:
            if manifest.get(key) != first.get(key):
                raise ValueError(f"{stem}: {key} is {manifest.get(key)!r}, {stems[0]} has {first.get(key)!r}: "
                                 "only snapshots of one run average")
        if run_id_of(manifest) != run_id_of(first):
            raise ValueError(f"{stem}: from run {run_id_of(manifest)!r}, {stems[0]} from {run_id_of(first)!r}: "
                             "only snapshots of one run average")
    norms = [policy.obs_norm for policy, _ in loaded]
    if any(n is not None for n in norms):
        states = [None if n is None else n.state_dict() for n in norms]
        base = states[0]
        if base is None or any(s is None or s.keys() != base.keys() or any(not torch.equal(s[k], base[k]) for k in s)
                               for s in states):
            raise ValueError("the policies hold different observation normalisers; an average of their actors "
                             "would be an actor of none of them")
    actors = [policy.actor for policy, _ in loaded]
    swa = AveragedModel(actors[0])
    for actor in actors:
        swa.update_parameters(actor)
    averaged = swa.module
    assert isinstance(averaged, Actor)  # (a deep copy of the first actor, holding the mean)
    newest = max(range(len(loaded)), key=lambda i: int(loaded[i][1].get("epochs") or 0))
    manifest = {k: v for k, v in loaded[newest][1].items()
                if k not in ("sha256", "format", "obs_dim", "act_dim", "hidden", "obs_norm", "league_member")}
    manifest["average"] = {
        "method": "equal-weight mean of the actor parameters (torch.optim.swa_utils.AveragedModel)",
        "command": command,
        "sources": [{"policy": str(stem), "sha256": file_sha256(policy_paths(stem)[1]),
                     "epochs": m.get("epochs"), "league_member": m.get("league_member")}
                    for stem, (_, m) in zip(stems, loaded, strict=True)],
    }
    out = policy_stem(out)
    if out.resolve() in {s.resolve() for s in stems}:
        raise ValueError(f"{out}: the output would overwrite one of the averaged policies")
    try:
        save_policy(out, averaged, manifest, obs_norm=norms[0])
    except OSError as exc:
        raise PolicyFileError(f"{out}: cannot write the averaged policy ({exc})") from exc
    return load_policy(out)[1]
