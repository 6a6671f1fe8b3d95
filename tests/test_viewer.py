"""Match pages (``triplesumo view``, ``play/replay --html``, ``evaluate --record-html``): the page draws what
MuJoCo computed. Poses read back from the page's HTML equal the re-simulation body by body; a real headless
Chromium's screenshot puts each agent's silhouette where MuJoCo's own render of the same frame and camera puts
it; bad match files are refused by name and write nothing."""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pytest

from triplesumo.cli import main
from triplesumo.evaluation.recording import MatchFile, MatchFileError, resimulate
from triplesumo.evaluation.viewer import GEOM_TYPES, PAGE_FORMAT, ViewConfig, read_page_data, write_page
from triplesumo.rules import rewards as rules_rewards
from triplesumo.rules.scenarios import scenarios

SCENARIOS = ("paper", "ffa", "pursuit", "2v2", "bodies")
STEPS = 12


def _record(folder: Path, scenario: str, steps: int = STEPS, policies: str = "*=random", seed: int = 3) -> Path:
    path = folder / f"{scenario}.npz"
    assert main(["play", "--scenario", scenario, "--policies", policies, "--seed", str(seed),
                 "--max-steps", str(steps), "--record", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def matches(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A short recorded match of every scenario, random policies."""
    folder = tmp_path_factory.mktemp("matches")
    return {s: _record(folder, s) for s in SCENARIOS}


def _page(tmp_path: Path, match: Path, *extra: str) -> tuple[Path, dict]:
    out = tmp_path / f"{match.stem}.html"
    assert main(["view", str(match), "--out", str(out), *extra]) == 0
    return out, read_page_data(out.read_text(encoding="utf-8"))


def test_every_scenario_is_a_scenario_the_page_builder_is_tested_on() -> None:
    assert set(scenarios()) == set(SCENARIOS)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_every_scenario_gets_a_page_whose_poses_are_the_resimulation_body_by_body(
        scenario: str, matches: dict[str, Path], tmp_path: Path) -> None:
    record = MatchFile.load(matches[scenario])
    out, data = _page(tmp_path, matches[scenario])
    assert data["format"] == PAGE_FORMAT and data["steps"] == record.steps
    assert [a["name"] for a in data["agents"]] == list(record.config.agent_names)
    assert [a["rgba"] for a in data["agents"]] == [list(a.rgba) for a in record.config.agents]
    assert data["frames"] == list(range(record.steps + 1))
    # the re-simulation, body by body and frame by frame, as float32
    for t, match in enumerate(resimulate(record)):
        model = match.model
        if t == 0:  # the scene: every geom of the compiled model, as MuJoCo has it
            assert data["bodies"] == [model.body(b).name for b in range(1, model.nbody)
                                      if np.any(model.geom_bodyid == b)]
            assert len(data["geoms"]) == model.ngeom
            for g, geom in enumerate(data["geoms"]):
                assert geom["name"] == model.geom(g).name
                assert geom["type"] == GEOM_TYPES[mujoco.mjtGeom(int(model.geom_type[g]))]
                np.testing.assert_allclose(geom["size"], model.geom_size[g], atol=1e-6)
                assert geom["pos"] == model.geom_pos[g].tolist() and geom["quat"] == model.geom_quat[g].tolist()
                body = model.geom_bodyid[g]
                assert geom["body"] == (data["bodies"].index(model.body(body).name) if body else -1)
            ids = [model.body(name).id for name in data["bodies"]]
        np.testing.assert_array_equal(data["poses"][t, :, :3], match.data.xpos[ids].astype(np.float32))
        np.testing.assert_array_equal(data["poses"][t, :, 3:], match.data.xquat[ids].astype(np.float32))
    assert t == record.steps
    # the bodies move: the page is not one frame repeated
    assert np.abs(data["poses"][-1] - data["poses"][0]).max() > 1e-3
    # the page loads nothing from anywhere
    text = out.read_text(encoding="utf-8")
    assert not re.search(r"<script[^>]+src=|<link[^>]+href=|<img[^>]+src=|@import", text)
    assert text.count("var THREE=") == 1


def test_the_reward_terms_on_the_timeline_are_the_rules(matches: dict[str, Path], tmp_path: Path) -> None:
    record = MatchFile.load(matches["paper"])
    _, data = _page(tmp_path, matches["paper"])
    assert data["terms"] == list(rules_rewards.TERMS)
    from triplesumo.evaluation.recording import resimulate_steps

    for t, (_, result) in enumerate(resimulate_steps(record)):
        if result is None:
            continue
        for i, info in enumerate(result.infos):
            np.testing.assert_array_equal(data["rewards"][t - 1, i],
                                          np.array([info[k] for k in rules_rewards.TERMS], dtype=np.float32))
            assert abs(float(data["rewards"][t - 1, i].sum()) - result.rewards[i]) < 1e-3
    assert np.abs(data["rewards"]).sum() > 0


def test_a_stride_keeps_every_kth_frame_and_the_last(matches: dict[str, Path], tmp_path: Path) -> None:
    _, full = _page(tmp_path, matches["ffa"])
    small_dir = tmp_path / "stride"
    small_dir.mkdir()
    _, small = _page(small_dir, matches["ffa"], "--stride", "5")
    assert small["frames"] == [0, 5, 10, STEPS]
    np.testing.assert_array_equal(small["poses"], full["poses"][[0, 5, 10, STEPS]])


def test_a_500_step_three_agent_page_is_under_3_mb(tmp_path: Path) -> None:
    match = _record(tmp_path, "paper", steps=500, policies="*=passive")
    assert MatchFile.load(match).steps == 500
    out, data = _page(tmp_path, match)
    assert len(data["agents"]) == 3 and len(data["frames"]) == 501
    assert out.stat().st_size <= 3_000_000


# --------------------------------------------------------------------------- where pages are written
def test_play_and_replay_write_pages_of_the_match_they_played(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    page, npz = tmp_path / "p.html", tmp_path / "p.npz"
    assert main(["play", "--scenario", "pursuit", "--max-steps", "9", "--seed", "4", "--record", str(npz),
                 "--html", str(page)]) == 0
    assert f"page: {page}" in capsys.readouterr().out
    again = tmp_path / "r.html"
    assert main(["replay", str(npz), "--html", str(again)]) == 0
    assert f"page: {again}" in capsys.readouterr().out
    played, replayed = (read_page_data(p.read_text(encoding="utf-8")) for p in (page, again))
    assert played["steps"] == MatchFile.load(npz).steps == replayed["steps"]
    np.testing.assert_array_equal(played["poses"], replayed["poses"])
    # without --record, play keeps no match file
    alone = tmp_path / "alone" / "a.html"
    assert main(["play", "--max-steps", "5", "--html", str(alone)]) == 0
    assert [p.name for p in alone.parent.iterdir()] == ["a.html"]


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_evaluate_record_html_writes_pages_beside_the_match_files(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ev"
    assert main(["evaluate", "--policy", "random", "--epochs", "3", "--steps-per-epoch", "8", "--n-envs", "2",
                 "--record-html", "2", "--out", str(out), "--no-progress"]) == 0
    assert "match pages:" in capsys.readouterr().out
    for label in ("trained", "passive", "random"):
        pages = sorted(p.name for p in (out / label / "matches").glob("*.html"))
        assert pages == ["epoch_00001.html", "epoch_00002.html"]
        data = read_page_data((out / label / "matches" / "epoch_00002.html").read_text(encoding="utf-8"))
        assert data["steps"] == MatchFile.load(out / label / "matches" / "epoch_00002.npz").steps


# --------------------------------------------------------------------------- refused inputs
def test_corrupt_foreign_and_altered_match_files_are_refused_by_name_and_write_nothing(
        matches: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = matches["paper"]
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(good.read_bytes()[:300])
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, weights=np.zeros(3))
    altered = tmp_path / "altered.npz"
    record = MatchFile.load(good)
    states = record.states.copy()
    states[5, 3] += 1e-3  # a torso moved by a millimetre at step 5: the re-simulation parts from it
    dataclasses.replace(record, states=states).save(altered)
    for bad, why in ((corrupt, "not a readable .npz match file"), (foreign, "not a TripleSumo match file"),
                     (altered, "replay differs from the recording at step 5"),
                     (tmp_path / "missing.npz", "no match file")):
        out = tmp_path / f"{bad.stem}.html"
        assert main(["view", str(bad), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"triplesumo view: error: {bad}" in err or f"no match file {bad}" in err
        assert why in err
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["altered.npz", "corrupt.npz", "foreign.npz"]
    # the altered file's recorded states can still be drawn, on request, without the rules' terms
    out = tmp_path / "states.html"
    assert main(["view", str(altered), "--out", str(out), "--no-verify"]) == 0
    data = read_page_data(out.read_text(encoding="utf-8"))
    assert data["verified"] is False and data["terms"] == [] and data["rewards"] == ""
    with pytest.raises(MatchFileError, match=str(altered)):
        write_page(MatchFile.load(altered), tmp_path / "x.html", source=altered)
    assert not (tmp_path / "x.html").exists()


def test_a_page_path_must_end_in_html(matches: dict[str, Path], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match=r"ViewConfig.out must be a .html path"):
        ViewConfig(out="page.htm")
    assert main(["view", str(matches["paper"]), "--out", str(tmp_path / "page.png")]) == 2
    assert "must be a .html path" in capsys.readouterr().err
    assert main(["play", "--html", str(tmp_path / "m.mp4")]) == 2
    assert "PlayConfig.html must be a .html path" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- a real browser
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (Debian: apt-get install chromium); "
                                                             "the browser checks of the match page need it")


def _chromium(tmp_path: Path, url: str, *args: str, size: int = 320) -> subprocess.CompletedProcess[str]:
    assert CHROMIUM is not None
    return subprocess.run([CHROMIUM, "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
                           "--enable-unsafe-swiftshader", "--hide-scrollbars", "--force-device-scale-factor=1",
                           f"--user-data-dir={tmp_path / 'profile'}", f"--window-size={size},{size}",
                           "--virtual-time-budget=4000", *args, url],
                          capture_output=True, text=True, timeout=120, check=False)


@needs_chromium
def test_the_page_runs_in_chromium_with_its_controls_and_overlays(matches: dict[str, Path], tmp_path: Path) -> None:
    title = "2v2 </script><!--<script> & co"  # text that would end or confuse an inline script, were it not escaped
    out, data = _page(tmp_path, matches["2v2"], "--title", title)
    assert data["title"] == title
    done = _chromium(tmp_path, f"{out.as_uri()}?frame=6&camera=follow:bug", "--dump-dom", size=900)
    dom = done.stdout
    assert "\u00b7 ready</title>" in dom, done.stderr[-2000:]  # the script ran to its end without an exception
    assert "2v2 &lt;/script&gt;&lt;!--&lt;script&gt; &amp; co</h1>" in dom
    assert "step 6 / 12" in dom
    assert dom.count('class="label"') == 4 and dom.count("<canvas") == 1 + 4  # the scene, a timeline per agent
    assert "opponent v" in dom and "outcome" in dom  # the reward terms beside the timelines


@needs_chromium
@pytest.mark.parametrize(("scenario", "step"), [("paper", 7), ("bodies", STEPS)])
def test_each_agent_lands_where_mujoco_renders_it(scenario: str, step: int, matches: dict[str, Path],
                                                  tmp_path: Path) -> None:
    """The page's screenshot (unlit colours, the model's overview camera) against MuJoCo's segmentation render of
    the same frame and camera: per agent, the intersection over union of the two silhouettes and the distance of
    their centroids."""
    import imageio.v2 as imageio

    record = MatchFile.load(matches[scenario])
    out, _ = _page(tmp_path, matches[scenario])
    shot = tmp_path / "shot.png"
    done = _chromium(tmp_path, f"{out.as_uri()}?frame={step}&camera=overview&bare=1&flat=1",
                     f"--screenshot={shot}")
    assert shot.is_file(), done.stderr[-2000:]
    pixels = imageio.imread(shot)[..., :3].astype(np.int16)
    height, width = pixels.shape[:2]
    assert (height, width) == (320, 320)
    match = next(m for t, m in enumerate(resimulate(record)) if t == step)
    model = match.model
    with mujoco.Renderer(model, height, width) as renderer:
        renderer.enable_segmentation_rendering()
        renderer.update_scene(match.data, camera="overview")
        seg = renderer.render()
    owner = np.full(model.ngeom + 1, -1)
    for g in range(model.ngeom):
        name = model.body(int(model.geom_bodyid[g])).name.split("/")[0]
        if name in match.agents:
            owner[g] = match.agents.index(name)
    is_geom = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
    mujoco_owner = np.where(is_geom, owner[np.where(is_geom, seg[..., 0], model.ngeom)], -1)
    colours = np.array([[round(255 * c) for c in a.rgba[:3]] for a in record.config.agents])
    # each page pixel goes to the agent whose colour it is (unlit: the colour itself, to antialiasing)
    nearest = np.abs(pixels[:, :, None, :] - colours[None, None]).max(axis=-1)
    page_owner = np.where(nearest.min(axis=-1) <= 8, nearest.argmin(axis=-1), -1)
    for k, agent in enumerate(match.agents):
        ours, theirs = page_owner == k, mujoco_owner == k
        assert theirs.sum() > 300, f"{agent} is not in MuJoCo's view"
        iou = (ours & theirs).sum() / (ours | theirs).sum()
        centroid = np.linalg.norm(np.argwhere(ours).mean(axis=0) - np.argwhere(theirs).mean(axis=0))
        assert iou >= 0.97, f"{agent}: silhouette IoU {iou:.3f}"
        assert centroid <= 0.5, f"{agent}: centroids {centroid:.2f} px apart"


# --------------------------------------------------------------------------- the docs site's match
DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_the_docs_page_embeds_the_shipped_teams_win_drawn_from_its_match_file() -> None:
    page, source = DOCS / "matches" / "shipped-team-win.html", DOCS / "matches" / "shipped-team-win.npz"
    assert page.stat().st_size < 1_500_000
    assert 'src="matches/shipped-team-win.html' in (DOCS / "viewer.md").read_text(encoding="utf-8")
    record = MatchFile.load(source)
    assert record.policies == {"ant": "zoo:ant", "bug": "zoo:bug", "spider": "zoo:spider"}
    assert record.outcomes == {"ant": "win", "bug": "win", "spider": "loss"}
    data = read_page_data(page.read_text(encoding="utf-8"))
    assert data["steps"] == record.steps
    for t, match in enumerate(resimulate(record)):
        ids = [match.model.body(name).id for name in data["bodies"]]
        np.testing.assert_array_equal(data["poses"][t], np.concatenate(
            [match.data.xpos[ids], match.data.xquat[ids]], axis=1).astype(np.float32))
