"""Outlines of a blank: a polygon checked and oriented, and the plane geometry the meshers and
the forming checks ask of it (numpy only; mm).

:func:`polygon_outline` turns ``blank.points`` into a simple counter-clockwise polygon (or an
:class:`~drape.errors.InputError` naming the key); :func:`inside_polygon`,
:func:`closest_on_polyline` and :func:`point_at` answer, for many points at once, whether they
lie inside, where their closest point on the outline is (by arc length) and which point has a
given arc length; :class:`Outline` asks the same of a polygon or a circle, and where a ray
from inside meets it.
"""

from __future__ import annotations

import math

import numpy as np

from drape.errors import InputError


def polygon_outline(points) -> np.ndarray:
    """The polygon's vertices (n, 2) counter-clockwise, duplicate closing point removed;
    InputError (key blank.points) unless it is a simple polygon of at least 3 vertices."""
    xy = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(xy) > 1 and np.allclose(xy[0], xy[-1]):
        xy = xy[:-1]
    if len(xy) < 3:
        raise InputError("a polygon needs at least 3 vertices", key="blank.points",
                         value=len(xy), expected="[[x0, y0], [x1, y1], [x2, y2], ...] in mm")
    n = len(xy)
    edges = [(xy[k], xy[(k + 1) % n]) for k in range(n)]
    lengths = [np.linalg.norm(b - a) for a, b in edges]
    if min(lengths) <= 1e-9 * max(lengths):
        raise InputError("a polygon with a repeated vertex", key="blank.points",
                         value=[list(p) for p in xy], expected="distinct vertices around an area")
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue
            if _segments_cross(*edges[i], *edges[j]):
                raise InputError("the polygon's edges cross", key="blank.points",
                                 value=f"edges {i} and {j}",
                                 expected="a simple polygon (vertices in order around it)")
    area = polygon_area(xy)
    if abs(area) <= 1e-12 * max(lengths) ** 2:
        raise InputError("a polygon with no area", key="blank.points",
                         value=[list(p) for p in xy], expected="vertices around an area")
    if area < 0:
        xy = xy[::-1].copy()
    return xy


def polygon_area(xy) -> float:
    """Signed area (mm^2) of the polygon xy (n, 2): positive counter-clockwise."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _segments_cross(a, b, c, d) -> bool:
    def orient(p, q, r):
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
    return (orient(a, b, c) * orient(a, b, d) < 0) and (orient(c, d, a) * orient(c, d, b) < 0)


def inside_polygon(xy, points) -> np.ndarray:
    """Whether each point (P, 2) lies inside the polygon xy (even-odd rule)."""
    x, y = points[:, 0][:, None], points[:, 1][:, None]
    x0, y0 = xy[:, 0][None, :], xy[:, 1][None, :]
    x1, y1 = np.roll(xy[:, 0], -1)[None, :], np.roll(xy[:, 1], -1)[None, :]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.sum(crosses & (x < xc), axis=1) % 2) == 1


def closest_on_polyline(xy, points):
    """Distance (P,) of each point to the closed polyline xy and the arc-length parameter of
    its closest point on it (from vertex 0, counter-clockwise)."""
    a = xy[None, :, :]
    d = (np.roll(xy, -1, axis=0) - xy)[None, :, :]
    length = np.linalg.norm(d[0], axis=1)
    start = np.concatenate([[0.0], np.cumsum(length)[:-1]])
    p = points[:, None, :]
    t = np.clip(np.sum((p - a) * d, axis=2) / (length ** 2)[None, :], 0.0, 1.0)
    gap = np.linalg.norm(p - (a + t[:, :, None] * d), axis=2)
    k = np.argmin(gap, axis=1)
    rows = np.arange(len(points))
    return gap[rows, k], start[k] + t[rows, k] * length[k]


def point_at(xy, s):
    """Points of the closed polyline xy at arc-length parameters s."""
    d = np.roll(xy, -1, axis=0) - xy
    length = np.linalg.norm(d, axis=1)
    ends = np.cumsum(length)
    s = np.mod(s, ends[-1])
    k = np.minimum(np.searchsorted(ends, s, side="right"), len(xy) - 1)
    t = (s - (ends[k] - length[k])) / length[k]
    return xy[k] + t[:, None] * d[k]


def cross_z(u, v):
    """The z component of the cross product of 2-D vectors (..., 2)."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


class Outline:
    """The closed outline a lattice is clipped to: a polygon (n, 2), counter-clockwise, or a
    circle of radius ``circle`` about ``centre`` (``polygon`` then its fine polygon, for the
    lattice's extent only). Arc-length parameters run counter-clockwise from the polygon's
    vertex 0 (the circle's point on +x)."""

    def __init__(self, polygon: np.ndarray, centre: np.ndarray, circle: float | None):
        self.polygon, self.centre, self.circle = polygon, centre, circle
        if circle is not None:
            self.total = 2 * math.pi * circle
        else:
            self.total = float(np.sum(np.linalg.norm(np.roll(polygon, -1, axis=0) - polygon,
                                                     axis=1)))

    def closest(self, q):
        """Distance (P,) of points q (P, 2) to the outline and the arc length of their
        closest points on it."""
        if self.circle is None:
            return closest_on_polyline(self.polygon, q)
        centre, circle = self.centre, self.circle
        return (circle - np.linalg.norm(q - centre, axis=1),
                circle * np.mod(np.arctan2(q[:, 1] - centre[1], q[:, 0] - centre[0]),
                                2 * math.pi))

    def inside(self, q) -> np.ndarray:
        if self.circle is None:
            return inside_polygon(self.polygon, q)
        return np.linalg.norm(q - self.centre, axis=1) < self.circle

    def points_at(self, s) -> np.ndarray:
        """The outline's points (P, 2) at arc lengths s (P,)."""
        if self.circle is None:
            return point_at(self.polygon, s)
        circle = self.circle
        return self.centre + circle * np.column_stack([np.cos(s / circle), np.sin(s / circle)])

    def along_ray(self, q, direction) -> np.ndarray:
        """Arc lengths (P,) of the outline's first points on the rays from q (P, 2) inside it
        along ``direction`` (P, 2)."""
        d = direction / np.linalg.norm(direction, axis=1)[:, None]
        if self.circle is not None:
            r = q - self.centre
            b = np.sum(r * d, axis=1)
            t = -b + np.sqrt(b * b - np.sum(r * r, axis=1) + self.circle ** 2)
            return self.closest(q + t[:, None] * d)[1]
        e = np.roll(self.polygon, -1, axis=0) - self.polygon
        r = self.polygon[None, :, :] - q[:, None, :]                     # (P, n, 2)
        denominator = cross_z(d[:, None, :], e[None, :, :])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = cross_z(r, e[None, :, :]) / denominator
            u = cross_z(r, d[:, None, :]) / denominator
        t = np.where((t > 0) & (u >= 0) & (u <= 1), t, np.inf)
        k = np.argmin(t, axis=1)
        return self.vertex_lengths()[k] + u[np.arange(len(q)), k] * np.linalg.norm(e, axis=1)[k]

    def vertex_lengths(self) -> np.ndarray | None:
        """Arc lengths of the polygon's vertices (None for a circle: it has none)."""
        if self.circle is not None:
            return None
        polygon = self.polygon
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.roll(polygon, -1, axis=0)
                                                               - polygon, axis=1))[:-1]])
