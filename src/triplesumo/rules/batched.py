"""The constant arrays of a game, over which every rule of :mod:`triplesumo.rules` is written.

Each rule is written once, over arrays of ``E`` matches in an array namespace ``xp`` --
``numpy`` or ``torch`` (the rules never import torch) -- using only what both spell alike
(``abs``, ``sign``, ``where``, ``maximum`` of two arrays, ``clip``, ``@``, and the methods ``sum``,
``any``, ``all``, ``reshape``, ``swapaxes``; ``concat`` and ``stack`` with ``axis``), and lives in
its own module:

- outcome and places: :func:`~.outcome.agents_out`, :func:`~.outcome.judge`,
  :func:`~.outcome.first_out_places`, :func:`~.outcome.judge_elimination`, :func:`~.outcome.place_values`;
- rewards: :func:`~.rewards.reward_terms`;
- observations: :func:`~.observations.paper_observation`, :func:`~.observations.egocentric_observation`
  (over :func:`~.observations.yaw_of` and :func:`~.observations.heading_quaternion`).

One :class:`~triplesumo.envs.match.Match` calls them with numpy on ``E = 1``; the CPU vector env
(:class:`~triplesumo.envs.batch.MatchBatch`) with numpy on all its matches; the MuJoCo Warp backend
with torch on its device. They read a roster through :class:`BatchedRules`, built here once per config.
This module also re-exports them, and holds :func:`bad_state`, the Warp backend's physics-trouble check.

Outcomes are integer codes per agent, :data:`~triplesumo.rules.outcome.OUTCOME_CODES`:
0 the match goes on, 1 win, 2 loss, 3 draw, 4 physics error.
"""

from __future__ import annotations

from typing import Any

from triplesumo.rules.observations import clip as clip
from triplesumo.rules.observations import egocentric_observation as egocentric_observation
from triplesumo.rules.observations import heading_quaternion as heading_quaternion
from triplesumo.rules.observations import paper_observation as paper_observation
from triplesumo.rules.observations import yaw_of as yaw_of
from triplesumo.rules.outcome import DRAW_CODE as DRAW_CODE
from triplesumo.rules.outcome import ERROR_CODE as ERROR_CODE
from triplesumo.rules.outcome import LOSS_CODE as LOSS_CODE
from triplesumo.rules.outcome import PLAYING
from triplesumo.rules.outcome import WIN_CODE as WIN_CODE
from triplesumo.rules.outcome import agents_out as agents_out
from triplesumo.rules.outcome import first_out_places as first_out_places
from triplesumo.rules.outcome import judge as judge
from triplesumo.rules.outcome import judge_elimination as judge_elimination
from triplesumo.rules.outcome import place_values as place_values
from triplesumo.rules.rewards import ordered_sum as ordered_sum
from triplesumo.rules.rewards import reward_terms as reward_terms
from triplesumo.rules.roster import BatchedRules as BatchedRules

GOES_ON = PLAYING
"""Code of a match that goes on (``OUTCOME_CODES["playing"]``)."""
MAX_VALUE = 1e10
"""A state entry beyond this (or NaN) is bad, as MuJoCo's ``mju_isBad`` (``mjMAXVAL``) judges it."""


def bad_state(xp: Any, *arrays: Any) -> Any:
    """``(E,)`` bool: a match whose ``(E, k)`` state arrays hold NaN, inf or entries beyond :data:`MAX_VALUE`.

    The batched counterpart of MuJoCo's bad-qpos/qvel/qacc warnings and the CPU path's
    ``non_finite_state`` check (a NaN compares False, hence the ``~(... <= ...)``).
    """
    bad = None
    for a in arrays:
        b = (~(xp.abs(a) <= MAX_VALUE)).any(-1)
        bad = b if bad is None else bad | b
    return bad
