"""Rendering shared by the PettingZoo and Gymnasium views of a match."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from triplesumo.envs.match import Match
from triplesumo.sim.render import FrameRenderer, HumanViewer, require_display

RENDER_MODES = ("human", "rgb_array")


class MatchAccess:
    """``model`` and ``data`` of the view's match (what ``env.unwrapped.model`` / ``.data`` give)."""

    match: Match

    @property
    def model(self) -> Any:
        """The compiled ``mujoco.MjModel``."""
        return self.match.model

    @property
    def data(self) -> Any:
        """The live ``mujoco.MjData``."""
        return self.match.data


class MatchView:
    """Frames of one match in a render mode: ``rgb_array`` (offscreen) or ``human`` (a window).

    The renderer or window is created on the first :meth:`render` and released by :meth:`close`.
    """

    def __init__(self, match: Match, render_mode: str | None, width: int, height: int) -> None:
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES} or None, got {render_mode!r}")
        if render_mode == "human":
            require_display()  # fail here, in Python: GLFW would end the process at the first frame
        self.match, self.render_mode, self.size = match, render_mode, (width, height)
        self._renderer: FrameRenderer | None = None
        self._viewer: HumanViewer | None = None

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """A frame in the view's render mode; ``mode`` may repeat it (RLlib's
        ``ParallelPettingZooEnv.render()`` passes its own, usually ``None``)."""
        if mode is not None and mode != self.render_mode:
            raise ValueError(f"render mode is fixed when the env is made (render_mode={self.render_mode!r}); "
                             f"got render({mode!r})")
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'.")
            return None
        if self.render_mode == "human":
            if self._viewer is None:
                self._viewer = HumanViewer(self.match.model, self.match.data)
            self._viewer.sync()
            return None
        if self._renderer is None:
            self._renderer = FrameRenderer(self.match.model, *self.size)
        return self._renderer.render(self.match.data)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
