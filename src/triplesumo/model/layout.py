"""Start poses that keep every body clear of every other.

Agents start evenly spaced on a circle around the ring's centre, the first at angle 0,
each facing the centre. That is the paper's pose, and it is kept whenever its bodies stand
at least :data:`CLEARANCE` apart. When they would not (more agents, longer legs), the
circle grows in steps of 5 cm and each agent in turn may turn away from the centre by a
multiple of 7.5 degrees (the smallest turn that clears the agents already placed), until
every pair is clear; a roster that cannot be placed inside the ring raises ``ValueError``.
Distances are exact capsule-to-capsule distances of the bodies' zero poses.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from triplesumo.model.bodies import BODIES

CLEARANCE = 0.05
"""Least gap (m) between the surfaces of two agents' geoms at the start pose (MuJoCo makes a
contact within 0.02: twice the bodies' geom margin)."""
_STEP = 0.05
_TURNS = (0.0, *(s * k * 7.5 for k in range(1, 13) for s in (1.0, -1.0)))
"""Turns (degrees) away from facing the centre, smallest first."""


def start_layout(bodies: Sequence[str], radius: float, max_radius: float) -> list[tuple[float, float, float]]:
    """``(x, y, yaw)`` of each agent, whose body kinds are ``bodies``, in roster order.

    ``radius`` is the preferred circle radius, ``max_radius`` the largest allowed (torsos
    must start inside the ring).
    """
    shapes = [_shape(b) for b in bodies]
    n = len(bodies)
    r = radius
    while r <= max_radius + 1e-9:
        poses: list[tuple[float, float, float]] = []
        worst = math.inf
        for i in range(n):
            angle = 2.0 * math.pi * i / n
            x, y = r * math.cos(angle), r * math.sin(angle)
            best: tuple[float, tuple[float, float, float]] | None = None
            for turn in _TURNS:
                pose = (x, y, angle + math.pi + math.radians(turn))
                gap = min((_gap(shapes[i], pose, shapes[j], poses[j]) for j in range(i)), default=math.inf)
                if gap >= CLEARANCE:
                    best = (gap, pose)
                    break
                if best is None or gap > best[0]:
                    best = (gap, pose)
            assert best is not None
            poses.append(best[1])
            worst = min(worst, best[0])
        if worst >= CLEARANCE:
            return poses
        r = round(r + _STEP, 6)
    raise ValueError(f"agents: cannot place bodies {list(bodies)} {CLEARANCE} m apart on a circle of radius "
                     f"{radius} to {max_radius} (inside the ring); use fewer agents or smaller bodies")


def gap_between(body_a: str, pose_a: tuple[float, float, float], body_b: str,
                pose_b: tuple[float, float, float]) -> float:
    """Least surface distance (m) between two bodies at ``(x, y, yaw)`` start poses."""
    return _gap(_shape(body_a), pose_a, _shape(body_b), pose_b)


_Shape = tuple[np.ndarray, np.ndarray, np.ndarray, float]


def _shape(kind: str) -> _Shape:
    caps = BODIES[kind].capsules()
    p0 = np.array([c[0] for c in caps])
    p1 = np.array([c[1] for c in caps])
    rad = np.array([c[2] for c in caps])
    reach = float(np.max(np.linalg.norm(p1[:, :2], axis=1) + rad))
    return p0, p1, rad, reach


def _place(shape: _Shape, pose: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    shift = np.array([x, y, 0.0])
    return shape[0] @ rot.T + shift, shape[1] @ rot.T + shift


def _gap(a: _Shape, pose_a: tuple[float, float, float], b: _Shape, pose_b: tuple[float, float, float]) -> float:
    centre_distance = math.hypot(pose_a[0] - pose_b[0], pose_a[1] - pose_b[1])
    if centre_distance > a[3] + b[3] + CLEARANCE:
        return centre_distance - a[3] - b[3]
    a0, a1 = _place(a, pose_a)
    b0, b1 = _place(b, pose_b)
    dist = _segment_distances(a0[:, None], a1[:, None], b0[None, :], b1[None, :])
    return float((dist - a[2][:, None] - b[2][None, :]).min())


def _segment_distances(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Distances between segments ``p1-q1`` and ``p2-q2`` (broadcast over leading axes; points allowed).

    The closest-point computation of Ericson, *Real-Time Collision Detection*, 5.1.9.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("...k,...k", d1, d1)
    e = np.einsum("...k,...k", d2, d2)
    f = np.einsum("...k,...k", d2, r)
    c = np.einsum("...k,...k", d1, r)
    b = np.einsum("...k,...k", d1, d2)
    a, e, f, c, b = np.broadcast_arrays(a, e, f, c, b)
    eps = 1e-12
    safe_a, safe_e = np.where(a > eps, a, 1.0), np.where(e > eps, e, 1.0)
    denom = a * e - b * b
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.where(denom > eps, denom, 1.0), 0.0, 1.0), 0.0)
    s = np.where(a > eps, s, 0.0)
    t = np.where(e > eps, (b * s + f) / safe_e, 0.0)
    below, above = t < 0.0, t > 1.0
    s = np.where(below, np.clip(-c / safe_a, 0.0, 1.0), s)
    s = np.where(above, np.clip((b - c) / safe_a, 0.0, 1.0), s)
    s = np.where(e > eps, s, np.clip(-c / safe_a, 0.0, 1.0))
    s = np.where(a > eps, s, 0.0)
    t = np.clip(t, 0.0, 1.0)
    closest1 = p1 + s[..., None] * d1
    closest2 = p2 + t[..., None] * d2
    return np.linalg.norm(closest1 - closest2, axis=-1)
