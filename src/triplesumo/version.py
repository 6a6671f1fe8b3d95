"""The package's version and the envs' behaviour version, at the bottom of the layers.

Every layer may read them (the ids in :mod:`triplesumo.registration`, run records, scenario
names); kept out of ``triplesumo/__init__``, which registers the Gymnasium ids on import,
so that reading a version never imports gymnasium.
"""

from __future__ import annotations

__version__ = "0.2.0"
ENV_VERSION = "v2"
"""Version of the envs' behaviour, in every id (``TripleSumo-v2``, ``triplesumo_v2``); the history is in
:class:`triplesumo.envs.parallel.TripleSumoParallelEnv`."""
