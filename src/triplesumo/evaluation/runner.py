"""Run matches between fixed policies: one seeded match, optionally filmed and recorded, or a
seeded schedule of matches with any policy in any seat, played many at a time."""

from __future__ import annotations

import copy
import sys
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from triplesumo.envs.match import Match
from triplesumo.evaluation.recording import MatchRecorder
from triplesumo.evaluation.video import check_writable, write_mp4
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.outcome import outcome_name
from triplesumo.sim.render import FrameRenderer

Policy = Callable[[np.ndarray], np.ndarray]

_torch_threads_lock = threading.Lock()
_torch_threads_users = 0
_torch_threads_before = 0


@contextmanager
def one_torch_thread() -> Iterator[None]:
    """Inside, torch (where this process has imported it) runs on one intra-op thread; its setting is restored
    when the last user leaves (matches played on several threads of one process share the setting).

    The runners call each policy on one observation at a time, and a one-row product is not worth splitting:
    torch's extra threads only spin against the MuJoCo threads for the cores. On the 2-core box beside a
    training run, 48 test matches of ``zoo:bug`` took 59.9 s of wall time and 46.5 s of CPU on torch's default
    2 threads, and 17.3 s and 8.6 s on one, with the same rows to the last bit (a one-row product sums each
    output in the same order on any thread count). Nothing here imports torch."""
    global _torch_threads_users, _torch_threads_before
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    with _torch_threads_lock:
        if _torch_threads_users == 0:
            _torch_threads_before = torch.get_num_threads()
            if _torch_threads_before != 1:
                torch.set_num_threads(1)
        _torch_threads_users += 1
    try:
        yield
    finally:
        with _torch_threads_lock:
            _torch_threads_users -= 1
            if _torch_threads_users == 0 and _torch_threads_before != 1:
                torch.set_num_threads(_torch_threads_before)


@dataclass
class MatchRecord:
    """What happened in one match, per agent in roster order."""

    outcomes: dict[str, str]
    """Each agent's side's result: win, loss, draw or error."""
    steps: int
    returns: dict[str, float]
    out_of_ring: list[str]
    terms: dict[str, dict[str, float]] = field(default_factory=dict)
    """Per agent, the sum over the match of each reward term and of dense/sparse reward."""
    frames: int = 0
    places: dict[str, int] = field(default_factory=dict)
    """Each agent's final place (1 = winner; 0 if the match ended in a physics error)."""


@one_torch_thread()
def play_match(policies: Mapping[str, Policy], seed: int, config: MatchConfig | None = None,
               video: Path | None = None, width: int = 480, height: int = 480,
               match: Match | None = None, record: Path | None = None,
               policy_names: Mapping[str, str] | None = None) -> MatchRecord:
    """Play one match to its end; agents without a policy are passive.

    With ``video`` the match is rendered from the overview camera and written as mp4
    (one frame per env step, plus the start). With ``record`` it is written as a replayable
    match file (:mod:`triplesumo.evaluation.recording`); ``policy_names`` are stored in it.
    """
    match = match or Match(config)
    unknown = [a for a in policies if a not in match.agents]
    if unknown:
        raise ValueError(f"policies for unknown agents {unknown}; agents are {list(match.agents)}")
    for out in (video, record):
        if out is not None:
            check_writable(Path(out))
    for k, name in enumerate(match.agents):
        reset = getattr(policies.get(name), "reset", None)
        if callable(reset):
            reset(seed=seed * 1000 + k + 1)
    obs, _ = match.reset(seed=seed)
    recorder = MatchRecorder(match, seed, dict(policy_names or {})) if record is not None else None
    renderer = FrameRenderer(match.model, width, height) if video is not None else None
    frames = [renderer.render(match.data)] if renderer else []
    returns = dict.fromkeys(match.agents, 0.0)
    terms: dict[str, dict[str, float]] = {a: {} for a in match.agents}
    try:
        while True:
            actions = np.zeros((match.n_agents, match.action_width))
            for i, name in enumerate(match.agents):
                policy = policies.get(name)
                if policy is not None and match.alive[i]:  # an eliminated agent no longer acts
                    actions[i, :match.action_sizes[i]] = match.check_action(name, policy(obs[i]))
            result = match.step_array(actions)
            if recorder:
                recorder.step(actions)
            obs = result.observations
            for i, name in enumerate(match.agents):
                returns[name] += float(result.rewards[i])
                for key, value in result.infos[i].items():
                    if key.startswith("reward_") or key in ("dense_reward", "sparse_reward"):
                        terms[name][key] = terms[name].get(key, 0.0) + value
            if renderer:
                frames.append(renderer.render(match.data))
            if result.terminated or result.truncated:
                break
    finally:
        if renderer:
            renderer.close()
    outcomes = {a: outcome_name(result.infos[i]["outcome"]) for i, a in enumerate(match.agents)}
    if recorder is not None and record is not None:
        recorder.finish(outcomes).save(Path(record))
    n_frames = write_mp4(frames, Path(video), fps=round(1.0 / match.sim.dt)) if video is not None else 0
    return MatchRecord(
        outcomes=outcomes,
        steps=match.steps, returns=returns,
        out_of_ring=[a for i, a in enumerate(match.agents)
                     if result.infos[i]["out_of_ring"] or result.infos[i]["eliminated"]],
        terms=terms, frames=n_frames, places={a: int(result.infos[i]["place"]) for i, a in enumerate(match.agents)},
    )


@dataclass
class SeatedResult:
    """One finished match of :func:`play_matches`."""

    index: int
    """The match's index in the schedule."""
    outcomes: list[str]
    """Each seat's side's result (win, loss, draw or error), roster order."""
    steps: int
    """Env steps the match lasted."""
    terms: dict[int, dict[str, float]]
    """For each seat asked for in ``terms_of``: the match's sums of ``dense_reward``,
    ``sparse_reward`` and every reward term."""
    places: list[int] = field(default_factory=list)
    """Each seat's place (1 = first; equal places share; under elimination rules the order agents
    left in), roster order; 0 where the match ended in a physics error."""


@one_torch_thread()
def play_matches(
    lineup: Callable[[int], Sequence[Policy | None]],
    reset_seed: Callable[[int], int],
    n: int,
    match_cfg: MatchConfig,
    n_envs: int = 16,
    n_threads: int = 2,
    first: int = 0,
    on_result: Callable[[SeatedResult], None] | None = None,
    terms_of: tuple[int, ...] = (),
    progress: str | None = None,
    end_seat: int | None = None,
    record: int = 0,
    record_dir: Path | None = None,
    policy_names: Mapping[str, str] | None = None,
) -> list[SeatedResult]:
    """Play matches ``first .. n - 1`` of a schedule, ``n_envs`` at a time; results in schedule order.

    Match ``i`` seats ``lineup(i)`` (one policy per agent in roster order; ``None`` is
    passive) and resets with seed ``reset_seed(i)``. Stateful policies (with
    ``reset(seed)``) get one copy per match slot and seat, re-seeded from
    ``(reset_seed(i), seat)`` at every match start, and every policy is called one
    observation at a time (torch on one thread: :func:`one_torch_thread`): so each match's result depends on its
    lineup and seed only, never on ``n_envs`` or on which matches ran beside it. ``on_result`` is called with
    each result in schedule order as soon as it and every earlier one have finished
    (matches end out of order). ``progress`` is a progress-bar label (``None``: no bar).

    Under elimination rules a match's result is taken when seat ``end_seat`` is eliminated
    (its own match is over), if given. Matches ``< record`` are written as replayable match
    files ``record_dir/epoch_NNNNN.npz`` (``policy_names`` stored in them).

    The matches run through the batched API (:class:`~triplesumo.envs.batch.VectorMatches`,
    autoreset): a slot whose match ends draws the schedule's next match and its seed while the
    env resets it (``VectorMatches.reset_seed``).
    """
    from triplesumo.envs.batch import VectorMatches
    from triplesumo.rules.rewards import TERMS

    if not 0 <= first < n:
        raise ValueError(f"first must be in [0, n={n}), got {first}")
    n_envs = min(n_envs, n - first)
    env = VectorMatches(n_envs, match_cfg, n_threads)
    matches = env.matches
    n_agents = len(match_cfg.agents)
    copies: list[dict[tuple[int, int], Any]] = [{} for _ in range(n_envs)]
    seated: list[list[Any]] = [[] for _ in range(n_envs)]
    slot_match = [-1] * n_envs
    keys = ("dense_reward", "sparse_reward", *TERMS)
    acc: list[dict[int, dict[str, float]]] = [{} for _ in range(n_envs)]
    recorders: list[MatchRecorder | None] = [None] * n_envs
    sizes, width = env.action_sizes, env.act_dim
    results: dict[int, SeatedResult] = {}
    next_match, next_result = first, first
    upcoming: dict[int, tuple[int, int]] = {}
    """Slot -> (schedule index, reset seed) of its next match, drawn when its match ends."""
    actions = np.zeros((n_envs, n_agents, width))

    def draw(k: int) -> int:
        """The next match of the schedule for slot ``k`` (-1: a filler, discarded); returns its reset seed."""
        nonlocal next_match
        i = next_match if next_match < n else -1
        next_match += 1
        seed = reset_seed(i if i >= 0 else n - 1)
        upcoming[k] = (i, seed)
        return seed if i >= 0 else seed + 1 + k

    def ending(k: int) -> int:
        """Slot ``k``'s match has ended inside ``env.step`` (its state is still the last one): record
        its last step, then draw its next match (``VectorMatches.reset_seed``)."""
        recorder = recorders[k]
        if recorder is not None:
            recorder.step(actions[k])
        return draw(k)

    def start(k: int) -> None:
        """Seat slot ``k``'s drawn match (the env has just reset it with that match's seed)."""
        i, seed = upcoming.pop(k)
        policies = list(lineup(i if i >= 0 else n - 1))
        if len(policies) != n_agents:
            raise ValueError(f"lineup({i}) has {len(policies)} policies for {n_agents} seats")
        for seat, p in enumerate(policies):
            if p is not None and callable(getattr(p, "reset", None)):
                p = copies[k].setdefault((seat, id(p)), copy.deepcopy(p))
                p.reset(seed=int(np.random.SeedSequence([seed, seat]).generate_state(1)[0]))
                policies[seat] = p
        seated[k] = policies
        slot_match[k] = i
        acc[k] = {seat: dict.fromkeys(keys, 0.0) for seat in terms_of}
        recorders[k] = (MatchRecorder(matches[k], seed, dict(policy_names or {}))
                        if record_dir is not None and 0 <= i < record else None)

    bar = None
    if progress is not None:
        from tqdm import tqdm

        bar = tqdm(total=n, initial=first, unit="match", desc=progress, dynamic_ncols=True)
    try:
        with env:
            obs = env.reset(seed=[draw(k) for k in range(n_envs)])[0]
            for k in range(n_envs):
                start(k)
            env.reset_seed = ending
            while len(results) < n - first:
                actions = np.zeros((n_envs, n_agents, width))
                for k in range(n_envs):
                    alive = matches[k].alive
                    for seat, p in enumerate(seated[k]):
                        if p is not None and alive[seat]:  # an eliminated agent no longer acts
                            actions[k, seat, :sizes[seat]] = p(obs[k][seat])
                obs, _, terminated, _, infos = env.step(actions)  # finished matches are already reset
                done = infos["_final_obs"]
                for k in range(n_envs):
                    for seat, sums in acc[k].items():
                        for key in sums:
                            sums[key] += float(infos[key][k, seat])
                    gone = end_seat is not None and bool(terminated[k, end_seat])  # its own match is over
                    recorder = recorders[k]
                    if recorder is not None and not done[k]:
                        recorder.step(actions[k])
                    if not (done[k] or gone):
                        continue
                    codes = infos["outcome"][k]
                    if recorder is not None and record_dir is not None:
                        outcomes = {a: outcome_name(int(c)) for a, c in zip(env.agents, codes, strict=True)}
                        recorder.finish(outcomes).save(record_dir / f"epoch_{slot_match[k] + 1:05d}.npz")
                    i = slot_match[k]
                    if i >= 0:
                        results[i] = SeatedResult(i, [outcome_name(int(c)) for c in codes], int(infos["step"][k]),
                                                  acc[k], [int(p) for p in infos["place"][k]])
                        if bar is not None:
                            bar.update(1)
                        while on_result is not None and next_result in results:
                            on_result(results[next_result])
                            next_result += 1
                    if not done[k]:  # the seat followed left a match that goes on: start the next one now
                        obs[k] = env.restart(k, draw(k))
                    start(k)
    finally:
        if bar is not None:
            bar.close()
    return [results[i] for i in range(first, n)]
