"""Adapters to other RL frameworks, each an optional import.

- :mod:`triplesumo.integrations.sb3`: a Stable-Baselines3 ``VecEnv`` over the batched
  matches (needs the ``sb3`` extra).
- :mod:`triplesumo.integrations.rllib`: RLlib multi-agent envs and ``AlgorithmConfig``
  factories (needs the ``ray`` extra: ``pip install "triplesumo[ray]"``).
- :mod:`triplesumo.integrations.ray_tasks`: test epochs played as Ray tasks.

Importing this package imports no framework; each adapter module imports its own.
"""
