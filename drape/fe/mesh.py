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

    from drape.geometry.blank import BLANK, BLANK_STRIP, build_blank

    def build(gmsh):
        return build_blank(gmsh, blank.shape, length=blank.length, width=blank.width,
                           radius=blank.radius, points=blank.points,
                           yarn_angle=blank.yarn_angle, cell=mesh_config.cell,
                           pattern=mesh_config.pattern, size=mesh_config.size)

    names = built_on_root(comm, build, "the blank", "a blank and mesh.size gmsh can mesh",
                          keep_open=True)
    single_thread_partitioner()
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
    strip = (cell_tags.find(names[BLANK_STRIP]) if BLANK_STRIP in names
             else np.zeros(0, dtype=np.int32))
    description = describe_mesh(comm, msh, strip, mesh_config.pattern)
    return BlankMesh(msh, facet_tags, boundaries, description, strip)


def built_on_root(comm, build, what: str, expected: str, keep_open: bool = False):
    """``build(gmsh)`` on rank 0 in a fresh gmsh session; its result there, None on the other
    ranks. An error there (gmsh raises plain Exceptions with its log message: made an
    InputError naming ``mesh``, "gmsh could not mesh {what}") is raised on every rank. With
    ``keep_open`` the session stays open on rank 0 after a success (the caller reads the model
    and finalizes it); otherwise it is closed."""
    import gmsh

    from drape.errors import InputError
    error, result = None, None
    if comm.rank == 0:
        gmsh.initialize(readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)
        try:
            result = build(gmsh)
        except InputError as failure:
            error = failure
        except Exception as failure:  # gmsh raises plain Exceptions with its log message
            error = InputError(f"gmsh could not mesh {what} ({failure})", key="mesh",
                               expected=expected)
        if error is not None or not keep_open:
            gmsh.finalize()
    error = comm.bcast(error, root=0)
    if error is not None:
        raise error
    return result


def single_thread_partitioner() -> None:
    """PT-Scotch 7 (DOLFINx's partitioner here) runs one thread per core by default, and the
    threads make the partition differ from run to run (2 ranks, the hemisphere's 2601 cells: 4
    different partitions in 5 runs; 5 identical ones with a single thread). A run and its
    resume must get the same partition for the same numbers (drape.io.checkpoint)."""
    os.environ.setdefault("SCOTCH_PTHREAD_NUMBER", "1")


def describe_mesh(comm, msh, strip: np.ndarray, pattern: str) -> str:
    """The mesh in a few words, for the log: cells, nodes, pattern, and how many cells lie in
    the strip between a clipped yarn lattice and the outline (``strip``: local cells)."""
    n_local = msh.topology.index_map(2).size_local
    n_strip = comm.allreduce(int(np.sum(strip < n_local)))
    return (f"{msh.topology.index_map(2).size_global} {msh.topology.cell_type.name} cells, "
            f"{msh.geometry.index_map().size_global} nodes, {pattern} pattern"
            + (f" ({n_strip} of them in the strip between the yarn lattice and the outline)"
               if n_strip else ""))
