"""``triplesumo.zoo.load("spider")``: the shipped policies (see :mod:`triplesumo.agents.zoo`)."""

from triplesumo.agents.zoo import ZOO_DIR, available, load, make_paper_env, make_policy

__all__ = ["ZOO_DIR", "available", "load", "make_paper_env", "make_policy"]
