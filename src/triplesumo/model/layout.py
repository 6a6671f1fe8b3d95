"""Start poses: fair to every agent, and clear of every other body and of the rim.

**Fair (env v2, the default).** Every torso starts ``edge`` metres from its nearest edge of the
square ring and as far from the edge behind it (the edge it would be pushed onto, straight back
along its heading), so no agent starts nearer the way out than another.

- Up to four agents stand on the ring's diagonals at ``(+-d, +-d)``, ``d = half_size - edge`` (the
  paper's code put its three torsos at (-1, -1), (1, -1) and (1, 1)). The roster takes the corners
  in the order (-d, -d), (d, d), (d, -d), (-d, d): the first two opposite, the third between them
  (the paper's Spider, beside both Ant and Bug), the fourth opposite the third.
- Five or more agents stand on the sides of a square of half-size ``d``, spread over the four sides
  (the first sides take one more) and evenly along each, every one facing square onto its side.

Every agent faces the centre (or its side) turned by one common angle, the smallest multiple of
7.5 degrees with every pair of bodies :data:`CLEARANCE` apart and every body's zero pose
:data:`RIM_CLEARANCE` inside the rim (every other agent may turn the other way: a mirror image is as
far from the edges). One turn for all keeps the layout symmetric: the distances to the nearest edge
and to the edge behind are the same for every agent, by construction. A quadruped facing the centre
from a corner has legs along the ring's axes that reach the rim; turned 45 degrees, its legs lie
along the diagonal and clear it. Where the preferred distance fits no turn, all agents move
together in 5 cm steps, first inwards, then outwards.

Not every roster fits: five quadrupeds stand clear of each other only 0.3 m from the edges with legs
0.7 m over the rim, and six not at all (their legs span 2.4 m in a 4 m ring). Such a roster starts
on the circle layout below, which is not fair; :func:`fair_layout` returns ``None`` for it. Every
scenario's roster of up to four agents is fair (tests/test_start_layout.py); a custom roster of mixed
bodies may not be (ant, spider and bug in that order fit no turn).

**Circle (env v0 and v1).** Agents evenly spaced on a circle around the ring's centre, the first at
angle 0, each facing the centre, kept whenever bodies stand at least :data:`CLEARANCE` apart;
otherwise the circle grows in 5 cm steps and each agent in turn may turn away from the centre by a
multiple of 7.5 degrees until every pair is clear. It is not fair: the first agent starts 0.6 m from
the edge behind it, the others 0.79 m from their nearest edge.

Distances are exact capsule-to-capsule distances of the bodies' zero poses.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np

from triplesumo.model.bodies import BODIES

CLEARANCE = 0.05
"""Least gap (m) between the surfaces of two agents' geoms at the start pose (MuJoCo makes a
contact within 0.02: twice the bodies' geom margin)."""
RIM_CLEARANCE = 0.02
"""Least gap (m) between every body's zero pose and the rim's inner face in the fair layout."""
RIM_HALF_WIDTH = 0.03
"""Half-width (m) of the rim along the ring's edge (the border geoms' size)."""
_STEP = 0.05
_TURNS = (0.0, *(s * k * 7.5 for k in range(1, 13) for s in (1.0, -1.0)))
"""Turns (degrees) away from facing the centre, smallest first."""


Pose = tuple[float, float, float]
_CORNERS = (225.0, 45.0, 315.0, 135.0)
"""Diagonal slots (degrees) in the order a roster takes them."""


def fair_layout(bodies: Sequence[str], edge: float, half_size: float) -> list[Pose] | None:
    """``(x, y, yaw)`` of each agent of the fair layout, whose body kinds are ``bodies``, in roster order:
    every torso the same distance from its nearest edge and from the edge behind it (module docstring);
    ``None`` where no such placement keeps the bodies clear of each other and of the rim.

    ``edge`` is the preferred distance; where no turn places the bodies clear there, the layout tries
    5 cm further in (up to 30 cm), then further out (down to 0.2 m).
    """
    poses = _fair_layout(tuple(bodies), float(edge), float(half_size))
    return None if poses is None else list(poses)


@functools.lru_cache(maxsize=64)
def _fair_layout(bodies: tuple[str, ...], edge: float, half_size: float) -> tuple[Pose, ...] | None:
    shapes = [_shape(b) for b in bodies]
    n = len(bodies)
    inward = [round(edge + _STEP * k, 6) for k in range(7)]
    outward = [round(edge - _STEP * k, 6) for k in range(1, 100) if edge - _STEP * k >= 0.2 - 1e-9]
    for e in [x for x in inward if x < half_size] + outward:
        for turn, signs in _signed_turns(n):
            poses = _fair_poses(n, half_size - e, [math.radians(turn) * sgn for sgn in signs])
            if all(rim_margin(b, p, half_size) >= RIM_CLEARANCE for b, p in zip(bodies, poses, strict=True)) and all(
                    _gap(shapes[i], poses[i], shapes[j], poses[j]) >= CLEARANCE for i in range(n) for j in range(i)):
                return tuple(poses)
    return None


def _signed_turns(n: int) -> list[tuple[float, tuple[int, ...]]]:
    """Each turn of :data:`_TURNS` for all agents alike, then (for turns > 0) with every other agent
    turned the other way: the mirror image of a pose is as far from the edges, so both are fair."""
    out: list[tuple[float, tuple[int, ...]]] = []
    for turn in _TURNS:
        out.append((turn, (1,) * n))
        if turn > 0:
            out.append((turn, tuple(1 if i % 2 == 0 else -1 for i in range(n))))
    return out


def _fair_poses(n: int, d: float, turns: list[float]) -> list[Pose]:
    if n <= len(_CORNERS):
        out = []
        for angle, turn in zip(_CORNERS[:n], turns, strict=True):
            a = math.radians(angle)
            out.append((d * math.sqrt(2.0) * math.cos(a), d * math.sqrt(2.0) * math.sin(a), a + math.pi + turn))
        return out
    counts = [n // 4 + (1 if s < n % 4 else 0) for s in range(4)]
    sides = [(s, k) for s in (0, 2, 1, 3) for k in range(counts[s])]  # opposite sides first: -y, +y, +x, -x
    out = []
    for (side, k), turn in zip(sorted(sides), turns, strict=True):
        normal = math.radians(270.0 + 90.0 * side)  # outward normal of side 0 (-y), 1 (+x), 2 (+y), 3 (-x)
        along = d * (2 * k + 1 - counts[side]) / counts[side]
        x = d * math.cos(normal) - along * math.sin(normal)
        y = d * math.sin(normal) + along * math.cos(normal)
        out.append((x, y, normal + math.pi + turn))
    return out


def rim_margin(body: str, pose: Pose, half_size: float) -> float:
    """Least gap (m) between ``body``'s zero pose at ``pose`` and the rim's inner face (negative: over it)."""
    shape = _shape(body)
    p0, p1 = _place(shape, pose)
    reach = np.maximum(np.abs(p0[:, :2]), np.abs(p1[:, :2])).max(axis=1) + shape[2]
    return float(half_size - RIM_HALF_WIDTH - reach.max())


def edge_distances(pose: Pose, half_size: float) -> tuple[float, float]:
    """Distances (m) from a torso at ``pose`` to its nearest edge, and to the edge straight behind it."""
    x, y, yaw = pose
    nearest = half_size - max(abs(x), abs(y))
    bx, by = -math.cos(yaw), -math.sin(yaw)
    behind = min((half_size - x) / bx if bx > 1e-12 else math.inf, (-half_size - x) / bx if bx < -1e-12 else math.inf,
                 (half_size - y) / by if by > 1e-12 else math.inf, (-half_size - y) / by if by < -1e-12 else math.inf)
    return nearest, behind


def start_layout(bodies: Sequence[str], radius: float, max_radius: float) -> list[Pose]:
    """``(x, y, yaw)`` of each agent of the circle layout (env v0, v1), whose body kinds are ``bodies``,
    in roster order.

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
