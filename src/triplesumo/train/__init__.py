"""Training: the DDPG loop over batched matches, checkpoints, metrics logging."""
