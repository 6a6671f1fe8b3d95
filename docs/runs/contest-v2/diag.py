"""Who leaves the ring, from where, after how many steps: N matches of a pair (Bug passive).

Usage: python3 diag.py ANT_POLICY SPIDER_POLICY N SEED (a policy is a file prefix or ``passive``)."""
import collections
import sys
import warnings

import numpy as np

import triplesumo
from triplesumo.agents.policy_file import load_fixed_policy


def edge_of(x: float, y: float) -> str:
    """The edge a torso at (x, y) left the ring through."""
    return "+x" if x > 2 else "-x" if x < -2 else "+y" if y > 2 else "-y"


def main() -> None:
    warnings.simplefilter("ignore")
    ant_p, spider_p, n, seed = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    pol = {name: None if spec == "passive" else load_fixed_policy(spec)[0]
           for name, spec in (("ant", ant_p), ("spider", spider_p))}
    env = triplesumo.parallel_env()
    who: collections.Counter[str] = collections.Counter()
    edges: collections.Counter[tuple[str, str]] = collections.Counter()
    steps = []
    for i in range(n):
        obs, _ = env.reset(seed=seed + i)
        t, info = 0, {}
        while env.agents:
            act = {a: pol[a](obs[a]) if pol.get(a) is not None else np.zeros(8, np.float32) for a in env.agents}
            obs, _, _, _, info = env.step(act)
            t += 1
        out = [a for a in ("ant", "bug", "spider") if info[a]["out_of_ring"]]
        who[",".join(out) or "none"] += 1
        steps.append(t)
        match = env.match
        for a in out:
            x, y = match.sim.torso_positions()[match.agents.index(a), :2]
            edges[(a, edge_of(x, y))] += 1
    print("out:", dict(who), f"mean steps {np.mean(steps):.0f}", "exits:", dict(edges))


if __name__ == "__main__":
    main()
