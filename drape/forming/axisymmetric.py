"""Exact tool surfaces of revolution about the z axis (hemisphere punch, die, holder; numpy only).

A tool is an (r, z) :class:`Profile` of :class:`Segment` and :class:`Arc` pieces, running with
the tool's material on its left; :class:`AxisymmetricSurface` answers the contact query
(:mod:`drape.forming.tool_query`) exactly: the closest point of a surface of revolution lies in
the point's meridian half-plane, so the 3-D problem is a 2-D closest point on the profile.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from drape.forming.tool_query import ContactQuery, tool_frame, unit


@dataclasses.dataclass(frozen=True)
class Segment:
    """A straight piece of a profile in the (r, z) half-plane, from ``start`` to ``end``."""

    start: tuple[float, float]
    end: tuple[float, float]

    def point(self, which: int) -> np.ndarray:
        return np.array(self.start if which == 0 else self.end, dtype=float)

    def tangent(self, which: int) -> np.ndarray:
        return unit(np.subtract(self.end, self.start).astype(float))

    def curvature(self) -> float:
        return 0.0

    def bounds(self) -> np.ndarray:
        """[[r_min, z_min], [r_max, z_max]] of the piece."""
        ends = np.array([self.start, self.end], dtype=float)
        return np.array([ends.min(axis=0), ends.max(axis=0)])

    def closest(self, q: np.ndarray):
        a, b = self.point(0), self.point(1)
        ab = b - a
        t = np.clip((q - a) @ ab / (ab @ ab), 0.0, 1.0)
        c = a + t[:, None] * ab
        n = np.array([ab[1], -ab[0]]) / math.hypot(*ab)
        end = np.where(t <= 0.0, 0, np.where(t >= 1.0, 1, -1))
        return c, np.broadcast_to(n, c.shape), end


@dataclasses.dataclass(frozen=True)
class Arc:
    """A circular piece of a profile: centre (r, z), radius, and the polar angles (rad) of its
    ends, measured from the +r axis towards +z. ``end_angle > start_angle`` runs
    counter-clockwise (the tool's material inside the circle: a convex rounding),
    ``end_angle < start_angle`` clockwise (material outside: a concave one)."""

    centre: tuple[float, float]
    radius: float
    start_angle: float
    end_angle: float

    @property
    def ccw(self) -> bool:
        return self.end_angle > self.start_angle

    def _radial(self, angle) -> np.ndarray:
        return np.array([math.cos(angle), math.sin(angle)])

    def point(self, which: int) -> np.ndarray:
        angle = self.start_angle if which == 0 else self.end_angle
        return np.asarray(self.centre, dtype=float) + self.radius * self._radial(angle)

    def tangent(self, which: int) -> np.ndarray:
        angle = self.start_angle if which == 0 else self.end_angle
        r = self._radial(angle)
        t = np.array([-r[1], r[0]])
        return t if self.ccw else -t

    def curvature(self) -> float:
        return 1.0 / self.radius

    def bounds(self) -> np.ndarray:
        """[[r_min, z_min], [r_max, z_max]]: the whole circle's box (it holds the arc)."""
        centre = np.asarray(self.centre, dtype=float)
        return np.array([centre - self.radius, centre + self.radius])

    def closest(self, q: np.ndarray):
        centre = np.asarray(self.centre, dtype=float)
        d = q - centre
        angle = np.arctan2(d[:, 1], d[:, 0])
        lo, hi = sorted((self.start_angle, self.end_angle))
        span = hi - lo
        rel = np.mod(angle - lo, 2.0 * np.pi)
        inside = rel <= span + 1e-15
        # outside the arc's angular range: the nearer end point
        p_lo = centre + self.radius * self._radial(lo)
        p_hi = centre + self.radius * self._radial(hi)
        nearer_lo = np.sum((q - p_lo) ** 2, axis=1) <= np.sum((q - p_hi) ** 2, axis=1)
        angle = np.where(inside, lo + rel, np.where(nearer_lo, lo, hi))
        radial = np.stack([np.cos(angle), np.sin(angle)], axis=1)
        c = centre + self.radius * radial
        n = radial if self.ccw else -radial
        lo_end, hi_end = (0, 1) if self.ccw else (1, 0)
        end = np.where(inside, -1, np.where(nearer_lo, lo_end, hi_end))
        return c, n, end


Piece = Segment | Arc


def _cross2(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


class Profile:
    """A chain of segments and arcs in the (r >= 0, z) half-plane, each piece starting where the
    previous one ends, running with the tool's material on its left (so that the right-hand
    normal, (t_z, -t_r) for the tangent t, points away from the tool). The chain is either
    closed (a ring: die, holder) or runs from the axis back to the axis (a solid on the axis:
    the punch), where it must cross the axis at right angles."""

    def __init__(self, pieces: Sequence[Piece], tol: float = 1e-9):
        self.pieces = tuple(pieces)
        if not self.pieces:
            raise ValueError("a profile needs at least one piece")
        scale = max(1.0, max(float(np.abs(p.point(i)).max()) for p in self.pieces for i in (0, 1)))
        self.tol = tol * scale
        for i, (a, b) in enumerate(zip(self.pieces, self.pieces[1:])):
            if np.linalg.norm(a.point(1) - b.point(0)) > self.tol:
                raise ValueError(f"profile pieces {i} and {i + 1} do not join")
        first, last = self.pieces[0], self.pieces[-1]
        self.closed = bool(np.linalg.norm(last.point(1) - first.point(0)) <= self.tol)
        if not self.closed:
            for piece, which in ((first, 0), (last, 1)):
                if abs(piece.point(which)[0]) > self.tol:
                    raise ValueError("an open profile must start and end on the axis (r = 0)")
                if abs(piece.tangent(which)[1]) > 1e-6:
                    raise ValueError("an open profile must meet the axis at right angles")
        # per piece end: the normal to use when the closest point is that end (the average of
        # the two pieces' normals at a corner: the sign test of a pseudo-normal), and whether
        # the joint is sharp (then the normal of a point in front is the direction to it)
        m = len(self.pieces)
        self._end_normal = np.zeros((m, 2, 2))
        self._end_sharp = np.zeros((m, 2), dtype=bool)
        right = lambda t: np.array([t[1], -t[0]])
        for i, piece in enumerate(self.pieces):
            for which in (0, 1):
                n_own = right(piece.tangent(which))
                j = i + (1 if which == 1 else -1)
                if 0 <= j < m or self.closed:
                    other = self.pieces[j % m]
                    n_other = right(other.tangent(1 - which))
                    pseudo = n_own + n_other
                    norm = np.linalg.norm(pseudo)
                    self._end_normal[i, which] = pseudo / norm if norm > 1e-12 else n_own
                    self._end_sharp[i, which] = abs(_cross2(n_own, n_other)) > 1e-9 or norm < 1.0
                else:  # on the axis: the mirror image continues smoothly
                    self._end_normal[i, which] = n_own
        # a box in (r, z) that holds the profile, and so the tool's solid (a ring's solid lies
        # inside its closed profile; a solid on the axis between the profile and the axis,
        # whose ends are on it): a point outside the box is in front of the tool, at least
        # its distance to the box away
        boxes = np.array([piece.bounds() for piece in self.pieces])
        self.box = np.array([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])

    def sharp_corners(self) -> np.ndarray:
        """The (r, z) points where the profile turns sharply (edges of the tool's solid)."""
        corners = [piece.point(which) for i, piece in enumerate(self.pieces) for which in (0, 1)
                   if self._end_sharp[i, which] and (which == 1 or i == 0)]
        return np.unique(np.array(corners).reshape(-1, 2), axis=0)

    def closest(self, q: np.ndarray):
        """Closest point (N, 2), distance (N,), sign test normal (N, 2), normal (N, 2), index
        of the piece and curvature of the profile there, for points q (N, 2) with r >= 0."""
        best_d2 = np.full(q.shape[0], np.inf)
        best_c = np.zeros_like(q)
        best_n = np.zeros_like(q)
        best_piece = np.zeros(q.shape[0], dtype=int)
        best_end = np.full(q.shape[0], -1)
        for i, piece in enumerate(self.pieces):
            c, n, end = piece.closest(q)
            d2 = np.sum((q - c) ** 2, axis=1)
            better = d2 < best_d2
            best_d2 = np.where(better, d2, best_d2)
            best_c[better] = c[better]
            best_n[better] = n[better]
            best_piece[better] = i
            best_end[better] = end[better]
        at_end = best_end >= 0
        which = np.clip(best_end, 0, 1)
        test_normal = np.where(at_end[:, None], self._end_normal[best_piece, which], best_n)
        sharp = at_end & self._end_sharp[best_piece, which]
        dist = np.sqrt(best_d2)
        sign = np.where(np.sum((q - best_c) * test_normal, axis=1) >= 0.0, 1.0, -1.0)
        towards = (q - best_c) / np.where(dist > 0.0, dist, 1.0)[:, None]
        use_direction = sharp & (dist > self.tol)
        normal = np.where(use_direction[:, None], sign[:, None] * towards,
                          np.where(sharp[:, None], test_normal, best_n))
        curvature = np.array([p.curvature() for p in self.pieces])[best_piece]
        return best_c, sign * dist, normal, best_piece, curvature


class AxisymmetricSurface:
    """The surface of revolution of a :class:`Profile` about the z axis, queried exactly."""

    def __init__(self, profile: Profile | Sequence[Piece], name: str = "tool"):
        self.profile = profile if isinstance(profile, Profile) else Profile(profile)
        self.name = name

    @staticmethod
    def _meridian(p: np.ndarray):
        r = np.hypot(p[:, 0], p[:, 1])
        on_axis = r <= 0.0
        e_r = np.zeros((p.shape[0], 3))
        e_r[:, 0] = np.where(on_axis, 1.0, p[:, 0] / np.where(on_axis, 1.0, r))
        e_r[:, 1] = np.where(on_axis, 0.0, p[:, 1] / np.where(on_axis, 1.0, r))
        return np.stack([r, p[:, 2]], axis=1), e_r

    def query(self, points, offset=None, cutoff: float | None = None) -> ContactQuery:
        """Exact for every point within ``cutoff`` (mm) of the tool's box in (r, z), and for
        all without a cutoff. A point farther from the box gets, in its meridian plane, the
        profile's first point as its closest point, that point's normal, and the distance to
        it as its gap: an upper bound of the true distance, which exceeds the cutoff."""
        p, shift = tool_frame(points, offset)
        q, e_r = self._meridian(p)
        c = np.empty_like(q)
        gap = np.empty(q.shape[0])
        n = np.empty_like(q)
        if cutoff is None:
            near = slice(None)
        else:
            outside = np.maximum(np.maximum(self.profile.box[0] - q, q - self.profile.box[1]), 0.0)
            far = np.einsum("ni,ni->n", outside, outside) > cutoff * cutoff
            near = ~far
            first = self.profile.pieces[0]
            c[far] = first.point(0)
            gap[far] = np.linalg.norm(q[far] - c[far], axis=1)
            tangent = first.tangent(0)
            n[far] = (tangent[1], -tangent[0])
        c[near], gap[near], n[near], _, _ = self.profile.closest(q[near])
        e_z = np.array([0.0, 0.0, 1.0])
        normal = n[:, :1] * e_r + n[:, 1:] * e_z
        closest = c[:, :1] * e_r + c[:, 1:] * e_z + shift
        return ContactQuery(gap, normal, closest)

    def principal_curvatures(self, points, offset=None) -> tuple[np.ndarray, np.ndarray]:
        """Absolute principal curvatures (1/mm) of the surface at the closest points: along the
        meridian (the profile's curvature) and along the parallel (|n_r| / r)."""
        p, _ = tool_frame(points, offset)
        q, _ = self._meridian(p)
        c, _, n, _, meridian = self.profile.closest(q)
        with np.errstate(divide="ignore", invalid="ignore"):
            parallel = np.where(c[:, 0] > self.profile.tol, np.abs(n[:, 0]) / c[:, 0], meridian)
        return meridian, parallel
