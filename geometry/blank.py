"""gmsh builders of the flat blank: a rectangle, a disc or a polygon, meshed in the X-Y plane (mm).

Call :func:`build_blank` on one rank with gmsh initialised; it leaves the meshed model in
``gmsh.model`` with physical groups: the surface ``blank`` and the boundary curves (rectangle:
``left`` x = 0, ``right`` x = length, ``bottom`` y = 0, ``top`` y = width; disc and polygon:
``edge``; and ``blank_strip``, the cells of a clipped lattice between it and the outline).

Patterns (yarn angle theta, degrees, warp G1 = (cos theta, sin theta)):

* ``aligned`` rectangle, theta a multiple of 90: gmsh's transfinite grid, element edges along
  the yarns (triangles: each grid square cut by one diagonal, legs along the yarns).
* ``aligned`` rectangle, theta = +-45 (mod 90): the *diamond lattice* (``lattice.diamond_lattice``):
  squares along the yarns everywhere except one row of cells along the outline, where the
  lattice's half-squares are cut into three quadrilaterals each. The outline must fit the
  lattice: length/width a ratio of small integers.
* ``aligned`` disc or polygon, any theta: the *clipped lattice* (``clipped_lattice.py``):
  yarn-aligned squares wherever they lie half an element inside the outline, and one strip of
  quadrilaterals from their staircase to the outline (``docs/blanks.md``).
* ``free``: gmsh's unstructured mesh (Frontal-Delaunay; quadrilaterals by Blossom recombination),
  not aligned with the yarns: such triangles lock in tension (``docs/fe-solver.md``).

The lattices are built in numpy by ``drape.geometry.lattice`` and a polygon is checked by
``drape.geometry.outline``; this module chooses the pattern and hands the mesh to gmsh. Bad
requests raise :class:`~drape.errors.InputError` naming the config key.
"""

from __future__ import annotations

import math

import numpy as np

from drape.errors import InputError
from drape.geometry.clipped_lattice import clipped_lattice
from drape.geometry.lattice import diamond_lattice, split_quads
from drape.geometry.outline import polygon_area, polygon_outline

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
                cells = split_quads(nodes, cells)
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
            cells, strip = split_quads(nodes, cells), np.concatenate([strip, strip])
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


# --- disc and polygon, free ----------------------------------------------------------------------

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
