"""Exact closest points on the double-dome forming tools (numpy only; units mm).

The double-dome punch, die and blank holder
(``drape.geometry.double_dome_tools.DoubleDomeTools``, built by gmsh/OpenCASCADE in
``double_dome_shape`` and ``build_double_dome_solids`` there) are queried here without a
triangulation: the gap is the exact signed distance to the CAD construction, its gradient (the
normal) is continuous, and a query costs a few dozen numpy operations per point (the
triangulated tools of ``drape.forming.meshed_search.MeshedSurface`` give a gap whose gradient
jumps from facet to facet, and are far slower: docs/contact.md, "Throughput"). Same interface as
the tools of ``drape.forming.surfaces``: ``query(points, offset=None, cutoff=None) ->
ContactQuery(gap, normal, closest)``; ``cutoff`` is ignored (the answer is exact for near points
and cheap for all). The signed-distance solids this module combines (dilation, intersection,
plates with an opening) are those of :mod:`drape.forming.signed_distance`; here is the one
piece particular to the double dome, its core :class:`DomeCore`, and the tools made of it.

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

import numpy as np

from drape.forming.signed_distance import (TINY, Dilated, Distance, PlateWithOpening, Stadium,
                                           StadiumPrism, SignedDistanceSurface, boundary_point,
                                           intersection, norm2)


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
        rho = norm2(y, dz)
        # branch by arithmetic (s = 1 sphere, 0 blend; exact): np.where is slower here
        s = ((u - a) * M + a * rho >= 0.0).astype(float)
        sign = 2.0 * s - 1.0
        mu = u - a * s
        mr = rho - M * (1.0 - s)
        d = norm2(mu, mr)
        sd = sign * d - (s * self.R - (1.0 - s) * self.Rs)
        # unit gradient in the meridian plane, lifted to 3-D with e_rho = (0, y, dz) / rho
        scale = sign / np.maximum(d, TINY)
        gu = mu * scale
        inv = mr * scale / np.maximum(rho, TINY)
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
        r = norm2(du, v)
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
        L = norm2(su, sz)
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
        """E = B' intersected with the prism (:func:`intersection`): the blob's closest point
        counts if it lies in the footprint, the wall's if it lies in the blob."""
        blob = self.blob(P)
        wall = self.prism.signed_distance(P)
        blob_foot = boundary_point(P, blob)
        blob_ok = self.footprint.signed_distance(blob_foot[0], blob_foot[1])[0] <= 0.0
        wall_ok = self.blob(boundary_point(P, wall)).sd <= 0.0
        return intersection(P, blob, blob_ok, wall, wall_ok, self.edge_point)


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
