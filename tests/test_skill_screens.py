"""benchmarks/skill_screens.py: what it takes from bench skill records, and its pooled statistics."""
from __future__ import annotations

import json
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from conftest import module_from_file

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "skill_screens.py"


def _module() -> ModuleType:
    return module_from_file(SCRIPT)


def _record(curves: dict[int, list[float]], every: int = 25_000) -> dict:
    """A bench skill record in the bench's own layout: one SAC run per seed, an evaluation every ``every``."""
    runs = [{"seed": seed, "evaluations": [{"budget": every * (i + 1), "env_steps": every * (i + 1) + 8 * (i % 2),
                                            "test_mwr": m} for i, m in enumerate(mwr)]}
            for seed, mwr in curves.items()]
    return {"command": "triplesumo bench skill", "algos": {"sac": {"runs": runs}}}


def _write(path: Path, curves: dict[int, list[float]]) -> Path:
    path.write_text(json.dumps(_record(curves)))
    return path


def test_a_seed_gives_its_value_at_the_budget_or_is_censored_when_it_stopped_at_the_target() -> None:
    seed_results = _module().seed_results
    out = seed_results(_record({0: [-0.2, 0.1, 0.25, 0.15], 1: [-0.1, 0.0, 0.05, 0.3], 2: [0.0, 0.21]}),
                       100_000, 0.2, "r.json")
    assert out[0]["value"] == 0.15 and out[0]["reached"]  # reached at 75k, lower again at 100k
    assert out[1]["value"] == 0.3 and out[1]["reached"]
    assert out[2]["value"] is None and out[2]["reached"]  # the bench stopped it at 50k: censored
    not_reached = seed_results(_record({3: [0.0, 0.1, 0.19, 0.199]}), 100_000, 0.2, "r.json")[3]
    assert not_reached == {"value": 0.199, "reached": False, "source": "r.json",
                           "curve": [(25_000, 0.0), (50_000, 0.1), (75_000, 0.19), (100_000, 0.199)]}
    assert not seed_results(_record({4: [0.3, 0.1]}), 50_000, 0.4, "r.json")[4]["reached"]
    with pytest.raises(ValueError, match=r"r\.json: seed 5 has no evaluation at 100,000"):
        seed_results(_record({5: [0.0, 0.1]}), 100_000, 0.2, "r.json")  # stopped early without reaching
    with pytest.raises(ValueError, match=r"x\.json: no runs of ppo"):
        seed_results({"algos": {"ppo": {}}}, 100_000, 0.2, "x.json")
    with pytest.raises(ValueError, match=r"x\.json: not a bench skill record"):
        seed_results({"command": "triplesumo bench train"}, 100_000, 0.2, "x.json")


def test_the_learner_is_the_records_only_one_or_the_one_named() -> None:
    seed_results = _module().seed_results
    td3 = _record({0: [0.0, 0.1, 0.1, 0.3]})
    td3["algos"] = {"td3": td3["algos"]["sac"]}
    assert seed_results(td3, 100_000, 0.2, "t.json")[0]["value"] == 0.3  # its only learner, not SAC
    both = {"algos": {**td3["algos"], **_record({0: [0.0, 0.0, 0.0, -0.1]})["algos"]}}
    with pytest.raises(ValueError, match=r"b\.json: holds td3, sac; name one as FILE@ALGO"):
        seed_results(both, 100_000, 0.2, "b.json")
    assert seed_results(both, 100_000, 0.2, "b.json", "sac")[0]["value"] == -0.1
    assert seed_results(both, 100_000, 0.2, "b.json", "td3")[0]["value"] == 0.3
    with pytest.raises(ValueError, match=r"b\.json: no runs of ppo \(the record holds td3, sac\)"):
        seed_results(both, 100_000, 0.2, "b.json", "ppo")


def test_the_command_line_reads_file_at_algo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    both = _record({0: [0.0, 0.1, 0.1, 0.3], 1: [0.0, 0.0, 0.0, 0.1]})
    both["algos"]["td3"] = _record({0: [0.0, 0.0, 0.0, -0.1], 1: [0.0, 0.0, 0.2, 0.0]})["algos"]["sac"]
    path = tmp_path / "both.json"
    path.write_text(json.dumps(both))
    out = _module().main(["--record", f"sac={path}@sac", f"td3={path}@td3", "--json", str(tmp_path / "o.json")])
    rows = {r["candidate"]: r for r in out["rows"]}
    assert rows["sac"]["values"] == {0: 0.3, 1: 0.1} and rows["td3"]["values"] == {0: -0.1, 1: 0.0}
    assert rows["td3"]["reached"] == 1 and out["records"][1] == ["td3", f"{path}@td3"]
    with pytest.raises(SystemExit):
        _module().main(["--record", f"x={path}"])  # two learners, none named
    assert "holds sac, td3; name one as FILE@ALGO" in capsys.readouterr().err


def test_gather_joins_a_candidates_files_and_refuses_two_curves_for_one_seed(tmp_path: Path) -> None:
    gather = _module().gather
    a = _write(tmp_path / "a.json", {0: [0.0, 0.1, 0.1, 0.1], 1: [0.0, 0.0, 0.0, 0.2]})
    b = _write(tmp_path / "b.json", {1: [0.0, 0.0, 0.0, 0.2], 2: [0.1, 0.1, 0.1, -0.1]})
    out = gather([("x", a, None), ("x", b, None), ("y", b, None)], 100_000, 0.2)
    assert sorted(out["x"]) == [0, 1, 2] and sorted(out["y"]) == [1, 2]
    assert out["x"][1]["source"] == str(a)  # the first file that gave the seed
    c = _write(tmp_path / "c.json", {0: [0.0, 0.1, 0.1, 0.3]})
    with pytest.raises(ValueError, match=r"x: seed 0 has two different curves, in .*a\.json and .*c\.json"):
        gather([("x", a, None), ("x", c, None)], 100_000, 0.2)
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ValueError, match=r"bad\.json: cannot read"):
        gather([("x", tmp_path / "bad.json", None)], 100_000, 0.2)


def test_the_share_at_the_target_and_the_chance_of_a_three_seed_median() -> None:
    m = _module()
    assert m.median_of_three(0.5) == 0.5 and m.median_of_three(0.0) == 0.0 and m.median_of_three(1.0) == 1.0
    assert m.median_of_three(0.4) == pytest.approx(3 * 0.4 ** 2 * 0.6 + 0.4 ** 3)  # two of three, or all three
    q = m.reach_share(4, 11)
    assert q["share"] == pytest.approx(4 / 11)
    from scipy.stats import beta

    # Clopper-Pearson by its definition: the beta quantiles at 2.5% and 97.5%
    assert q["ci"] == pytest.approx([beta.ppf(0.025, 4, 8), beta.ppf(0.975, 5, 7)])
    assert q["median_of_3_ci"] == pytest.approx([m.median_of_three(c) for c in q["ci"]])
    assert q["median_of_3_ci"][0] < q["median_of_3"] < q["median_of_3_ci"][1]
    assert m.reach_share(0, 4)["ci"][0] == 0.0 and m.reach_share(4, 4)["ci"][1] == 1.0


def test_pooled_statistics_match_a_hand_computation() -> None:
    m = _module()
    groups = {"a": [0.1, 0.3, 0.2], "b": [-0.1, 0.1], "c": [0.5, 0.4, 0.6, 0.7]}
    results = {label: {s: {"value": v, "reached": v >= 0.2, "curve": [], "source": ""} for s, v in enumerate(vs)}
               for label, vs in groups.items()}
    results["d"] = {0: {"value": None, "reached": True, "curve": [], "source": ""},
                    1: {"value": 0.0, "reached": False, "curve": [], "source": ""}}  # one value: not in the ANOVA
    out = m.analyse(results)
    rows = {r["candidate"]: r for r in out["rows"]}
    assert rows["c"]["mean"] == pytest.approx(0.55) and rows["c"]["reached"] == 4
    assert rows["a"]["reach"]["share"] == pytest.approx(2 / 3) and rows["c"]["reach"]["median_of_3"] == 1.0
    assert rows["d"]["censored"] == 1 and rows["d"]["mean"] == 0.0 and rows["d"]["reached"] == 1
    p = out["pooled"]
    assert (p["candidates"], p["values"], p["runs"], p["reached"]) == (3, 9, 11, 7)
    values = [np.array(v) for v in groups.values()]
    n, k = 9, 3
    grand = np.concatenate(values).mean()
    msw = sum(((v - v.mean()) ** 2).sum() for v in values) / (n - k)
    msb = sum(len(v) * (v.mean() - grand) ** 2 for v in values) / (k - 1)
    n0 = (n - (3 ** 2 + 2 ** 2 + 4 ** 2) / n) / (k - 1)
    assert p["within_sd"] == pytest.approx(math.sqrt(msw))
    assert p["f"] == pytest.approx(msb / msw)
    assert p["between_sd"] == pytest.approx(math.sqrt((msb - msw) / n0))
    assert 0 < p["p"] < 0.01  # c is far above a and b
    same = {label: {s: {"value": v, "reached": False, "curve": [], "source": ""}
                    for s, v in enumerate([0.0, 0.2, 0.1])} for label in "xyz"}
    flat = m.analyse(same)["pooled"]
    assert flat["f"] == pytest.approx(0.0) and flat["between_sd"] == 0.0  # truncated at 0, not negative


def test_seeds_per_arm_is_the_normal_approximation() -> None:
    seeds_per_arm = _module().seeds_per_arm
    z = 1.959964 + 0.841621
    assert seeds_per_arm(0.137, 0.10) == math.ceil(2 * z * z * 0.137 ** 2 / 0.01) == 30
    assert seeds_per_arm(0.137, 0.05) == math.ceil(2 * z * z * 0.137 ** 2 / 0.0025) == 118  # half the lift: 4x
    assert seeds_per_arm(0.2, 0.1, power=0.9) > seeds_per_arm(0.2, 0.1)


def test_the_script_reads_the_default_recipes_committed_record_and_writes_json(tmp_path: Path,
                                                                             capsys: pytest.CaptureFixture) -> None:
    m = _module()
    other = _write(tmp_path / "o.json", {0: [0.0, 0.0, 0.0, 0.05], 1: [0.0, 0.0, 0.0, -0.05]})
    out = tmp_path / "screens.json"
    result = m.main(["--record", f"default={ROOT / 'docs/bench/skill_idle.json'}", f"other={other}",
                     "--json", str(out)])
    rows = {r["candidate"]: r for r in result["rows"]}
    assert rows["default"]["values"] == {0: 0.355, 1: 0.04, 2: 0.18} and rows["default"]["reached"] == 1
    assert json.loads(out.read_text())["pooled"]["values"] == 5
    printed = capsys.readouterr().out
    assert "s0:+0.355 s1:+0.040 s2:+0.180" in printed and "1 of 5 seeds reached +0.20 by 100,000" in printed
    with pytest.raises(SystemExit):
        m.main(["--record", "no-equals-sign"])


def test_pairing_with_a_baseline_uses_the_seeds_both_have_and_matches_a_hand_computation(tmp_path: Path,
                                                                                          capsys: pytest.CaptureFixture
                                                                                          ) -> None:
    m = _module()

    def seeds(values: dict[int, float | None]) -> dict[int, dict]:
        return {k: {"value": v, "reached": v is None, "curve": [], "source": ""} for k, v in values.items()}

    results = {"base": seeds({0: 0.1, 1: 0.2, 2: -0.1, 3: 0.0}), "a": seeds({0: 0.3, 1: 0.3, 2: None, 5: 0.9}),
               "b": seeds({0: 0.0, 1: 0.0, 2: 0.1, 3: 0.2}), "c": seeds({3: 0.5})}
    out = m.paired(results, "base")
    da, db = np.array([0.2, 0.1]), np.array([-0.1, -0.2, 0.2, 0.2])  # seed 2 of a is censored, seed 5 unpaired
    assert out["mean_difference"] == {"a": pytest.approx(0.15), "b": pytest.approx(0.025), "c": pytest.approx(0.5)}
    sd = math.sqrt((((da - da.mean()) ** 2).sum() + ((db - db.mean()) ** 2).sum()) / (1 + 3))  # c: one pair only
    assert out["pairs"] == 6 and out["difference_sd"] == pytest.approx(sd)
    z = 1.959964 + 0.841621
    assert out["pairs_needed"]["0.10"] == math.ceil(z * z * sd * sd / 0.01)
    with pytest.raises(ValueError, match=r"baseline 'nope' is not one of the labels \['a', 'b', 'base', 'c'\]"):
        m.paired(results, "nope")
    a = _write(tmp_path / "a.json", {0: [0.0, 0.0, 0.0, 0.05], 1: [0.0, 0.0, 0.0, -0.05]})
    b = _write(tmp_path / "b.json", {0: [0.0, 0.0, 0.0, 0.25], 1: [0.0, 0.0, 0.0, 0.0]})
    c = _write(tmp_path / "c.json", {0: [0.0, 0.0, 0.0, 0.1], 1: [0.0, 0.0, 0.0, 0.1]})
    result = m.main(["--record", f"a={a}", f"b={b}", f"c={c}", "--baseline", "a"])
    assert result["paired"]["mean_difference"] == {"b": pytest.approx(0.125), "c": pytest.approx(0.1)}
    assert "paired with a on the same seed (4 pairs)" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        m.main(["--record", f"a={a}", "--baseline", "x"])
