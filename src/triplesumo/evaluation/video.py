"""Write frames of a match to an mp4 (imageio with the ffmpeg binary from its wheel)."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import imageio.v2 as imageio
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
    """Encode ``(H, W, 3)`` uint8 frames as H.264 mp4; returns the number of frames written."""
    path = check_writable(Path(path))
    n = 0
    writer: Any = imageio.get_writer(path, fps=fps, codec="libx264", quality=7, macro_block_size=8)
    with writer:
        for frame in frames:
            writer.append_data(np.asarray(frame, dtype=np.uint8))
            n += 1
    if n == 0:
        path.unlink(missing_ok=True)
        raise ValueError("no frames to write")
    return n


def count_frames(path: Path) -> int:
    """Decode an mp4 and count its frames (used to check recordings)."""
    reader: Any = imageio.get_reader(path)
    with reader:
        return sum(1 for _ in reader)
