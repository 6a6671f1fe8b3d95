"""Every MJCF name the code looks up, in one place.

Agent names are prefixes: the quadruped body is attached once per agent under
``"<agent>/"``, so Spider's torso body is ``spider/torso`` and its free joint
``spider/root``. Nothing outside :mod:`triplesumo.model` spells a name itself.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

ASSETS = Path(str(resources.files("triplesumo") / "assets"))
TATAMI_XML = ASSETS / "tatami.xml"
QUADRUPED_XML = ASSETS / "quadruped.xml"

# Arena (tatami.xml)
FLOOR_GEOM = "floor"
TATAMI_GEOM = "tatami"
RING_MARKER_GEOM = "border_right"
"""Border marker at x = +half-size; its position defines the ring's playable half-size."""
CAMERA_OVERVIEW = "overview"

# Quadruped (quadruped.xml), unprefixed
TORSO_BODY = "torso"
ROOT_JOINT = "root"
LEG_JOINTS = ("hip_1", "ankle_1", "hip_2", "ankle_2", "hip_3", "ankle_3", "hip_4", "ankle_4")
"""Hinge joints in actuator order: one motor per joint, named like the joint."""


def prefix(agent: str) -> str:
    """The name prefix of an agent's attached body."""
    return f"{agent}/"


def scoped(agent: str, name: str) -> str:
    """The compiled-model name of ``name`` inside ``agent``'s body."""
    return prefix(agent) + name
