"""Choose a headless OpenGL backend before MuJoCo is imported (it reads MUJOCO_GL then)."""

from __future__ import annotations

import os
import sys


def ensure_headless_gl() -> None:
    """Pick EGL for offscreen rendering when no GL backend is chosen and no display exists.

    ``MUJOCO_GL`` is read when ``mujoco`` is first imported, so this runs at the top of
    ``triplesumo/__init__.py``. Set ``MUJOCO_GL=osmesa`` yourself where EGL is missing.
    """
    if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY") and sys.platform.startswith("linux"):
        os.environ["MUJOCO_GL"] = "egl"
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
