"""Every MJCF name the code looks up, in one place.

Agent names are prefixes: each agent's body is attached once per agent under
``"<agent>/"``, so Spider's torso body is ``spider/torso`` and its free joint
``spider/root``. Nothing outside :mod:`triplesumo.model` spells a name itself.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

ASSETS = Path(str(resources.files("triplesumo") / "assets"))
TATAMI_XML = ASSETS / "tatami.xml"
BODY_XML = ASSETS / "body.xml"

# Arena (tatami.xml)
FLOOR_GEOM = "floor"
TATAMI_GEOM = "tatami"
RING_MARKER_GEOM = "border_right"
"""Border marker at x = +half-size; its position defines the ring's playable half-size."""
BORDER_GEOMS = ("border_top", "border_right", "border_bottom", "border_left")
"""The four cylinders (radius 3 cm, axis on the tatami's top) along the ring's edge: the paper's
solid rim (``PhysicsConfig.border_rim``, the default), or visual markers only (env v0's ring)."""
CAMERA_OVERVIEW = "overview"

# A body (body.xml and the legs triplesumo.model.bodies grows on it), unprefixed
TORSO_BODY = "torso"
ROOT_JOINT = "root"


def hip(leg: int) -> str:
    """Name of leg ``leg``'s (1-based) hip hinge and of its motor."""
    return f"hip_{leg}"


def ankle(leg: int) -> str:
    """Name of leg ``leg``'s (1-based) ankle hinge and of its motor."""
    return f"ankle_{leg}"


def prefix(agent: str) -> str:
    """The name prefix of an agent's attached body."""
    return f"{agent}/"


def scoped(agent: str, name: str) -> str:
    """The compiled-model name of ``name`` inside ``agent``'s body."""
    return prefix(agent) + name
