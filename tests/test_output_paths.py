"""Output folders and files are told apart by how they are used, not by a dot in the name."""

from __future__ import annotations

from pathlib import Path

from triplesumo.evaluation.video import check_writable


def test_a_folder_with_a_dot_in_its_name_is_made_as_a_folder(tmp_path: Path) -> None:
    out = tmp_path / "runs" / "ddpg.actor_lr=1e-4"
    assert check_writable(out, folder=True) == out
    assert out.is_dir()


def test_a_file_path_makes_only_its_folder(tmp_path: Path) -> None:
    video = tmp_path / "videos" / "match.mp4"
    assert check_writable(video) == video
    assert video.parent.is_dir() and not video.exists()
