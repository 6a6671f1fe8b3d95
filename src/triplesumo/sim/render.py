"""Frames of a match: offscreen ``rgb_array`` through ``mujoco.Renderer`` and the
``human`` view through ``mujoco.viewer``.

On a machine without a display set ``MUJOCO_GL=egl`` (or ``osmesa``) before MuJoCo
creates a context; :func:`ensure_headless_gl` does that when nothing is set and no
display exists. Never fork a process after a renderer exists (the child hangs): use
``spawn`` for workers.
"""

from __future__ import annotations

import os
import sys
from typing import Any

import mujoco
import numpy as np

from triplesumo._gl import ensure_headless_gl
from triplesumo.model import names

__all__ = ["FrameRenderer", "HumanViewer", "NoDisplayError", "ensure_headless_gl", "no_display_reason",
           "require_display"]


class NoDisplayError(RuntimeError):
    """``render_mode="human"`` asked for where no window can open."""


def no_display_reason() -> str | None:
    """Why an interactive window cannot open here, or ``None`` if it may.

    Without this check GLFW fails inside ``mujoco.viewer`` at the first frame: it ends the
    process (no Python exception) and leaves ``MUJOCO_LOG.TXT`` in the working folder.
    """
    gl = os.environ.get("MUJOCO_GL", "")
    if gl in ("egl", "osmesa"):
        return f"MUJOCO_GL={gl} selects offscreen rendering, which has no windows"
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (neither DISPLAY nor WAYLAND_DISPLAY is set)"
    return None


def require_display() -> None:
    """:class:`NoDisplayError` saying what to do instead when no window can open here."""
    reason = no_display_reason()
    if reason is not None:
        raise NoDisplayError(
            f"render_mode='human' needs a window, but {reason}. Use render_mode='rgb_array' and "
            "save the frames (e.g. gymnasium.wrappers.RecordVideo, or `triplesumo play --video "
            "match.mp4`), or run where a display exists (set DISPLAY, unset MUJOCO_GL).")


class FrameRenderer:
    """Renders RGB frames of one ``MjData`` from the arena's overview camera."""

    def __init__(self, model: mujoco.MjModel, width: int = 480, height: int = 480,
                 camera: str = names.CAMERA_OVERVIEW, shadows: bool = False) -> None:
        if width < 1 or height < 1:
            raise ValueError(f"render size must be positive, got {width}x{height}")
        ensure_headless_gl()
        self._renderer = mujoco.Renderer(model, height=height, width=width)
        self._camera = camera
        scene = self._renderer.scene
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadows
        scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = shadows

    def render(self, data: mujoco.MjData) -> np.ndarray:
        """``(height, width, 3)`` uint8 frame of the current state."""
        self._renderer.update_scene(data, camera=self._camera)
        return self._renderer.render().copy()

    def close(self) -> None:
        self._renderer.close()


class HumanViewer:
    """An interactive window (``mujoco.viewer.launch_passive``), synced once per env step."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        require_display()
        import mujoco.viewer

        self._handle: Any = mujoco.viewer.launch_passive(model, data)

    def sync(self) -> None:
        if self._handle.is_running():
            self._handle.sync()

    def close(self) -> None:
        self._handle.close()
