"""What walking straight at an opponent pays, per agent, on N fair starts (docs/CONTEST.md, "Why the Spider does not
push"): the self-velocity term of 0.3 m/s straight at the target, everyone else still, with the paper's per-axis sign
and with a dead zone. Usage: python3 axis_signs.py [N] [DEAD_ZONE]"""
import sys
from collections import Counter

import numpy as np

import triplesumo
from triplesumo.model import PAPER_AGENTS
from triplesumo.rules import RewardConfig, Teams
from triplesumo.rules.rewards import RewardRule

n, dead = (int(sys.argv[1]) if len(sys.argv) > 1 else 200), (float(sys.argv[2]) if len(sys.argv) > 2 else 0.25)
env, speed = triplesumo.parallel_env(), 0.3
pairs = (("spider", "ant"), ("spider", "bug"), ("ant", "spider"), ("bug", "spider"))
paid = {(z, p): Counter() for z in (0.0, dead) for p in pairs}
for seed in range(n):
    env.reset(seed=seed)
    agents, pos = list(env.match.agents), env.match.sim.torso_positions()[:, :2].astype(np.float64)
    for z in (0.0, dead):
        cfg = RewardConfig(axis_dead_zone=z)
        rule = RewardRule(Teams.from_agents(PAPER_AGENTS), cfg)
        for who, target in pairs:
            i, j = agents.index(who), agents.index(target)
            vel = np.zeros((len(agents), 3))
            vel[i, :2] = speed * (pos[j] - pos[i]) / np.linalg.norm(pos[j] - pos[i])
            share = rule.dense(pos.tolist(), vel.tolist())[i][1] / (cfg.self_velocity * speed)
            paid[z, (who, target)][round(share, 1)] += 1
print(f"self-velocity term for walking at the target, as a share of C2 x speed, over {n} fair starts (count per value)")
for (z, (who, target)), c in paid.items():
    print(f"dead zone {z:4.2f}  {who:6s} -> {target:6s}  {dict(sorted(c.items()))}")
