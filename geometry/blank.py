"""gmsh builders of the flat blank: a rectangle, a disc or a polygon, meshed in the X-Y plane (mm).

Call :func:`build_blank` on one rank with gmsh initialised; it leaves the meshed model in
``gmsh.model`` with physical groups: the surface ``blank`` and the boundary curves (rectangle:
``left`` x = 0, ``right`` x = length, ``bottom`` y = 0, ``top`` y = width; disc and polygon:
``edge``; and ``blank_strip``, the cells of a clipped lattice between it and the outline).

Patterns (yarn angle theta, degrees, warp G1 = (cos theta, sin theta)):

* ``aligned`` rectangle, theta a multiple of 90: gmsh's transfinite grid, element edges along
  the yarns (triangles: each grid square cut by one diagonal, legs along the yarns).
* ``aligned`` rectangle, theta = +-45 (mod 90): the *diamond lattice* (see :func:`diamond_lattice`):
  squares along the yarns everywhere except one row of cells along the outline, where the
  lattice's half-squares are cut into three quadrilaterals each. The outline must fit the
  lattice: length/width a ratio of small integers.
* ``aligned`` disc or polygon, any theta: the *clipped lattice* (see :func:`clipped_lattice`):
  yarn-aligned squares wherever they lie half an element inside the outline, and one strip of
  quadrilaterals from their staircase to the outline (``docs/blanks.md``).
* ``free``: gmsh's unstructured mesh (Frontal-Delaunay; quadrilaterals by Blossom recombination),
  not aligned with the yarns: such triangles lock in tension (``docs/fe-solver.md``).

Bad requests raise :class:`~drape.errors.InputError` naming the config key.
"""

from __future__ import annotations

import math

import numpy as np

from drape.errors import InputError

BLANK = "blank"
#: the cells between a clipped yarn lattice and the outline (disc, polygon)
BLANK_STRIP = "blank_strip"
RECTANGLE_SIDES = ("left", "right", "bottom", "top")
DISC_EDGE = "edge"
#: refuse meshes estimated larger than this (elements), a likely typo in mesh.size
MAX_ELEMENTS = 4_000_000

# gmsh element types
_LINE, _TRIANGLE, _QUAD = 1, 2, 3


def build_blank(gmsh, shape: str, *, length: float = 100.0, width: float = 100.0,
                radius: float = 50.0, points=(), yarn_angle: float = 0.0,
                cell: str = "quadrilateral", pattern: str = "aligned",
                size: float = 5.0) -> dict[str, int]:
    """Mesh the blank into the current gmsh model; returns {physical name: tag} of dimension 1
    (boundaries) and the tag of ``blank`` (dimension 2; and of ``blank_strip``, the cells
    between a clipped lattice and the outline, when there are such)."""
    outline = polygon_outline(points) if shape == "polygon" else None
    area = (length * width if shape == "rectangle" else math.pi * radius ** 2 if shape == "disc"
            else abs(polygon_area(outline)))
    estimate = area / size ** 2 * (2 if cell == "triangle" else 1)
    if not estimate <= MAX_ELEMENTS:
        smallest = math.sqrt(area / MAX_ELEMENTS)
        raise InputError(f"about {estimate:.3g} elements", key="mesh.size", value=size,
                         expected=f"a size giving at most {MAX_ELEMENTS:.0e} elements " + (
                             f"(>= {smallest:.3g} mm here)" if math.isfinite(smallest) else
                             "(and a blank of finite area)"))
    gmsh.model.add("blank")
    quads = cell == "quadrilateral"
    angle = yarn_angle % 90.0
    if shape == "rectangle":
        if pattern == "aligned" and (math.isclose(angle, 0.0, abs_tol=1e-9)
                                     or math.isclose(angle, 90.0)):
            names = _rectangle_grid(gmsh, length, width, size, quads)
        elif pattern == "aligned" and math.isclose(angle, 45.0):
            nodes, cells, sides = diamond_lattice(length, width, size)
            if not quads:
                cells = _split_quads(nodes, cells)
            names = _discrete(gmsh, nodes, cells, sides, quads)
        elif pattern == "aligned":
            raise InputError("a yarn-aligned mesh of a rectangle needs yarns at a multiple of "
                             "45 deg",
                             key="blank.yarn_angle", value=yarn_angle,
                             expected="0, 90, 45 or -45, or mesh.pattern = \"free\" (not aligned: "
                                      "see the locking note in docs/fe-solver.md)")
        else:
            names = _rectangle_free(gmsh, length, width, size, quads)
    elif pattern == "aligned":
        if shape == "disc":
            phi = 2 * math.pi * np.arange(360) / 360        # for the lattice's extent only
            outline, circle = radius * np.column_stack([np.cos(phi), np.sin(phi)]), radius
        else:
            circle = None
        nodes, cells, edge, strip = clipped_lattice(outline, yarn_angle, size, circle=circle)
        if not quads:
            cells, strip = _split_quads(nodes, cells), np.concatenate([strip, strip])
        names = _discrete(gmsh, nodes, cells, {DISC_EDGE: edge}, quads, strip=strip)
    elif shape == "disc":
        names = _disc_free(gmsh, radius, yarn_angle, size, quads)
    else:
        names = _polygon_free(gmsh, outline, size, quads)
    _check_cells(gmsh, quads)
    return names


# --- rectangle -----------------------------------------------------------------------------------

def _rectangle_outline(gmsh, length, width):
    geo = gmsh.model.geo
    p = [geo.addPoint(*xy, 0.0) for xy in ((0, 0), (length, 0), (length, width), (0, width))]
    lines = {"bottom": geo.addLine(p[0], p[1]), "right": geo.addLine(p[1], p[2]),
             "top": geo.addLine(p[2], p[3]), "left": geo.addLine(p[3], p[0])}
    loop = geo.addCurveLoop([lines["bottom"], lines["right"], lines["top"], lines["left"]])
    surface = geo.addPlaneSurface([loop])
    return lines, surface


def _rectangle_grid(gmsh, length, width, size, quads):
    lines, surface = _rectangle_outline(gmsh, length, width)
    geo = gmsh.model.geo
    nx, ny = max(1, round(length / size)), max(1, round(width / size))
    for name, n in (("bottom", nx), ("top", nx), ("left", ny), ("right", ny)):
        geo.mesh.setTransfiniteCurve(lines[name], n + 1)
    geo.mesh.setTransfiniteSurface(surface, "Left")
    if quads:
        geo.mesh.setRecombine(2, surface)
    geo.synchronize()
    names = _physical(gmsh, {name: [tag] for name, tag in lines.items()}, [surface])
    gmsh.model.mesh.generate(2)
    return names


def _rectangle_free(gmsh, length, width, size, quads):
    lines, surface = _rectangle_outline(gmsh, length, width)
    gmsh.model.geo.synchronize()
    names = _physical(gmsh, {name: [tag] for name, tag in lines.items()}, [surface])
    _free_mesh(gmsh, size, quads)
    return names


def _free_mesh(gmsh, size, quads):
    gmsh.option.setNumber("Mesh.CharacteristicLengthMin", size)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMax", size)
    gmsh.option.setNumber("Mesh.CharacteristicLengthFromPoints", 0)
    if quads:
        gmsh.option.setNumber("Mesh.Algorithm", 6)               # (8 crashes in gmsh 4.8.4)
        gmsh.option.setNumber("Mesh.RecombineAll", 1)
        gmsh.option.setNumber("Mesh.RecombinationAlgorithm", 3)  # Blossom, full-quad
    else:
        gmsh.option.setNumber("Mesh.Algorithm", 6)               # Frontal-Delaunay
    gmsh.model.mesh.generate(2)


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
            c = (6 * p, 6 * q)
            S, E, N, W = (c[0], c[1] - 6), (c[0] + 6, c[1]), (c[0], c[1] + 6), (c[0] - 6, c[1])
            inside = [0 <= v[0] <= 12 * i and 0 <= v[1] <= 12 * j for v in (S, E, N, W)]
            if all(inside):
                mid = lambda u, v: ((u[0] + v[0]) // 2, (u[1] + v[1]) // 2)  # noqa: E731
                SE, EN, NW, WS = mid(S, E), mid(E, N), mid(N, W), mid(W, S)
                for quad in ((S, SE, c, WS), (SE, E, EN, c), (c, EN, N, NW), (WS, c, NW, W)):
                    quads.append([node(*v) for v in quad])
                continue
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
            mid = lambda u, v: ((u[0] + v[0]) // 2, (u[1] + v[1]) // 2)  # noqa: E731
            MAB, MBP, MPA = mid(A, B), mid(B, P), mid(P, A)
            for quad in ((A, MAB, G, MPA), (MAB, B, MBP, G), (G, MBP, P, MPA)):
                quads.append([node(*v) for v in quad])
    key_array = np.array(list(keys), dtype=np.int64)
    nodes = key_array * unit
    # the outline exactly, despite the round-off of s/6
    cells = np.array(quads, dtype=np.int64)
    sides = {}
    for side, axis, value in (("bottom", 1, 0), ("top", 1, 12 * j), ("left", 0, 0),
                              ("right", 0, 12 * i)):
        on = np.nonzero(key_array[:, axis] == value)[0]
        on = on[np.argsort(key_array[on, 1 - axis])]
        sides[side] = np.column_stack([on[:-1], on[1:]])
    nodes[key_array[:, 0] == 12 * i, 0] = length
    nodes[key_array[:, 1] == 12 * j, 1] = width
    return nodes, cells, sides


def _split_quads(nodes, quads):
    """Each quadrilateral into two triangles along its shorter diagonal."""
    a, b, c, d = (quads[:, k] for k in range(4))
    d02 = np.linalg.norm(nodes[a] - nodes[c], axis=1)
    d13 = np.linalg.norm(nodes[b] - nodes[d], axis=1)
    use02 = d02 <= d13 * (1 + 1e-12)
    first = np.where(use02[:, None], np.column_stack([a, b, c]), np.column_stack([a, b, d]))
    second = np.where(use02[:, None], np.column_stack([a, c, d]), np.column_stack([b, c, d]))
    return np.vstack([first, second])


def _discrete(gmsh, nodes, cells, sides, quads, strip=None):
    """Hand a mesh made here to gmsh as discrete entities (so it goes through gmshio); the
    cells where ``strip`` (a mask) is true in a second physical surface, ``blank_strip``."""
    surface = gmsh.model.addDiscreteEntity(2)
    xyz = np.column_stack([nodes, np.zeros(len(nodes))]).ravel()
    gmsh.model.mesh.addNodes(2, surface, np.arange(1, len(nodes) + 1), xyz)
    element = _QUAD if quads else _TRIANGLE
    strip = np.zeros(len(cells), dtype=bool) if strip is None else np.asarray(strip)
    tags = np.arange(1, len(cells) + 1)
    gmsh.model.mesh.addElementsByType(surface, element, tags[~strip], (cells[~strip] + 1).ravel())
    extra = None
    if strip.any():
        extra = gmsh.model.addDiscreteEntity(2)
        gmsh.model.mesh.addElementsByType(extra, element, tags[strip], (cells[strip] + 1).ravel())
    next_tag = len(cells) + 1
    curves = {}
    for name, segments in sides.items():
        curve = gmsh.model.addDiscreteEntity(1)
        gmsh.model.mesh.addElementsByType(curve, _LINE,
                                          np.arange(next_tag, next_tag + len(segments)),
                                          (segments + 1).ravel())
        next_tag += len(segments)
        curves[name] = [curve]
    names = _physical(gmsh, curves, [surface])
    if extra is not None:
        tag = max(names.values()) + 1
        gmsh.model.addPhysicalGroup(2, [extra], tag)
        gmsh.model.setPhysicalName(2, tag, BLANK_STRIP)
        names[BLANK_STRIP] = tag
    return names


# --- disc ---------------------------------------------------------------------------------------

def _disc_free(gmsh, radius, yarn_angle, size, quads):
    geo = gmsh.model.geo
    centre = geo.addPoint(0.0, 0.0, 0.0)
    angles = [math.radians(yarn_angle + 45.0 + 90.0 * k) for k in range(4)]
    rim = [geo.addPoint(radius * math.cos(a), radius * math.sin(a), 0.0) for a in angles]
    arcs = [geo.addCircleArc(rim[k], centre, rim[(k + 1) % 4]) for k in range(4)]
    surface = geo.addPlaneSurface([geo.addCurveLoop(arcs)])
    geo.synchronize()
    names = _physical(gmsh, {DISC_EDGE: arcs}, [surface])
    _free_mesh(gmsh, size, quads)
    return names


def _polygon_free(gmsh, outline, size, quads):
    geo = gmsh.model.geo
    p = [geo.addPoint(x, y, 0.0) for x, y in outline]
    lines = [geo.addLine(p[k], p[(k + 1) % len(p)]) for k in range(len(p))]
    surface = geo.addPlaneSurface([geo.addCurveLoop(lines)])
    geo.synchronize()
    names = _physical(gmsh, {DISC_EDGE: lines}, [surface])
    _free_mesh(gmsh, size, quads)
    return names


# --- common ---------------------------------------------------------------------------------------

def _physical(gmsh, curves: dict[str, list[int]], surfaces: list[int]) -> dict[str, int]:
    names = {}
    for tag, (name, entities) in enumerate(curves.items(), start=1):
        gmsh.model.addPhysicalGroup(1, entities, tag)
        gmsh.model.setPhysicalName(1, tag, name)
        names[name] = tag
    surface_tag = len(curves) + 1
    gmsh.model.addPhysicalGroup(2, surfaces, surface_tag)
    gmsh.model.setPhysicalName(2, surface_tag, BLANK)
    names[BLANK] = surface_tag
    return names


def _check_cells(gmsh, quads):
    types, tags, _ = gmsh.model.mesh.getElements(2)
    want = _QUAD if quads else _TRIANGLE
    counts = {int(t): len(tg) for t, tg in zip(types, tags)}
    if counts.get(want, 0) == 0 or set(counts) - {want}:
        raise InputError(f"gmsh produced elements of types {counts}", key="mesh.cell",
                         value="quadrilateral" if quads else "triangle",
                         expected="a mesh of one cell type; try another mesh.size or pattern")


# --- any outline: a yarn-aligned lattice clipped to it, and a strip of cells to the outline ------

def polygon_outline(points) -> np.ndarray:
    """The polygon's vertices (n, 2) counter-clockwise, duplicate closing point removed;
    InputError (key blank.points) unless it is a simple polygon of at least 3 vertices."""
    xy = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(xy) > 1 and np.allclose(xy[0], xy[-1]):
        xy = xy[:-1]
    if len(xy) < 3:
        raise InputError("a polygon needs at least 3 vertices", key="blank.points",
                         value=len(xy), expected="[[x0, y0], [x1, y1], [x2, y2], ...] in mm")
    n = len(xy)
    edges = [(xy[k], xy[(k + 1) % n]) for k in range(n)]
    lengths = [np.linalg.norm(b - a) for a, b in edges]
    if min(lengths) <= 1e-9 * max(lengths):
        raise InputError("a polygon with a repeated vertex", key="blank.points",
                         value=[list(p) for p in xy], expected="distinct vertices around an area")
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue
            if _segments_cross(*edges[i], *edges[j]):
                raise InputError("the polygon's edges cross", key="blank.points",
                                 value=f"edges {i} and {j}",
                                 expected="a simple polygon (vertices in order around it)")
    area = polygon_area(xy)
    if abs(area) <= 1e-12 * max(lengths) ** 2:
        raise InputError("a polygon with no area", key="blank.points",
                         value=[list(p) for p in xy], expected="vertices around an area")
    if area < 0:
        xy = xy[::-1].copy()
    return xy


def polygon_area(xy) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _segments_cross(a, b, c, d) -> bool:
    def orient(p, q, r):
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
    return (orient(a, b, c) * orient(a, b, d) < 0) and (orient(c, d, a) * orient(c, d, b) < 0)


def _inside(xy, points) -> np.ndarray:
    """Whether each point (P, 2) lies inside the polygon xy (even-odd rule)."""
    x, y = points[:, 0][:, None], points[:, 1][:, None]
    x0, y0 = xy[:, 0][None, :], xy[:, 1][None, :]
    x1, y1 = np.roll(xy[:, 0], -1)[None, :], np.roll(xy[:, 1], -1)[None, :]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.sum(crosses & (x < xc), axis=1) % 2) == 1


def _closest(xy, points):
    """Distance (P,) of each point to the closed polyline xy and the arc-length parameter of
    its closest point on it (from vertex 0, counter-clockwise)."""
    a = xy[None, :, :]
    d = (np.roll(xy, -1, axis=0) - xy)[None, :, :]
    length = np.linalg.norm(d[0], axis=1)
    start = np.concatenate([[0.0], np.cumsum(length)[:-1]])
    p = points[:, None, :]
    t = np.clip(np.sum((p - a) * d, axis=2) / (length ** 2)[None, :], 0.0, 1.0)
    gap = np.linalg.norm(p - (a + t[:, :, None] * d), axis=2)
    k = np.argmin(gap, axis=1)
    rows = np.arange(len(points))
    return gap[rows, k], start[k] + t[rows, k] * length[k]


def _at(xy, s):
    """Points of the closed polyline xy at arc-length parameters s."""
    d = np.roll(xy, -1, axis=0) - xy
    length = np.linalg.norm(d, axis=1)
    ends = np.cumsum(length)
    s = np.mod(s, ends[-1])
    k = np.minimum(np.searchsorted(ends, s, side="right"), len(xy) - 1)
    t = (s - (ends[k] - length[k])) / length[k]
    return xy[k] + t[:, None] * d[k]


#: a lattice cell is kept when its corners lie at least this many element sizes inside the
#: outline: the strip between the lattice and the outline is then 0.5 to about 1.5 sizes wide
LATTICE_MARGIN = 0.5


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
    theta = math.radians(yarn_angle)
    g1 = np.array([math.cos(theta), math.sin(theta)])
    g2 = np.array([-math.sin(theta), math.cos(theta)])
    centre = np.asarray(centre, dtype=float)
    local = (outline - centre) @ np.column_stack([g1, g2])          # yarn coordinates
    lo = np.floor(local.min(axis=0) / size - 1).astype(int)
    hi = np.ceil(local.max(axis=0) / size + 1).astype(int)
    I, J = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    ni, nj = I.shape
    lattice = (centre + ((I.ravel() + 0.5) * size)[:, None] * g1
               + ((J.ravel() + 0.5) * size)[:, None] * g2)
    if circle is not None:
        closest = lambda q: (circle - np.linalg.norm(q - centre, axis=1),      # noqa: E731
                             circle * np.mod(np.arctan2(q[:, 1] - centre[1], q[:, 0] - centre[0]),
                                             2 * math.pi))
        inside = lambda q: np.linalg.norm(q - centre, axis=1) < circle         # noqa: E731
        total = 2 * math.pi * circle
    else:
        closest = lambda q: _closest(outline, q)                                # noqa: E731
        inside = lambda q: _inside(outline, q)                                  # noqa: E731
        total = float(np.sum(np.linalg.norm(np.roll(outline, -1, axis=0) - outline, axis=1)))
    gap, _ = closest(lattice)
    good = inside(lattice) & (gap >= LATTICE_MARGIN * size)
    good = good.reshape(ni, nj)
    keep = good[:-1, :-1] & good[1:, :-1] & good[1:, 1:] & good[:-1, 1:]
    if not keep.any():
        raise InputError("the blank is too small for its mesh", key="mesh.size", value=size,
                         expected="an element size a few times smaller than the blank")
    index = lambda i, j: i * nj + j          # noqa: E731
    ci, cj = np.nonzero(keep)
    quads = np.column_stack([index(ci, cj), index(ci + 1, cj), index(ci + 1, cj + 1),
                             index(ci, cj + 1)])
    # the staircase: edges of exactly one kept cell, counter-clockwise around the lattice
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
    loop = np.array(loop)
    # where the staircase nodes go on the outline: their closest points, made monotonic
    _, s = closest(lattice[loop])
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
    # every vertex of the outline a node (not for the disc's polygon)
    if circle is None:
        vertex_s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.roll(outline, -1, axis=0)
                                                                  - outline, axis=1))[:-1]])
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
    if circle is not None:
        rim = centre + circle * np.column_stack([np.cos(s / circle), np.sin(s / circle)])
    else:
        rim = _at(outline, s)
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
    p = nodes[quads]
    e = np.roll(p, -1, axis=1) - p
    f = np.roll(e, -1, axis=1)
    cross = e[:, :, 0] * f[:, :, 1] - e[:, :, 1] * f[:, :, 0]
    if (cross <= 0).any():
        raise InputError(f"{int(np.any(cross <= 0, axis=1).sum())} cell(s) between the yarn "
                         "lattice and the outline are not convex", key="mesh.size",
                         expected="a smaller element size, or a rounder outline")


def misalignment_deg(nodes, quads, yarn_angle: float) -> np.ndarray:
    """Per quadrilateral, the largest angle (deg, 0 to 45) between one of its edges and the
    nearer yarn: 0 for a cell whose edges all follow the yarns."""
    p = nodes[quads]
    e = np.roll(p, -1, axis=1) - p
    angle = np.degrees(np.arctan2(e[:, :, 1], e[:, :, 0])) - yarn_angle
    off = np.abs(np.mod(angle + 45.0, 90.0) - 45.0)
    return off.max(axis=1)
