"""Rigid tool surfaces for contact: signed gap, normal and closest point (numpy and scipy only).

Every tool answers one question, vectorised over points (no Python loop over points)::

    gap, normal, closest = tool.query(points, offset)

* ``points`` (N, 3): current positions x = X + u of the membrane's quadrature points (mm).
* ``offset`` (3,): the tool's current rigid translation (the punch moved by the stroke); the
  tool is stored in its working position, so ``offset`` is (0, 0, -stroke) for the punch.
* ``gap`` (N,): signed distance to the tool's surface, positive in front of it (outside the
  tool's solid), negative inside (penetration).
* ``normal`` (N, 3): unit normal of the tool surface at the closest point, pointing away from
  the tool's solid (the direction the tool pushes the fabric).
* ``closest`` (N, 3): the closest point of the tool's surface, in the global frame.
* ``cutoff`` (mm, optional): exact answers are needed only for points within ``cutoff`` of the
  tool; farther points may get an upper bound of their distance (still > cutoff, positive
  outside). It makes queries of points far from a meshed tool cheap.

Two implementations:

* :class:`AxisymmetricSurface` -- exact, for tools of revolution about the z axis described by
  an (r, z) profile of segments and arcs (hemisphere punch and shank, die with its entry
  fillet, blank-holder ring). The closest point of a surface of revolution lies in the point's
  meridian half-plane, so the 3-D problem is a 2-D closest point on the profile.
* :class:`MeshedSurface` -- any triangulated surface (gmsh tools, STEP files): k-d trees on
  triangle centroids propose candidates, the exact point-triangle projection is evaluated over
  them, and lower bounds certify the answer (candidates are added until they do), so the
  result is the exact closest point of the triangulation. Normals are interpolated from vertex
  normals with the barycentric coordinates of the closest point: a continuous normal field.

The method and its accuracy are described in ``docs/contact.md``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple, Protocol, Sequence

import numpy as np
from scipy.spatial import cKDTree


class ContactQuery(NamedTuple):
    """What a tool reports for N points (see the module docstring)."""

    gap: np.ndarray
    normal: np.ndarray
    closest: np.ndarray


class RigidSurface(Protocol):
    name: str

    def query(self, points, offset=None, cutoff: float | None = None) -> ContactQuery: ...


def _tool_frame(points, offset) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), not {points.shape}")
    shift = np.zeros(3) if offset is None else np.asarray(offset, dtype=float).reshape(3)
    return points - shift, shift


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(norm > 0.0, norm, 1.0)


# --- analytic tools of revolution -------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Segment:
    """A straight piece of a profile in the (r, z) half-plane, from ``start`` to ``end``."""

    start: tuple[float, float]
    end: tuple[float, float]

    def point(self, which: int) -> np.ndarray:
        return np.array(self.start if which == 0 else self.end, dtype=float)

    def tangent(self, which: int) -> np.ndarray:
        return _unit(np.subtract(self.end, self.start).astype(float))

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
        p, shift = _tool_frame(points, offset)
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
        p, _ = _tool_frame(points, offset)
        q, _ = self._meridian(p)
        c, _, n, _, meridian = self.profile.closest(q)
        with np.errstate(divide="ignore", invalid="ignore"):
            parallel = np.where(c[:, 0] > self.profile.tol, np.abs(n[:, 0]) / c[:, 0], meridian)
        return meridian, parallel


# --- triangulated tools -----------------------------------------------------------------------

@dataclasses.dataclass
class TriangleSurface:
    """A triangulated tool surface: nodes (V, 3) in mm, triangles (T, 3) node indices, unit
    vertex normals (V, 3) pointing away from the tool's solid, and the tool's name."""

    name: str
    nodes: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray

    def __post_init__(self):
        self.nodes = np.ascontiguousarray(self.nodes, dtype=float)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int64)
        self.normals = np.ascontiguousarray(self.normals, dtype=float)
        if self.nodes.ndim != 2 or self.nodes.shape[1] != 3:
            raise ValueError("nodes must have shape (V, 3)")
        if self.triangles.ndim != 2 or self.triangles.shape[1] != 3 or self.triangles.size == 0:
            raise ValueError("triangles must have shape (T, 3), T >= 1")
        if self.normals.shape != self.nodes.shape:
            raise ValueError("normals must have the shape of nodes")
        if self.triangles.min() < 0 or self.triangles.max() >= len(self.nodes):
            raise ValueError("triangle node index out of range")

    def triangle_normals(self) -> np.ndarray:
        a, b, c = (self.nodes[self.triangles[:, i]] for i in range(3))
        return _unit(np.cross(b - a, c - a))

    def edge_lengths(self) -> np.ndarray:
        a, b, c = (self.nodes[self.triangles[:, i]] for i in range(3))
        return np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                         np.linalg.norm(a - c, axis=1)], axis=1)

    def translated(self, offset) -> "TriangleSurface":
        return TriangleSurface(self.name, self.nodes + np.asarray(offset, dtype=float),
                               self.triangles.copy(), self.normals.copy())


def closest_point_on_triangles(p, a, b, c):
    """Closest points of triangles (a, b, c) to points p, all (M, 3), paired row by row.

    Returns (closest (M, 3), barycentric coordinates (M, 3) of the closest point with respect
    to a, b, c, squared distance (M,)). Voronoi-region method (Ericson, Real-Time Collision
    Detection, 2005, sec. 5.1.5), vectorised; degenerate triangles fall back to their edges.
    """
    ab, ac, ap = b - a, c - a, p - a
    bp, cp = p - b, p - c
    dot = lambda u, v: np.einsum("ij,ij->i", u, v)
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in = vb / denom
        w_in = vc / denom
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    m = p.shape[0]
    bary = np.empty((m, 3))
    bary[:, 0] = 1.0 - v_in - w_in
    bary[:, 1] = v_in
    bary[:, 2] = w_in
    # regions, the last assignment winning: interior first, then edges, then vertices
    regions = [
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), lambda: (0.0, 1.0 - t_bc, t_bc)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), lambda: (1.0 - t_ac, 0.0, t_ac)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), lambda: (1.0 - t_ab, t_ab, 0.0)),
        ((d6 >= 0) & (d5 <= d6), lambda: (0.0, 0.0, 1.0)),
        ((d3 >= 0) & (d4 <= d3), lambda: (0.0, 1.0, 0.0)),
        ((d1 <= 0) & (d2 <= 0), lambda: (1.0, 0.0, 0.0)),
    ]
    for mask, value in regions:
        if np.any(mask):
            u, v, w = value()
            for k, coord in enumerate((u, v, w)):
                bary[mask, k] = coord if np.isscalar(coord) else coord[mask]
    bad = ~np.all(np.isfinite(bary), axis=1)
    if np.any(bad):  # degenerate (zero-area) triangles: the best of their three edges
        bary[bad] = _degenerate_bary(p[bad], a[bad], b[bad], c[bad])
    closest = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    d2_out = np.einsum("ij,ij->i", p - closest, p - closest)
    return closest, bary, d2_out


def _degenerate_bary(p, a, b, c):
    best = np.full(p.shape[0], np.inf)
    bary = np.zeros((p.shape[0], 3))
    for i, j in ((0, 1), (1, 2), (0, 2)):
        x, y = (a, b, c)[i], (a, b, c)[j]
        e = y - x
        ee = np.einsum("ij,ij->i", e, e)
        t = np.clip(np.einsum("ij,ij->i", p - x, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
        q = x + t[:, None] * e
        d2 = np.einsum("ij,ij->i", p - q, p - q)
        better = d2 < best
        best = np.where(better, d2, best)
        bary[better] = 0.0
        bary[better, i] = 1.0 - t[better]
        bary[better, j] = t[better]
    return bary


class MeshedSurface:
    """Exact closest points on a triangulated surface, with interpolated normals.

    Search (vectorised over points; docs/contact.md):

    1. a k-d tree on all triangle centroids gives each point its ``k`` nearest centroids; the
       exact point-triangle distance to those triangles is an upper bound d on the distance;
       the next 3 k nearest are evaluated where their lower bound (below) is under d, and if
       the last of them is farther than d + R_c, class c (below) holds no better triangle;
    2. triangles are grouped by their radius r (largest centroid-to-vertex distance) into
       classes spanning a factor 2, one k-d tree each. A triangle of class c whose centroid
       is farther than d + R_c (R_c the class's largest radius) cannot be closer than d, so
       each class tree is asked for its nearest centroids until they leave that ball. Of those,
       a triangle is evaluated only if its lower bound max(|x - centroid| - r,
       |(x - centroid) . n|) (n its plane's normal) is below the current d; d shrinks as
       triangles are evaluated.

    So the result is the exact closest point of the triangulation, whatever k. Grouping by
    size keeps the balls tight where the mesh is fine (fillets) although flat faces carry
    large triangles; the plane bound discards most candidates near flat or gently curved
    regions.

    ``cutoff`` (mm, optional): balls are limited to cutoff + R_c. Points within ``cutoff`` of
    the surface still get the exact answer; for points farther away the reported distance is
    an upper bound of the true one, which is > cutoff. A finite-element solver needs exact
    answers near the tools only, and this bounds the cost of points far from them.

    Candidate lists (``margin`` > 0, mm; for a solver that asks about the same points again
    and again as they move a little): :meth:`query` keeps, per point, the position p0 where it
    last searched, its distance d0 there, and the triangles within d0 + 2 margin of p0.
    While a point stays within ``margin`` of p0, its closest triangle is among
    them (a triangle left out is farther than d0 + 2 margin - margin from it, while the one
    closest at p0 is nearer than d0 + margin), and of them only those within d0 + 2 delta of
    p0 (delta the point's move since p0) can be closest: only these are evaluated, 2-5 per
    point in a Newton iteration. A point that moved farther than margin is searched again.
    Points farther than cutoff + margin at p0 keep their closest
    triangle then, whose distance stays an upper bound, above cutoff. So the answers are those
    of the search without the lists. The lists are kept for one set of points (their number
    and the cutoff): another set starts them again.
    """

    def __init__(self, surface: TriangleSurface, k: int = 2, workers: int = 1,
                 margin: float = 0.0):
        self.surface = surface
        self.name = surface.name
        tri = surface.triangles
        self._a = surface.nodes[tri[:, 0]]
        self._b = surface.nodes[tri[:, 1]]
        self._c = surface.nodes[tri[:, 2]]
        self._centroids = (self._a + self._b + self._c) / 3.0
        self._radii = np.max([np.linalg.norm(v - self._centroids, axis=1)
                              for v in (self._a, self._b, self._c)], axis=0)
        self._plane = _unit(np.cross(self._b - self._a, self._c - self._a))
        # per triangle, for _project: edges e0 = b - a, e1 = c - a and their dot products
        self._e0, self._e1 = self._b - self._a, self._c - self._a
        e0e0 = np.einsum("ij,ij->i", self._e0, self._e0)
        e0e1 = np.einsum("ij,ij->i", self._e0, self._e1)
        e1e1 = np.einsum("ij,ij->i", self._e1, self._e1)
        self._gram = np.stack([e0e0, e0e1, e1e1, e0e0 * e1e1 - e0e1 ** 2], axis=1)
        self.radius = float(self._radii.max())
        self._tree = cKDTree(self._centroids)
        smallest = max(float(self._radii.min()), 1e-9 * max(1.0, self.radius))
        level = np.floor(np.log2(np.maximum(self._radii, smallest) / smallest)).astype(int)
        self._classes = []
        for lvl in np.unique(level):
            members = np.nonzero(level == lvl)[0]
            self._classes.append((cKDTree(self._centroids[members]), members,
                                  float(self._radii[members].max())))
        self._normals = _unit(surface.normals)
        self.n_triangles = len(tri)
        self.k = max(1, min(k, self.n_triangles))
        self.workers = workers
        self.margin = float(margin)
        self._lists = None          # the candidate lists (margin > 0), see _query_listed
        self.pairs_evaluated = 0    # counters, for benchmarks
        self.searched = 0           # points searched (not answered from their lists)

    def _project(self, q, tris):
        """Squared distances (M,) and barycentric coordinates (M, 3) of the closest points of
        triangles ``tris`` (M,) to points q (M, 3), paired row by row: the projection on the
        triangle's plane where it falls inside the triangle, else the nearest of its three
        edges' closest points (the closest point of a triangle to a point whose projection
        lies outside it is on its boundary). Per pair only w = q - a, |w|^2, w.e0 and w.e1
        are vectors; the rest is scalars of the triangle (precomputed), which makes it several
        times cheaper than :func:`closest_point_on_triangles` (the reference, which it
        matches to round-off)."""
        w = q - self._a[tris]
        ww = np.einsum("ij,ij->i", w, w)
        s0 = np.einsum("ij,ij->i", w, self._e0[tris])
        s1 = np.einsum("ij,ij->i", w, self._e1[tris])
        g = self._gram[tris]
        d00, d01, d11, det = g[:, 0], g[:, 1], g[:, 2], g[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            v = (d11 * s0 - d01 * s1) / det
            t = (d00 * s1 - d01 * s0) / det
        inside = (v >= 0.0) & (t >= 0.0) & (v + t <= 1.0) & (det > 0.0)
        bary = np.empty((tris.size, 3))
        bary[:, 1], bary[:, 2] = v, t
        bary[:, 0] = 1.0 - v - t
        d2 = ww - v * s0 - t * s1
        out = np.flatnonzero(~inside)
        if out.size:
            ww, s0, s1 = ww[out], s0[out], s1[out]
            d00, d01, d11 = d00[out], d01[out], d11[out]
            # edges a-b, a-c and b-c: the clamped parameter along each, and the squared distance
            s2, d22 = s1 - s0 - d01 + d00, d11 - 2.0 * d01 + d00
            with np.errstate(divide="ignore", invalid="ignore"):
                t0 = np.clip(np.where(d00 > 0.0, s0 / d00, 0.0), 0.0, 1.0)
                t1 = np.clip(np.where(d11 > 0.0, s1 / d11, 0.0), 0.0, 1.0)
                t2 = np.clip(np.where(d22 > 0.0, s2 / d22, 0.0), 0.0, 1.0)
            edge = np.stack([ww - 2.0 * t0 * s0 + t0 * t0 * d00,
                             ww - 2.0 * t1 * s1 + t1 * t1 * d11,
                             ww - 2.0 * s0 + d00 - 2.0 * t2 * s2 + t2 * t2 * d22], axis=1)
            which = np.argmin(edge, axis=1)
            d2[out] = edge[np.arange(out.size), which]
            zero = np.zeros(out.size)
            tt = np.choose(which, [t0, t1, t2])
            bary[out] = np.stack([np.choose(which, [1.0 - tt, 1.0 - tt, zero]),
                                  np.choose(which, [tt, zero, 1.0 - tt]),
                                  np.choose(which, [zero, tt, tt])], axis=1)
        return np.maximum(d2, 0.0), bary

    def _evaluate(self, p, rows, tris, best):
        """Exact distances for the pairs (p[rows[i]], triangle tris[i]); keeps the closest per
        point in best = (triangle, barycentric coordinates, squared distance)."""
        if rows.size == 0:
            return
        tri_best, bary_best, d2_best = best
        self.pairs_evaluated += rows.size
        d2, bary = self._project(p[rows], tris)
        order = np.lexsort((d2, rows))
        rows_sorted = rows[order]
        first = np.ones(rows.size, dtype=bool)
        first[1:] = rows_sorted[1:] != rows_sorted[:-1]
        pick = order[first]
        rows, d2 = rows[pick], d2[pick]
        better = d2 < d2_best[rows]
        upd, pick = rows[better], pick[better]
        tri_best[upd] = tris[pick]
        bary_best[upd] = bary[pick]
        d2_best[upd] = d2[better]

    def closest_triangles(self, points, cutoff: float | None = None, chunk: int = 50_000):
        """Index of the closest triangle, barycentric coordinates of the closest point in it,
        and the distance, for points (N, 3) in the tool's own frame."""
        p = np.ascontiguousarray(points, dtype=float)
        n = p.shape[0]
        best = (np.zeros(n, dtype=np.int64), np.zeros((n, 3)), np.full(n, np.inf))
        for lo in range(0, n, chunk):  # chunks bound the memory of the candidate arrays
            self._search(p, np.arange(lo, min(n, lo + chunk)), cutoff, best)
        return best[0], best[1], np.sqrt(best[2])

    # --- candidate lists -----------------------------------------------------------------
    def _query_listed(self, p, cutoff):
        """closest_triangles(p, cutoff) through the candidate lists (class docstring)."""
        n, m = p.shape[0], self.margin
        lists = self._lists
        if lists is None or lists["n"] != n or lists["cutoff"] != cutoff:
            lists = self._lists = {"n": n, "cutoff": cutoff, "origin": p.copy(),
                                   "d0": np.zeros(n), "start": np.zeros(n + 1, dtype=np.int64),
                                   "tris": np.zeros(0, dtype=np.int64), "dist": np.zeros(0)}
            moved = np.arange(n)
        else:
            moved = np.flatnonzero(np.linalg.norm(p - lists["origin"], axis=1) > m)
        if moved.size:
            self._relist(p, moved, cutoff)
        start, tris = lists["start"], lists["tris"]
        rows = np.repeat(np.arange(n), np.diff(start))
        # a point moved by delta since p0 is nearer than d0 + delta to its closest triangle at
        # p0, and any triangle farther than d0 + 2 delta from p0 is farther than that from it:
        # only the entries within d0 + 2 delta are evaluated (delta << margin within a step)
        delta = np.linalg.norm(p - lists["origin"], axis=1)
        bound = lists["d0"] + 2.0 * delta + 1e-9 * (1.0 + lists["d0"])
        use = np.flatnonzero(lists["dist"] <= bound[rows])
        rows, tris = rows[use], tris[use]
        self.pairs_evaluated += rows.size
        d2, bary = self._project(p[rows], tris)
        first = np.searchsorted(rows, np.arange(n))       # every point keeps its p0 closest
        least = np.minimum.reduceat(d2, first)
        at = np.flatnonzero(d2 == least[rows])
        _, pick = np.unique(rows[at], return_index=True)
        pick = at[pick]
        return tris[pick], bary[pick], np.sqrt(d2[pick])

    def _relist(self, p, moved, cutoff):
        """Search the points ``moved`` again and replace their lists (and origins)."""
        lists, m = self._lists, self.margin
        q = p[moved]
        self.searched += moved.size
        reach = None if cutoff is None else cutoff + m
        tri, _, dist = self.closest_triangles(q, reach)
        near = np.ones(moved.size, dtype=bool) if reach is None else dist <= reach
        # first every point's closest at p0 with its distance d0 (so that np.unique below keeps
        # that entry); far points keep only it (an upper bound, above the cutoff)
        rows, cand, dists = [np.arange(moved.size)], [tri], [dist]
        inside = np.flatnonzero(near)
        radius = dist[inside] + 2.0 * m
        for tree, members, r_class in self._classes:
            found = tree.query_ball_point(q[inside], radius + r_class, workers=self.workers,
                                          return_sorted=False)
            sizes = np.fromiter((len(f) for f in found), dtype=np.int64, count=found.size)
            if not sizes.sum():
                continue
            local = np.repeat(np.arange(inside.size), sizes)
            members_found = members[np.concatenate([f for f in found if f]).astype(np.int64)]
            centre = np.linalg.norm(q[inside][local] - self._centroids[members_found], axis=1)
            lower = self._lower_bound(q[inside][local], members_found[:, None],
                                      centre[:, None])[:, 0]
            keep = np.flatnonzero(lower <= radius[local])
            local, members_found = local[keep], members_found[keep]
            # the list holds the triangles within d0 + 2 margin: their exact distance decides
            d2, _ = self._project(q[inside][local], members_found)
            keep = d2 <= radius[local] ** 2
            rows.append(inside[local[keep]])
            cand.append(members_found[keep])
            dists.append(np.sqrt(d2[keep]))
        rows, cand, dists = np.concatenate(rows), np.concatenate(cand), np.concatenate(dists)
        # the new lists (rows index into moved) replace the old ones of those points
        n = lists["n"]
        start, tris = lists["start"], lists["tris"]
        old_rows = np.repeat(np.arange(n), np.diff(start))
        stays = np.ones(n, dtype=bool)
        stays[moved] = False
        keep_old = stays[old_rows]
        all_rows = np.concatenate([old_rows[keep_old], moved[rows]])
        all_tris = np.concatenate([tris[keep_old], cand])
        all_dist = np.concatenate([lists["dist"][keep_old], dists])
        # sorted by point, no repeats (the closest at p0 comes twice: the first, d0, is kept)
        key, first = np.unique(all_rows * self.n_triangles + all_tris, return_index=True)
        lists["tris"] = key % self.n_triangles
        lists["dist"] = all_dist[first]
        lists["start"] = np.searchsorted(key // self.n_triangles, np.arange(n + 1))
        lists["origin"][moved] = q
        lists["d0"][moved] = dist

    def _lower_bound(self, p, tris, dist):
        """Lower bound of the distance from points p (n, 3) to triangles tris (n, k) whose
        centroids are dist (n, k) away: max(dist - r, distance to the triangle's plane)."""
        rel = p[:, None, :] - self._centroids[tris]
        plane = np.abs(np.einsum("ijk,ijk->ij", rel, self._plane[tris]))
        return np.maximum(dist - self._radii[tris], plane)

    def _search(self, p, rows, cutoff, best):
        # 1. the k nearest centroids give d; the next ones are evaluated if they may beat it
        k0 = min(self.k, self.n_triangles)
        k1 = min(max(4 * self.k, 8), self.n_triangles)
        dist, idx = self._tree.query(p[rows], k=k1, workers=self.workers)
        dist, idx = dist.reshape(rows.size, k1), idx.reshape(rows.size, k1)
        self._evaluate(p, np.repeat(rows, k0), idx[:, :k0].ravel(), best)
        if k1 > k0:
            lower = self._lower_bound(p[rows], idx[:, k0:], dist[:, k0:])
            i, j = np.nonzero(lower ** 2 < best[2][rows][:, None])
            self._evaluate(p, rows[i], idx[:, k0:][i, j], best)
        if k1 == self.n_triangles:
            return
        global_kth = dist[:, -1]
        # 2. per size class, the centroids within d + R_c not among those k1
        for tree, members, r_class in self._classes:
            reach = np.sqrt(best[2][rows]) + r_class
            if cutoff is not None:
                reach = np.minimum(reach, cutoff + r_class)
            open_ = global_kth < reach              # else no unseen centroid is within reach
            pending, k = rows[open_], min(4, members.size)
            while pending.size:
                reach = np.sqrt(best[2][pending]) + r_class
                if cutoff is not None:
                    reach = np.minimum(reach, cutoff + r_class)
                # the bound only prunes the tree search (centroids beyond it come back as inf)
                dist, local = tree.query(p[pending], k=k, distance_upper_bound=float(reach.max()),
                                         workers=self.workers)
                dist, local = dist.reshape(pending.size, k), local.reshape(pending.size, k)
                tris = members[np.minimum(local, members.size - 1)]
                lower = self._lower_bound(p[pending], tris, dist)
                need = (dist <= reach[:, None]) & (lower ** 2 < best[2][pending][:, None])
                i, j = np.nonzero(need)
                self._evaluate(p, pending[i], tris[i, j], best)
                more = (dist[:, -1] <= reach) & (k < members.size)
                pending, k = pending[more], min(4 * k, members.size)

    def query(self, points, offset=None, cutoff: float | None = None) -> ContactQuery:
        p, shift = _tool_frame(points, offset)
        if self.margin > 0.0:
            tri, bary, dist = self._query_listed(p, cutoff)
        else:
            self.searched += p.shape[0]
            tri, bary, dist = self.closest_triangles(p, cutoff)
        nodes = self.surface.triangles[tri]
        normal = _unit(np.einsum("ij,ijk->ik", bary, self._normals[nodes]))
        closest = np.einsum("ij,ijk->ik", bary, self.surface.nodes[nodes])
        dist = np.linalg.norm(p - closest, axis=1)      # from the point, not |w|^2 - ...
        side = np.einsum("ij,ij->i", p - closest, normal)
        gap = np.where(side >= 0.0, dist, -dist)
        return ContactQuery(gap, normal, closest + shift)
