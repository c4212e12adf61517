"""The rigid forming tools: the ``[tools]`` table and :func:`build_tools`, which meshes any tool
set with gmsh.

Three tool sets, each a punch, a die and a blank holder in their working positions (mm):

* ``hemisphere`` -- a hemispherical punch on a cylindrical shank, a die plate with a circular
  opening and an entry fillet, a blank-holder ring;
* ``double_dome`` -- the woven-composites double-dome benchmark shape: two spherical domes
  joined by a saddle (a concave rolling-ball blend between them) on a stadium footprint, the die
  cavity its offset by the clearance, the holder a plate around the cavity;
* ``step`` -- user tools read from STEP files.

Working positions: the blank lies in the plane z = 0; the die is below it (top face at
z = -gap), the holder on top of the blank outside the die opening (bottom face at z = +gap),
the punch above (lowest point at z = +gap) and moves down (-z) by the stroke. Every dimension,
its default and where it comes from are in ``docs/tools.md``.

:func:`build_tools` meshes the tools with gmsh and returns one
:class:`~drape.forming.triangulated.TriangleSurface` per tool (closed surface of the tool's
solid, vertex normals pointing out of it). Each tool set has its own module (dimensions,
solids, exact twin): ``drape.geometry.hemisphere_tools`` (:func:`analytic_tools`, exact
surfaces of revolution), ``drape.geometry.double_dome_tools``
(:func:`analytic_double_dome_tools`, exact signed distances), ``drape.geometry.step_tools``
(CAD import); ``drape.geometry.tool_files`` writes tool surfaces to a file a user can open (VTK
.vtu or gmsh .msh). Their public names are importable from here too (``__all__``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from drape.config import from_mapping, positive, read_toml, setting
from drape.errors import InputError
from drape.forming.triangulated import TriangleSurface
from drape.geometry._gmsh import boundary_surfaces, extract_surface, mesh_surfaces, scratch_model
from drape.geometry.double_dome_tools import (DoubleDomeTools, analytic_double_dome_tools,
                                              build_double_dome_solids, double_dome_height)
from drape.geometry.hemisphere_tools import (HemisphereTools, analytic_tools,
                                             build_hemisphere_solids, hemisphere_profiles)
from drape.geometry.step_tools import StepHolder, StepTool, StepTools, check_step_file, import_step
from drape.geometry.tool_files import TOOL_NAMES, write_tool_surfaces

__all__ = ["TOOL_NAMES", "DoubleDomeTools", "HemisphereTools", "StepHolder", "StepTool",
           "StepTools", "ToolMeshing", "ToolsConfig", "analytic_double_dome_tools",
           "analytic_tools", "build_tools", "check_step_file", "double_dome_height",
           "hemisphere_profiles", "load_tools_config", "write_tool_surfaces"]


# --- configuration ----------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class ToolMeshing:
    """Element size of the tool surfaces: on each face h = min(sqrt(3 R s), R / n) for its
    smallest curvature radius R (s the chord tolerance, n the elements per radius), clamped to
    [min_size, max_size]; planes get max_size. ``size`` replaces the rule by one size."""

    chord_tolerance: float = setting(0.05, "largest distance allowed between a triangle and the "
                                     "curved surface it stands for (sets h on curved faces)",
                                     positive, "mm")
    elements_per_radius: float = setting(4.0, "at least this many elements per radius of "
                                         "curvature (keeps normals smooth on small fillets)",
                                         positive)
    min_size: float = setting(0.2, "smallest element size", positive, "mm")
    max_size: float = setting(10.0, "largest element size (flat faces)", positive, "mm")
    size: float | None = setting(None, "one element size for every face, replacing the rule",
                                 positive, "mm")

    def validate(self):
        if self.min_size > self.max_size:
            raise InputError("min_size is larger than max_size", key="min_size",
                             value=self.min_size, expected=f"a size <= max_size = {self.max_size}")


@dataclasses.dataclass(frozen=True)
class ToolsConfig:
    """The ``[tools]`` table: which tool set, its dimensions, and the surface meshing."""

    kind: Literal["hemisphere", "double_dome", "step"] = setting("hemisphere", "which tool set")
    hemisphere: HemisphereTools = setting(HemisphereTools(), "hemisphere tool dimensions")
    double_dome: DoubleDomeTools = setting(DoubleDomeTools(), "double-dome tool dimensions")
    step: StepTools = setting(StepTools(), "STEP files per tool")
    mesh: ToolMeshing = setting(ToolMeshing(), "element size of the tool surfaces")

    def validate(self):
        if self.kind == "step" and not (self.step.punch.given or self.step.die.given
                                        or self.step.holder.given):
            raise InputError("kind = 'step' but no STEP file is given", key="step",
                             expected="a [tools.step.punch] (or .die, .holder) table with file")


def load_tools_config(path: str | Path, table: str | None = None) -> ToolsConfig:
    """Read a ToolsConfig from a TOML file (the whole file, or one table of it, e.g. "tools")."""
    data = read_toml(path)
    if table is not None:
        data = data.get(table, {})
    return from_mapping(ToolsConfig, data, source=str(path), prefix=table or "")


# --- building -------------------------------------------------------------------------------------

_MESH_OPTIONS = {"Mesh.MeshSizeFromPoints": 0, "Mesh.MeshSizeFromCurvature": 0,
                 "Mesh.MeshSizeExtendFromBoundary": 0, "Mesh.MeshSizeMin": 0.0,
                 "Mesh.MeshSizeMax": 1e22, "Mesh.Algorithm": 6}


def build_tools(config: ToolsConfig | HemisphereTools | DoubleDomeTools | StepTools,
                mesh: ToolMeshing | None = None, comm=None) -> dict[str, TriangleSurface]:
    """Build the tools with gmsh (OpenCASCADE), mesh their surfaces and return one
    :class:`TriangleSurface` per tool, in working position, keyed 'punch', 'die', 'holder'.

    With an MPI communicator of more than one rank, rank 0 builds and the others receive the
    arrays (the tools are identical on every rank)."""
    if comm is not None and comm.size > 1:
        return _built_on_rank_0(config, mesh, comm)
    if isinstance(config, ToolsConfig):
        mesh = mesh or config.mesh
        config = {"hemisphere": config.hemisphere, "double_dome": config.double_dome,
                  "step": config.step}[config.kind]
    mesh = mesh or ToolMeshing()
    with scratch_model(options=_MESH_OPTIONS) as gmsh:
        faces, sides = _tool_faces(gmsh, config)
        try:
            mesh_surfaces(mesh, sorted({f for fs in faces.values() for f in fs}))
        except Exception as error:
            raise InputError(f"gmsh could not mesh the tool surfaces ({error})",
                             expected="tools gmsh can mesh; try other [tools.mesh] sizes"
                             ) from None
        return {name: extract_surface(name, faces[name], sides.get(name, "solid"))
                for name in faces}


def _built_on_rank_0(config, mesh, comm) -> dict[str, TriangleSurface]:
    """build_tools on rank 0, its result (or its error) broadcast: every rank returns the same
    tools or raises the same error, none waits for rank 0."""
    result = None
    if comm.rank == 0:
        try:
            result = build_tools(config, mesh)
        except InputError as error:
            result = ("InputError", error.problem, error.source, error.key,
                      error.value, error.expected)
        except Exception as error:
            result = ("Exception", f"{type(error).__name__}: {error}")
    result = comm.bcast(result, root=0)
    if isinstance(result, tuple) and result[0] == "InputError":
        problem, source, key, value, expected = result[1:]
        raise InputError(problem, source=source, key=key, value=value, expected=expected)
    if isinstance(result, tuple):
        raise RuntimeError(f"building the tools failed on rank 0: {result[1]}")
    return result


def _tool_faces(gmsh, config) -> tuple[dict[str, list[int]], dict]:
    """Add the tool set's solids (or STEP surfaces) to the gmsh model: per tool, the surface
    tags to mesh, and its side ('solid', or the working direction of an open surface; only
    tools that are not solids are in this dict)."""
    sides = {}
    if isinstance(config, (HemisphereTools, DoubleDomeTools)):
        builder = build_hemisphere_solids if isinstance(config, HemisphereTools) else \
            build_double_dome_solids
        try:
            volumes = {name: [tag] for name, tag in builder(gmsh, config).items()}
        except Exception as error:   # OpenCASCADE refused a boolean or a fillet
            raise InputError(f"gmsh/OpenCASCADE could not build the tools ({error})",
                             expected="dimensions that give valid solids (docs/tools.md)"
                             ) from None
    elif isinstance(config, StepTools):
        volumes = {}
        for name in TOOL_NAMES:
            tool = getattr(config, name)
            if not tool.given:
                continue
            vols, surfs = import_step(gmsh, tool, f"step.{name}")
            volumes[name] = vols if vols is not None else surfs
            sides[name] = "solid" if vols is not None else \
                ((0.0, 0.0, 1.0) if tool.side == "up" else (0.0, 0.0, -1.0))
    else:
        raise TypeError(f"not a tool configuration: {type(config).__name__}")
    faces = {}
    for name, tags in volumes.items():
        if sides.get(name, "solid") == "solid":
            faces[name] = boundary_surfaces(tags)
        else:
            faces[name] = tags
    return faces, sides
