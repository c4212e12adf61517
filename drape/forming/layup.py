"""A stack as laid up, flat, before forming: where each ply lies on which.

A ply lies on the plies below it where they are and on the die where none is; a ply over a
partial ply (a patch, a drop-off) steps down past its edge onto the next ply below. From the
plies' flat triangles (:class:`drape.forming.ply_surfaces.StackNodes`' numbering, any rank):
:func:`laid_heights` gives each point's mid-surface height and :func:`bridged_ply` the ply
past its neighbour that the ply-ply contact pairs it with where a partial ply between two
plies leaves them touching; :func:`interface_directions` the pairs of plies that the contact
searches, each direction of each interface and those bridges.

Plain numpy and scipy.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from drape.forming.ply_pair import FrictionLaw
from drape.forming.ply_surfaces import StackNodes
from drape.forming.surfaces import closest_point_on_triangles

#: ``inside_by``: a point within this fraction of its ply's element size of a ply's flat
#: triangles lies on that ply (round-off of points on its outline)
ON_PLY = 1e-9


def closest_triangles(corners: np.ndarray, points: np.ndarray):
    """Per point (P, 3), the row of its closest triangle among ``corners`` (T, 3 corners, 3),
    the barycentric coordinates of its closest point there and the squared distance (mm²)."""
    centroids = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroids[:, None], axis=2).max()
    tree = cKDTree(centroids)
    # the closest triangle's centroid lies within the nearest centroid's distance plus a
    # triangle's radius (that triangle is at most as far as its centroid)
    nearest, _ = tree.query(points)
    found = tree.query_ball_point(points, nearest + radius + 1e-9)
    counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
    which = np.repeat(np.arange(len(points)), counts)
    candidates = np.concatenate(found).astype(np.int64)
    _, bary, squared = closest_point_on_triangles(points[which], corners[candidates, 0],
                                                  corners[candidates, 1], corners[candidates, 2])
    # per point its closest candidate (ties share the closest point, so either will do)
    order = np.lexsort((squared, which))
    first = np.ones(len(order), dtype=bool)
    first[1:] = which[order][1:] != which[order][:-1]
    best = order[first]
    return candidates[best], bary[best], squared[best]


def outline_distance(xy_nodes, triangles, points) -> np.ndarray:
    """Distance (P,) of points (P, 2) to the outline of flat triangles (T, 3) of the nodes
    xy_nodes (N, 2): to the nearest of their edges that no other of them shares."""
    edges = np.sort(np.vstack([triangles[:, [1, 2]], triangles[:, [2, 0]],
                               triangles[:, [0, 1]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    a, b = xy_nodes[unique[counts == 1, 0]], xy_nodes[unique[counts == 1, 1]]
    tree = cKDTree(0.5 * (a + b))
    half = 0.5 * np.linalg.norm(b - a, axis=1).max()
    # the nearest edge's midpoint lies within the nearest midpoint's distance plus half an edge
    nearest, _ = tree.query(points)
    found = tree.query_ball_point(points, nearest + half + 1e-9)
    counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
    which = np.repeat(np.arange(len(points)), counts)
    edge = np.concatenate(found).astype(np.int64)
    d = b[edge] - a[edge]
    along = np.clip(np.sum((points[which] - a[edge]) * d, axis=1) / np.sum(d * d, axis=1), 0, 1)
    distance = np.linalg.norm(points[which] - a[edge] - along[:, None] * d, axis=1)
    out = np.full(len(points), np.inf)
    np.minimum.at(out, which, distance)
    return out


def _element_sizes(xy_nodes, triangles, triangle_ply, n_plies) -> np.ndarray:
    """Per ply, its element size (mm): its longest flat triangle edge (0 for a ply with none)."""
    corners = xy_nodes[triangles]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    return np.array([longest[triangle_ply == k].max(initial=0.0) for k in range(n_plies)])


def _coverage(xy_nodes, triangles, triangle_ply, n_plies, xy, plies, lower: bool,
              inside_by: float | None = None):
    """(P, n_plies) whether each point (xy (P, 2), of ply ``plies``) lies within one of its
    own ply's elements (its longest triangle edge) of ply j's flat triangles (``inside_by``:
    inside them, at least that many of its elements from their outline), for the plies j
    below it (``lower``) or above it; False elsewhere."""
    plies = np.asarray(plies)
    points = np.column_stack([xy, np.zeros(len(xy))])
    corners = np.column_stack([xy_nodes, np.zeros(len(xy_nodes))])[triangles]
    reach = _element_sizes(xy_nodes, triangles, triangle_ply, n_plies)
    within = reach if inside_by is None else ON_PLY * np.maximum(reach, 1.0)
    covered = np.zeros((len(xy), n_plies), dtype=bool)
    for j in range(n_plies):
        rows = np.flatnonzero(plies > j if lower else plies < j)
        mine = triangle_ply == j
        if len(rows) and mine.any():
            _, _, squared = closest_triangles(corners[mine], points[rows])
            on = squared <= within[plies[rows]] ** 2
            if inside_by is not None:
                depth = outline_distance(xy_nodes, triangles[mine], xy[rows])
                on &= depth >= inside_by * reach[plies[rows]]
            covered[rows[on], j] = True
    return covered


def bridged_ply(xy_nodes, triangles, triangle_ply, n_plies, xy, plies, inset: float,
                above: bool = False) -> np.ndarray:
    """Per point (xy (P, 2), of ply k = ``plies``), the ply j < k - 1 (``above``: j > k + 1)
    it can touch across the plies between, -1 if none: the nearest ply to k that it lies on
    (its flat outline, to round-off), past ply k's neighbour, with no ply between that surely
    keeps them apart. A ply between does where the point lies on it, but where the point lies
    ``inset`` of its elements or more inside its own ply's outline, only where it lies that
    far inside the ply between too: its edge band is where a partial ply may slide off.
    (Plies of one outline share their edge band: there the plies between keep them apart.)"""
    plies = np.asarray(plies)
    args = (xy_nodes, triangles, triangle_ply, n_plies, xy, plies, not above)
    on = _coverage(*args, inside_by=0.0)
    deep = _coverage(*args, inside_by=inset)
    size = _element_sizes(xy_nodes, triangles, triangle_ply, n_plies)
    interior = np.zeros(len(xy), dtype=bool)
    for k in np.unique(plies):
        rows = np.flatnonzero(plies == k)
        depth = outline_distance(xy_nodes, triangles[triangle_ply == k], xy[rows])
        interior[rows] = depth >= inset * size[k]
    keeps_apart = np.where(interior[:, None], deep, on)
    out = np.full(len(xy), -1)
    step = 1 if above else -1
    for row in np.flatnonzero(on.any(axis=1)):
        k = plies[row]
        for j in range(k + step, n_plies if above else -1, step):
            if abs(j - k) > 1 and on[row, j]:
                out[row] = j
                break
            if keeps_apart[row, j]:
                break
    return out


def laid_heights(xy_nodes, triangles, triangle_ply, thicknesses, xy, plies):
    """Mid-surface heights (P,) of points xy (P, 2, mm) of plies ``plies`` (P,) in a stack
    laid up flat, and the number of plies in each point's column (the point's own included).

    A point of ply k sits (t_j + t_k)/2 above the highest ply j < k under it, whose own height
    follows the same rule at the same xy, and at z = 0 (on the die) where no ply is under it.
    Ply j is under the point where the point lies within one of ply k's elements (its longest
    triangle edge) of ply j's flat triangles (``triangles`` (T, 3) of the nodes ``xy_nodes``
    (N, 2), ply ``triangle_ply``): a ply over a partial ply steps down over its next element
    past the edge, not across the edge into the ply below. Plies of one outline are stacked at
    :func:`drape.forming.plies.ply_heights`, to the bit."""
    plies = np.asarray(plies)
    thicknesses = np.asarray(thicknesses, dtype=float)
    covered = _coverage(xy_nodes, triangles, triangle_ply, len(thicknesses), xy, plies, True)
    height, last = np.zeros(len(xy)), np.full(len(xy), -1)
    for j, thickness in enumerate(thicknesses):
        on = np.flatnonzero(covered[:, j])
        below = last[on]
        height[on] = np.where(below < 0, 0.0,
                              height[on] + 0.5 * (thicknesses[np.maximum(below, 0)] + thickness))
        last[on] = j
    height = np.where(last < 0, 0.0,
                      height + 0.5 * (thicknesses[np.maximum(last, 0)] + thicknesses[plies]))
    return height, 1 + covered.sum(axis=1)


# --- the interfaces' directions, for the ply-ply contact (drape.forming.ply_contact) -------------
#: a bridge across a partial ply (:func:`bridges`) takes the nodes within this many of their
#: ply's elements inside the partial ply's outline too: the partial ply may slide by that
#: much over the forming before a node it uncovers misses the ply below it (bridges are
#: found once, on the flat stack)
BRIDGE_INSET = 1.0


@dataclasses.dataclass
class Direction:
    """One direction of one interface: slave ply's nodes against master ply's triangles."""

    interface: int
    slave: int
    master: int
    sign: float               # +1: the master lies below the slave, -1: above
    offset: float             # (t_slave + t_master) / 2, mm
    law: FrictionLaw
    #: (N,) which of the slave ply's nodes take part (None: all): across a partial ply, those
    #: with no ply between them and the master ply (:func:`bridged_ply`)
    slaves: object = None


def interface_directions(nodes: StackNodes, thicknesses, laws) -> list[Direction]:
    """Every direction of every interface of a stack (``laws``: one per interface, bottom
    first): ply k's nodes against ply k + 1's triangles and ply k + 1's against ply k's, then
    the :func:`bridges` across partial plies."""
    out = []
    for k, law in enumerate(laws):
        offset = 0.5 * (thicknesses[k] + thicknesses[k + 1])
        out.append(Direction(k, k, k + 1, -1.0, offset, law))
        out.append(Direction(k, k + 1, k, +1.0, offset, law))
    return out + bridges(nodes, thicknesses, laws)


def bridges(nodes: StackNodes, thicknesses, laws) -> list[Direction]:
    """The contact of plies that a partial ply between them leaves touching: ply k on ply
    j < k - 1 where no ply lies between them (:func:`bridged_ply`), both
    directions, with the law of the interface under ply k (its underside's); counted to that
    interface. None in a stack of whole plies.

    Its slaves are the nodes outside the partial ply's outline, the element past its edge
    included, over which ply k steps down onto ply j (:func:`laid_heights`): there
    ply k leaves the partial ply's contact (its edge ramp) and must find ply j's, else the two
    plies over a free span (the die's opening) pass through each other, held by their bending
    alone, and Newton's matrix is singular. They include the nodes over the partial ply's
    last element inside its edge too (BRIDGE_INSET), so that a partial ply may slide by as
    much before ply k can miss ply j; there the partial ply keeps them apart, a gap of its
    thickness, which the penalty does not feel where it is at least the smoothing g0."""
    n_plies = len(thicknesses)
    xy = nodes.reference[:, :2]
    args = (xy, nodes.triangles, nodes.triangle_ply, n_plies, xy, nodes.ply, BRIDGE_INSET)
    under, over = bridged_ply(*args), bridged_ply(*args, above=True)
    out = []
    for k in range(2, n_plies):
        for j in range(k - 1):
            up = (nodes.ply == k) & (under == j)
            down = (nodes.ply == j) & (over == k)
            if up.any() or down.any():
                offset = 0.5 * (thicknesses[j] + thicknesses[k])
                out.append(Direction(k - 1, j, k, -1.0, offset, laws[k - 1], down))
                out.append(Direction(k - 1, k, j, +1.0, offset, laws[k - 1], up))
    return out
