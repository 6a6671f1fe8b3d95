"""Seeds of many matches from one: below both vector backends (``envs.batch`` on MuJoCo, ``envs.warp`` on
MuJoCo Warp), which give match ``k`` of ``reset(seed)`` the same start this way."""

from __future__ import annotations

import numpy as np


def match_seeds(seed: int, n_matches: int) -> list[int]:
    """The reset seed of each match of ``MatchBatch.reset_all(seed)``, from ``SeedSequence(seed).spawn``."""
    return [int(child.generate_state(1, np.uint64)[0]) for child in np.random.SeedSequence(seed).spawn(n_matches)]
