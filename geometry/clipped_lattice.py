"""A yarn-aligned square lattice clipped to any outline (a polygon or a circle), and one strip
of quadrilaterals from the lattice's staircase boundary to the outline (numpy, no gmsh; mm).

:func:`clipped_lattice` is the mesh of a disc or polygon blank with ``mesh.pattern =
"aligned"`` (``drape.geometry.blank`` hands it to gmsh; ``docs/blanks.md`` shows it). The
strip's outer (rim) nodes follow the staircase nodes' closest points on the outline; where that
would fold a strip cell (a riser of the staircase along an outline edge at a small angle to the
yarns, or a polygon corner between the yarns' directions) the rim nodes move within the range
that keeps the cells convex, and a corner may get a cell of its own: three rim nodes (the
vertex between two others) and one staircase node.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from drape.errors import InputError
from drape.geometry.outline import Outline, cross_z

#: a lattice cell is kept when its corners lie at least this many element sizes inside the
#: outline: the strip between the lattice and the outline is then 0.5 to about 1.5 sizes wide
LATTICE_MARGIN = 0.5
#: how far (deg) inside the directions that keep its cells convex a moved spoke (staircase node
#: to rim node) stays
SPOKE_MARGIN_DEG = 15.0
#: the shortest strip cell edge on the outline, as a fraction of the mean
MIN_RIM_SPACING = 0.05
#: a corner cell's rim nodes lie this far from the vertex along its edges (in element sizes)
CORNER_REACH = (0.3, 1.5)


def clipped_lattice(outline: np.ndarray, yarn_angle: float, size: float, centre=(0.0, 0.0),
                    circle: float | None = None):
    """A mesh of the region inside ``outline`` (closed polygon (n, 2), counter-clockwise;
    a disc: its fine polygon and ``circle`` the radius, centred on ``centre``) for yarns at
    ``yarn_angle`` (deg): squares of side ``size`` along the yarns (one centred on ``centre``)
    wherever they lie at least LATTICE_MARGIN sizes inside the outline, and one ring of
    quadrilaterals from the lattice's staircase boundary to the outline, one per staircase
    edge and one per polygon corner that needs a cell of its own; every vertex of the outline
    is a node.

    Returns nodes (N, 2), quadrilaterals (M, 4) counter-clockwise, the boundary segments
    (K, 2) and a boolean mask of the strip cells (M,)."""
    centre = np.asarray(centre, dtype=float)
    shape = Outline(outline, centre, circle)
    lattice, ni, nj = _yarn_grid(outline, yarn_angle, size, centre)
    quads = _kept_squares(lattice, ni, nj, shape, size)
    loop = _staircase(quads, size)
    rim = _fit_rim(lattice[loop], shape, size)
    return _with_strip(lattice, quads, loop, rim, shape, size)


def _yarn_grid(outline, yarn_angle, size, centre):
    """Nodes (ni nj, 2) of the yarn-aligned square grid of side ``size`` covering the outline
    with a cell to spare, a cell centred on ``centre``; node (i, j) is row i nj + j."""
    theta = math.radians(yarn_angle)
    g1 = np.array([math.cos(theta), math.sin(theta)])
    g2 = np.array([-math.sin(theta), math.cos(theta)])
    local = (outline - centre) @ np.column_stack([g1, g2])          # yarn coordinates
    lo = np.floor(local.min(axis=0) / size - 1).astype(int)
    hi = np.ceil(local.max(axis=0) / size + 1).astype(int)
    I, J = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    ni, nj = I.shape
    lattice = (centre + ((I.ravel() + 0.5) * size)[:, None] * g1
               + ((J.ravel() + 0.5) * size)[:, None] * g2)
    return lattice, ni, nj


def _kept_squares(lattice, ni, nj, shape: Outline, size):
    """The grid squares (M, 4 node rows, counter-clockwise) whose corners all lie at least
    LATTICE_MARGIN sizes inside the outline; where two of them meet at a corner only (in a
    sharp corner of the outline) the one with fewer neighbours goes, and of pieces that fall
    apart the largest stays (:func:`_one_piece`)."""
    gap, _ = shape.closest(lattice)
    good = shape.inside(lattice) & (gap >= LATTICE_MARGIN * size)
    good = good.reshape(ni, nj)
    keep = _one_piece(good[:-1, :-1] & good[1:, :-1] & good[1:, 1:] & good[:-1, 1:])
    if not keep.any():
        raise InputError("the blank is too small for its mesh", key="mesh.size", value=size,
                         expected="an element size a few times smaller than the blank")
    index = lambda i, j: i * nj + j          # noqa: E731
    ci, cj = np.nonzero(keep)
    return np.column_stack([index(ci, cj), index(ci + 1, cj), index(ci + 1, cj + 1),
                            index(ci, cj + 1)])


def _one_piece(keep):
    """The kept squares (boolean grid) without pinches (two squares meeting at a corner only:
    of the two, the one with fewer kept edge neighbours goes) and, if they fall apart, their
    largest edge-connected piece. A grid with neither is returned as it is."""
    keep = keep.copy()
    for _ in range(keep.size):
        a, b = keep[:-1, :-1], keep[1:, 1:]          # the squares around each inner grid node
        c, d = keep[1:, :-1], keep[:-1, 1:]
        pinches = np.argwhere((a & b & ~c & ~d) | (c & d & ~a & ~b))
        if pinches.size == 0:
            break
        padded = np.pad(keep, 1).astype(int)
        neighbours = (padded[:-2, 1:-1] + padded[2:, 1:-1] + padded[1:-1, :-2]
                      + padded[1:-1, 2:])
        i, j = pinches[0]
        pair = [(i, j), (i + 1, j + 1)] if keep[i, j] else [(i + 1, j), (i, j + 1)]
        keep[min(pair, key=lambda square: neighbours[square])] = False
    labels, count = ndimage.label(keep)
    if count > 1:
        keep = labels == 1 + int(np.argmax(np.bincount(labels.ravel())[1:]))
    return keep


def _staircase(quads, size) -> np.ndarray:
    """The kept squares' boundary (edges of exactly one of them) as one loop of node rows,
    counter-clockwise; InputError if it pinches or falls apart."""
    edges = np.concatenate([quads[:, [0, 1]], quads[:, [1, 2]], quads[:, [2, 3]], quads[:, [3, 0]]])
    key = {tuple(e) for e in edges.tolist()}
    boundary = [e for e in edges.tolist() if (e[1], e[0]) not in key]
    following = {}
    for a, b in boundary:
        if a in following:
            raise InputError("the outline pinches the yarn lattice (two lattice squares meet at "
                             "a corner only)", key="mesh.size", value=size,
                             expected="a smaller element size, or a rounder outline")
        following[a] = b
    loop = [boundary[0][0]]
    while following[loop[-1]] != loop[0]:
        loop.append(following[loop[-1]])
        if len(loop) > len(boundary):
            break
    if len(loop) != len(boundary):
        raise InputError("the yarn lattice inside the outline is not one piece", key="mesh.size",
                         value=size, expected="a smaller element size, or a rounder outline")
    return np.array(loop)


# --- the strip's rim nodes --------------------------------------------------------------------

def _strictly_convex(p):
    """Per quadrilateral (M, 4, 2 corners, counter-clockwise): True if it is strictly convex."""
    e = np.roll(p, -1, axis=1) - p
    return np.all(cross_z(e, np.roll(e, -1, axis=1)) > 0, axis=1)


class _SpokeCones:
    """Where each staircase node's spoke to its rim node may point for the strip cells beside
    it to be convex: to the outer side of both staircase edges at the node, a half-plane at a
    straight node and a quadrant at a corner; an angular interval ``middle`` +- ``half`` (rad)."""

    def __init__(self, staircase):
        self.staircase = staircase
        edges = np.roll(staircase, -1, axis=0) - staircase
        outward = np.column_stack([edges[:, 1], -edges[:, 0]])       # of the edge out of a node
        outward /= np.linalg.norm(outward, axis=1)[:, None]
        into = np.roll(outward, 1, axis=0)                            # of the edge into it
        self.middle = np.arctan2(*(outward + into)[:, ::-1].T)
        self.half = 0.5 * np.pi - 0.5 * np.arccos(np.clip(np.sum(outward * into, axis=1), -1, 1))

    def room(self, nodes, points):
        """How far (rad) inside its node's cone the spoke from each of ``nodes`` to its
        ``points`` (P, 2) lies; negative outside."""
        d = points - self.staircase[nodes]
        off = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - self.middle[nodes])))
        return self.half[nodes] - np.abs(off)


class _Rim:
    """The strip's outline (rim) nodes as arc lengths along the outline, unwrapped to increase
    once around it from node 0's. Staircase node j's spoke ends at ``s_in[j]`` in the cell of
    the staircase edge into j and at ``s_out[j]`` in the cell of the edge out of it: the same
    point, except at a corner cell, which joins node j to s_in[j], the polygon vertex at
    ``corners[j]`` and s_out[j]. ``fixed`` nodes (pinned vertices, corner nodes) do not move."""

    def __init__(self, s, fixed):
        self.s_in, self.s_out = s.copy(), s.copy()
        self.fixed = fixed.copy()
        self.corners: dict[int, float] = {}

    def sequence(self):
        """The rim nodes' arc lengths in order (R,), the rows of each staircase node's in and
        out rim nodes (N,), and the corner cells as (staircase node, row of the vertex)."""
        s, into, out, corners = [], [], [], []
        for j in range(len(self.s_in)):
            into.append(len(s))
            s.append(self.s_in[j])
            if j in self.corners:
                corners.append((j, len(s)))
                s.extend([self.corners[j], self.s_out[j]])
            out.append(len(s) - 1)
        return np.array(s), np.array(into), np.array(out), corners

    def rows(self, n):
        """The rim nodes' arc lengths in order (R,) and the strip cells (N + C, 4) as rows of
        [the n staircase nodes; the R rim nodes], counter-clockwise: one per staircase edge,
        then one per corner cell. Whether a row is a corner cell: row >= n."""
        s, into, out, corners = self.sequence()
        stair = np.arange(n)
        following = np.roll(stair, -1)
        cells = np.column_stack([n + out, n + into[following], following, stair])
        corner_cells = np.array([[n + into[j], n + v, n + out[j], j] for j, v in corners],
                                dtype=np.int64).reshape(-1, 4)
        return s, np.vstack([cells, corner_cells])

    def folded(self, shape: Outline, staircase):
        """Rows of the strip cells (as :meth:`rows`) that are not strictly convex or have an
        edge on the outline shorter than MIN_RIM_SPACING of the mean."""
        n = len(staircase)
        s, rows = self.rows(n)
        convex = _strictly_convex(np.vstack([staircase, shape.points_at(s)])[rows])
        spacing = np.append(s[1:], s[0] + shape.total) - s
        short = spacing <= MIN_RIM_SPACING * shape.total / len(s)
        # a cell's edges on the outline start at its first rim node, and a corner cell's at
        # its second (the vertex) too
        short_cells = short[rows[:, 0] - n]
        short_cells[n:] |= short[rows[n:, 1] - n]
        return np.flatnonzero(~convex | short_cells)


def _fit_rim(staircase, shape: Outline, size) -> _Rim:
    """The rim nodes: the staircase nodes' closest points on the outline, in order along it and
    every polygon vertex pinned to the nearest; where a strip cell then folds, the nodes around
    it moved (:func:`_untwist`), and a vertex amid folds given a corner cell (:func:`_corner`)."""
    n = len(staircase)
    cones = _SpokeCones(staircase)
    _, s = shape.closest(staircase)
    s = _in_order_along(s, shape.total)
    pins = _pin_vertices(s, shape, cones, size)
    fixed = np.zeros(n, dtype=bool)
    fixed[list(pins)] = True
    rim = _Rim(s, fixed)
    folded = _untwist(rim, cones, shape)
    if folded.size == 0:
        return rim
    near = np.mod(folded[folded < n][:, None] + np.arange(-3, 4), n)
    for node, vertex in pins.items():
        if node in near:
            rim.fixed[node] = False
            if not _corner(rim, vertex, cones, shape, size):
                rim.fixed[node] = True              # no convex corner cell: the pin stays
    _untwist(rim, cones, shape)
    return rim


def _in_order_along(s, total):
    """The staircase nodes' closest-point arc lengths s made to increase once around the
    outline (unwrapped), then smoothed where they would run backwards or bunch up."""
    steps = np.mod(np.diff(np.append(s, s[0])) + 0.5 * total, total) - 0.5 * total
    if not math.isclose(steps.sum(), total, rel_tol=1e-6):
        raise InputError("the outline is not star-like enough for its yarn lattice",
                         key="blank.points", expected="a convex or nearly convex outline")
    s = s[0] + np.concatenate([[0.0], np.cumsum(steps[:-1])])
    mean = total / len(s)
    for _ in range(500):
        if np.min(np.diff(np.append(s, s[0] + total))) >= 0.1 * mean:
            break
        ext = np.concatenate([[s[-1] - total], s, [s[0] + total]])
        s = 0.5 * s + 0.25 * (ext[:-2] + ext[2:])
    return s


def _near(s, reference, total):
    """Arc lengths s shifted by whole turns to lie within half a turn of ``reference``."""
    return reference + (np.mod(s - reference + 0.5 * total, total) - 0.5 * total)


def _pin_vertices(s, shape: Outline, cones: _SpokeCones, size) -> dict[int, int]:
    """Each outline vertex moved onto a rim node (s changed in place), so that it is a node:
    the node nearest to it along the outline or, if another vertex has it or the spoke to the
    vertex from that one's staircase node would leave its cone, the one of the three nearest
    whose cone holds it best. Returns {staircase node: vertex index}; InputError if another
    vertex has all three."""
    total = shape.total
    pins: dict[int, int] = {}
    vertex_s = shape.vertex_lengths()
    for vertex, sv in enumerate([] if vertex_s is None else vertex_s):
        nearest = np.argsort(np.abs(_near(s, sv, total) - sv), kind="stable")[:3]
        room = cones.room(nearest, np.repeat(shape.points_at(np.array([sv])), 3, axis=0))
        room[np.isin(nearest, list(pins))] = -np.inf
        k = int(nearest[0] if room[0] > 0 else nearest[np.argmax(room)])
        if k in pins:
            raise InputError("two corners of the outline closer than an element",
                             key="mesh.size", value=size,
                             expected="a smaller element size, or corners farther apart")
        pins[k] = vertex
        s[k] = _near(sv, s[k], total)
    return pins


def _corner(rim: _Rim, vertex: int, cones: _SpokeCones, shape: Outline, size) -> bool:
    """Give polygon vertex ``vertex`` a corner cell: of the four staircase nodes nearest to it,
    the one whose cell (its rim nodes CORNER_REACH sizes from the vertex along its two edges,
    or its foot on them) is the least distorted. False (and nothing changed) if none is
    convex."""
    polygon, total = shape.polygon, shape.total
    n_vertices = len(polygon)
    corner = polygon[vertex]
    before, after = polygon[vertex - 1], polygon[(vertex + 1) % n_vertices]
    t_in = (corner - before) / np.linalg.norm(corner - before)
    t_out = (after - corner) / np.linalg.norm(after - corner)
    staircase = cones.staircase
    edges = np.roll(staircase, -1, axis=0) - staircase
    sv = shape.vertex_lengths()[vertex]
    best, best_quality = None, 0.0
    for j in np.argsort(np.linalg.norm(staircase - corner, axis=1))[:4]:
        if rim.fixed[j] or j in rim.corners:
            continue
        q = staircase[j]
        low, high = CORNER_REACH[0] * size, CORNER_REACH[1] * size
        a = np.clip((corner - q) @ t_in, low, min(high, 0.4 * np.linalg.norm(corner - before)))
        b = np.clip((q - corner) @ t_out, low, min(high, 0.4 * np.linalg.norm(after - corner)))
        r_in, r_out = corner - a * t_in, corner + b * t_out
        cell = np.array([[r_in, corner, r_out, q]])
        e = np.roll(cell[0], -1, axis=0) - cell[0]
        turns = cross_z(e, np.roll(e, -1, axis=0)) / (np.linalg.norm(e, axis=1)
                                                     * np.linalg.norm(np.roll(e, -1, axis=0),
                                                                      axis=1))
        spokes = np.array([cross_z(r_in - q, edges[j - 1]) / np.linalg.norm(r_in - q) / size,
                           cross_z(r_out - q, edges[j]) / np.linalg.norm(r_out - q) / size])
        quality = min(turns.min(), spokes.min())
        if quality > best_quality:
            best, best_quality = (j, a, b), quality
    if best is None:
        return False
    j, a, b = best
    reference = rim.s_in[j]
    rim.s_in[j] = _near(sv - a, reference, total)
    rim.s_out[j] = _near(sv + b, reference, total)
    rim.corners[j] = _near(sv, reference, total)
    rim.fixed[j] = True
    return True


def _untwist(rim: _Rim, cones: _SpokeCones, shape: Outline, widest: int = 4) -> np.ndarray:
    """Move the free rim nodes of folded strip cells (then of their neighbours too, one more on
    each side per round) into the range of outline points that spokes SPOKE_MARGIN_DEG inside
    their cones reach; if cells still fold, a few sweeps put each such node midway between its
    neighbours, within that range. Cells that do not fold keep their nodes, so a mesh without
    folds is unchanged. Returns the rows of the cells still folded (as :meth:`_Rim.rows`)."""
    staircase, total = cones.staircase, shape.total
    n = len(staircase)
    half = cones.half - np.radians(SPOKE_MARGIN_DEG)
    folded = rim.folded(shape, staircase)
    for reach in range(1, widest + 1):
        edges = folded[folded < n]
        if edges.size == 0:
            break
        moving = np.zeros(n, dtype=bool)
        for offset in range(1 - reach, reach + 1):
            moving[np.mod(edges + offset, n)] = True
        moving &= ~rim.fixed
        rows = np.flatnonzero(moving)
        sides = [_near(shape.along_ray(staircase[rows], np.column_stack(
                     [np.cos(cones.middle[rows] + sign * half[rows]),
                      np.sin(cones.middle[rows] + sign * half[rows])])), rim.s_in[rows], total)
                 for sign in (-1.0, 1.0)]
        low, high = np.minimum(*sides), np.maximum(*sides)
        rim.s_in[rows] = rim.s_out[rows] = np.clip(rim.s_in[rows], low, high)
        folded = rim.folded(shape, staircase)
        for _ in range(0 if folded.size == 0 else 20):
            for row, lo, hi in zip(rows, low, high):
                previous = rim.s_out[row - 1] - (total if row == 0 else 0.0)
                following = rim.s_in[(row + 1) % n] + (total if row == n - 1 else 0.0)
                rim.s_in[row] = rim.s_out[row] = np.clip(0.5 * (previous + following), lo, hi)
        folded = rim.folded(shape, staircase)
    return folded


def _with_strip(lattice, quads, loop, rim: _Rim, shape: Outline, size):
    """The mesh: the kept squares' nodes renumbered, the rim nodes after them, one strip
    quadrilateral per staircase edge (rim to staircase) and one per corner cell; InputError if
    the rim nodes run backwards or bunch up, or a strip cell is not convex."""
    s, rows = rim.rows(len(loop))
    if np.min(np.diff(np.append(s, s[0] + shape.total))) <= MIN_RIM_SPACING * shape.total / len(s):
        raise InputError("cannot lay the outline's nodes in order along it", key="mesh.size",
                         value=size, expected="a smaller element size, a rounder outline, or "
                                              "mesh.pattern = \"free\"")
    used = np.unique(quads)
    renumber = -np.ones(len(lattice), dtype=np.int64)
    renumber[used] = np.arange(len(used))
    nodes = np.vstack([lattice[used], shape.points_at(s)])
    rim_ids = len(used) + np.arange(len(s))
    strip = np.concatenate([renumber[loop], rim_ids])[rows]
    convex = _strictly_convex(nodes[strip])
    if not convex.all():
        where = nodes[strip[~convex]].mean(axis=1)
        raise InputError(f"{int((~convex).sum())} cell(s) between the yarn lattice and the "
                         "outline are not convex (near " + ", ".join(
                             f"({x:.1f}, {y:.1f})" for x, y in where[:3]) + " mm)",
                         key="mesh.size", value=size, expected="a smaller element size, a "
                         "rounder outline, or mesh.pattern = \"free\"")
    cells = np.vstack([renumber[quads], strip])
    mask = np.zeros(len(cells), dtype=bool)
    mask[len(quads):] = True
    return nodes, cells, np.column_stack([rim_ids, np.roll(rim_ids, -1)]), mask
