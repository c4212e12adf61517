"""A stack as laid up, flat, before forming: where each ply lies on which.

A ply lies on the plies below it where they are and on the die where none is; a ply over a
partial ply (a patch, a drop-off) steps down past its edge onto the next ply below. From the
plies' flat triangles (:class:`drape.forming.ply_contact.StackNodes`' numbering, any rank):
:func:`laid_heights` gives each point's mid-surface height and :func:`ply_under` the ply
directly under or over it, which is the one the ply-ply contact pairs it with where a
partial ply between two plies leaves them touching.

Plain numpy and scipy.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from drape.forming.surfaces import closest_point_on_triangles

#: ``on_it``: a point within this fraction of its ply's element size of a ply's flat triangles
#: lies on that ply (round-off of points on its outline)
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


def _coverage(xy_nodes, triangles, triangle_ply, n_plies, xy, plies, lower: bool,
              on_it: bool = False):
    """(P, n_plies) whether each point (xy (P, 2), of ply ``plies``) lies within one of its
    own ply's elements (its longest triangle edge) of ply j's flat triangles (``on_it``: on
    them, to round-off), for the plies j below it (``lower``) or above it; False elsewhere."""
    plies = np.asarray(plies)
    points = np.column_stack([xy, np.zeros(len(xy))])
    corners = np.column_stack([xy_nodes, np.zeros(len(xy_nodes))])[triangles]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    reach = np.array([longest[triangle_ply == k].max(initial=0.0) for k in range(n_plies)])
    if on_it:
        reach = ON_PLY * np.maximum(reach, 1.0)
    covered = np.zeros((len(xy), n_plies), dtype=bool)
    for j in range(n_plies):
        rows = np.flatnonzero(plies > j if lower else plies < j)
        mine = triangle_ply == j
        if len(rows) and mine.any():
            _, _, squared = closest_triangles(corners[mine], points[rows])
            covered[rows[squared <= reach[plies[rows]] ** 2], j] = True
    return covered


def ply_under(xy_nodes, triangles, triangle_ply, n_plies, xy, plies, above: bool = False,
              on_it: bool = False):
    """Per point (xy (P, 2), of ply ``plies``), the highest ply under it (``above``: the
    lowest ply over it) within one of its ply's elements (:func:`laid_heights`; ``on_it``:
    whose flat outline it lies within), -1 if none."""
    covered = _coverage(xy_nodes, triangles, triangle_ply, n_plies, xy, plies, not above,
                        on_it)
    index = np.arange(n_plies)
    if above:
        return np.where(covered.any(axis=1), np.where(covered, index, n_plies).min(axis=1), -1)
    return np.where(covered, index, -1).max(axis=1)


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
