"""Learning algorithms as a library: DDPG, TD3, SAC and PPO, replay and exploration noise.

``base`` (what every learner shares), ``offpolicy`` (the DDPG/TD3/SAC core), ``ddpg``,
``td3``, ``sac``, ``ppo``, ``config`` (shared validation). Modules are imported explicitly
(``triplesumo.algos.ddpg``, ``.replay``, ``.noise``) so that the numpy-only replay and noise
modules do not pull in torch.
"""
