"""Write frames of a match to an mp4 (imageio with the ffmpeg binary from its wheel)."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np


def check_writable(path: Path, folder: bool = False) -> Path:
    """Create the folder a file ``path`` goes in (or, with ``folder=True``, the folder ``path``
    itself, whatever its name: ``runs/eval.v2`` is a folder) and fail now, naming it, if it
    cannot be written."""
    path = Path(path)
    folder_path = path if folder else path.parent
    return _check_folder(folder_path, path)


def _check_folder(folder: Path, path: Path) -> Path:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(f"cannot create output folder {folder}: {exc.strerror}") from exc
    if not os.access(folder, os.W_OK):
        raise PermissionError(f"output folder {folder} is not writable")
    return path


def write_mp4(frames: Iterable[np.ndarray], path: Path, fps: int) -> int:
    """Encode ``(H, W, 3)`` uint8 frames as H.264 mp4; returns the number of frames written.

    The video is written to a temp file beside ``path``, decoded back and renamed into place only when it
    holds every frame: ffmpeg reports a failed write (a full disk: "Error writing trailer") only on its
    stderr, so a truncated file would otherwise pass as written. ``OSError`` names ``path``, and any earlier
    file there is left as it was.
    """
    import imageio.v2 as imageio  # (the video extra: imported when a video is written)

    path = check_writable(Path(path))
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    n = 0
    try:
        writer: Any = imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, macro_block_size=8)
        with writer:
            for frame in frames:
                writer.append_data(np.asarray(frame, dtype=np.uint8))
                n += 1
        if n == 0:
            raise ValueError("no frames to write")
        try:
            written = count_frames(tmp)
        except Exception as exc:  # (imageio raises OSError, RuntimeError or its own for a broken mp4)
            raise OSError(f"{path}: the video was not written: ffmpeg left an unreadable file ({exc}); a full "
                          "disk?") from exc
        if written != n:
            raise OSError(f"{path}: the video was not written: {written} of {n} frames reached the disk (a full "
                          "disk?)")
        os.replace(tmp, path)
    except OSError as exc:
        if str(path) in str(exc):
            raise
        raise OSError(f"{path}: the video was not written ({exc})") from exc
    finally:
        tmp.unlink(missing_ok=True)
    return n


def count_frames(path: Path) -> int:
    """Decode an mp4 and count its frames (used to check recordings)."""
    import imageio.v2 as imageio

    reader: Any = imageio.get_reader(path)
    with reader:
        return sum(1 for _ in reader)
