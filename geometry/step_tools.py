"""Tools read from STEP files (CAD import): their configuration, the file check and the import.

A tool is either closed solids (the tool is their material) or surfaces with a stated working
side (+z: a die, -z: a punch or holder). :func:`import_step` brings one into the current gmsh
model, scaled and moved to its working position, for ``drape.geometry.tools.build_tools``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from drape.config import positive, setting
from drape.errors import InputError


@dataclasses.dataclass(frozen=True)
class StepTool:
    """One tool read from a STEP file (solids, or surfaces with a stated working side); no file:
    no such tool."""

    file: str = setting("", "path of the STEP file (relative paths: from the working "
                        "directory); empty: no such tool")
    scale: float = setting(1.0, "factor applied to the file's coordinates (e.g. 1000 for a file "
                           "in metres)", positive)
    translate: tuple[float, ...] = setting((0.0, 0.0, 0.0), "translation applied after scaling, "
                                           "to put the tool in its working position", unit="mm")
    side: Literal["solid", "up", "down"] = setting(
        "solid", "'solid': the file holds closed solids, the tool is their material; 'up' / "
        "'down': the file holds surfaces whose working side faces +z (a die) / -z (a punch, a "
        "holder)")

    @property
    def given(self) -> bool:
        return bool(self.file)

    def validate(self):
        if len(self.translate) != 3:
            raise InputError("not a 3-vector", key="translate", value=list(self.translate),
                             expected="[dx, dy, dz]")
        if not self.file:
            if self != type(self)():
                raise InputError("settings given but no file", key="file",
                                 expected="the path of a STEP file")
            return
        check_step_file(self.file, self.side, key="file")


@dataclasses.dataclass(frozen=True)
class StepHolder(StepTool):
    """The blank holder from a STEP file, and how it is driven."""

    control: Literal["force", "position"] = setting(
        "force", "'force': the holder moves along the press axis (z) until its contact force is "
        "process.holder_force, as the built-in holders do; 'position': it stays where the file "
        "(scale, translate) puts it, and its force is whatever the blank answers (measured, "
        "reported in the log and summary.json)")


@dataclasses.dataclass(frozen=True)
class StepTools:
    """User tools from STEP files: any of punch, die, holder (at least one)."""

    punch: StepTool = setting(StepTool(), "the punch (moves down by the stroke)")
    die: StepTool = setting(StepTool(), "the die")
    holder: StepHolder = setting(StepHolder(), "the blank holder")

    def validate(self):
        if not (self.punch.given or self.die.given or self.holder.given):
            raise InputError("no tool given", expected="at least one of [step.punch], "
                             "[step.die], [step.holder] with a file")


def check_step_file(path: str, side: str = "solid", key: str = "file"):
    """Raise an InputError unless gmsh reads at least one surface (and, for side='solid', one
    solid) from the STEP file."""
    p = Path(path)
    if not p.is_file():
        raise InputError("file not found" if not p.exists() else "not a file", key=key,
                         value=path, expected="the path of an existing STEP file")
    from drape.geometry._gmsh import scratch_model
    with scratch_model("drape-step-check") as gmsh:
        try:
            entities = gmsh.model.occ.importShapes(str(p), highestDimOnly=False)
            gmsh.model.occ.synchronize()
        except Exception as error:  # gmsh raises a bare Exception with OCC's message
            raise InputError(f"gmsh cannot read it ({error})", key=key, value=path,
                             expected="a STEP file with at least one surface") from None
        n_volumes = sum(1 for d, _ in entities if d == 3)
        n_surfaces = sum(1 for d, _ in entities if d == 2)
    if n_surfaces == 0:
        raise InputError("gmsh reads no surface from it", key=key, value=path,
                         expected="a STEP file with at least one surface or solid")
    if side == "solid" and n_volumes == 0:
        raise InputError("the file holds surfaces but no closed solid", key=key, value=path,
                         expected="a STEP file with solids, or side = 'up' / 'down' to say "
                                  "which side of its surfaces the tool works with")


def import_step(gmsh, tool: StepTool, key: str):
    """Import one tool's file into the current OCC model: (volume tags, None) for a solid
    tool, (None, surface tags) for a surface tool."""
    occ = gmsh.model.occ
    try:
        entities = occ.importShapes(tool.file, highestDimOnly=True)
    except Exception as error:
        raise InputError(f"gmsh cannot read it ({error})", key=f"{key}.file", value=tool.file,
                         expected="a STEP file with at least one surface") from None
    if tool.scale != 1.0:
        occ.dilate(entities, 0, 0, 0, tool.scale, tool.scale, tool.scale)
    if any(tool.translate):
        occ.translate(entities, *tool.translate)
    occ.synchronize()
    volumes = [t for d, t in entities if d == 3]
    if tool.side == "solid":
        if not volumes:
            raise InputError("the file holds no closed solid", key=f"{key}.file",
                             value=tool.file, expected="solids, or side = 'up' / 'down'")
        return volumes, None
    surfaces = sorted({abs(t) for _, t in gmsh.model.getBoundary(
        [e for e in entities if e[0] == 3], combined=False, oriented=False)} |
        {t for d, t in entities if d == 2})
    return None, surfaces
