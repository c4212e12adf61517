"""A triangulated tool surface (nodes, triangles, vertex normals) and the reference closest
point of a triangle to a point (numpy only).

:class:`TriangleSurface` is what the gmsh tool builders (``drape.geometry.tools``) return and
:class:`drape.forming.meshed_search.MeshedSurface` searches; :func:`closest_point_on_triangles`
is the textbook projection that the search's own faster one is checked against.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drape.forming.tool_query import unit


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
        return unit(np.cross(b - a, c - a))

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
