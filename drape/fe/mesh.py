"""The blank's mesh: built by gmsh on rank 0 (``geometry/blank.py``), distributed by DOLFINx.

:func:`create_blank_mesh` returns a :class:`BlankMesh`: the DOLFINx mesh (topological and
geometric dimension 2, the flat reference in mm), its facet tags and the map from boundary names
to tags. An error while meshing on rank 0 is broadcast so that every rank raises the same
:class:`~drape.errors.InputError`.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np


@dataclasses.dataclass
class BlankMesh:
    mesh: object                 # dolfinx.mesh.Mesh
    facet_tags: object           # dolfinx.mesh.MeshTags (dimension 1)
    boundaries: dict[str, int]   # name -> facet tag
    description: str
    #: local cells (owned and ghosts) between a clipped yarn lattice and the outline: not
    #: yarn-aligned
    strip_cells: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int32))

    def facets(self, name: str) -> np.ndarray:
        """Local facet indices of a named boundary ("boundary": the whole outline)."""
        from dolfinx import mesh as dmesh
        if name == "boundary":
            self.mesh.topology.create_connectivity(1, 2)
            return dmesh.exterior_facet_indices(self.mesh.topology)
        return self.facet_tags.find(self.boundaries[name])


def create_blank_mesh(comm, blank, mesh_config, centred: bool = False) -> BlankMesh:
    """Mesh the blank described by the job's ``[blank]`` and ``[mesh]`` tables; ``centred``
    moves a rectangle from [0, length] x [0, width] to be centred on the origin (forming)."""
    import gmsh
    from dolfinx.io import gmshio

    from drape.errors import InputError
    from drape.geometry.blank import BLANK, BLANK_STRIP, build_blank

    error, names = None, None
    if comm.rank == 0:
        gmsh.initialize(readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)
        try:
            names = build_blank(gmsh, blank.shape, length=blank.length, width=blank.width,
                                radius=blank.radius, points=blank.points,
                                yarn_angle=blank.yarn_angle,
                                cell=mesh_config.cell, pattern=mesh_config.pattern,
                                size=mesh_config.size)
        except InputError as failure:
            error = failure
        except Exception as failure:  # gmsh raises plain Exceptions with its log message
            error = InputError(f"gmsh could not mesh the blank ({failure})", key="mesh",
                               expected="a blank and mesh.size gmsh can mesh")
        if error is not None:
            gmsh.finalize()
    error = comm.bcast(error, root=0)
    if error is not None:
        raise error
    # PT-Scotch 7 (DOLFINx's partitioner here) runs one thread per core by default, and the
    # threads make the partition differ from run to run (2 ranks, the hemisphere's 2601 cells:
    # 4 different partitions in 5 runs; 5 identical ones with a single thread). A run and its
    # resume must get the same partition for the same numbers (drape.io.checkpoint).
    os.environ.setdefault("SCOTCH_PTHREAD_NUMBER", "1")
    try:
        msh, cell_tags, facet_tags = gmshio.model_to_mesh(gmsh.model, comm, 0, gdim=2)
    finally:
        if comm.rank == 0:
            gmsh.finalize()
    names = comm.bcast(names, root=0)
    if centred and blank.shape == "rectangle":
        msh.geometry.x[:, 0] -= blank.length / 2.0
        msh.geometry.x[:, 1] -= blank.width / 2.0
    boundaries = {name: tag for name, tag in names.items() if name not in (BLANK, BLANK_STRIP)}
    cells = msh.topology.index_map(2).size_global
    kind = msh.topology.cell_type.name
    strip = (cell_tags.find(names[BLANK_STRIP]) if BLANK_STRIP in names
             else np.zeros(0, dtype=np.int32))
    n_local = msh.topology.index_map(2).size_local
    n_strip = comm.allreduce(int(np.sum(strip < n_local)))
    description = (f"{cells} {kind} cells, {msh.geometry.index_map().size_global} nodes, "
                   f"{mesh_config.pattern} pattern"
                   + (f" ({n_strip} of them in the strip between the yarn lattice and the "
                      f"outline)" if n_strip else ""))
    return BlankMesh(msh, facet_tags, boundaries, description, strip)
