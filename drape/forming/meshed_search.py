"""Exact closest points on a triangulated tool surface, with interpolated normals: k-d trees
propose candidate triangles and lower bounds certify the answer (numpy and scipy; the
point-triangle projection and the candidate lists' evaluation compiled with numba).

:class:`MeshedSurface` answers the contact query of :mod:`drape.forming.tool_query` for a
:class:`~drape.forming.triangulated.TriangleSurface` (gmsh-built and STEP tools); the search
and its accuracy are in ``docs/contact.md``.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from drape.forming.tool_query import ContactQuery, tool_frame, unit
from drape.forming.triangulated import TriangleSurface

#: numpy's rules for a division by zero (inf or nan, no exception): a degenerate triangle's
#: projection is nan and falls to its edges, as in the reference
jit = numba.njit(cache=True, error_model="numpy")


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
        self._plane = unit(np.cross(self._b - self._a, self._c - self._a))
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
        self._normals = unit(surface.normals)
        self.n_triangles = len(tri)
        self.k = max(1, min(k, self.n_triangles))
        self.workers = workers
        self.margin = float(margin)
        self._lists = None          # the candidate lists (margin > 0), see _query_listed
        self.pairs_evaluated = 0    # counters, for benchmarks
        self.searched = 0           # points searched (not answered from their lists)

    def _project(self, q, tris):
        """Squared distances (M,) and barycentric coordinates (M, 3) of the closest points of
        triangles ``tris`` (M,) to points q (M, 3), paired row by row (:func:`_project_one`)."""
        q = np.ascontiguousarray(q, dtype=float)
        tris = np.ascontiguousarray(tris, dtype=np.int64)
        d2, bary = np.empty(tris.size), np.empty((tris.size, 3))
        _project_pairs(q, tris, self._a, self._e0, self._e1, self._gram, d2, bary)
        return d2, bary

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
        # a point moved by delta since p0 is nearer than d0 + delta to its closest triangle at
        # p0, and any triangle farther than d0 + 2 delta from p0 is farther than that from it:
        # only the entries within d0 + 2 delta are evaluated (delta << margin within a step)
        delta = np.linalg.norm(p - lists["origin"], axis=1)
        bound = lists["d0"] + 2.0 * delta + 1e-9 * (1.0 + lists["d0"])
        tri, bary, d2 = np.zeros(n, dtype=np.int64), np.zeros((n, 3)), np.empty(n)
        self.pairs_evaluated += _closest_listed(
            np.ascontiguousarray(p), lists["start"], lists["tris"], lists["dist"], bound, self._a,
            self._e0, self._e1, self._gram, tri, bary, d2)
        return tri, bary, np.sqrt(d2)

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
        p, shift = tool_frame(points, offset)
        if self.margin > 0.0:
            tri, bary, dist = self._query_listed(p, cutoff)
        else:
            self.searched += p.shape[0]
            tri, bary, dist = self.closest_triangles(p, cutoff)
        nodes = self.surface.triangles[tri]
        normal = unit(np.einsum("ij,ijk->ik", bary, self._normals[nodes]))
        closest = np.einsum("ij,ijk->ik", bary, self.surface.nodes[nodes])
        dist = np.linalg.norm(p - closest, axis=1)      # from the point, not |w|^2 - ...
        side = np.einsum("ij,ij->i", p - closest, normal)
        gap = np.where(side >= 0.0, dist, -dist)
        return ContactQuery(gap, normal, closest + shift)


@jit
def _project_one(q0, q1, q2, a, e0, e1, gram):
    """Squared distance and barycentric coordinates of the closest point of one triangle (a, e0
    = b - a, e1 = c - a, gram = (e0.e0, e0.e1, e1.e1, determinant)) to q: the projection on
    the triangle's plane where it falls inside the triangle, else the nearest of its three
    edges' closest points (the closest point of a triangle to a point whose projection lies
    outside it is on its boundary). Only w = q - a, |w|^2, w.e0 and w.e1 depend on the pair,
    which makes it several times cheaper than
    :func:`~drape.forming.triangulated.closest_point_on_triangles` (the reference, which it
    matches to round-off)."""
    w0, w1, w2 = q0 - a[0], q1 - a[1], q2 - a[2]
    ww = w0 * w0 + w1 * w1 + w2 * w2
    s0 = w0 * e0[0] + w1 * e0[1] + w2 * e0[2]
    s1 = w0 * e1[0] + w1 * e1[1] + w2 * e1[2]
    d00, d01, d11, det = gram[0], gram[1], gram[2], gram[3]
    v = (d11 * s0 - d01 * s1) / det
    t = (d00 * s1 - d01 * s0) / det
    if v >= 0.0 and t >= 0.0 and v + t <= 1.0 and det > 0.0:
        return max(ww - v * s0 - t * s1, 0.0), 1.0 - v - t, v, t
    # edges a-b, a-c and b-c: the clamped parameter along each, and the squared distance
    s2, d22 = s1 - s0 - d01 + d00, d11 - 2.0 * d01 + d00
    t0 = min(max(s0 / d00 if d00 > 0.0 else 0.0, 0.0), 1.0)
    t1 = min(max(s1 / d11 if d11 > 0.0 else 0.0, 0.0), 1.0)
    t2 = min(max(s2 / d22 if d22 > 0.0 else 0.0, 0.0), 1.0)
    edge0 = ww - 2.0 * t0 * s0 + t0 * t0 * d00
    edge1 = ww - 2.0 * t1 * s1 + t1 * t1 * d11
    edge2 = ww - 2.0 * s0 + d00 - 2.0 * t2 * s2 + t2 * t2 * d22
    if edge0 <= edge1 and edge0 <= edge2:
        return max(edge0, 0.0), 1.0 - t0, t0, 0.0
    if edge1 <= edge2:
        return max(edge1, 0.0), 1.0 - t1, 0.0, t1
    return max(edge2, 0.0), 0.0, 1.0 - t2, t2


@jit
def _project_pairs(q, tris, a, e0, e1, gram, d2, bary):
    for i in range(tris.shape[0]):
        k = tris[i]
        d2[i], bary[i, 0], bary[i, 1], bary[i, 2] = _project_one(q[i, 0], q[i, 1], q[i, 2], a[k],
                                                                 e0[k], e1[k], gram[k])


@jit
def _closest_listed(p, start, tris, dist, bound, a, e0, e1, gram, tri, bary, d2):
    """Per point i, the closest of its listed triangles tris[start[i]:start[i + 1]] whose
    listed distance is within bound[i] (the first of equally near ones; the list holds the
    point's closest at p0, always within it): its triangle, barycentric coordinates and
    squared distance. Returns the number of pairs evaluated."""
    evaluated = 0
    for i in range(p.shape[0]):
        best = np.inf
        for entry in range(start[i], start[i + 1]):
            if dist[entry] > bound[i]:
                continue
            k = tris[entry]
            evaluated += 1
            squared, b0, b1, b2 = _project_one(p[i, 0], p[i, 1], p[i, 2], a[k], e0[k], e1[k],
                                               gram[k])
            if squared < best:
                best = squared
                tri[i], bary[i, 0], bary[i, 1], bary[i, 2] = k, b0, b1, b2
        d2[i] = best
    return evaluated


def warm_up() -> None:
    """Compile (or load from numba's cache) the projection kernels: one listed query of a
    two-triangle square."""
    square = TriangleSurface("square", np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]),
                             np.array([[0, 1, 2], [0, 2, 3]]), np.tile([0.0, 0.0, 1.0], (4, 1)))
    MeshedSurface(square, margin=0.5).query(np.array([[0.2, 0.3, 0.1], [2.0, 2.0, 1.0]]),
                                            cutoff=1.0)
