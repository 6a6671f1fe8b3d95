"""Seeds: what a seed may be, and the seeds of many matches from one.

Below both vector backends (``envs.batch`` on MuJoCo, ``envs.warp`` on MuJoCo Warp) and every view, so that
one seed starts one match whichever view plays it: match ``k`` of a vector view's ``reset(seed=s)`` is the
match a single view's ``reset(seed=s + k)`` starts (Gymnasium's convention for vector envs)."""

from __future__ import annotations

from typing import Any

import numpy as np


def check_seed(seed: Any, name: str = "seed") -> int:
    """``seed`` as an int, or ``ValueError`` naming ``name``: numpy's generators take integers >= 0 only."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"{name} must be a non-negative integer (0, 1, 2, ...), got {seed!r}")
    return int(seed)


def match_seeds(seed: int, n_matches: int) -> list[int]:
    """The reset seed of each of ``n_matches`` matches started from ``seed``: ``seed + k`` for match ``k``."""
    seed = check_seed(seed)
    return [seed + k for k in range(n_matches)]
