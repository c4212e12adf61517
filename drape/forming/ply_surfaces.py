"""The master surfaces of a stack's ply-ply contact (drape.forming.ply_contact): the stack's
nodes and triangles in global numbering, its quadrilaterals split into triangles, the plies'
outlines, and an order of the triangles that does not depend on the ranks. Plain numpy."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class StackNodes:
    """The stack's nodes and master triangles in global numbering (the same on every rank)."""

    reference: np.ndarray     # (N, 3) reference position: X, Y and the laid-up height (mm)
    ply: np.ndarray           # (N,) the ply of each node
    area: np.ndarray          # (N,) lumped reference area of each node (mm²)
    triangles: np.ndarray     # (T, 3) node numbers, counter-clockwise seen from +z
    triangle_ply: np.ndarray  # (T,)


def split_cells(cells: np.ndarray, reference_xy: np.ndarray, dolfinx_quads: bool = True):
    """Triangles (T, 3) of the cells (M, 3 or 4): a quadrilateral (in DOLFINx's vertex order,
    0, 1, 3, 2 around it; else 0, 1, 2, 3) into two along the diagonal nearer the direction
    of its reference centre from the origin, so that a mesh symmetric about the origin is
    split symmetrically (the half turn and the mirrors map the triangles onto triangles; a
    split by vertex order broke a symmetric stack's symmetry); each turned counter-clockwise
    in the reference plane; also the index of the cell each came from."""
    cells = np.asarray(cells)
    if cells.shape[1] == 4:
        around = cells[:, [0, 1, 3, 2]] if dolfinx_quads else cells.copy()
        p = reference_xy[around]
        centre = p.mean(axis=1)

        def alignment(a, b):     # |cos| of the diagonal a-b with the centre's direction
            d = p[:, b] - p[:, a]
            return np.abs(np.sum(d * centre, axis=1)) / (np.linalg.norm(d, axis=1)
                                                         * np.linalg.norm(centre, axis=1)
                                                         + np.finfo(float).tiny)
        other = alignment(1, 3) > alignment(0, 2) + 1e-12
        around[other] = around[other][:, [1, 2, 3, 0]]
        triangles = np.vstack([around[:, [0, 1, 2]], around[:, [0, 2, 3]]])
        origin = np.concatenate([np.arange(len(cells))] * 2)
    else:
        triangles, origin = cells.copy(), np.arange(len(cells))
    p = reference_xy[triangles]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    clockwise = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    triangles[clockwise] = triangles[clockwise][:, [0, 2, 1]]
    return triangles, origin


def triangle_outline(triangles: np.ndarray, triangle_ply: np.ndarray):
    """Per triangle (T, 3 each): whether the edge opposite each vertex lies on its ply's
    outline (no other triangle of the ply shares it), and whether each vertex does."""
    if not len(triangles):
        return np.zeros((0, 3), dtype=bool), np.zeros((0, 3), dtype=bool)
    opposite = [(1, 2), (2, 0), (0, 1)]
    edges = np.stack([np.sort(triangles[:, list(e)], axis=1) for e in opposite], axis=1)
    keys = np.column_stack([np.repeat(triangle_ply, 3), edges.reshape(-1, 2)])
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    outline = (counts[inverse.ravel()] == 1).reshape(-1, 3)
    on_outline = np.zeros(int(triangles.max()) + 1, dtype=bool)
    on_outline[edges[outline].ravel()] = True
    return outline, on_outline[triangles]


def closest_on_outline(bary, outline_edges, outline_vertices):
    """Of P closest points on triangles, given by their barycentric coordinates bary (P, 3)
    (exact zeros where the point lies on an edge or at a vertex, as
    :func:`~drape.forming.surfaces.closest_point_on_triangles` gives them): which lie on an
    edge of the ply's outline (``outline_edges`` (P, 3): the edge opposite each vertex is one)
    or at a vertex of it (``outline_vertices`` (P, 3)); and whether each lies on an edge, and
    which (the index of the vertex opposite it)."""
    zeros = bary == 0.0
    on_vertex = zeros.sum(axis=1) == 2
    on_edge = zeros.sum(axis=1) == 1
    edge = np.argmax(zeros, axis=1)
    rows = np.arange(len(bary))
    outside = ((on_vertex & outline_vertices[rows, np.argmax(bary, axis=1)])
               | (on_edge & outline_edges[rows, edge]))
    return outside, on_edge, edge


def reference_order(nodes: StackNodes) -> np.ndarray:
    """Each master triangle's place (T,) in the order of its reference centroid's ply,
    distance from the origin, x and y: the same on any number of ranks, where the node
    numbers are not; and, nearest first, the same for a triangle and its images under the
    half turn and the mirrors about the origin, so that a symmetric stack keeps its symmetry
    (ties are everywhere on plies meshed alike; with (ply, x, y) alone a [0/90, 0/90] stack's
    shear broke the half turn by 4 % of its peak)."""
    if not len(nodes.triangles):
        return np.zeros(0, dtype=np.int64)
    # rounded: the mean of three coordinates may differ in its last bit with their order
    centroids = np.round(nodes.reference[nodes.triangles].mean(axis=1), 6)
    distance = np.round(np.hypot(centroids[:, 0], centroids[:, 1]), 6)
    order = np.lexsort((centroids[:, 1], centroids[:, 0], distance, nodes.triangle_ply))
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    return rank
