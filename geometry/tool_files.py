"""Tool surfaces written to a file a user can open beside the results (ParaView, gmsh).

:func:`write_tool_surfaces` writes :class:`~drape.forming.triangulated.TriangleSurface` s as a
VTK unstructured grid (``.vtu``, numpy only) or a gmsh mesh (``.msh``), one tool id per tool.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from drape.errors import InputError
from drape.forming.triangulated import TriangleSurface

#: the tools' names, in the order of their ids in the written files (others follow)
TOOL_NAMES = ("punch", "die", "holder")


def write_tool_surfaces(path: str | Path, surfaces: dict[str, TriangleSurface] | list,
                        offsets: dict[str, tuple[float, float, float]] | None = None) -> Path:
    """Write tool surfaces to one file a user can open beside the results (ParaView, gmsh):

    * ``.vtu`` -- VTK unstructured grid (triangles), point data ``normal``, cell data ``tool``
      (0 punch, 1 die, 2 holder, 3.. others in order); written with numpy only;
    * ``.msh`` -- gmsh mesh, one physical surface per tool, named after it.

    ``offsets`` moves tools (e.g. {'punch': (0, 0, -stroke)}) before writing."""
    path = Path(path)
    if isinstance(surfaces, dict):
        surfaces = list(surfaces.values())
    offsets = offsets or {}
    moved = [s.translated(offsets[s.name]) if s.name in offsets else s for s in surfaces]
    ids = [TOOL_NAMES.index(s.name) if s.name in TOOL_NAMES else len(TOOL_NAMES) + i
           for i, s in enumerate(moved)]
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".vtu":
        _write_vtu(path, moved, ids)
    elif path.suffix == ".msh":
        _write_msh(path, moved, ids)
    else:
        raise InputError("unknown tool file format", value=str(path),
                         expected="a path ending in .vtu or .msh")
    return path


def _write_vtu(path: Path, surfaces, ids):
    nodes = np.concatenate([s.nodes for s in surfaces])
    normals = np.concatenate([s.normals for s in surfaces])
    starts = np.cumsum([0] + [len(s.nodes) for s in surfaces[:-1]])
    tri = np.concatenate([s.triangles + k for s, k in zip(surfaces, starts)])
    tool = np.concatenate([np.full(len(s.triangles), i) for s, i in zip(surfaces, ids)])
    names = "; ".join(f"{i} = {s.name}" for s, i in zip(surfaces, ids))

    def array(values, name, kind, components=1, fmt="%.9g"):
        text = " ".join(fmt % v for v in np.asarray(values).ravel())
        return (f'<DataArray type="{kind}" Name="{name}" NumberOfComponents="{components}" '
                f'format="ascii">{text}</DataArray>')

    xml = [
        '<?xml version="1.0"?>',
        f"<!-- drape tool surfaces; cell data 'tool': {escape(names)} -->",
        '<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">',
        "<UnstructuredGrid>",
        f'<Piece NumberOfPoints="{len(nodes)}" NumberOfCells="{len(tri)}">',
        "<Points>", array(nodes, "Points", "Float64", 3), "</Points>",
        "<Cells>", array(tri, "connectivity", "Int64", fmt="%d"),
        array(3 * np.arange(1, len(tri) + 1), "offsets", "Int64", fmt="%d"),
        array(np.full(len(tri), 5), "types", "UInt8", fmt="%d"), "</Cells>",
        '<PointData Normals="normal">', array(normals, "normal", "Float64", 3), "</PointData>",
        '<CellData Scalars="tool">', array(tool, "tool", "Int32", fmt="%d"), "</CellData>",
        "</Piece>", "</UnstructuredGrid>", "</VTKFile>",
    ]
    path.write_text("\n".join(xml) + "\n")


def _write_msh(path: Path, surfaces, ids):
    from drape.geometry._gmsh import scratch_model
    with scratch_model("drape-tools-out") as gmsh:
        next_node = 1
        next_element = 1
        for surface, i in zip(surfaces, ids):
            entity = gmsh.model.addDiscreteEntity(2)
            tags = np.arange(next_node, next_node + len(surface.nodes))
            gmsh.model.mesh.addNodes(2, entity, tags.tolist(), surface.nodes.ravel().tolist())
            elements = np.arange(next_element, next_element + len(surface.triangles))
            gmsh.model.mesh.addElementsByType(entity, 2, elements.tolist(),
                                              (tags[surface.triangles]).ravel().tolist())
            group = gmsh.model.addPhysicalGroup(2, [entity], i + 1)
            gmsh.model.setPhysicalName(2, group, surface.name)
            next_node += len(surface.nodes)
            next_element += len(surface.triangles)
        gmsh.write(str(path))
