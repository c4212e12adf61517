"""Exact tool surfaces of revolution about the z axis (hemisphere punch, die, holder).

A tool is an (r, z) :class:`Profile` of :class:`Segment` and :class:`Arc` pieces, running with
the tool's material on its left; :class:`AxisymmetricSurface` answers the contact query
(:mod:`drape.forming.tool_query`) exactly: the closest point of a surface of revolution lies in
the point's meridian half-plane, so the 3-D problem is a 2-D closest point on the profile,
searched point by point in a loop compiled with numba (it runs at every residual).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numba
import numpy as np

from drape.forming.tool_query import ContactQuery, tool_frame, unit

jit = numba.njit(cache=True)
#: kinds of profile piece in the compiled search
SEGMENT, ARC = 0, 1


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

    def encoded(self) -> tuple[int, tuple]:
        """(kind, parameters) of the compiled closest-point search (_closest_points)."""
        return SEGMENT, (*self.start, *self.end, 0.0, 0.0)


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

    def encoded(self) -> tuple[int, tuple]:
        """(kind, parameters) of the compiled closest-point search (_closest_points)."""
        lo, hi = sorted((self.start_angle, self.end_angle))
        return ARC, (*self.centre, self.radius, lo, hi, 1.0 if self.ccw else 0.0)


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
        encoded = [piece.encoded() for piece in self.pieces]
        self._kinds = np.array([kind for kind, _ in encoded], dtype=np.int64)
        self._parameters = np.array([parameters for _, parameters in encoded], dtype=float)
        self._curvatures = np.array([piece.curvature() for piece in self.pieces])

    def sharp_corners(self) -> np.ndarray:
        """The (r, z) points where the profile turns sharply (edges of the tool's solid)."""
        corners = [piece.point(which) for i, piece in enumerate(self.pieces) for which in (0, 1)
                   if self._end_sharp[i, which] and (which == 1 or i == 0)]
        return np.unique(np.array(corners).reshape(-1, 2), axis=0)

    def closest(self, q: np.ndarray):
        """Closest point (N, 2), signed distance (N,), normal (N, 2), index of the piece and
        curvature of the profile there, for points q (N, 2) with r >= 0."""
        q = np.ascontiguousarray(q, dtype=float)
        c, distance, normal = np.empty_like(q), np.empty(q.shape[0]), np.empty_like(q)
        piece = np.empty(q.shape[0], dtype=np.int64)
        _closest_points(q, self._kinds, self._parameters, self._end_normal, self._end_sharp,
                        self.tol, c, distance, normal, piece)
        return c, distance, normal, piece, self._curvatures[piece]


@jit
def _on_piece(q0, q1, kind, g):
    """Closest point (c0, c1) of (q0, q1) on one piece, its normal (n0, n1) and which end it
    is (0, 1; -1 inside): a segment g = (a0, a1, b0, b1), an arc g = (centre0, centre1,
    radius, lo, hi, ccw) with lo < hi its ends' polar angles."""
    if kind == SEGMENT:
        a0, a1, ab0, ab1 = g[0], g[1], g[2] - g[0], g[3] - g[1]
        t = min(max(((q0 - a0) * ab0 + (q1 - a1) * ab1) / (ab0 * ab0 + ab1 * ab1), 0.0), 1.0)
        length = math.hypot(ab0, ab1)
        end = 0 if t <= 0.0 else (1 if t >= 1.0 else -1)
        return a0 + t * ab0, a1 + t * ab1, ab1 / length, -ab0 / length, end
    centre0, centre1, radius, lo, hi, ccw = g[0], g[1], g[2], g[3], g[4], g[5] > 0.5
    rel = (math.atan2(q1 - centre1, q0 - centre0) - lo) % (2.0 * math.pi)
    inside = rel <= (hi - lo) + 1e-15
    lo0, lo1 = centre0 + radius * math.cos(lo), centre1 + radius * math.sin(lo)
    hi0, hi1 = centre0 + radius * math.cos(hi), centre1 + radius * math.sin(hi)
    nearer_lo = (q0 - lo0) ** 2 + (q1 - lo1) ** 2 <= (q0 - hi0) ** 2 + (q1 - hi1) ** 2
    angle = lo + rel if inside else (lo if nearer_lo else hi)
    radial0, radial1 = math.cos(angle), math.sin(angle)
    sense = 1.0 if ccw else -1.0
    if inside:
        end = -1
    elif nearer_lo:
        end = 0 if ccw else 1
    else:
        end = 1 if ccw else 0
    return (centre0 + radius * radial0, centre1 + radius * radial1, sense * radial0,
            sense * radial1, end)


@jit
def _closest_one(q0, q1, kinds, parameters, end_normal, end_sharp, tol):
    """Profile.closest at one point: the nearest piece (the first of equally near ones); the
    sign from the piece's normal, or at a piece's end from the pseudo-normal of the two pieces
    meeting there; at a sharp corner the normal is the direction to the point. Returns the
    closest point, the signed distance, the normal and the piece."""
    best, best_piece, best_end = math.inf, 0, -1
    c0 = c1 = n0 = n1 = 0.0
    for k in range(kinds.shape[0]):
        p0, p1, m0, m1, end = _on_piece(q0, q1, kinds[k], parameters[k])
        d2 = (q0 - p0) ** 2 + (q1 - p1) ** 2
        if d2 < best:
            best, best_piece, best_end = d2, k, end
            c0, c1, n0, n1 = p0, p1, m0, m1
    test0, test1, sharp = n0, n1, False
    if best_end >= 0:
        test0 = end_normal[best_piece, best_end, 0]
        test1 = end_normal[best_piece, best_end, 1]
        sharp = end_sharp[best_piece, best_end]
    dist = math.sqrt(best)
    sign = 1.0 if (q0 - c0) * test0 + (q1 - c1) * test1 >= 0.0 else -1.0
    if sharp and dist > tol:
        n0, n1 = sign * (q0 - c0) / dist, sign * (q1 - c1) / dist
    elif sharp:
        n0, n1 = test0, test1
    return c0, c1, sign * dist, n0, n1, best_piece


@jit
def _closest_points(q, kinds, parameters, end_normal, end_sharp, tol, c, distance, normal,
                    piece):
    for i in range(q.shape[0]):
        c[i, 0], c[i, 1], distance[i], normal[i, 0], normal[i, 1], piece[i] = _closest_one(
            q[i, 0], q[i, 1], kinds, parameters, end_normal, end_sharp, tol)


@jit
def _query_points(points, shift, box, cutoff, first, first_normal, kinds, parameters,
                  end_normal, end_sharp, tol, gap, normal, closest):
    """AxisymmetricSurface.query at every point: the point's meridian half-plane (r, z) and
    radial direction e_r (e_x on the axis), the closest point of the profile there (or, farther
    than ``cutoff`` from the box, its first point), mapped back to 3-D."""
    for i in range(points.shape[0]):
        x, y, z = points[i, 0] - shift[0], points[i, 1] - shift[1], points[i, 2] - shift[2]
        r = math.hypot(x, y)
        e0, e1 = (1.0, 0.0) if r <= 0.0 else (x / r, y / r)
        out_r = max(max(box[0, 0] - r, r - box[1, 0]), 0.0)
        out_z = max(max(box[0, 1] - z, z - box[1, 1]), 0.0)
        if out_r * out_r + out_z * out_z > cutoff * cutoff:
            c0, c1, n0, n1 = first[0], first[1], first_normal[0], first_normal[1]
            signed = math.sqrt((r - c0) ** 2 + (z - c1) ** 2)
        else:
            c0, c1, signed, n0, n1, _ = _closest_one(r, z, kinds, parameters, end_normal,
                                                     end_sharp, tol)
        gap[i] = signed
        normal[i, 0], normal[i, 1], normal[i, 2] = n0 * e0, n0 * e1, n1
        closest[i, 0] = c0 * e0 + shift[0]
        closest[i, 1] = c0 * e1 + shift[1]
        closest[i, 2] = c1 + shift[2]


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
        points = np.ascontiguousarray(points, dtype=float)
        _, shift = tool_frame(points, offset)
        profile, first = self.profile, self.profile.pieces[0]
        tangent = first.tangent(0)
        gap, normal, closest = np.empty(len(points)), np.empty_like(points), np.empty_like(points)
        _query_points(points, shift, profile.box, math.inf if cutoff is None else float(cutoff),
                      first.point(0), np.array([tangent[1], -tangent[0]]), profile._kinds,
                      profile._parameters, profile._end_normal, profile._end_sharp, profile.tol,
                      gap, normal, closest)
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


def warm_up() -> None:
    """Compile (or load from numba's cache) the closest-point kernels: one query of a flat
    profile with an arc."""
    surface = AxisymmetricSurface(Profile([Arc((0.0, 1.0), 1.0, -0.5 * math.pi, 0.0),
                                           Segment((1.0, 1.0), (0.0, 1.0))]))
    surface.query(np.zeros((1, 3)), cutoff=1.0)
    surface.principal_curvatures(np.zeros((1, 3)))
