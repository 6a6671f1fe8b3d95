"""Training: the loop of one or more learners (DDPG, TD3, SAC, PPO) over batched matches, self-play leagues,
checkpoints, metrics logging."""
