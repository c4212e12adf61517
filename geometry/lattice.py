"""Yarn-aligned quadrilateral lattices of a blank, built in numpy (no gmsh; mm).

* :func:`diamond_lattice` -- a rectangle with yarns at +-45 deg: squares along the yarns and
  one row of cut half-diamonds along the outline (its sides fit :func:`lattice_periods`);
* :func:`clipped_lattice` -- any outline (polygon or circle), any yarn angle: the squares that
  lie well inside it and one strip of quadrilaterals from their staircase to the outline;
* :func:`split_quads` -- the same meshes in triangles; :func:`misalignment_deg` -- how far a
  cell's edges are from the yarns.

``drape.geometry.blank`` hands these meshes to gmsh; ``docs/blanks.md`` shows them.
"""

from __future__ import annotations

import math

import numpy as np

from drape.errors import InputError
from drape.geometry.outline import closest_on_polyline, inside_polygon, point_at


# --- the +-45 degree diamond lattice ------------------------------------------------------------

def lattice_periods(length: float, width: float, size: float) -> tuple[int, int]:
    """Numbers (i, j) of lattice periods 2s along x and y, s = length/(2i) = width/(2j), with
    the yarn-aligned edge s/sqrt(2) as close to ``size`` as the outline allows."""
    target = max(1, round(width / (2.0 * size * math.sqrt(2.0))))
    candidates = []
    for j in range(1, 4 * target + 1):
        i = length * j / width
        if abs(i - round(i)) <= 1e-9 * max(1.0, i) and round(i) >= 1:
            candidates.append((abs(math.log(j / target)), j, round(i)))
    if not candidates:
        raise InputError("the rectangle does not fit a +-45 deg yarn lattice",
                         key="blank.length", value=length,
                         expected=f"length/width = i/j with small integers (e.g. 2, 3, 2.5) for "
                                  f"width = {width:g}; or mesh.pattern = \"free\"")
    _, j, i = min(candidates)
    return i, j


def diamond_lattice(length: float, width: float, size: float):
    """A yarn-aligned quadrilateral mesh of [0, length] x [0, width] for yarns at +-45 deg.

    The coarse lattice has nodes (p s, q s), p + q even: squares ("diamonds") of side s sqrt 2
    whose edges follow the yarns. Each whole diamond becomes 4 squares of side s/sqrt 2 (the
    element size). The outline passes through lattice nodes and cuts the diamonds on it into
    right triangles; each becomes 3 quadrilaterals through its centroid and edge midpoints, which
    are also nodes of the neighbouring squares, so the mesh is conforming. Every yarn line
    through a corner of the blank (the zone borders of a bias-extension test) is a mesh line.

    Returns nodes (N, 2), quadrilaterals (M, 4) counter-clockwise, and {side: segments (K, 2)}.
    """
    i, j = lattice_periods(length, width, size)
    s = width / (2 * j)
    unit = s / 6.0                     # node keys are integer multiples of s/6
    keys: dict[tuple[int, int], int] = {}

    def node(a, b):                    # a, b in units of s/6
        return keys.setdefault((a, b), len(keys))

    quads = []
    for p in range(0, 2 * i + 1):
        for q in range(0, 2 * j + 1):
            if (p + q) % 2 == 0:
                continue
            for quad in _diamond_cells(p, q, i, j):
                quads.append([node(*v) for v in quad])
    key_array = np.array(list(keys), dtype=np.int64)
    nodes = key_array * unit
    cells = np.array(quads, dtype=np.int64)
    sides = {}
    for side, axis, value in (("bottom", 1, 0), ("top", 1, 12 * j), ("left", 0, 0),
                              ("right", 0, 12 * i)):
        on = np.nonzero(key_array[:, axis] == value)[0]
        on = on[np.argsort(key_array[on, 1 - axis])]
        sides[side] = np.column_stack([on[:-1], on[1:]])
    # the outline exactly, despite the round-off of s/6
    nodes[key_array[:, 0] == 12 * i, 0] = length
    nodes[key_array[:, 1] == 12 * j, 1] = width
    return nodes, cells, sides


def _mid(u, v):
    """The midpoint of two node keys (integer units of s/6, so exact)."""
    return ((u[0] + v[0]) // 2, (u[1] + v[1]) // 2)


def _diamond_cells(p: int, q: int, i: int, j: int):
    """The quadrilaterals (node keys, counter-clockwise) of the diamond centred on the coarse
    lattice point (p s, q s), p + q odd, in a blank of i by j periods: 4 squares if the diamond
    is whole, 3 quadrilaterals of the right triangle the outline leaves of it if not."""
    c = (6 * p, 6 * q)
    S, E, N, W = (c[0], c[1] - 6), (c[0] + 6, c[1]), (c[0], c[1] + 6), (c[0] - 6, c[1])
    inside = [0 <= v[0] <= 12 * i and 0 <= v[1] <= 12 * j for v in (S, E, N, W)]
    if all(inside):
        SE, EN, NW, WS = _mid(S, E), _mid(E, N), _mid(N, W), _mid(W, S)
        return ((S, SE, c, WS), (SE, E, EN, c), (c, EN, N, NW), (WS, c, NW, W))
    # a half diamond: the two vertices on the outline and the apex, counter-clockwise
    if q == 0:
        A, B, P = W, E, N
    elif q == 2 * j:
        A, B, P = E, W, S
    elif p == 0:
        A, B, P = N, S, E
    else:
        A, B, P = S, N, W
    G = ((A[0] + B[0] + P[0]) // 3, (A[1] + B[1] + P[1]) // 3)
    MAB, MBP, MPA = _mid(A, B), _mid(B, P), _mid(P, A)
    return ((A, MAB, G, MPA), (MAB, B, MBP, G), (G, MBP, P, MPA))


# --- any outline: a yarn-aligned lattice clipped to it, and a strip of cells to the outline ------

#: a lattice cell is kept when its corners lie at least this many element sizes inside the
#: outline: the strip between the lattice and the outline is then 0.5 to about 1.5 sizes wide
LATTICE_MARGIN = 0.5


class _Outline:
    """The closed outline a lattice is clipped to: a polygon (n, 2), counter-clockwise, or a
    circle of radius ``circle`` about ``centre`` (``polygon`` then its fine polygon, for the
    lattice's extent only). Arc-length parameters run counter-clockwise from the polygon's
    vertex 0 (the circle's point on +x)."""

    def __init__(self, polygon: np.ndarray, centre: np.ndarray, circle: float | None):
        self.polygon, self.centre, self.circle = polygon, centre, circle
        if circle is not None:
            self.total = 2 * math.pi * circle
        else:
            self.total = float(np.sum(np.linalg.norm(np.roll(polygon, -1, axis=0) - polygon,
                                                     axis=1)))

    def closest(self, q):
        """Distance (P,) of points q (P, 2) to the outline and the arc length of their
        closest points on it."""
        if self.circle is None:
            return closest_on_polyline(self.polygon, q)
        centre, circle = self.centre, self.circle
        return (circle - np.linalg.norm(q - centre, axis=1),
                circle * np.mod(np.arctan2(q[:, 1] - centre[1], q[:, 0] - centre[0]),
                                2 * math.pi))

    def inside(self, q) -> np.ndarray:
        if self.circle is None:
            return inside_polygon(self.polygon, q)
        return np.linalg.norm(q - self.centre, axis=1) < self.circle

    def points_at(self, s) -> np.ndarray:
        """The outline's points (P, 2) at arc lengths s (P,)."""
        if self.circle is None:
            return point_at(self.polygon, s)
        circle = self.circle
        return self.centre + circle * np.column_stack([np.cos(s / circle), np.sin(s / circle)])

    def vertex_lengths(self) -> np.ndarray | None:
        """Arc lengths of the polygon's vertices (None for a circle: it has none)."""
        if self.circle is not None:
            return None
        polygon = self.polygon
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.roll(polygon, -1, axis=0)
                                                               - polygon, axis=1))[:-1]])


def clipped_lattice(outline: np.ndarray, yarn_angle: float, size: float, centre=(0.0, 0.0),
                    circle: float | None = None):
    """A mesh of the region inside ``outline`` (closed polygon (n, 2), counter-clockwise;
    a disc: its fine polygon and ``circle`` the radius, centred on ``centre``) for yarns at
    ``yarn_angle`` (deg): squares of side ``size`` along the yarns (one centred on ``centre``)
    wherever they lie at least LATTICE_MARGIN sizes inside the outline, and one ring of
    quadrilaterals from the lattice's staircase boundary to the outline, one per staircase
    edge. The ring's outline nodes follow the staircase nodes' closest points on the outline,
    smoothed along it where those would run backwards; every vertex of the outline is a node.

    Returns nodes (N, 2), quadrilaterals (M, 4) counter-clockwise, the boundary segments
    (K, 2) and a boolean mask of the strip cells (M,)."""
    centre = np.asarray(centre, dtype=float)
    shape = _Outline(outline, centre, circle)
    lattice, ni, nj = _yarn_grid(outline, yarn_angle, size, centre)
    quads = _kept_squares(lattice, ni, nj, shape, size)
    loop = _staircase(quads, size)
    _, s = shape.closest(lattice[loop])
    s = _in_order_along(s, shape.total)
    s = _pin_vertices(s, shape.vertex_lengths(), shape.total, size)
    return _with_strip(lattice, quads, loop, shape.points_at(s))


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


def _kept_squares(lattice, ni, nj, shape: _Outline, size):
    """The grid squares (M, 4 node rows, counter-clockwise) whose corners all lie at least
    LATTICE_MARGIN sizes inside the outline."""
    gap, _ = shape.closest(lattice)
    good = shape.inside(lattice) & (gap >= LATTICE_MARGIN * size)
    good = good.reshape(ni, nj)
    keep = good[:-1, :-1] & good[1:, :-1] & good[1:, 1:] & good[:-1, 1:]
    if not keep.any():
        raise InputError("the blank is too small for its mesh", key="mesh.size", value=size,
                         expected="an element size a few times smaller than the blank")
    index = lambda i, j: i * nj + j          # noqa: E731
    ci, cj = np.nonzero(keep)
    return np.column_stack([index(ci, cj), index(ci + 1, cj), index(ci + 1, cj + 1),
                            index(ci, cj + 1)])


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


def _pin_vertices(s, vertex_s, total, size):
    """Each outline vertex (arc lengths vertex_s; None: none) moved onto the nearest rim node,
    so that it is a node; InputError if two share one or the nodes fall out of order."""
    mean = total / len(s)
    if vertex_s is not None:
        taken = set()
        for sv in vertex_s:
            k = int(np.argmin(np.abs(np.mod(s - sv + 0.5 * total, total) - 0.5 * total)))
            if k in taken:
                raise InputError("two corners of the outline closer than an element",
                                 key="mesh.size", value=size,
                                 expected="a smaller element size, or corners farther apart")
            taken.add(k)
            s[k] += np.mod(sv - s[k] + 0.5 * total, total) - 0.5 * total
    increments = np.diff(np.append(s, s[0] + total))
    if increments.min() <= 0.05 * mean:
        raise InputError("cannot lay the outline's nodes in order along it", key="mesh.size",
                         value=size, expected="a smaller element size, or a rounder outline")
    return s


def _with_strip(lattice, quads, loop, rim):
    """The mesh: the kept squares' nodes renumbered, the rim nodes after them, and one strip
    quadrilateral per staircase edge (rim to staircase); InputError if one is not convex."""
    used = np.unique(quads)
    renumber = -np.ones(len(lattice), dtype=np.int64)
    renumber[used] = np.arange(len(used))
    nodes = np.vstack([lattice[used], rim])
    n = len(loop)
    rim_ids = len(used) + np.arange(n)
    a, b = renumber[loop], renumber[np.roll(loop, -1)]
    pa, pb = rim_ids, np.roll(rim_ids, -1)
    strip = np.column_stack([pa, pb, b, a])
    cells = np.vstack([renumber[quads], strip])
    _check_convex(nodes, strip)
    mask = np.zeros(len(cells), dtype=bool)
    mask[len(quads):] = True
    return nodes, cells, np.column_stack([pa, pb]), mask


def _check_convex(nodes, quads):
    """InputError unless every quadrilateral (M, 4) is strictly convex."""
    p = nodes[quads]
    e = np.roll(p, -1, axis=1) - p
    f = np.roll(e, -1, axis=1)
    cross = e[:, :, 0] * f[:, :, 1] - e[:, :, 1] * f[:, :, 0]
    if (cross <= 0).any():
        raise InputError(f"{int(np.any(cross <= 0, axis=1).sum())} cell(s) between the yarn "
                         "lattice and the outline are not convex", key="mesh.size",
                         expected="a smaller element size, or a rounder outline")


# --- triangles and alignment ----------------------------------------------------------------------

def split_quads(nodes, quads):
    """Each quadrilateral into two triangles along its shorter diagonal."""
    a, b, c, d = (quads[:, k] for k in range(4))
    d02 = np.linalg.norm(nodes[a] - nodes[c], axis=1)
    d13 = np.linalg.norm(nodes[b] - nodes[d], axis=1)
    use02 = d02 <= d13 * (1 + 1e-12)
    first = np.where(use02[:, None], np.column_stack([a, b, c]), np.column_stack([a, b, d]))
    second = np.where(use02[:, None], np.column_stack([a, c, d]), np.column_stack([b, c, d]))
    return np.vstack([first, second])


def misalignment_deg(nodes, quads, yarn_angle: float) -> np.ndarray:
    """Per quadrilateral, the largest angle (deg, 0 to 45) between one of its edges and the
    nearer yarn: 0 for a cell whose edges all follow the yarns."""
    p = nodes[quads]
    e = np.roll(p, -1, axis=1) - p
    angle = np.degrees(np.arctan2(e[:, :, 1], e[:, :, 0])) - yarn_angle
    off = np.abs(np.mod(angle + 45.0, 90.0) - 45.0)
    return off.max(axis=1)
