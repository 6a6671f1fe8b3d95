"""Adapters to other RL frameworks, each an optional import.

- :mod:`triplesumo.integrations.rllib`: RLlib multi-agent envs and ``AlgorithmConfig``
  factories (needs the ``ray`` extra: ``pip install "triplesumo[ray]"``).

Importing this package imports no framework; each adapter module imports its own.
"""
