"""The plies of a stack as disconnected pieces of one DOLFINx mesh, tagged by ply.

A UFL form lives on one mesh, so the plies that the ply-ply contact couples must be pieces of
the same mesh. Each ply is meshed on rank 0 exactly as today's blank (``geometry/blank.py``'s
:func:`build_blank`, with the ply's outline, orientation and the job's ``[mesh]``), the pieces
are put side by side in one cell array (node numbers offset, nothing shared) and DOLFINx
distributes the whole. Every piece lies in the flat reference X-Y plane, where the membrane is
written; ply k's mid-surface is at the height ``heights[k]`` (mm) above it, which the ply
contact adds to the reference positions (:attr:`StackMesh.node_heights`).

:class:`StackMesh` is a :class:`~drape.fe.mesh.BlankMesh` (a MembraneProblem takes it as is)
with the cell tags by ply (value k on ply k's cells), the plies' heights and thicknesses.
Facet tags: ply k's boundary ``name`` (``left``, ``edge``, ...) is ``ply{k}.{name}`` in
:attr:`boundaries`; a one-ply stack also has the plain names, with today's tags: its mesh is
today's blank's, node for node (tests/test_ply_contact.py).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drape.fe.mesh import BlankMesh, built_on_root, describe_mesh, single_thread_partitioner

#: facet tags of ply k are the gmsh tags of its boundaries plus k times this
PLY_TAG_STRIDE = 1000


@dataclasses.dataclass
class StackMesh(BlankMesh):
    #: MeshTags of dimension 2: the ply index of every local cell (owned and ghosts)
    ply_tags: object = None
    heights: tuple = ()          # height of each ply's mid-surface (mm)
    thicknesses: tuple = ()      # each ply's thickness (mm)

    @property
    def n_plies(self) -> int:
        return len(self.heights)

    def cell_plies(self) -> np.ndarray:
        """The ply of every local cell (owned and ghosts), (n_cells,) int32."""
        index_map = self.mesh.topology.index_map(2)
        plies = np.full(index_map.size_local + index_map.num_ghosts, -1, dtype=np.int32)
        plies[self.ply_tags.indices] = self.ply_tags.values
        return plies


def _mesh_ply(gmsh, ply_blank, mesh_config):
    """Mesh one ply with today's blank builder; returns its nodes (N, 3), cells (M, n) and
    their gmsh physical tags, boundary segments (K, 2) and their tags, and the names."""
    from dolfinx.io.gmshio import extract_geometry, extract_topology_and_markers

    from drape.geometry.blank import build_blank
    names = build_blank(gmsh, ply_blank.shape, length=ply_blank.length, width=ply_blank.width,
                        radius=ply_blank.radius, points=ply_blank.points,
                        yarn_angle=ply_blank.yarn_angle, cell=mesh_config.cell,
                        pattern=mesh_config.pattern, size=mesh_config.size)
    x = extract_geometry(gmsh.model)
    topologies = extract_topology_and_markers(gmsh.model)
    by_dimension = {}
    for element, data in topologies.items():
        _, dim, _, _, _, _ = gmsh.model.mesh.getElementProperties(element)
        by_dimension[dim] = (element, np.asarray(data["topology"], dtype=np.int64),
                             np.asarray(data["cell_data"], dtype=np.int32))
    gmsh.model.remove()
    return x, by_dimension[2], by_dimension.get(1), names


def create_stack_mesh(comm, ply_blanks, heights, thicknesses, mesh_config,
                      centred: bool = False) -> StackMesh:
    """Mesh the plies (BlankConfig each: :meth:`drape.forming.plies.PlyConfig.blank`) into one
    distributed mesh; ``centred`` moves each rectangle to be centred on the origin (forming).
    An error while meshing on rank 0 is raised on every rank (as create_blank_mesh does)."""
    # DOLFINx imported on every rank before rank 0 meshes alone: its first import initialises
    # PETSc, a collective that would otherwise meet the other ranks' broadcast (a crash)
    import dolfinx.io.gmshio  # noqa: F401
    payload = built_on_root(
        comm, lambda gmsh: _stack_arrays(gmsh, ply_blanks, mesh_config, centred), "a ply",
        "plies and a mesh.size gmsh can mesh")
    msh, cell_tags, facet_tags, names = _distributed(comm, payload)
    tdim = 2
    # cell values: PLY_TAG_STRIDE * ply + the blank's own tag (blank or blank_strip)
    from dolfinx import cpp as _cpp

    from drape.geometry.blank import BLANK, BLANK_STRIP
    ply_of_cell = (cell_tags.values // PLY_TAG_STRIDE).astype(np.int32)
    ply_tags = _cpp.mesh.MeshTags_int32(msh._mesh, tdim, cell_tags.indices, ply_of_cell)
    ply_tags.name = "ply"
    strip_values = [k * PLY_TAG_STRIDE + ply_names[BLANK_STRIP]
                    for k, ply_names in enumerate(names) if BLANK_STRIP in ply_names]
    strip = np.sort(cell_tags.indices[np.isin(cell_tags.values, strip_values)]).astype(np.int32)
    boundaries = {f"ply{k}.{name}": tag + k * PLY_TAG_STRIDE
                  for k, ply_names in enumerate(names)
                  for name, tag in ply_names.items() if name not in (BLANK, BLANK_STRIP)}
    if len(ply_blanks) == 1:
        boundaries.update({name: tag for name, tag in names[0].items()
                           if name not in (BLANK, BLANK_STRIP)})
    description = describe_mesh(comm, msh, strip, mesh_config.pattern)
    if len(ply_blanks) > 1:
        description = f"{len(ply_blanks)} plies, {description}"
    return StackMesh(msh, facet_tags, boundaries, description, strip, ply_tags=ply_tags,
                     heights=tuple(float(h) for h in heights),
                     thicknesses=tuple(float(t) for t in thicknesses))


def _distributed(comm, payload):
    """The DOLFINx mesh of rank 0's arrays, distributed, with its cell and facet tags; returns
    (mesh, cell tags, facet tags, each ply's physical names)."""
    from dolfinx import cpp as _cpp
    from dolfinx.io.gmshio import cell_perm_array, ufl_mesh
    from dolfinx.mesh import create_mesh, meshtags_from_entities
    header = comm.bcast(None if payload is None else payload["header"], root=0)
    cell_id, num_nodes, facet_nodes, facet_id, names = header
    if comm.rank == 0:
        x, cells, cell_values = payload["x"], payload["cells"], payload["cell_values"]
        facets, facet_values = payload["facets"], payload["facet_values"]
    else:
        x, cells = np.empty((0, 3)), np.empty((0, num_nodes), dtype=np.int64)
        cell_values = np.empty(0, dtype=np.int32)
        facets = np.empty((0, facet_nodes), dtype=np.int64)
        facet_values = np.empty(0, dtype=np.int32)
    single_thread_partitioner()
    domain = ufl_mesh(cell_id, 2)
    cell_type = _cpp.mesh.to_type(str(domain.ufl_cell()))
    cells = cells[:, cell_perm_array(cell_type, num_nodes)]
    msh = create_mesh(comm, cells, x[:, :2], domain)
    tdim = 2

    def tags(dim, entities, values):
        local, local_values = _cpp.io.distribute_entity_data(msh._mesh, dim, entities, values)
        msh.topology.create_connectivity(dim, 0)
        adjacency = _cpp.graph.AdjacencyList_int32(local)
        return meshtags_from_entities(msh, dim, adjacency, local_values.astype(np.int32))

    cell_tags = tags(tdim, cells, cell_values)
    facet_type = _cpp.mesh.cell_entity_type(cell_type, tdim - 1, 0)
    facets = facets[:, cell_perm_array(facet_type, facet_nodes)]
    msh.topology.create_connectivity(tdim - 1, tdim)
    facet_tags = tags(tdim - 1, facets, facet_values)
    facet_tags.name = "Facet tags"
    return msh, cell_tags, facet_tags, names


def _stack_arrays(gmsh, ply_blanks, mesh_config, centred):
    """Rank 0: every ply meshed by build_blank, its arrays offset and concatenated; the tags
    of ply k are its own plus k * PLY_TAG_STRIDE, its names in ``header[4][k]``."""
    xs, cells, cell_values, facets, facet_values, names = [], [], [], [], [], []
    offset, cell_id, facet_id = 0, None, None
    for k, blank in enumerate(ply_blanks):
        x, (cell_id, ply_cells, ply_values), boundary, ply_names = _mesh_ply(gmsh, blank,
                                                                             mesh_config)
        if max(ply_names.values()) >= PLY_TAG_STRIDE:
            raise ValueError("gmsh tags beyond the ply stride")  # pragma: no cover
        if centred and blank.shape == "rectangle":
            x = x - np.array([blank.length / 2.0, blank.width / 2.0, 0.0])
        xs.append(x)
        cells.append(ply_cells + offset)
        cell_values.append(ply_values + k * PLY_TAG_STRIDE)
        facet_id, segments, segment_values = boundary
        facets.append(segments + offset)
        facet_values.append(segment_values + k * PLY_TAG_STRIDE)
        names.append(ply_names)
        offset += len(x)
    return {"x": np.vstack(xs), "cells": np.vstack(cells),
            "cell_values": np.concatenate(cell_values), "facets": np.vstack(facets),
            "facet_values": np.concatenate(facet_values),
            "header": (cell_id, cells[0].shape[1], 2, facet_id, names)}
