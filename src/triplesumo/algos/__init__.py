"""Learning algorithms as a library: DDPG, its replay buffer and exploration noise.

Modules are imported explicitly (``triplesumo.algos.ddpg``, ``.replay``, ``.noise``) so that
the numpy-only replay and noise modules do not pull in torch.
"""
