"""Stage 1 of the protocol as code: each side learns to push still opponents, screened as it trains, and the pair
rule picks which of its screened checkpoints meet.

The rules (docs/CONTEST.md, fixed before any pair was played):

* **Screens.** A side trains in legs of ``screen_every`` epochs. After each leg its policy is kept
  (``ROLE/screens/policy-EPOCH``) and played, frozen, on the screen's ``screen_epochs`` starts (``screen_seed`` + i)
  against still opponents: the Ant against a passive Spider and Bug, the Spider against a passive Ant and Bug. Its
  *push rate* is its share of wins there (an opponent pushed out).
* **The checkpoint rule** (:func:`first_passing`): a side's pick is its earliest screened checkpoint whose push rate is
  at least :data:`~triplesumo.reproduce.config.PUSH_MIN`; the side stops training there. A side that reaches its
  epoch budget without one fails the stage (:class:`~triplesumo.reproduce.config.PairError`).
* **The pair rule** (:func:`pair_move`): the two picks play the match with Bug passive on the same screen starts. A
  team MWR inside :data:`~triplesumo.reproduce.config.CONTEST_BAND` makes the pair; a team that loses by more gets a
  stronger Ant (the Ant trains on to its next screened checkpoint that passes), a team that wins by more a stronger
  Spider. Every pair played is recorded (``pair/pair.json``); the pair then goes to the contest check on its own
  held-out starts.

Everything here is resumable: a killed leg resumes from its run's last checkpoint, a screen or a pair's match from
its evaluation's rows, and the rules are replayed from the records (``ROLE/screens.json``, ``pair/pair.json``).
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from triplesumo.agents.policy_file import atomic_write_bytes, policy_paths
from triplesumo.reproduce.config import CONTEST_BAND, PUSH_MIN, PairError

SCREENS_FILE = "screens.json"
PAIR_FILE = "pair.json"
ROLES = ("ant", "spider")


def first_passing(screens: Sequence[dict[str, Any]], after: int = 0,
                  push_min: float = PUSH_MIN) -> dict[str, Any] | None:
    """The checkpoint rule: the earliest screen after epoch ``after`` whose push rate (``n_win / n``) is at least
    ``push_min``, or None."""
    return next((s for s in sorted(screens, key=lambda s: s["epoch"])
                 if s["epoch"] > after and s["n_win"] / s["n"] >= push_min), None)


def pair_move(team_mwr: float, band: tuple[float, float] = CONTEST_BAND) -> str:
    """The pair rule on the team's MWR with Bug passive: ``"pair"`` inside the band (both ends included), ``"ant"``
    (train a stronger Ant) when the team loses by more, ``"spider"`` (a stronger Spider) when it wins by more."""
    lo, hi = band
    if team_mwr < lo:
        return "ant"
    if team_mwr > hi:
        return "spider"
    return "pair"


def counts_of(summary_path: Path) -> dict[str, int]:
    """An evaluation's counts of its one candidate (``summary.json``): n, n_win, n_loss, n_draw, from the learner's
    seat."""
    summary = json.loads(summary_path.read_text())
    c = next(iter(summary["candidates"].values()))
    return {k: int(c[k]) for k in ("n", "n_win", "n_loss", "n_draw")}


def read_record(path: Path, default: dict[str, Any]) -> dict[str, Any]:
    """A stage-1 record (JSON), or ``default`` when it is not there yet; ``ValueError`` naming a damaged one."""
    if not path.exists():
        return default
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not a readable stage-1 record ({exc}); restore it or delete it to redo the "
                         "screens it held") from None


def write_record(path: Path, record: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(record, indent=2) + "\n").encode())


def keep_policy(run_dir: Path, epoch: int) -> Path:
    """Copy the run's policy files (written at the end of its leg) to ``screens/policy-EPOCH``; the copy's stem."""
    stem = run_dir / "screens" / f"policy-{epoch}"
    stem.parent.mkdir(parents=True, exist_ok=True)
    for src, dst in zip(policy_paths(run_dir / "policy"), policy_paths(stem), strict=True):
        shutil.copy2(src, dst)
    return stem


class Side:
    """One side's training in legs with a screen after each (:func:`first_passing` picks its checkpoint).

    ``train(epochs)`` trains (or resumes) the side's run to ``epochs`` and returns its env steps;
    ``screen(policy, out)`` plays a screen and returns its counts; ``budget`` is the side's largest epoch."""

    def __init__(self, role: str, run_dir: Path, every: int, budget: int, starts: str,
                 train: Callable[[int], int], screen: Callable[[str, Path], dict[str, int]],
                 push_min: float = PUSH_MIN) -> None:
        self.role, self.run_dir, self.every, self.budget, self.push_min = role, run_dir, every, budget, push_min
        self.path = run_dir / SCREENS_FILE
        self.starts, self._train, self._screen = starts, train, screen

    def record(self) -> dict[str, Any]:
        return read_record(self.path, {"role": self.role, "starts": self.starts, "every": self.every,
                                       "push_min": self.push_min, "screens": []})

    def screens(self) -> list[dict[str, Any]]:
        return list(self.record()["screens"])

    def pick(self, after: int = 0) -> dict[str, Any] | None:
        return first_passing(self.screens(), after, self.push_min)

    def until_pass(self, after: int = 0) -> dict[str, Any]:
        """Train and screen leg by leg until a screen after epoch ``after`` passes; that screen.
        :class:`PairError` when the budget runs out first."""
        while (found := self.pick(after)) is None:
            record = self.record()
            done = max((s["epoch"] for s in record["screens"]), default=0)
            epoch = done + self.every
            if epoch > self.budget:
                rates = ", ".join(f"{s['n_win']}/{s['n']} at {s['epoch']:,}" for s in record["screens"])
                what = (f"pushed still opponents out in fewer than {self.push_min:.0%} of its screen's starts at "
                        f"every checkpoint after epoch {after:,} up to its budget of {self.budget:,} epochs"
                        if after < self.budget else
                        f"has no checkpoint after epoch {after:,}: its budget of {self.budget:,} epochs is spent")
                raise PairError(f"stage 1: the {self.role.capitalize()} {what} ({rates}; {self.path}). Raise "
                                f"the budget (--{self.role}-epochs) and re-run: the run resumes")
            start = time.perf_counter()
            env_steps = self._train(epoch)
            trained = time.perf_counter() - start
            stem = keep_policy(self.run_dir, epoch)
            start = time.perf_counter()
            counts = self._screen(str(stem), self.run_dir / "screens" / f"epoch-{epoch}")
            screened = time.perf_counter() - start
            row = {"epoch": epoch, "env_steps": env_steps, **counts,
                   "push": round(counts["n_win"] / counts["n"], 4),
                   "policy": str(stem.relative_to(self.run_dir)), "train_seconds": round(trained, 1),
                   "screen_seconds": round(screened, 1)}
            record["screens"].append(row)
            write_record(self.path, record)
            print(f"  {self.role} at {epoch:,} epochs: pushes {counts['n_win']} of {counts['n']} still opponents out "
                  f"({'passes' if counts['n_win'] / counts['n'] >= self.push_min else 'not yet'}; trained "
                  f"{trained:.0f} s, screened {screened:.0f} s)")
        return found


def play_pair_rule(sides: dict[str, Side], path: Path,
                   play: Callable[[dict[str, Any], dict[str, Any]], dict[str, int]],
                   band: tuple[float, float] = CONTEST_BAND) -> dict[str, Any]:
    """The pair rule (:func:`pair_move`) from each side's first passing checkpoint: play a pair, move the side the
    rule names on to its next passing checkpoint, until a pair lies in the band. ``play(ant, spider)`` returns the
    counts of the match with Bug passive from the Spider's seat. Every pair played goes into ``path``; the pick is
    ``record["pick"]``. :class:`PairError` when a side's budget runs out first."""
    record = read_record(path, {"band": list(band), "pairs": []})
    if record.get("pick"):
        return record
    current = {role: side.until_pass(0) for role, side in sides.items()}
    while True:
        played = {(p["ant_epoch"], p["spider_epoch"]): p for p in record["pairs"]}
        key = (current["ant"]["epoch"], current["spider"]["epoch"])
        if key not in played:
            counts = play(current["ant"], current["spider"])
            team_mwr = (counts["n_loss"] - counts["n_win"]) / counts["n"]  # the Spider's losses are the team's wins
            entry = {"ant_epoch": key[0], "spider_epoch": key[1], "counts": counts, "team_mwr": round(team_mwr, 4),
                     "move": pair_move(team_mwr, band)}
            record["pairs"].append(entry)
            write_record(path, record)
            print(f"  pair: Ant {key[0]:,} / Spider {key[1]:,}, Bug passive: team MWR {team_mwr:+.3f} -> "
                  + ("the pair" if entry["move"] == "pair" else f"a stronger {entry['move'].capitalize()}"))
        else:
            entry = played[key]
        if entry["move"] == "pair":
            record["pick"] = {role: {"epoch": current[role]["epoch"],
                                     "policy": str(sides[role].run_dir.name + "/" + current[role]["policy"])}
                              for role in ROLES}
            write_record(path, record)
            return record
        role = entry["move"]
        try:
            current[role] = sides[role].until_pass(current[role]["epoch"])
        except PairError as exc:  # the rule wants a stronger side that its budget cannot give: say so, and keep it
            lo, hi = band
            where = "above" if entry["team_mwr"] > hi else "below"
            record["failed"] = (f"the pair rule found no pair: with Ant {key[0]:,} / Spider {key[1]:,} and Bug passive "
                                f"the team's MWR is {entry['team_mwr']:+.3f}, {where} the band [{lo:+.2f}, {hi:+.2f}], "
                                f"so the {role.capitalize()} must get stronger, but {exc}")
            write_record(path, record)
            raise PairError(record["failed"]) from None
