"""Exact closest points on the double-dome forming tools (numpy only; units mm).

The double-dome punch, die and blank holder (``drape.geometry.tools.DoubleDomeTools``, built
by gmsh/OpenCASCADE in ``_double_dome_shape`` and ``_build_double_dome``) are queried here
without a triangulation: the gap is the exact signed distance to the CAD construction, its
gradient (the normal) is continuous, and a query costs a few dozen numpy operations per point
(the triangulated tools of ``drape.forming.surfaces.MeshedSurface`` give a gap whose gradient jumps
from
facet to facet, and are far slower: docs/contact.md, "Throughput"). Same interface as the tools of
``drape.forming.surfaces``: ``query(points, offset=None, cutoff=None) -> ContactQuery(gap, normal,
closest)``; ``cutoff`` is ignored (the answer is exact for near points and cheap for all).

**Method: every rounded edge is an opening.** A solid whose convex edges are rounded by a
rolling ball of radius r (an OpenCASCADE fillet) equals its erosion by r dilated by a ball of
radius r (the *opening*). The dilation of a set by r has the signed distance of the set minus
r, exact outside the set. So each tool is written as ``sd(core) - r`` with a sharp-edged core
whose signed distance is found from its few smooth pieces:

* **core E** (punch frame): the blob B' (two spheres of radius R' = R - rk centred at
  (+-a, 0, zc) whose crease is blended by a concave rolling ball of radius Rs' = Rs + rk: the
  punch's domes and saddle eroded by the edge radius rk) intersected with the vertical prism on
  the stadium footprint of half-width w' = W/2 - rk. B' is a solid of revolution about the line
  y = 0, z = zc, so its signed distance is a 2-D problem in (x, rho), rho the distance to that
  line: a sphere's circle or the blend's circle, split by the line through their centres.
  Outside E the closest point is the closest point of B' (if it lies in the footprint), of the
  prism's wall (if it lies in B') or of the edge curve where they meet: horizontal circles on
  the end half-discs (the spheres are coaxial with the wall's cylinders), and on the straight
  sides the plane curve z = h(x) in y = +-w' (a circle of the sphere's section, and the
  blend's spiric section, found by a bracketed Newton iteration).
* **punch** = E dilated by rk.
* **die**: the cavity is the punch's offset by the clearance c, so its core is the same E
  moved down by the full stroke (spheres R + c eroded by rk + c have radius R - rk; blend
  Rs - c + rk + c = Rs + rk; footprint W/2 + c - rk - c = w'). K = that core dilated by
  rk + c + re is the cavity dilated by the entry radius re; the die is the opening by re of the
  half-space below the top face minus the cavity, i.e. {z <= -gap - re} minus K, dilated by
  re. At z = -gap - re the boundary of K is the vertical wall over the stadium of half-width
  W/2 + c + re (checked when the tool is made): that stadium is the rim where the plane and K
  meet.
* **holder**: the opening by rh of the plate above z = gap minus the vertical prism on the
  stadium of half-width ho: {z >= gap + rh} minus the prism of half-width ho + rh, dilated by
  rh.

**What is ignored** (the fabric touches only the working faces): the punch's top face (the
core's walls run up to the spheres' upper halves, far above it), the die block's outer faces
and bottom, the holder's top and outer faces: die and holder are unbounded outward. Points far
from a tool (beyond the blend's focal distance Rs' from the saddle, say) get the distance to a
point of the surface, an upper bound of the true one; within the tools' working range the
answer is exact to round-off.

The normal is the gradient of the gap with respect to the point (the contact Jacobian relies
on it), and closest = point - gap * normal. The method and its measured agreement with the
meshed tools are in ``docs/contact.md`` ("Exact double-dome tools").
"""

from __future__ import annotations

import math
from typing import NamedTuple, Protocol

import numpy as np

from drape.forming.surfaces import ContactQuery, _tool_frame, _unit


class Distance(NamedTuple):
    """Signed distance sd (N,) to a solid's boundary (negative inside) and its gradient grad
    (3, N), a unit vector; the closest boundary point is P - sd * grad.

    Inside this module points are (3, N) arrays P, one contiguous row per coordinate (numpy
    is several times faster on them than on the columns of an (N, 3) array)."""

    sd: np.ndarray
    grad: np.ndarray


class Solid(Protocol):
    def signed_distance(self, P: np.ndarray) -> Distance: ...


_TINY = 1e-300     # a floor for divisors that are zero only at isolated points


def _length(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """sqrt(a^2 + b^2) (np.hypot guards against overflow, needless in mm, and is several
    times slower)."""
    return np.sqrt(a * a + b * b)


def _foot(P: np.ndarray, d: Distance) -> np.ndarray:
    """The closest boundary points P - sd grad (3, N)."""
    return P - d.sd * d.grad


def _towards(rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Length and unit direction of the vectors rel (3, M)."""
    return np.sqrt(np.einsum("ij,ij->j", rel, rel)), _unit(rel.T).T


def _intersection(P: np.ndarray, a: Distance, a_ok: np.ndarray, b: Distance, b_ok: np.ndarray,
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
        sd[edge], grad[:, edge] = _towards(E - edge_point(E))
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
        r = _length(dx, y)
        inv = 1.0 / np.maximum(r, _TINY)
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


# --- the core E: rolling-ball blob intersected with the stadium prism ----------------------------

class DomeCore:
    """The sharp-edged core E of the double-dome punch (and, moved down, of its cavity).

    * blob B': spheres of radius ``sphere_radius`` R' centred at (+-a, 0, zc) (a =
      ``dome_offset``, zc = ``centre_z``), their crease filled by a rolling ball of radius
      ``blend_radius`` Rs': about the x axis a torus with spine circle of radius M =
      sqrt((R' + Rs')^2 - a^2) in the plane x = 0 and tube radius Rs', covering |x| <= x_b =
      a Rs' / (R' + Rs'), the material outside the tube;
    * prism: the vertical prism on the stadium of half-length a and half-width w' =
      ``half_width``.

    :meth:`signed_distance` is exact outside E within the blend's focal distance Rs' (and
    inside E to a depth where the nearest boundary point is on its lower face or walls); the
    spheres' upper halves stand for the punch's top, which the fabric never reaches.
    """

    def __init__(self, dome_offset: float, sphere_radius: float, blend_radius: float,
                 half_width: float, centre_z: float):
        a, R, Rs, w = (float(v) for v in (dome_offset, sphere_radius, blend_radius, half_width))
        if a <= 0 or R <= 0 or Rs <= 0 or w <= 0:
            raise ValueError("dome offset, radii and half-width must be positive")
        if R + Rs <= a:
            raise ValueError("the spheres are too far apart for the blend to touch both")
        self.a, self.R, self.Rs, self.w, self.zc = a, R, Rs, w, float(centre_z)
        self.M = math.sqrt((R + Rs) ** 2 - a ** 2)
        self.x_blend = a * Rs / (R + Rs)
        if self.M - Rs <= w or R <= w:
            raise ValueError("the blob does not cover the footprint (its lower face must span "
                             "the walls everywhere)")
        #: radius of a sphere's section by the wall planes y = +-w'
        self.r_wall = math.sqrt(R ** 2 - w ** 2)
        if self.r_wall < a - self.x_blend:
            raise ValueError("the spheres' sections do not reach the blend along the walls")
        self.footprint = Stadium(a, w)
        self.prism = StadiumPrism(self.footprint)
        #: height of the edge on the end half-discs (horizontal circles of radius w')
        self.z_end = self.zc - self.r_wall
        h, dh, _ = self._saddle_section(np.array([0.0, self.x_blend]))
        #: the highest point of the edge curve: mid-length, where the blend is highest
        self.z_edge_max = float(h[0])
        self._z_blend, self._slope_blend = float(h[1]), float(dh[1])

    # the blob B', a solid of revolution about the line y = 0, z = zc ------------------------

    def blob(self, P: np.ndarray) -> Distance:
        """Signed distance to B': in the meridian half-plane (u = |x|, rho), the sphere's
        circle (centre (a, 0), radius R') on the far side of the line through its centre and
        the blend circle's centre (0, M), the blend circle (radius Rs', material outside) on
        the near side. The two agree, with their gradients, on that line, so the result is
        C1; it is exact within Rs' of the blend and for points nearer the sphere than its
        centre."""
        a, M = self.a, self.M
        x, y, dz = P[0], P[1], P[2] - self.zc
        u = np.abs(x)
        rho = _length(y, dz)
        # branch by arithmetic (s = 1 sphere, 0 blend; exact): np.where is slower here
        s = ((u - a) * M + a * rho >= 0.0).astype(float)
        sign = 2.0 * s - 1.0
        mu = u - a * s
        mr = rho - M * (1.0 - s)
        d = _length(mu, mr)
        sd = sign * d - (s * self.R - (1.0 - s) * self.Rs)
        # unit gradient in the meridian plane, lifted to 3-D with e_rho = (0, y, dz) / rho
        scale = sign / np.maximum(d, _TINY)
        gu = mu * scale
        inv = mr * scale / np.maximum(rho, _TINY)
        grad = np.stack([gu * np.copysign(1.0, x), y * inv, dz * inv])
        odd = np.nonzero((d <= 0.0) | (rho <= 0.0))[0]
        if odd.size:        # a circle's centre or the axis (far from the surface): straight down
            grad[:, odd] = np.array([[0.0], [0.0], [-1.0]])
        return Distance(sd, grad)

    # the edge curve, where B' meets the prism's wall ----------------------------------------

    def _saddle_section(self, x: np.ndarray):
        """The blend's section by the wall plane y = w': z = h(x) for 0 <= x <= x_b, with
        h' and h'' (the lower branch of a spiric section)."""
        s = np.sqrt(self.Rs ** 2 - x * x)
        rho = self.M - s
        t = np.sqrt(rho * rho - self.w ** 2)
        d_rho = x / s
        dd_rho = self.Rs ** 2 / (s * s * s)
        h = self.zc - t
        dh = -rho * d_rho / t
        ddh = (self.w ** 2 * d_rho * d_rho - rho * dd_rho * t * t) / (t * t * t)
        return h, dh, ddh

    def _closest_on_saddle_section(self, u: np.ndarray, z: np.ndarray) -> np.ndarray:
        """x in [0, x_b] of the point of the blend's section nearest to (u, z) (2-D, in the
        wall plane): the root of g(x) = (x - u) + (h(x) - z) h'(x), by Newton's method kept
        inside a bracket [lo, hi] with g(lo) <= 0 <= g(hi) (bisection where a step would
        leave it), so it converges for every point. g(0) = -u <= 0; where g(x_b) <= 0 the
        nearest point is x_b (also the end of the sphere's arc)."""
        xb = self.x_blend
        x = np.full(u.shape, xb)
        active = np.nonzero((xb - u) + (self._z_blend - z) * self._slope_blend > 0.0)[0]
        ua, za = u[active], z[active]
        xa = np.clip(ua, 0.0, xb)
        lo, hi = np.zeros(active.size), np.full(active.size, xb)
        tol = 1e-12 * max(1.0, xb)
        for _ in range(100):
            if active.size == 0:
                break
            h, dh, ddh = self._saddle_section(xa)
            g = (xa - ua) + (h - za) * dh
            dg = 1.0 + dh * dh + (h - za) * ddh
            lo = np.where(g < 0.0, xa, lo)
            hi = np.where(g > 0.0, xa, hi)
            newton = dg > 0.0
            step = g / np.where(newton, dg, 1.0)
            new = xa - step
            ok = newton & (new >= lo) & (new <= hi)
            new = np.where(ok, new, 0.5 * (lo + hi))
            done = (ok & (np.abs(step) <= tol)) | (hi - lo <= tol)
            x[active[done]] = new[done]
            keep = ~done
            active, xa, ua, za = active[keep], new[keep], ua[keep], za[keep]
            lo, hi = lo[keep], hi[keep]
        x[active] = xa
        return x

    def edge_point(self, P: np.ndarray) -> np.ndarray:
        """The point (3, M) of the edge curve (where the blob's lower face meets the prism's
        wall) nearest to each point P (3, M): the nearest of the end half-circle, the
        sphere's arc and the blend's section in the wall plane on the point's side (the
        curve is symmetric in x and y, and the mirror pieces are farther)."""
        a, w, zc, xb = self.a, self.w, self.zc, self.x_blend
        x, y, z = P
        u, v = np.abs(x), np.abs(y)
        # 1. the end half-circle: radius w' about (a, 0) at z_end, same azimuth as the point
        du = np.maximum(u - a, 0.0)
        r = _length(du, v)
        round_ = r > 0.0
        inv = w / np.where(round_, r, 1.0)
        best_u = np.where(round_, a + du * inv, a)
        best_v = np.where(round_, v * inv, w)
        best_z = np.full_like(u, self.z_end)
        best = (u - best_u) ** 2 + (v - best_v) ** 2 + (z - self.z_end) ** 2
        off_plane = (v - w) ** 2
        # 2. the sphere's arc in the wall plane: circle (a, zc), radius r_wall, x_b <= x <= a;
        #    outside its angular range, the nearer of its ends
        su, sz = u - a, z - zc
        L = _length(su, sz)
        cos, sin = su / np.where(L > 0, L, 1.0), sz / np.where(L > 0, L, 1.0)
        on_arc = (L > 0) & (sin < 0.0) & (cos <= 0.0) & (a + self.r_wall * cos >= xb)
        near_b = (u - xb) ** 2 + (z - self._z_blend) ** 2 < su ** 2 + (z - self.z_end) ** 2
        au = np.where(on_arc, a + self.r_wall * cos, np.where(near_b, xb, a))
        az = np.where(on_arc, zc + self.r_wall * sin,
                      np.where(near_b, self._z_blend, self.z_end))
        # 3. the blend's section in the wall plane, 0 <= x <= x_b
        tu = self._closest_on_saddle_section(u, z)
        tz = self._saddle_section(tu)[0]
        for cu, cz in ((au, az), (tu, tz)):
            d2 = off_plane + (u - cu) ** 2 + (z - cz) ** 2
            better = d2 < best
            best_u = np.where(better, cu, best_u)
            best_v = np.where(better, w, best_v)
            best_z = np.where(better, cz, best_z)
            best = np.where(better, d2, best)
        return np.stack([np.where(x < 0.0, -best_u, best_u), np.where(y < 0.0, -best_v, best_v),
                         best_z])

    # E = B' intersected with the prism ---------------------------------------------------------

    def signed_distance(self, P: np.ndarray) -> Distance:
        """E = B' intersected with the prism (:func:`_intersection`): the blob's closest point
        counts if it lies in the footprint, the wall's if it lies in the blob."""
        blob = self.blob(P)
        wall = self.prism.signed_distance(P)
        foot = _foot(P, blob)
        blob_ok = self.footprint.signed_distance(foot[0], foot[1])[0] <= 0.0
        wall_ok = self.blob(_foot(P, wall)).sd <= 0.0
        return _intersection(P, blob, blob_ok, wall, wall_ok, self.edge_point)


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
        """Q = the half-space intersected with the hole's complement (:func:`_intersection`):
        the plane's closest point counts if it is outside the rim, the hole's if it is on
        Q's side of the plane."""
        up, z0 = self._up, self.z0
        plane_grad = np.zeros_like(P)
        plane_grad[2] = up
        plane = Distance(up * (P[2] - z0), plane_grad)
        hole = self.hole.signed_distance(P)
        rest = Distance(-hole.sd, -hole.grad)          # the hole's complement
        plane_ok = self.rim.signed_distance(P[0], P[1])[0] >= 0.0
        rest_ok = up * (_foot(P, hole)[2] - z0) <= 0.0

        def rim_point(E):
            rs, gx, gy = self.rim.signed_distance(E[0], E[1])
            return np.stack([E[0] - rs * gx, E[1] - rs * gy, np.full_like(rs, z0)])

        return _intersection(P, plane, plane_ok, rest, rest_ok, rim_point)


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
        p, shift = _tool_frame(points, offset)
        P = np.ascontiguousarray(p.T)
        n = P.shape[1]
        gap, normal, closest = np.empty(n), np.empty((3, n)), np.empty((3, n))
        for lo in range(0, n, self.chunk):
            part = slice(lo, min(n, lo + self.chunk))
            block = np.ascontiguousarray(P[:, part])
            d = self.solid.signed_distance(block)
            gap[part], normal[:, part], closest[:, part] = d.sd, d.grad, _foot(block, d)
        return ContactQuery(gap, normal.T, closest.T + shift)


def double_dome_surfaces(*, dome_offset: float, punch_width: float, dome_radius: float,
                         saddle_radius: float, punch_edge_radius: float, die_entry_radius: float,
                         clearance: float, gap: float, full_stroke: float,
                         holder_opening_radius: float, holder_edge_radius: float
                         ) -> dict[str, SignedDistanceSurface]:
    """The exact punch, die and holder of the double dome in their working positions (the
    names and meanings of ``drape.geometry.tools.DoubleDomeTools``; all in mm)."""
    a, rk, re, c = dome_offset, punch_edge_radius, die_entry_radius, clearance
    eroded = dict(dome_offset=a, sphere_radius=dome_radius - rk,
                  blend_radius=saddle_radius + rk, half_width=0.5 * punch_width - rk)
    core = DomeCore(centre_z=gap + dome_radius, **eroded)
    cavity_core = DomeCore(centre_z=gap + dome_radius - full_stroke, **eroded)
    z_rim = -gap - re
    if cavity_core.z_edge_max > z_rim:
        raise ValueError(f"the cavity's vertical wall ends {cavity_core.z_edge_max - z_rim:.3g} "
                         "mm too high for the entry fillet: the die is not the opening of a "
                         "vertical-walled cavity (DoubleDomeTools.validate should refuse this)")
    die = PlateWithOpening(z_rim, False, Dilated(cavity_core, rk + c + re),
                           Stadium(a, 0.5 * punch_width + c + re))
    zh, rh = gap + holder_edge_radius, holder_edge_radius
    opening = Stadium(a, holder_opening_radius + rh)
    holder = PlateWithOpening(zh, True, StadiumPrism(opening), opening)
    return {"punch": SignedDistanceSurface(Dilated(core, rk), "punch"),
            "die": SignedDistanceSurface(Dilated(die, re), "die"),
            "holder": SignedDistanceSurface(Dilated(holder, rh), "holder")}
