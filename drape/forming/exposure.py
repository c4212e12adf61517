"""Which points of a stack of plies each tool can touch: those no other ply covers, on the
plies' current surfaces.

The die touches a point of ply i where no ply below it (k < i) covers it, the punch and the
holder where no ply above it (k > i) does. Ply k covers a point where the point's closest
point on ply k's mid-surface (its cells split into flat triangles, at their current
positions) lies inside the ply, not on its outline: a point past ply k's edge has its closest
point on an edge or a vertex of the outline. Taken on the deformed plies, the masks follow
plies that draw in past each other's edges, and a partial ply or a drop-off is whatever its
mesh covers.

Plain numpy and scipy on the stack's nodes in global numbering
(:class:`drape.forming.ply_surfaces.StackNodes`); the points are this rank's.
"""

from __future__ import annotations

import numpy as np

from drape.forming.ply_surfaces import StackNodes, closest_on_outline, triangle_outline
from drape.forming.layup import closest_triangles


class StackExposure:
    """The masks of the points each tool can touch, for the stack's nodes and triangles."""

    def __init__(self, nodes: StackNodes):
        self.nodes = nodes
        self.outline_edges, self.outline_vertices = triangle_outline(nodes.triangles,
                                                                     nodes.triangle_ply)
        self.n_plies = int(nodes.ply.max(initial=0)) + 1

    def covered(self, x_nodes: np.ndarray, k: int, points: np.ndarray) -> np.ndarray:
        """Whether ply k, its nodes at x_nodes (N, 3, mm), covers the points (P, 3, mm)."""
        triangles = np.flatnonzero(self.nodes.triangle_ply == k)
        if not len(points) or not len(triangles):
            return np.zeros(len(points), dtype=bool)
        best, bary, _ = closest_triangles(x_nodes[self.nodes.triangles[triangles]], points)
        triangle = triangles[best]
        past, _, _ = closest_on_outline(bary, self.outline_edges[triangle],
                                        self.outline_vertices[triangle])
        return ~past

    def masks(self, x_nodes: np.ndarray, point_plies: np.ndarray, points: np.ndarray):
        """(exposed from above, exposed from below): which points (P, 3, mm; ``point_plies``
        (P,) the ply of each) no ply above covers (the punch's and the holder's) and which
        no ply below covers (the die's), the nodes at x_nodes (N, 3, mm)."""
        point_plies = np.asarray(point_plies)
        above = np.zeros(len(points), dtype=bool)
        below = np.zeros(len(points), dtype=bool)
        for k in range(self.n_plies):
            lower, upper = point_plies < k, point_plies > k
            others = lower | upper
            hit = np.zeros(len(points), dtype=bool)
            hit[others] = self.covered(x_nodes, k, points[others])
            above |= hit & lower
            below |= hit & upper
        return ~above, ~below
