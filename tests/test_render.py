"""Headless ``rgb_array`` frames (EGL; MUJOCO_GL is set in conftest.py)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from triplesumo import TripleSumoEnv, parallel_env


def test_rgb_array_frames_show_the_match() -> None:
    env = parallel_env(render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0)
    first = env.render()
    assert first.shape == (120, 160, 3)
    assert first.dtype == np.uint8
    assert first.std() > 10.0  # not a blank or constant frame
    # the rendered frame is a copy, not the renderer's buffer
    again = env.render()
    np.testing.assert_array_equal(first, again)
    # move Spider far away (off the ring, onto the floor side): the picture changes
    match = env.unwrapped.match
    spider = match.sim.agents[2]
    match.data.qpos[spider.root_qpos:spider.root_qpos + 3] = [0.0, 1.8, 0.9]
    mujoco.mj_forward(match.model, match.data)
    moved = env.render()
    diff = np.abs(moved.astype(int) - first.astype(int))
    assert (diff.sum(axis=2) > 30).mean() > 0.005
    env.close()


def test_frames_differ_between_states_far_apart_in_time() -> None:
    env = parallel_env(render_mode="rgb_array", width=160, height=120)
    env.reset(seed=1)
    start = env.render()
    rng = np.random.default_rng(1)
    for _ in range(40):
        _, _, term, trunc, _ = env.step({a: rng.uniform(-1, 1, 8) for a in env.possible_agents})
        if any(term.values()) or any(trunc.values()):
            break
    later = env.render()
    assert later.shape == start.shape
    assert np.abs(later.astype(int) - start.astype(int)).mean() > 0.5
    env.close()


def test_gymnasium_view_renders_rgb_array() -> None:
    env = TripleSumoEnv(render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (120, 160, 3)
    assert frame.dtype == np.uint8
    assert frame.std() > 10.0
    env.close()


def test_render_without_mode_returns_none() -> None:
    env = parallel_env()
    env.reset(seed=0)
    with pytest.warns(UserWarning):
        assert env.render() is None


@pytest.mark.parametrize("make", [lambda: parallel_env(render_mode="human"),
                                  lambda: TripleSumoEnv(render_mode="human")])
def test_human_mode_without_a_display_is_a_python_error_saying_what_to_do(
        make, monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    from triplesumo.sim.render import NoDisplayError

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(NoDisplayError, match=r"needs a window.*render_mode='rgb_array'"):
        make()
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_render_takes_the_mode_rllib_passes() -> None:
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    env = ParallelPettingZooEnv(parallel_env(render_mode="rgb_array", width=64, height=48))
    env.reset(seed=0)
    assert env.render().shape == (48, 64, 3)  # RLlib passes its render_mode (None): the env's own mode
    inner = env.par_env
    assert inner.render("rgb_array").shape == (48, 64, 3)
    with pytest.raises(ValueError, match="render mode is fixed"):
        inner.render("human")


def test_a_video_that_does_not_fit_on_the_disk_is_an_error_naming_the_file(tmp_path) -> None:
    """Issue 39, item 16 S: on a full disk ``play --video`` exited 0 with a truncated mp4 (ffmpeg's "Error writing
    trailer" only on its stderr). Written on a real 64 KiB tmpfs: an OSError names the file, and an earlier video
    there is left whole; on a roomy disk the same frames write and decode back."""
    from conftest import small_disk
    from triplesumo.evaluation.video import count_frames, write_mp4

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (96, 96, 3), dtype=np.uint8) for _ in range(40)]  # noise: ~ 300 KiB of H.264
    assert write_mp4(frames, tmp_path / "ok.mp4", fps=20) == 40 and count_frames(tmp_path / "ok.mp4") == 40
    with small_disk(tmp_path / "small", "64k") as small:
        (small / "match.mp4").write_bytes(b"earlier video")
        with pytest.raises(OSError, match=rf"{small / 'match.mp4'}: the video was not written"):
            write_mp4(frames, small / "match.mp4", fps=20)
        assert (small / "match.mp4").read_bytes() == b"earlier video"
        assert [p.name for p in small.iterdir()] == ["match.mp4"]  # no temp file left
