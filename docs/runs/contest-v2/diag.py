"""Who leaves the ring, from where, after how many steps: N matches of a pair (Bug passive)."""
import sys, collections, numpy as np, warnings
warnings.simplefilter("ignore")
import triplesumo
from triplesumo.agents.policy_file import load_fixed_policy
ant_p, spider_p, n, seed = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
pol = {}
for name, spec in (("ant", ant_p), ("spider", spider_p)):
    pol[name] = None if spec == "passive" else load_fixed_policy(spec)[0]
env = triplesumo.parallel_env()
who = collections.Counter(); steps = []; edges = collections.Counter()
for i in range(n):
    obs, _ = env.reset(seed=seed + i)
    t = 0
    while env.agents:
        act = {a: (pol[a](obs[a]) if pol.get(a) is not None else np.zeros(8, np.float32)) for a in env.agents}
        obs, r, term, trunc, info = env.step(act)
        t += 1
    out = [a for a in ("ant", "bug", "spider") if info[a]["out_of_ring"]]
    who[",".join(out) or "none"] += 1
    steps.append(t)
    m = env.match
    for a in out:
        i_a = m.agents.index(a); x, y = m.sim.torso_positions()[i_a, :2]
        edges[(a, "+x" if x > 2 else "-x" if x < -2 else "+y" if y > 2 else "-y")] += 1
print("out:", dict(who), "mean steps %.0f" % np.mean(steps), "exits:", dict(edges))
