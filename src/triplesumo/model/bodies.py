"""RoboSumo's three bodies, grown from one parametrised leg.

RoboSumo (Al-Shedivat et al., 2018) fights with an *ant* (4 legs), a *bug* (6) and a
*spider* (8). Every leg is the same chain: a fixed segment out of the torso, a thigh on a
vertical *hip* hinge and a shin on a horizontal *ankle* hinge, one motor per hinge. A
:class:`BodyPlan` says how many legs, where they point and how long and thick they are;
:func:`body_spec` grows that body on the torso of ``assets/body.xml``. Legs come in mirrored
pairs about the body's +y axis, at ``90 +- spread`` degrees from +x, the left (x < 0) leg of
each pair first; leg ``i`` has joints and motors ``hip_i`` and ``ankle_i``.

Proportions are RoboSumo's ``ant.xml``, ``bug.xml`` and ``spider.xml`` (the bug's legs all
take its diagonal legs' lengths). The ant is bit for bit the quadruped TripleSumo always
had: coordinates are rounded to a micrometre, as an MJCF file writes them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from triplesumo.model import names


@dataclass(frozen=True)
class BodyPlan:
    """The shape of one RoboSumo body."""

    spreads: tuple[float, ...]
    """Angles (degrees) of each leg pair from the body's +y axis; one pair per entry."""
    segments: tuple[tuple[float, float], ...]
    """(horizontal length, rise) in metres of the leg's fixed segment, thigh and shin."""
    radius: float
    """Capsule radius of every leg segment."""
    hip_range: tuple[float, float]
    """Hip hinge range in degrees."""
    ankle_range: tuple[float, float]
    """Ankle hinge range in degrees of a left leg (a right leg's axis and range are mirrored)."""

    @property
    def n_legs(self) -> int:
        """Number of legs (two per spread)."""
        return 2 * len(self.spreads)

    @property
    def leg_angles(self) -> tuple[float, ...]:
        """Direction of each leg in degrees from the body's +x axis, leg order."""
        return tuple(a for s in self.spreads for a in (90.0 + s, 90.0 - s))

    def leg_points(self, leg: int) -> list[np.ndarray]:
        """Torso centre, then the end of the segment, thigh and shin of ``leg`` (0-based), body frame."""
        theta = math.radians(self.leg_angles[leg])
        c, s = math.cos(theta), math.sin(theta)
        points = [np.zeros(3)]
        for length, rise in self.segments:
            step = np.array([_um(length * c), _um(length * s), _um(rise)])
            points.append(points[-1] + step)
        return points

    def capsules(self) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """Every geom of the body at its zero pose as ``(start, end, radius)``, torso first."""
        torso = np.zeros(3)
        out = [(torso, torso, TORSO_RADIUS)]
        for leg in range(self.n_legs):
            p = self.leg_points(leg)
            out += [(p[k], p[k + 1], self.radius) for k in range(3)]
        return out


TORSO_RADIUS = 0.25
"""Radius of the torso sphere in ``assets/body.xml``."""
TORSO_HEIGHT = 0.75
"""Height of the torso in ``assets/body.xml`` (the attach frame puts it at the start height)."""

_DIAGONAL = math.hypot(0.2, 0.2)
BODIES: dict[str, BodyPlan] = {
    "ant": BodyPlan(spreads=(45.0, 135.0),
                    segments=((_DIAGONAL, 0.0), (_DIAGONAL, 0.0), (2 * _DIAGONAL, 0.0)),
                    radius=0.08, hip_range=(-30.0, 30.0), ankle_range=(-70.0, -30.0)),
    "bug": BodyPlan(spreads=(40.0, 90.0, 140.0),
                    segments=((0.28, 0.0), (0.28, 0.0), (0.505, 0.0)),
                    radius=0.08, hip_range=(-30.0, 30.0), ankle_range=(-70.0, -30.0)),
    "spider": BodyPlan(spreads=(15.0, 60.0, 105.0, 150.0),
                       segments=((0.216, 0.125), (0.195, 0.113), (0.433, -0.6)),
                       radius=0.04, hip_range=(-20.0, 20.0), ankle_range=(-35.0, 45.0)),
}
"""RoboSumo's bodies by name: ant (quadruped), bug (hexapod), spider (octopod)."""


def body_spec(kind: str) -> mujoco.MjSpec:
    """The uncompiled body ``kind`` (a key of :data:`BODIES`), names unprefixed."""
    if kind not in BODIES:
        raise ValueError(f"unknown body {kind!r}; bodies are {sorted(BODIES)}")
    plan = BODIES[kind]
    spec = mujoco.MjSpec.from_file(str(names.BODY_XML))
    spec.modelname = kind
    cls = spec.find_default("body")
    torso = spec.body(names.TORSO_BODY)
    for leg in range(plan.n_legs):
        i = leg + 1
        p = plan.leg_points(leg)
        left = math.cos(math.radians(plan.leg_angles[leg])) < 0
        sign = 1.0 if left else -1.0
        lo, hi = plan.ankle_range
        ankle_range = [lo, hi] if left else [-hi, -lo]
        seg = [p[k + 1] - p[k] for k in range(3)]
        # The ankle turns about the horizontal axis across the leg, scaled to a unit largest component.
        across = np.array([seg[0][1], -seg[0][0], 0.0]) * sign
        across = np.round(across / np.abs(across).max(), 6)

        root = torso.add_body(default=cls, name=f"leg_{i}")
        root.add_geom(default=cls, name=f"leg_{i}_geom", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                      fromto=[0, 0, 0, *seg[0]], size=[plan.radius, 0, 0])
        thigh = root.add_body(default=cls, name=f"thigh_{i}", pos=seg[0])
        thigh.add_joint(default=cls, name=names.hip(i), type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1],
                        range=list(plan.hip_range))
        thigh.add_geom(default=cls, name=f"thigh_{i}_geom", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                       fromto=[0, 0, 0, *seg[1]], size=[plan.radius, 0, 0])
        shin = thigh.add_body(default=cls, name=f"shin_{i}", pos=seg[1])
        shin.add_joint(default=cls, name=names.ankle(i), type=mujoco.mjtJoint.mjJNT_HINGE, axis=across,
                       range=ankle_range)
        shin.add_geom(default=cls, name=f"shin_{i}_geom", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                      fromto=[0, 0, 0, *seg[2]], size=[plan.radius, 0, 0])
    for leg in range(plan.n_legs):
        for joint in (names.hip(leg + 1), names.ankle(leg + 1)):
            spec.add_actuator(default=cls, name=joint, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    return spec


def _um(x: float) -> float:
    """``x`` rounded to a micrometre (``+ 0.0`` turns ``-0.0`` into ``0.0``)."""
    return round(x, 6) + 0.0
