"""How far a SAC learner's twin critics sit from the soft returns its own collecting policy realises.

``python benchmarks/critic_bias.py RUN_DIR [--matches 150] [--seed 777] [--json OUT]`` loads the latest checkpoint of
the SAC run in ``RUN_DIR`` (or ``--checkpoint epoch-N``), plays ``--matches`` matches of the run's own match (its
scenario and the other agents' policies; match ``i`` resets with ``--seed`` + i) with the learner's agent sampling
its stochastic policy, as it collects in training, and compares at every step of the learner the critics'
``Q_1(s, a)`` and ``Q_2(s, a)`` with the soft return realised from there,

    G_t = Σ_{k ≥ 0} γ^k r_{t+k} - α Σ_{j ≥ 1} γ^{jn} log π(a_{t+jn} | s_{t+jn}),

the quantity SAC's n-step soft Q estimates (its target adds the entropy term where it bootstraps), without
bootstrap (matches that end by the time limit are left out: their returns would need one). It prints and writes,
over all steps and over the first ``--early`` steps of each match, the mean realised return and the mean bias
``Q - G`` of the minimum of the two critics (clipped double Q, the default ``pessimism`` 1) and of their mean
(``pessimism`` 0), each with its standard error across matches (the steps of one match are not independent), and
the mean ``|Q_1 - Q_2| / 2``: the premise of the pessimism candidate of ``docs/bench/skill.md``."""
from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np


def soft_returns(rewards: np.ndarray, log_probs: np.ndarray, alpha: float, gamma: float, n_step: int = 1) -> np.ndarray:
    """``G_t = Σ_{k ≥ 0} γ^k r_{t+k} - α Σ_{j ≥ 1} γ^{jn} log π_{t+jn}`` for every step ``t`` of one match that ended by
    a win or a loss (no bootstrap after its last step): the fixed point of SAC's n-step target, which adds the
    entropy term only where it bootstraps, every n steps (n = 1: the soft return of the SAC paper)."""
    rewards, log_probs = np.asarray(rewards, float), np.asarray(log_probs, float)
    if rewards.shape != log_probs.shape or rewards.ndim != 1:
        raise ValueError(f"rewards and log_probs must be two 1-D arrays of one length, got {rewards.shape} and "
                         f"{log_probs.shape}")
    if n_step < 1:
        raise ValueError(f"n_step must be >= 1, got {n_step}")
    steps = len(rewards)
    discounted, entropy = np.zeros(steps + 1), np.zeros(steps + n_step)
    for t in range(steps - 1, -1, -1):
        discounted[t] = rewards[t] + gamma * discounted[t + 1]
        if t + n_step < steps:  # E_t = γ^n (log π_{t+n} + E_{t+n})
            entropy[t] = gamma ** n_step * (log_probs[t + n_step] + entropy[t + n_step])
    return discounted[:steps] - alpha * entropy[:steps]


def bias_table(per_match: list[dict[str, np.ndarray]], early: int) -> dict[str, dict[str, float]]:
    """Mean return, the biases of the critics' minimum and mean, and ``|Q_1 - Q_2| / 2``, each the mean over matches
    of its per-match mean, with the standard error across matches; over all steps and the first ``early``."""
    out = {}
    for name, cut in (("all_steps", None), (f"first_{early}_steps", early)):
        rows = [{k: v[:cut] for k, v in m.items()} for m in per_match]
        cols = {
            "return": [r["g"].mean() for r in rows],
            "bias_min": [(np.minimum(r["q1"], r["q2"]) - r["g"]).mean() for r in rows],
            "bias_mean": [((r["q1"] + r["q2"]) / 2 - r["g"]).mean() for r in rows],
            "half_gap": [(np.abs(r["q1"] - r["q2"]) / 2).mean() for r in rows],
        }
        table: dict[str, float] = {"matches": len(rows), "states": int(sum(len(r["g"]) for r in rows))}
        for key, values in cols.items():
            table[key] = round(float(np.mean(values)), 2)
            table[f"{key}_se"] = round(float(np.std(values, ddof=1) / np.sqrt(len(values))), 2) if len(values) > 1 \
                else float("nan")
        out[name] = table
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", help="a SAC training run's folder (config.json, checkpoints/)")
    parser.add_argument("--checkpoint", default=None, help="epoch-N (default: the latest)")
    parser.add_argument("--matches", type=int, default=150)
    parser.add_argument("--seed", type=int, default=777, help="match i resets with seed + i")
    parser.add_argument("--early", type=int, default=30, help="the opening steps reported on their own")
    parser.add_argument("--json", default=None, help="write the table here")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    import torch

    from triplesumo.agents.zoo import policies_from_pairs
    from triplesumo.algos.sac import SAC
    from triplesumo.envs.match import Match
    from triplesumo.train import checkpoint
    from triplesumo.train.run_folder import config_from_json

    torch.set_num_threads(1)
    run = Path(args.run_dir)
    cfg = config_from_json(json.loads((run / "config.json").read_text()), str(run / "config.json"))
    sac = [agent for agent, algo in cfg.learners().items() if algo == "sac"]
    if len(sac) != 1 or len(cfg.learners()) != 1:
        raise SystemExit(f"{run}: critic_bias reads a run with one SAC learner, this one learns {cfg.learn}")
    agent_name = sac[0]
    folder = checkpoint.find(run, args.checkpoint) if args.checkpoint else checkpoint.latest(run)
    tensors, state, _, _ = checkpoint.load(folder, need_replay=False)
    match = Match(cfg.match_config())
    seat = match.agents.index(agent_name)
    learner = SAC(match.observer.sizes[agent_name], match.action_sizes[seat], cfg.algo_config(agent_name), seed=0)
    prefix = f"{agent_name}."
    learner.load_state_dict({k[len(prefix):]: v for k, v in tensors.items()
                             if k.startswith(prefix) and not k.startswith(f"{prefix}optim.")})
    others = policies_from_pairs(cfg.policies, args.seed, cfg.obs_mode)
    generator = torch.Generator().manual_seed(args.seed)
    alpha, gamma = learner.alpha, learner.config.gamma
    per_match, left_out, t0 = [], 0, time.perf_counter()
    for i in range(args.matches):
        obs, _ = match.reset(seed=args.seed + i)
        steps: list[tuple[float, float, float, float]] = []
        while True:
            actions = np.zeros((match.n_agents, match.action_width))
            for k, name in enumerate(match.agents):
                if k == seat:
                    with torch.no_grad():
                        o = torch.as_tensor(obs[k], dtype=torch.float32)[None]
                        o = learner.obs_norm(o) if learner.obs_norm is not None else o
                        action, log_prob = learner.actor.sample(o, generator)
                        q1, q2 = (float(c(o, action)) for c in learner.critics)
                    actions[k, :match.action_sizes[k]] = action[0].numpy()
                    now = (q1, q2, float(log_prob))
                elif name in others and match.alive[k]:
                    actions[k, :match.action_sizes[k]] = match.check_action(name, others[name](obs[k]))
            result = match.step_array(actions)
            steps.append((*now, float(result.rewards[seat])))
            obs = result.observations
            if result.terminated or result.truncated:
                break
        if result.truncated and not result.terminated:
            left_out += 1
            continue
        q1s, q2s, log_probs, rewards = (np.array(col) for col in zip(*steps, strict=True))
        per_match.append({"q1": q1s, "q2": q2s, "g": soft_returns(rewards, log_probs, alpha, gamma,
                                                                                  learner.config.n_step)})
    if len(per_match) < 2:
        raise SystemExit(f"{run}: {len(per_match)} of {args.matches} matches ended by a win or a loss; need 2")
    table = {"run": str(run), "checkpoint": folder.name, "env_steps": state.get("env_steps"), "alpha": round(alpha, 4),
             "gamma": gamma, "n_step": learner.config.n_step, "pessimism": learner.config.pessimism,
             "seed": args.seed, "time_limit_left_out": left_out, "seconds": round(time.perf_counter() - t0, 1),
             **bias_table(per_match, args.early)}
    for key in ("all_steps", f"first_{args.early}_steps"):
        t = table[key]
        print(f"{key}: {t['matches']} matches, {t['states']} states; return {t['return']:+.1f} ± {t['return_se']:.1f}; "
              f"bias of min Q {t['bias_min']:+.1f} ± {t['bias_min_se']:.1f}; of mean Q {t['bias_mean']:+.1f} ± "
              f"{t['bias_mean_se']:.1f}; |Q1 - Q2| / 2 {t['half_gap']:.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(table, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
