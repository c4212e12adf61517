"""Yarn-aligned quadrilateral lattices of a blank, built in numpy (no gmsh; mm).

* :func:`diamond_lattice` -- a rectangle with yarns at +-45 deg: squares along the yarns and
  one row of cut half-diamonds along the outline (its sides fit :func:`lattice_periods`);
* :func:`split_quads` -- the same meshes in triangles; :func:`misalignment_deg` -- how far a
  cell's edges are from the yarns.

Any outline (polygon or circle) at any yarn angle: ``drape.geometry.clipped_lattice``.
``drape.geometry.blank`` hands these meshes to gmsh; ``docs/blanks.md`` shows them.
"""

from __future__ import annotations

import math

import numpy as np

from drape.errors import InputError


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
