"""gmsh builders of the flat blank: a rectangle or a disc, meshed in the X-Y plane (mm).

Call :func:`build_blank` on one rank with gmsh initialised; it leaves the meshed model in
``gmsh.model`` with physical groups: the surface ``blank`` and the boundary curves (rectangle:
``left`` x = 0, ``right`` x = length, ``bottom`` y = 0, ``top`` y = width; disc: ``edge``).

Patterns (yarn angle theta, degrees, warp G1 = (cos theta, sin theta)):

* ``aligned`` rectangle, theta a multiple of 90: gmsh's transfinite grid, element edges along
  the yarns (triangles: each grid square cut by one diagonal, legs along the yarns).
* ``aligned`` rectangle, theta = +-45 (mod 90): the *diamond lattice* (see :func:`diamond_lattice`):
  squares along the yarns everywhere except one row of cells along the outline, where the
  lattice's half-squares are cut into three quadrilaterals each. The outline must fit the
  lattice: length/width a ratio of small integers.
* ``aligned`` disc: an O-grid whose central square (half the radius to its corners) follows the
  yarns; the four blocks around it bend towards the circle.
* ``free``: gmsh's unstructured mesh (Frontal-Delaunay; quadrilaterals by Blossom recombination),
  not aligned with the yarns: such triangles lock in tension (``docs/fe-solver.md``).

Bad requests raise :class:`~drape.errors.InputError` naming the config key.
"""

from __future__ import annotations

import math

import numpy as np

from drape.errors import InputError

BLANK = "blank"
RECTANGLE_SIDES = ("left", "right", "bottom", "top")
DISC_EDGE = "edge"
#: refuse meshes estimated larger than this (elements), a likely typo in mesh.size
MAX_ELEMENTS = 4_000_000

# gmsh element types
_LINE, _TRIANGLE, _QUAD = 1, 2, 3


def build_blank(gmsh, shape: str, *, length: float = 100.0, width: float = 100.0,
                radius: float = 50.0, yarn_angle: float = 0.0, cell: str = "quadrilateral",
                pattern: str = "aligned", size: float = 5.0) -> dict[str, int]:
    """Mesh the blank into the current gmsh model; returns {physical name: tag} of dimension 1
    (boundaries) and the tag of ``blank`` (dimension 2)."""
    area = length * width if shape == "rectangle" else math.pi * radius ** 2
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
    else:
        names = _disc(gmsh, radius, yarn_angle, size, quads, aligned=(pattern == "aligned"))
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


def _discrete(gmsh, nodes, cells, sides, quads):
    """Hand a mesh made here to gmsh as discrete entities (so it goes through gmshio)."""
    surface = gmsh.model.addDiscreteEntity(2)
    xyz = np.column_stack([nodes, np.zeros(len(nodes))]).ravel()
    gmsh.model.mesh.addNodes(2, surface, np.arange(1, len(nodes) + 1), xyz)
    element = _QUAD if quads else _TRIANGLE
    gmsh.model.mesh.addElementsByType(surface, element, np.arange(1, len(cells) + 1),
                                      (cells + 1).ravel())
    next_tag = len(cells) + 1
    curves = {}
    for name, segments in sides.items():
        curve = gmsh.model.addDiscreteEntity(1)
        gmsh.model.mesh.addElementsByType(curve, _LINE,
                                          np.arange(next_tag, next_tag + len(segments)),
                                          (segments + 1).ravel())
        next_tag += len(segments)
        curves[name] = [curve]
    return _physical(gmsh, curves, [surface])


# --- disc ---------------------------------------------------------------------------------------

def _disc(gmsh, radius, yarn_angle, size, quads, aligned):
    geo = gmsh.model.geo
    centre = geo.addPoint(0.0, 0.0, 0.0)
    angles = [math.radians(yarn_angle + 45.0 + 90.0 * k) for k in range(4)]
    rim = [geo.addPoint(radius * math.cos(a), radius * math.sin(a), 0.0) for a in angles]
    arcs = [geo.addCircleArc(rim[k], centre, rim[(k + 1) % 4]) for k in range(4)]
    if not aligned:
        loop = geo.addCurveLoop(arcs)
        surface = geo.addPlaneSurface([loop])
        geo.synchronize()
        names = _physical(gmsh, {DISC_EDGE: arcs}, [surface])
        _free_mesh(gmsh, size, quads)
        return names
    inner = 0.5 * radius                            # distance of the square's corners
    corner = [geo.addPoint(inner * math.cos(a), inner * math.sin(a), 0.0) for a in angles]
    sides = [geo.addLine(corner[k], corner[(k + 1) % 4]) for k in range(4)]
    spokes = [geo.addLine(corner[k], rim[k]) for k in range(4)]
    n_side = max(1, round(inner * math.sqrt(2.0) / size))
    n_spoke = max(1, round((radius - inner) / size))
    surfaces = [geo.addPlaneSurface([geo.addCurveLoop(sides)])]
    for k in range(4):
        loop = geo.addCurveLoop([spokes[k], arcs[k], -spokes[(k + 1) % 4], -sides[k]])
        surfaces.append(geo.addPlaneSurface([loop]))
    for curve in sides + arcs:
        geo.mesh.setTransfiniteCurve(curve, n_side + 1)
    for curve in spokes:
        geo.mesh.setTransfiniteCurve(curve, n_spoke + 1)
    for surface in surfaces:
        geo.mesh.setTransfiniteSurface(surface, "Left")
        if quads:
            geo.mesh.setRecombine(2, surface)
    geo.synchronize()
    names = _physical(gmsh, {DISC_EDGE: arcs}, surfaces)
    gmsh.model.mesh.generate(2)
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
