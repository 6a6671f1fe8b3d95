"""The per-match account of who leaves the ring (triplesumo.evaluation.exits)."""
from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest

from triplesumo.agents.zoo import make_policy
from triplesumo.envs.match import Match
from triplesumo.evaluation.evaluate import play_test_epochs
from triplesumo.evaluation.exits import edge_of, exit_rows, geom_owners, summarize_exits, touching, upright
from triplesumo.train.config import TrainConfig


def test_edge_of_names_the_axis_furthest_out() -> None:
    assert [edge_of(2.1, 0.5), edge_of(-2.3, 1.9), edge_of(0.2, 2.05), edge_of(1.0, -2.4)] == ["+x", "-x", "+y", "-y"]


def test_upright_reads_the_torso_axis() -> None:
    assert upright(np.array([1.0, 0.0, 0.0, 0.0])) == 1.0
    assert upright(np.array([0.0, 1.0, 0.0, 0.0])) == -1.0  # half a turn about x: upside down
    assert upright(np.array([np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0])) == pytest.approx(0.0)  # on its side


def test_touching_sees_two_overlapping_agents_and_only_them() -> None:
    match = Match(TrainConfig().match_config())
    match.reset(seed=3)
    ant, bug, spider = (match.sim.agents[match.agents.index(a)] for a in ("ant", "bug", "spider"))
    owner = geom_owners(match)
    mujoco.mj_forward(match.model, match.data)
    assert not touching(match, owner).any()  # the start: apart, in the air
    qpos = match.data.qpos
    qpos[bug.root_qpos:bug.root_qpos + 3] = qpos[spider.root_qpos:spider.root_qpos + 3] + [0.15, 0.0, 0.0]
    mujoco.mj_forward(match.model, match.data)
    touch = touching(match, owner)
    b, s, a = (match.agents.index(n) for n in ("bug", "spider", "ant"))
    assert touch[b, s] and touch[s, b]
    assert not touch[a].any() and not touch.diagonal().any()


@pytest.mark.slow  # 4 s alone, 10 s on the loaded shared 2-core box
def test_rows_agree_with_the_projects_test_epochs_and_classify_each_end() -> None:
    warnings.simplefilter("ignore")
    cfg = TrainConfig(steps_per_epoch=150)
    match_cfg = cfg.match_config()
    pol = {a: make_policy(f"zoo:{a}", frozen=True) for a in ("ant", "bug", "spider")}
    rows = exit_rows(pol, 4, 10_000, match_cfg)
    reference = play_test_epochs(pol["bug"], {"ant": pol["ant"], "spider": pol["spider"]}, "bug", 4, 10_000,
                                 match_cfg, n_envs=4, n_threads=1)
    assert [(r["outcome"], r["steps"]) for r in rows] == [(r["outcome"], r["steps"]) for r in reference]
    ends = {r["first_out"] for r in rows}
    assert ends - {"none"}, "the shipped pair and Bug end some of 4 matches within 150 steps"
    for r in rows:
        out = r["first_out"].split("+")
        expected = "draw" if out == ["none"] else "win" if out == ["spider"] else "loss"
        assert r["outcome"] == expected, r
        assert (r["steps"] == 150) == (out == ["none"])
        assert r["self_exit"] == (out != ["none"] and r["pushed_by"] == "")
        assert len(r["edge"].split(";")) == len(out) or out == ["none"]
        if "bug" in out:
            assert r["focus_end_radius"] > 1.0 and r["focus_edge"] == r["edge"].split(";")[out.index("bug")]
        else:
            assert r["focus_end_radius"] <= 1.0
        for other in ("ant", "spider"):
            first, steps = r[f"focus_first_touch_{other}"], r[f"focus_touch_steps_{other}"]
            assert (first < 0) == (steps == 0) and steps <= r["steps"] and first <= r["steps"]
        assert r["focus_path"] >= r["focus_travel"] and -1 <= r["focus_end_upright"] <= 1
        assert (r["focus_flipped"] < 0) or r["focus_flipped"] <= r["steps"]


def test_summary_counts_self_exits_pushes_of_the_partner_and_contacts() -> None:
    def row(outcome: str, out: str, by: str, touch: int, steps: int = 100) -> dict[str, object]:
        return {"outcome": outcome, "steps": steps, "first_out": out, "pushed_by": by,
                "self_exit": out != "none" and by == "", "focus_first_touch_spider": touch,
                "focus_mean_dist_spider": 1.0, "focus_end_radius": 0.5, "focus_touch_steps_spider": max(touch, 0),
                "focus_path": 2.0, "focus_flipped": 5 if out == "bug" else -1}

    rows = [row("loss", "bug", "", -1, 40),           # Bug walks out alone
            row("loss", "ant", "bug+spider", 10, 80),  # Bug helps push its partner out
            row("win", "spider", "ant+bug", 20, 120),  # Bug among the pushers of Spider
            row("draw", "none", "", 30, 500)]
    s = summarize_exits(rows)
    assert s["mwr"] == pytest.approx(-0.25)
    assert (s["bug_out"], s["ant_out"], s["spider_out"], s["none_out"]) == (0.25, 0.25, 0.25, 0.25)
    assert s["bug_self_exit"] == 0.25 and s["bug_out_touched_by_spider"] == 0.0
    assert s["ant_self_exit"] == 0.0 and s["spider_self_exit"] == 0.0
    assert s["bug_pushed_ant_out"] == 0.25 and s["bug_pushed_spider_out"] == 0.25
    assert s["bug_touched_spider"] == 0.75 and s["median_first_touch_spider"] == 20
    assert s["median_exit_step"] == 80
    assert (s["median_step_bug_out"], s["median_step_ant_out"], s["median_step_spider_out"]) == (40, 80, 120)
    assert s["flipped"] == 0.25 and s["median_touch_steps_spider"] == 15
    with pytest.raises(ValueError, match="at least one row"):
        summarize_exits([])
    assert np.isfinite(s["mean_dist_spider"])


def test_skill_diagnosis_plays_the_pair_it_is_given(tmp_path) -> None:
    """``--pair`` replaces the bench's zoo pair: with every agent still, nobody leaves and every match is a draw;
    ``--policy`` given twice plays both (the second does not replace the first)."""
    import json
    import runpy
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "skill_diagnosis.py"
    main = runpy.run_path(str(script))["main"]
    assert main(["--policy", "still=passive", "--epochs", "2", "--pair", "ant=passive", "spider=passive",
                 "--policy", "again=passive", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert sorted(summary) == ["again", "still"]
    s = summary["still"]
    assert (s["matches"], s["mwr"], s["none_out"], s["ant_out"], s["spider_out"]) == (2, 0.0, 1.0, 0.0, 0.0)


def test_skill_diagnosis_snapshots_groups_policies_by_env_steps(tmp_path) -> None:
    """``--snapshots`` groups ``GROUP-ENVSTEPS`` labels, orders them by env steps, and writes their spread and a
    plot; a label without env steps is left out, and a folder without a summary is refused by name."""
    import json
    import runpy
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "skill_diagnosis.py"
    main = runpy.run_path(str(script))["main"]
    png = tmp_path / "snap.png"
    with pytest.raises(SystemExit, match="summary.json: no summary"):
        main(["--out", str(tmp_path), "--snapshots", str(png)])
    summary = {"s0-200": {"mwr": 0.3}, "s0-100": {"mwr": 0.1}, "s0-150": {"mwr": -0.1}, "s1-90": {"mwr": 0.2},
               "skilled": {"mwr": 0.5}}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert main(["--out", str(tmp_path), "--snapshots", str(png), "--target", "0.2"]) == 0
    stats = json.loads((tmp_path / "snapshots.json").read_text())
    assert sorted(stats) == ["s0", "s1"]
    s0 = stats["s0"]
    assert s0["env_steps"] == [100, 150, 200] and s0["mwr"] == [0.1, -0.1, 0.3]
    assert s0["mean"] == pytest.approx(0.1, abs=1e-4) and s0["sd"] == pytest.approx(0.2, abs=1e-4)
    assert (s0["min"], s0["max"], s0["share_at_target"]) == (-0.1, 0.3, pytest.approx(1 / 3, abs=1e-4))
    assert stats["s1"]["sd"] is None and stats["s1"]["share_at_target"] == 1.0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
