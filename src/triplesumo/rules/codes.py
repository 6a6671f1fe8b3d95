"""The outcome of an agent as a name and as an int code: what infos report (:mod:`.outcome` judges it)."""

from __future__ import annotations

WIN, LOSS, DRAW = "win", "loss", "draw"
ERROR = "error"
"""A physics error truncated the match (see ``MatchConfig.on_physics_error``)."""

OUTCOME_CODES: dict[str, int] = {"playing": 0, WIN: 1, LOSS: 2, DRAW: 3, ERROR: 4}
"""Int code of each outcome in infos: 0 while the match goes on, 1 win, 2 loss, 3 draw,
4 physics error."""
PLAYING, WIN_CODE, LOSS_CODE, DRAW_CODE, ERROR_CODE = OUTCOME_CODES.values()
OUTCOME_NAMES: tuple[str, ...] = tuple(OUTCOME_CODES)
"""``OUTCOME_NAMES[code]`` is the outcome's name (``"playing"`` for 0)."""
