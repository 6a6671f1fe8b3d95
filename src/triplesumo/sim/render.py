"""Frames of a match: offscreen ``rgb_array`` through ``mujoco.Renderer`` and the
``human`` view through ``mujoco.viewer``.

On a machine without a display set ``MUJOCO_GL=egl`` (or ``osmesa``) before MuJoCo
creates a context; :func:`ensure_headless_gl` does that when nothing is set and no
display exists. Never fork a process after a renderer exists (the child hangs): use
``spawn`` for workers.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from triplesumo._gl import ensure_headless_gl
from triplesumo.model import names

__all__ = ["FrameRenderer", "HumanViewer", "ensure_headless_gl"]


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
        import mujoco.viewer

        self._handle: Any = mujoco.viewer.launch_passive(model, data)

    def sync(self) -> None:
        if self._handle.is_running():
            self._handle.sync()

    def close(self) -> None:
        self._handle.close()
