"""Write the site's environment pages from the code: ``python docs/gen_env_pages.py``.

One page per scenario (``docs/environments/NAME.md``: ids, the default roster's agents and
spaces, the scenario's documentation, its video) and one overview
(``docs/environments/index.md``: the docstrings of the PettingZoo and Gymnasium views).
The pages are committed so that they read on any Git host too; ``tests/test_docs.py`` fails
when they differ from what this script writes now (``--check`` says the same from the shell).
"""

from __future__ import annotations

import inspect
import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
OUT = DOCS / "environments"
_HEADER = "<!-- Written by docs/gen_env_pages.py from the code; edit the docstrings, then rerun it. -->\n\n"


def markdown(doc: str) -> str:
    """A docstring as Markdown: dedented, Sphinx roles (``:class:`x```) and double backticks as code."""
    text = inspect.cleandoc(doc)
    text = re.sub(r":(?:class|mod|func|meth|attr|data|obj):`~?([^`]+)`", r"`\1`", text)
    return re.sub(r"``([^`]+)``", r"`\1`", text) + "\n"


def _demote(text: str) -> str:
    """Headings one level down (a docstring's ``## Section`` under a page's ``##``)."""
    return re.sub(r"^(#+) ", r"#\1 ", text, flags=re.M)


def overview_page() -> str:
    from triplesumo.envs.parallel import TripleSumoParallelEnv
    from triplesumo.envs.single import TripleSumoEnv
    from triplesumo.rules.scenarios import SCENARIOS

    parallel = (TripleSumoParallelEnv.__doc__ or "").split("\n## Scenarios\n")[0]
    rows = "\n".join(f"| [`{sc.name}`]({sc.name}.md) | `{sc.gym_id}` | `{sc.pettingzoo_name}` | `{sc.learner}` |"
                     for sc in SCENARIOS.values())
    return (f"{_HEADER}# Environments\n\nEvery scenario is one game on the same tatami, seen through the same views: "
            "`triplesumo.parallel_env(scenario=NAME)` (PettingZoo), `gym.make(ID)` (Gymnasium, one learner) and "
            "`triplesumo.vector_env(scenario=NAME)` (all matches and agents as arrays).\n\n"
            "| scenario | Gymnasium id | PettingZoo name | default learner |\n| --- | --- | --- | --- |\n"
            f"{rows}\n\n## The match (`TripleSumoParallelEnv`)\n\n{_demote(markdown(parallel))}\n"
            f"## One learner (`TripleSumoEnv`)\n\n{_demote(markdown(TripleSumoEnv.__doc__ or ''))}")


def _shape(space: object) -> str:
    return str(getattr(space, "shape", "?"))


def scenario_page(name: str) -> str:
    import triplesumo
    from triplesumo.registration import BASE_ID, ELIMINATION_SCENARIOS, PAPER_ID
    from triplesumo.rules.config import RewardConfig
    from triplesumo.rules.rewards import TERMS
    from triplesumo.rules.scenarios import get_scenario

    sc = get_scenario(name)
    env = triplesumo.parallel_env(scenario=name)
    ego = triplesumo.parallel_env(scenario=name, obs_mode="egocentric")
    try:
        sim = env.match.sim  # control ranges as compiled into the model
        agents = [f"| `{spec.name}` | `{spec.team}` | {spec.body} | +-{float(sim.ctrl_high[k].max()):.2f} | "
                  f"{_shape(env.action_space(spec.name))} | {_shape(env.observation_space(spec.name))} | "
                  f"{_shape(ego.observation_space(spec.name))} |"
                  for k, spec in enumerate(env.config.agents)]
    finally:
        env.close()
        ego.close()
    sizes = ", ".join(f"`{k}={v!r}`" for k, v in sc.sizes.items()) or "none"
    fields = ", ".join(f"`{k}={v!r}`" for k, v in sc.fields.items()) or "none (the paper's rules)"
    video = DOCS / f"scenario_{name}.mp4"
    media = (f'<video controls muted loop width="480" src="../scenario_{name}.mp4"></video>\n\n'
             f"A seeded match ([mp4](../scenario_{name}.mp4)).\n\n" if video.exists() else "")
    reward = RewardConfig()
    if name == "paper":
        gym_row = (f"`gym.make({PAPER_ID!r})` (Ant and Spider from the shipped zoo) or `gym.make({BASE_ID!r})` "
                   f"(the others passive unless given), learner `{sc.learner}`")
    else:
        gym_row = f"`gym.make({sc.gym_id!r})`, learner `{sc.learner}` (the others passive unless given)"
    vector = ("Gymnasium's `SyncVectorEnv` of single matches (a learner out ends its own episode)"
              if name in ELIMINATION_SCENARIOS else "the native vector env (all matches step together)")
    return (f"{_HEADER}# `{name}`\n\n{media}"
            "| | |\n| --- | --- |\n"
            f"| PettingZoo | `triplesumo.parallel_env(scenario={name!r})`, name `{sc.pettingzoo_name}` |\n"
            f"| Gymnasium | {gym_row} |\n| `gym.make_vec` | {vector} |\n"
            f"| roster sizes | {sizes} |\n| rule fields | {fields} |\n\n"
            "## Agents and spaces (defaults)\n\n"
            "Actions are `Box(-1, 1, (n,), float32)`, scaled to the agent's control range; observations "
            "`Box(-inf, inf, (n,), float32)` in `obs_mode=\"paper\"` (default) or `\"egocentric\"`.\n\n"
            "| agent | team | body | control range | action | observation (paper) | observation (egocentric) |\n"
            "| --- | --- | --- | --- | --- | --- | --- |\n" + "\n".join(agents) + "\n\n"
            f"Reward terms, reported in `info[agent]` (their sum is the reward): {', '.join(f'`{t}`' for t in TERMS)}; "
            f"defaults win {reward.win:+g}, loss {reward.loss:+g}, still {reward.still:+g} "
            "(`triplesumo.rules.RewardConfig`; formulas on the [overview](index.md#rewards)).\n\n"
            f"{markdown(sc.doc)}")


def pages() -> dict[Path, str]:
    """Every generated page by path."""
    from triplesumo.rules.scenarios import SCENARIOS

    out = {OUT / "index.md": overview_page()}
    out.update({OUT / f"{name}.md": scenario_page(name) for name in SCENARIOS})
    return out


def main(argv: list[str]) -> int:
    stale = [path for path, text in pages().items() if not path.exists() or path.read_text() != text]
    if "--check" in argv:
        for path in stale:
            print(f"out of date: {path.relative_to(DOCS.parent)} (run python docs/gen_env_pages.py)")
        return 1 if stale else 0
    OUT.mkdir(exist_ok=True)
    for path, text in pages().items():
        path.write_text(text)
    print(f"wrote {len(stale)} page(s)" if stale else "pages up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
