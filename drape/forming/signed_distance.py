"""Solids given by an exact signed distance, and the rules that combine them (numpy only; mm).

A :class:`Solid` answers ``signed_distance(P) -> Distance(sd, grad)`` for points P (3, N):
the signed distance to its boundary (negative inside) and its unit gradient. The pieces here
are those the double-dome tools (:mod:`drape.forming.double_dome`) are made of:

* :func:`intersection` -- the signed distance of A and B from those of A and B and the curve
  where their boundaries meet (exact outside when told whose closest points count);
* :class:`Stadium`, :class:`StadiumPrism` -- the plane capsule and its vertical prism;
* :class:`Dilated` -- a solid grown by a ball: its distance minus the radius (exact outside);
* :class:`PlateWithOpening` -- a half-space minus a hole whose wall is vertical at the plane;
* :class:`SignedDistanceSurface` -- a solid as a rigid tool: the contact query of
  :mod:`drape.forming.tool_query` (gap = sd, normal = grad, closest = P - sd grad).
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np

from drape.forming.tool_query import ContactQuery, tool_frame, unit


class Distance(NamedTuple):
    """Signed distance sd (N,) to a solid's boundary (negative inside) and its gradient grad
    (3, N), a unit vector; the closest boundary point is P - sd * grad.

    Points here (and in drape.forming.double_dome) are (3, N) arrays P, one contiguous row per
    coordinate (numpy is several times faster on them than on the columns of an (N, 3)
    array)."""

    sd: np.ndarray
    grad: np.ndarray


class Solid(Protocol):
    def signed_distance(self, P: np.ndarray) -> Distance: ...


TINY = 1e-300     # a floor for divisors that are zero only at isolated points


def norm2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """sqrt(a^2 + b^2) (np.hypot guards against overflow, needless in mm, and is several
    times slower)."""
    return np.sqrt(a * a + b * b)


def boundary_point(P: np.ndarray, d: Distance) -> np.ndarray:
    """The closest boundary points P - sd grad (3, N)."""
    return P - d.sd * d.grad


def length_and_direction(rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Length and unit direction of the vectors rel (3, M)."""
    return np.sqrt(np.einsum("ij,ij->j", rel, rel)), unit(rel.T).T


def intersection(P: np.ndarray, a: Distance, a_ok: np.ndarray, b: Distance, b_ok: np.ndarray,
                 edge_point) -> Distance:
    """Signed distance to the intersection of two solids A and B, from theirs.

    Inside both: the larger of the two (exact for an intersection). Outside: if P is outside
    A and A's closest point lies in B (``a_ok``), that point is the closest point of A and B
    (its distance, d(P, A), bounds d(P, A and B) from below); likewise for B (``b_ok``);
    where neither holds, the closest point is on the edge where the two boundaries meet,
    given by ``edge_point(points (3, M)) -> (3, M)``."""
    inside = (a.sd <= 0.0) & (b.sd <= 0.0)
    a_ok = a_ok & (a.sd > 0.0)
    b_ok = b_ok & (b.sd > 0.0)
    use_b = np.where(inside, b.sd > a.sd, b_ok & ~a_ok)
    sd = np.where(use_b, b.sd, a.sd)
    grad = np.where(use_b, b.grad, a.grad)
    edge = np.nonzero(~inside & ~a_ok & ~b_ok)[0]
    if edge.size:
        E = P[:, edge]
        sd[edge], grad[:, edge] = length_and_direction(E - edge_point(E))
    return Distance(sd, grad)


# --- the stadium footprint ----------------------------------------------------------------------

class Stadium:
    """The plane stadium (capsule) of points within ``half_width`` of the segment |x| <=
    ``half_length``, y = 0: two half-discs centred at (+-half_length, 0) joined by straight
    sides y = +-half_width. Its signed distance is the distance to the segment minus the
    half-width, exact everywhere."""

    def __init__(self, half_length: float, half_width: float):
        if half_length < 0 or half_width <= 0:
            raise ValueError(f"not a stadium: half length {half_length}, half width "
                             f"{half_width}")
        self.half_length = float(half_length)
        self.half_width = float(half_width)

    def signed_distance(self, x: np.ndarray, y: np.ndarray):
        """Signed distance (N,) of the points (x, y) and the unit gradient (gx, gy); the
        closest point of the stadium's boundary is (x, y) - sd (gx, gy)."""
        dx = x - np.minimum(np.maximum(x, -self.half_length), self.half_length)
        r = norm2(dx, y)
        inv = 1.0 / np.maximum(r, TINY)
        gx, gy = dx * inv, y * inv
        on_axis = np.nonzero(r <= 0.0)[0]    # on the segment: any side will do, take +y
        gy[on_axis] = 1.0
        return r - self.half_width, gx, gy


class StadiumPrism:
    """The vertical prism (unbounded in z) on a :class:`Stadium`."""

    def __init__(self, stadium: Stadium):
        self.stadium = stadium

    def signed_distance(self, P: np.ndarray) -> Distance:
        sd, gx, gy = self.stadium.signed_distance(P[0], P[1])
        return Distance(sd, np.stack([gx, gy, np.zeros_like(gx)]))


# --- dilation, plates with an opening, the tool ------------------------------------------------

class Dilated:
    """A solid dilated by a ball of ``radius`` (Minkowski sum): its signed distance minus the
    radius (exact outside the solid)."""

    def __init__(self, solid: Solid, radius: float):
        self.solid, self.radius = solid, float(radius)

    def signed_distance(self, P: np.ndarray) -> Distance:
        d = self.solid.signed_distance(P)
        return Distance(d.sd - self.radius, d.grad)


class PlateWithOpening:
    """Q = a half-space minus a hole: {z <= z0} (``above=False``, the die) or {z >= z0}
    (``above=True``, the holder) minus the solid ``hole``, whose section by the plane z = z0
    is the stadium ``rim`` and whose boundary is vertical there (so the plane's points are
    outside the hole exactly where they are outside the rim, and Q's edge is the rim curve at
    z0).

    Inside Q: the larger of the plane's signed distance and minus the hole's. Outside: the
    nearest of (a) the point's projection on the plane if it is outside the rim, (b) the
    hole's closest boundary point if it is on Q's side of the plane, (c) the rim curve at z0
    where neither is."""

    def __init__(self, z0: float, above: bool, hole: Solid, rim: Stadium):
        self.z0, self.above, self.hole, self.rim = float(z0), bool(above), hole, rim
        self._up = -1.0 if above else 1.0        # the plane's gradient is (0, 0, up)

    def signed_distance(self, P: np.ndarray) -> Distance:
        """Q = the half-space intersected with the hole's complement (:func:`intersection`):
        the plane's closest point counts if it is outside the rim, the hole's if it is on
        Q's side of the plane."""
        up, z0 = self._up, self.z0
        plane_grad = np.zeros_like(P)
        plane_grad[2] = up
        plane = Distance(up * (P[2] - z0), plane_grad)
        hole = self.hole.signed_distance(P)
        rest = Distance(-hole.sd, -hole.grad)          # the hole's complement
        plane_ok = self.rim.signed_distance(P[0], P[1])[0] >= 0.0
        rest_ok = up * (boundary_point(P, hole)[2] - z0) <= 0.0

        def rim_point(E):
            rs, gx, gy = self.rim.signed_distance(E[0], E[1])
            return np.stack([E[0] - rs * gx, E[1] - rs * gy, np.full_like(rs, z0)])

        return intersection(P, plane, plane_ok, rest, rest_ok, rim_point)


class SignedDistanceSurface:
    """A rigid tool whose solid is given by an exact signed distance (see the module
    docstring); the interface of ``drape.forming.surfaces.RigidSurface``."""

    def __init__(self, solid: Solid, name: str = "tool", chunk: int = 16384):
        self.solid, self.name = solid, name
        #: points per block: numpy's temporaries of a few 100 kB stay in the allocator's
        #: pool and the cache; much larger ones are mapped afresh each time (several times
        #: slower)
        self.chunk = int(chunk)

    def query(self, points, offset=None, cutoff: float | None = None) -> ContactQuery:
        """Gap, unit normal (= d gap / d point) and closest point of every point (N, 3) with
        the tool translated by ``offset``; ``cutoff`` is accepted for the common interface
        and unused (every answer is exact near the tool and cheap far from it)."""
        p, shift = tool_frame(points, offset)
        P = np.ascontiguousarray(p.T)
        n = P.shape[1]
        gap, normal, closest = np.empty(n), np.empty((3, n)), np.empty((3, n))
        for lo in range(0, n, self.chunk):
            part = slice(lo, min(n, lo + self.chunk))
            block = np.ascontiguousarray(P[:, part])
            d = self.solid.signed_distance(block)
            gap[part], normal[:, part], closest[:, part] = d.sd, d.grad, boundary_point(block, d)
        return ContactQuery(gap, normal.T, closest.T + shift)
