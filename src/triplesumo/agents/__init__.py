"""Networks and policies that drive agents (actor/critic MLPs, numpy-facing policy wrappers).

Nothing here knows about environments: networks take array sizes, policies take arrays.
"""
