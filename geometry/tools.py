"""The rigid forming tools: configuration, gmsh/OpenCASCADE builders, analytic twins, output.

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
:class:`drape.forming.surfaces.TriangleSurface` per tool (closed surface of the tool's solid, vertex
normals pointing out of it); :func:`analytic_tools` gives the exact
:class:`drape.forming.surfaces.AxisymmetricSurface` of each hemisphere tool;
:func:`write_tool_surfaces`
writes tool surfaces to a file a user can open (VTK .vtu or gmsh .msh).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal
from xml.sax.saxutils import escape

import numpy as np

from drape.config import from_mapping, non_negative, positive, read_toml, setting
from drape.errors import InputError
from drape.forming.double_dome import SignedDistanceSurface, double_dome_surfaces
from drape.forming.surfaces import Arc, AxisymmetricSurface, Profile, Segment, TriangleSurface

TOOL_NAMES = ("punch", "die", "holder")


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
class HemisphereTools:
    """Hemisphere forming: dimensions of the scale of published hemisphere forming tests of
    woven fabrics (punch diameters of the order of 100 mm); the values are drape's choice."""

    punch_radius: float = setting(50.0, "radius of the hemispherical punch", positive, "mm")
    shank_height: float = setting(60.0, "height of the punch's cylindrical shank above the "
                                  "hemisphere's equator", positive, "mm")
    die_opening_radius: float = setting(55.0, "radius of the die's circular opening (its "
                                        "cylindrical wall, below the entry fillet)", positive, "mm")
    die_fillet_radius: float = setting(5.0, "radius of the die's entry fillet", positive, "mm")
    die_outer_radius: float = setting(150.0, "outer radius of the die plate", positive, "mm")
    die_thickness: float = setting(50.0, "thickness of the die plate", positive, "mm")
    holder_inner_radius: float = setting(65.0, "inner radius of the blank-holder ring", positive,
                                         "mm")
    holder_outer_radius: float = setting(150.0, "outer radius of the blank-holder ring",
                                         positive, "mm")
    holder_thickness: float = setting(20.0, "thickness of the blank-holder ring", positive, "mm")
    holder_fillet_radius: float = setting(5.0, "rounding of the holder's inner lower edge "
                                          "(0: sharp)", non_negative, "mm")
    clearance: float = setting(1.0, "smallest radial gap required between punch and die "
                               "opening (room for the fabric)", non_negative, "mm")
    gap: float = setting(0.0, "initial distance of the tools from the blank plane z = 0 (die "
                         "top at -gap, holder bottom and punch tip at +gap)", non_negative, "mm")

    def validate(self):
        need = self.punch_radius + self.clearance
        if self.die_opening_radius < need:
            raise InputError("the die opening leaves no clearance around the punch",
                             key="die_opening_radius", value=self.die_opening_radius,
                             expected=f">= punch_radius + clearance = {need:g} mm")
        room = self.die_outer_radius - self.die_opening_radius
        if self.die_fillet_radius >= min(room, self.die_thickness):
            raise InputError("the entry fillet does not fit on the die", key="die_fillet_radius",
                             value=self.die_fillet_radius,
                             expected=f"< die_outer_radius - die_opening_radius = {room:g} mm "
                                      f"and < die_thickness = {self.die_thickness:g} mm")
        edge = self.die_opening_radius + self.die_fillet_radius
        if self.holder_inner_radius < edge:
            raise InputError("the holder would press on the die's entry fillet",
                             key="holder_inner_radius", value=self.holder_inner_radius,
                             expected=f">= die_opening_radius + die_fillet_radius = {edge:g} mm")
        if self.holder_outer_radius > self.die_outer_radius:
            raise InputError("the holder reaches beyond the die", key="holder_outer_radius",
                             value=self.holder_outer_radius,
                             expected=f"<= die_outer_radius = {self.die_outer_radius:g} mm")
        if self.holder_outer_radius <= self.holder_inner_radius + self.holder_fillet_radius:
            edge = self.holder_inner_radius + self.holder_fillet_radius
            raise InputError("the holder ring has no flat face", key="holder_outer_radius",
                             value=self.holder_outer_radius,
                             expected=f"> holder_inner_radius + holder_fillet_radius = {edge:g} mm")
        if self.holder_fillet_radius >= self.holder_thickness:
            raise InputError("the holder's fillet does not fit its thickness",
                             key="holder_fillet_radius", value=self.holder_fillet_radius,
                             expected=f"< holder_thickness = {self.holder_thickness:g} mm")

    @property
    def full_stroke(self) -> float:
        """Punch travel from its working position to the die plate's lower face."""
        return 2 * self.gap + self.die_thickness


@dataclasses.dataclass(frozen=True)
class DoubleDomeTools:
    """Double-dome benchmark (Khan et al. 2010): die footprint about 470 x 270 mm, 60 mm deep,
    two domes joined by a saddle. The shape's construction and every other value are drape's."""

    die_length: float = setting(470.0, "die block length along x (benchmark: about 470)",
                                positive, "mm")
    die_width: float = setting(270.0, "die block width along y (benchmark: about 270)",
                               positive, "mm")
    depth: float = setting(60.0, "cavity depth, die top face to the domes' bottom (benchmark: "
                           "60)", positive, "mm")
    die_thickness: float = setting(80.0, "die block height", positive, "mm")
    punch_length: float = setting(380.0, "punch footprint length along x (a stadium: two "
                                  "half-discs joined by straight sides)", positive, "mm")
    punch_width: float = setting(180.0, "punch footprint width along y", positive, "mm")
    dome_radius: float = setting(250.0, "radius of the two spherical domes (centred above the "
                                 "centres of the footprint's half-discs)", positive, "mm")
    saddle_radius: float = setting(100.0, "radius of the concave blend joining the domes (the "
                                   "saddle)", positive, "mm")
    punch_edge_radius: float = setting(10.0, "rounding of the punch edge where domes and saddle "
                                       "meet the side walls", positive, "mm")
    die_entry_radius: float = setting(10.0, "fillet of the cavity's rim at the die top face",
                                      positive, "mm")
    clearance: float = setting(2.0, "normal gap between punch and cavity at full stroke (the "
                               "cavity is the punch offset by it)", positive, "mm")
    punch_height: float = setting(100.0, "punch height from the dome tips to its top face",
                                  positive, "mm")
    holder_margin: float = setting(5.0, "gap between the holder's opening and the cavity's "
                                   "entry fillet", non_negative, "mm")
    holder_thickness: float = setting(20.0, "blank-holder plate thickness", positive, "mm")
    holder_edge_radius: float = setting(5.0, "rounding of the holder opening's lower edge",
                                        positive, "mm")
    gap: float = setting(0.0, "initial distance of the tools from the blank plane z = 0",
                         non_negative, "mm")

    # derived dimensions
    @property
    def dome_offset(self) -> float:
        """x of the domes' centres (and of the footprint's half-disc centres)."""
        return 0.5 * (self.punch_length - self.punch_width)

    @property
    def full_stroke(self) -> float:
        """Punch travel until its tips are ``clearance`` above the cavity bottom."""
        return 2 * self.gap + self.depth - self.clearance

    @property
    def holder_opening_radius(self) -> float:
        return 0.5 * self.punch_width + self.clearance + self.die_entry_radius + self.holder_margin

    def rim_depths(self, samples: int = 400) -> np.ndarray:
        """Depth below the die top of the cavity's shaped surface along the rim of its
        footprint (where the vertical wall ends), from the analytic shape."""
        a, rf = self.dome_offset, 0.5 * self.punch_width + self.clearance
        s = np.linspace(0.0, 1.0, samples)
        straight = np.stack([a * (2 * s - 1), np.full_like(s, rf)], axis=1)
        angle = np.pi * (s - 0.5)
        end = np.stack([a + rf * np.cos(angle), rf * np.sin(angle)], axis=1)
        rim = np.concatenate([straight, end])
        return -self.gap - double_dome_height(self, rim[:, 0], rim[:, 1], "cavity")

    def validate(self):
        a = self.dome_offset
        if a <= 0:
            raise InputError("the punch footprint is not longer than wide", key="punch_length",
                             value=self.punch_length,
                             expected=f"> punch_width = {self.punch_width:g} mm")
        if self.saddle_radius <= self.clearance:
            raise InputError("the saddle blend is too tight for the clearance",
                             key="saddle_radius", value=self.saddle_radius,
                             expected=f"> clearance = {self.clearance:g} mm")
        rf = 0.5 * self.punch_width + self.clearance
        inner = math.sqrt((self.dome_radius + self.saddle_radius) ** 2 - a ** 2) \
            if self.dome_radius + self.saddle_radius > a else 0.0
        saddle_too_narrow = inner - self.saddle_radius + self.clearance <= rf
        if self.dome_radius <= math.hypot(a, rf) or saddle_too_narrow:
            raise InputError("the domes do not cover the punch footprint", key="dome_radius",
                             value=self.dome_radius,
                             expected=f"> {math.hypot(a, rf):g} mm (and a saddle wider than the "
                                      "footprint) for this footprint")
        need = self.die_entry_radius + self.punch_edge_radius + self.clearance + 1.0
        shallowest = float(self.rim_depths().min())
        if shallowest < need:
            raise InputError(f"the cavity's side wall vanishes (its shallowest rim is "
                             f"{shallowest:.1f} mm deep)", key="depth", value=self.depth,
                             expected=f"a rim at least die_entry_radius + punch_edge_radius + "
                                      f"clearance + 1 = {need:g} mm deep everywhere: a deeper "
                                      "cavity, flatter domes or a larger saddle radius")
        hole = self.holder_opening_radius
        if 2 * hole >= self.die_width - 2.0 or 2 * (hole + a) >= self.die_length - 2.0:
            raise InputError("the die leaves no flange for the holder outside the cavity",
                             key="die_width", value=self.die_width,
                             expected=f"die_width > {2 * hole + 2:g} and die_length > "
                                      f"{2 * (hole + a) + 2:g} mm")
        if self.die_thickness <= self.depth + 1.0:
            raise InputError("the die block is not deeper than its cavity", key="die_thickness",
                             value=self.die_thickness,
                             expected=f"> depth + 1 = {self.depth + 1:g} mm")
        if self.punch_height <= self.depth:
            raise InputError("the punch is shorter than the cavity is deep", key="punch_height",
                             value=self.punch_height, expected=f"> depth = {self.depth:g} mm")
        if self.holder_edge_radius >= self.holder_thickness:
            raise InputError("the holder's edge rounding does not fit its thickness",
                             key="holder_edge_radius", value=self.holder_edge_radius,
                             expected=f"< holder_thickness = {self.holder_thickness:g} mm")


def double_dome_height(cfg: DoubleDomeTools, x, y, which: Literal["punch", "cavity"] = "punch"):
    """z of the shaped surface (domes and saddle, before the edge roundings) above the point
    (x, y): the punch's lower surface in its working position, or the cavity's bottom. NaN
    outside the domes' reach. Exact for the construction used by the builder: two spheres of
    radius R (R + c for the cavity) centred at (+-a, 0, zc), blended by a rolling ball of radius
    Rs (Rs - c), which sweeps a torus about the x axis for |x| <= a Rs / (R + Rs)."""
    x = np.abs(np.asarray(x, dtype=float))
    y = np.asarray(y, dtype=float)
    a = cfg.dome_offset
    c = 0.0 if which == "punch" else cfg.clearance
    R, Rs = cfg.dome_radius + c, cfg.saddle_radius - c
    zc = cfg.gap + cfg.dome_radius if which == "punch" else \
        -cfg.gap - cfg.depth + cfg.dome_radius + cfg.clearance
    major = math.sqrt((R + Rs) ** 2 - a ** 2)
    x_blend = a * Rs / (R + Rs)
    with np.errstate(invalid="ignore"):
        sphere = zc - np.sqrt(R ** 2 - (x - a) ** 2 - y ** 2)
        rho = major - np.sqrt(np.maximum(Rs ** 2 - x ** 2, 0.0))
        saddle = zc - np.sqrt(rho ** 2 - y ** 2)
    return np.where(x <= x_blend, saddle, sphere)


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


# --- analytic twins of the hemisphere tools ----------------------------------------------------

def hemisphere_profiles(cfg: HemisphereTools) -> dict[str, Profile]:
    """The (r, z) profiles of the hemisphere tools' solids, as built by :func:`build_tools`."""
    g, R, S = cfg.gap, cfg.punch_radius, cfg.shank_height
    punch = Profile([
        Arc((0.0, g + R), R, -0.5 * math.pi, 0.0),
        Segment((R, g + R), (R, g + R + S)),
        Segment((R, g + R + S), (0.0, g + R + S)),
    ])
    top, Ro, rf = -g, cfg.die_opening_radius, cfg.die_fillet_radius
    Rout, T = cfg.die_outer_radius, cfg.die_thickness
    die = Profile([
        Segment((Ro, top - T), (Rout, top - T)),
        Segment((Rout, top - T), (Rout, top)),
        Segment((Rout, top), (Ro + rf, top)),
        Arc((Ro + rf, top - rf), rf, 0.5 * math.pi, math.pi),
        Segment((Ro, top - rf), (Ro, top - T)),
    ])
    zb, Ri, Rh = g, cfg.holder_inner_radius, cfg.holder_outer_radius
    Th, rh = cfg.holder_thickness, cfg.holder_fillet_radius
    pieces = [
        Segment((Ri + rh, zb), (Rh, zb)),
        Segment((Rh, zb), (Rh, zb + Th)),
        Segment((Rh, zb + Th), (Ri, zb + Th)),
        Segment((Ri, zb + Th), (Ri, zb + rh)),
    ]
    if rh > 0:
        pieces.append(Arc((Ri + rh, zb + rh), rh, math.pi, 1.5 * math.pi))
    return {"punch": punch, "die": die, "holder": Profile(pieces)}


def analytic_tools(cfg: HemisphereTools) -> dict[str, AxisymmetricSurface]:
    """Exact surfaces of the hemisphere tools (no meshing): punch, die, holder."""
    return {name: AxisymmetricSurface(profile, name)
            for name, profile in hemisphere_profiles(cfg).items()}


def analytic_double_dome_tools(cfg: DoubleDomeTools) -> dict[str, SignedDistanceSurface]:
    """Exact surfaces of the double-dome tools (no meshing): punch, die, holder, each the
    opening of a sharp-edged core (drape.forming.double_dome; docs/contact.md, "Exact double-dome
    tools"). The die and holder are unbounded outward and the punch has no top face: only the
    working faces are modelled."""
    try:
        return double_dome_surfaces(
            dome_offset=cfg.dome_offset, punch_width=cfg.punch_width,
            dome_radius=cfg.dome_radius, saddle_radius=cfg.saddle_radius,
            punch_edge_radius=cfg.punch_edge_radius, die_entry_radius=cfg.die_entry_radius,
            clearance=cfg.clearance, gap=cfg.gap, full_stroke=cfg.full_stroke,
            holder_opening_radius=cfg.holder_opening_radius,
            holder_edge_radius=cfg.holder_edge_radius)
    except ValueError as error:     # dimensions validate() lets through but the shape cannot have
        raise InputError(f"these double-dome dimensions give no valid tool shape ({error})",
                         key="tools.double_dome",
                         expected="a deeper cavity, a smaller die_entry_radius or flatter "
                                  "domes (docs/tools.md, Double dome)") from None


# --- gmsh builders ------------------------------------------------------------------------------

_MESH_OPTIONS = {"Mesh.MeshSizeFromPoints": 0, "Mesh.MeshSizeFromCurvature": 0,
                 "Mesh.MeshSizeExtendFromBoundary": 0, "Mesh.MeshSizeMin": 0.0,
                 "Mesh.MeshSizeMax": 1e22, "Mesh.Algorithm": 6}


def _edges_of(gmsh, dim_tags):
    return {abs(t) for _, t in gmsh.model.getBoundary(dim_tags, combined=False, oriented=False)}


def _circle_edges_at(gmsh, volume, radius, z, tol=1e-6):
    """Curves of a volume lying on the horizontal circle of given radius at height z."""
    found = []
    for curve in _edges_of(gmsh, gmsh.model.getBoundary([(3, volume)], combined=False,
                                                         oriented=False)):
        x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(1, curve)
        scale = max(1.0, radius)
        if abs(z0 - z) < tol * scale and abs(z1 - z) < tol * scale and \
                abs(max(x1, y1, -x0, -y0) - radius) < 1e-5 * scale:
            found.append(curve)
    return found


def _build_hemisphere(gmsh, cfg: HemisphereTools) -> dict[str, int]:
    occ = gmsh.model.occ
    g, R = cfg.gap, cfg.punch_radius
    ball = occ.addSphere(0, 0, g + R, R, angle1=-0.5 * math.pi, angle2=0.0)
    shank = occ.addCylinder(0, 0, g + R, 0, 0, cfg.shank_height, R)
    punch, _ = occ.fuse([(3, ball)], [(3, shank)])
    top, T = -g, cfg.die_thickness
    plate = occ.addCylinder(0, 0, top - T, 0, 0, T, cfg.die_outer_radius)
    hole = occ.addCylinder(0, 0, top - T - 1.0, 0, 0, T + 2.0, cfg.die_opening_radius)
    die, _ = occ.cut([(3, plate)], [(3, hole)])
    ring = occ.addCylinder(0, 0, g, 0, 0, cfg.holder_thickness, cfg.holder_outer_radius)
    inner = occ.addCylinder(0, 0, g - 1.0, 0, 0, cfg.holder_thickness + 2.0,
                            cfg.holder_inner_radius)
    holder, _ = occ.cut([(3, ring)], [(3, inner)])
    occ.synchronize()
    die_v = die[0][1]
    edge = _circle_edges_at(gmsh, die_v, cfg.die_opening_radius, top)
    die_v = occ.fillet([die_v], edge, [cfg.die_fillet_radius])[0][1]
    holder_v = holder[0][1]
    if cfg.holder_fillet_radius > 0:
        occ.synchronize()
        edge = _circle_edges_at(gmsh, holder_v, cfg.holder_inner_radius, g)
        holder_v = occ.fillet([holder_v], edge, [cfg.holder_fillet_radius])[0][1]
    occ.synchronize()
    return {"punch": punch[0][1], "die": die_v, "holder": holder_v}


def _stadium_prism(occ, half_length, radius, z0, height):
    """A vertical prism on the stadium footprint |x| <= half_length with half-discs of the
    given radius at x = +-half_length, from z0 to z0 + height."""
    a, r = half_length, radius
    pts = [occ.addPoint(a, -r, z0), occ.addPoint(a + r, 0, z0), occ.addPoint(a, r, z0),
           occ.addPoint(-a, r, z0), occ.addPoint(-a - r, 0, z0), occ.addPoint(-a, -r, z0)]
    ca, cb = occ.addPoint(a, 0, z0), occ.addPoint(-a, 0, z0)
    curves = [occ.addCircleArc(pts[0], ca, pts[1]), occ.addCircleArc(pts[1], ca, pts[2]),
              occ.addLine(pts[2], pts[3]), occ.addCircleArc(pts[3], cb, pts[4]),
              occ.addCircleArc(pts[4], cb, pts[5]), occ.addLine(pts[5], pts[0])]
    face = occ.addPlaneSurface([occ.addCurveLoop(curves)])
    out = occ.extrude([(2, face)], 0, 0, height)
    return [t for d, t in out if d == 3][0]


def _double_dome_shape(gmsh, cfg: DoubleDomeTools, which: str) -> int:
    """The punch (which='punch', in its working position) or the cavity solid (its offset by
    the clearance, reaching 10 mm above the die top face so that cutting it is clean)."""
    occ = gmsh.model.occ
    a, c = cfg.dome_offset, cfg.clearance
    if which == "punch":
        R, Rs, rk = cfg.dome_radius, cfg.saddle_radius, cfg.punch_edge_radius
        rf = 0.5 * cfg.punch_width
        tip = cfg.gap
        z0, height = tip - 1.0, cfg.punch_height + 1.0
    else:
        R, Rs, rk, rf = (cfg.dome_radius + c, cfg.saddle_radius - c, cfg.punch_edge_radius + c,
                         0.5 * cfg.punch_width + c)
        tip = -cfg.gap - cfg.depth
        z0, height = tip - 1.0, cfg.depth + 11.0
    zc = tip + R
    s1 = occ.addSphere(a, 0, zc, R)
    s2 = occ.addSphere(-a, 0, zc, R)
    blob, _ = occ.fuse([(3, s1)], [(3, s2)])
    occ.synchronize()
    faces = gmsh.model.getBoundary(blob, combined=False, oriented=False)
    crease = [t for t in _edges_of(gmsh, faces)
              if max(abs(v) for v in gmsh.model.getBoundingBox(1, t)[0::3]) < 1e-4 * R]
    blob = occ.fillet([blob[0][1]], crease, [Rs])
    prism = _stadium_prism(occ, a, rf, z0, height)
    shape, _ = occ.intersect([(3, prism)], blob)
    occ.synchronize()
    volume = shape[0][1]
    faces = [t for _, t in gmsh.model.getBoundary([(3, volume)], combined=False, oriented=False)]
    shaped = [abs(t) for t in faces if gmsh.model.getType(2, abs(t)) not in ("Plane", "Cylinder")]
    height = lambda t: gmsh.model.getBoundingBox(2, t)[5] - gmsh.model.getBoundingBox(2, t)[2]
    walls = [abs(t) for t in faces if abs(t) not in shaped and height(abs(t)) > 1e-6]
    rim = _edges_of(gmsh, [(2, t) for t in shaped]) & _edges_of(gmsh, [(2, t) for t in walls])
    volume = occ.fillet([volume], sorted(rim), [rk])[0][1]
    occ.synchronize()
    return volume


def _build_double_dome(gmsh, cfg: DoubleDomeTools) -> dict[str, int]:
    occ = gmsh.model.occ
    punch = _double_dome_shape(gmsh, cfg, "punch")
    cavity = _double_dome_shape(gmsh, cfg, "cavity")
    top = -cfg.gap
    L, W = cfg.die_length, cfg.die_width
    block = occ.addBox(-L / 2, -W / 2, top - cfg.die_thickness, L, W, cfg.die_thickness)
    die, _ = occ.cut([(3, block)], [(3, cavity)])
    occ.synchronize()
    die_v = die[0][1]
    rim = _top_inner_edges(gmsh, die_v, top, L, W)
    die_v = occ.fillet([die_v], rim, [cfg.die_entry_radius])[0][1]
    plate = occ.addBox(-L / 2, -W / 2, cfg.gap, L, W, cfg.holder_thickness)
    hole = _stadium_prism(occ, cfg.dome_offset, cfg.holder_opening_radius, cfg.gap - 1.0,
                          cfg.holder_thickness + 2.0)
    holder, _ = occ.cut([(3, plate)], [(3, hole)])
    occ.synchronize()
    holder_v = holder[0][1]
    edges = _top_inner_edges(gmsh, holder_v, cfg.gap, L, W)
    holder_v = occ.fillet([holder_v], edges, [cfg.holder_edge_radius])[0][1]
    occ.synchronize()
    return {"punch": punch, "die": die_v, "holder": holder_v}


def _top_inner_edges(gmsh, volume, z, length, width, tol=1e-6):
    """Curves of a volume in the plane z that are not on the block's outer rectangle."""
    edges = []
    for curve in _edges_of(gmsh, gmsh.model.getBoundary([(3, volume)], combined=False,
                                                        oriented=False)):
        x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(1, curve)
        if abs(z0 - z) > tol * max(1.0, abs(z)) + tol or abs(z1 - z) > tol * max(1.0, abs(z)) + tol:
            continue
        on_outer = (abs(x0 + length / 2) < 1e-4 and abs(x1 + length / 2) < 1e-4) or \
                   (abs(x0 - length / 2) < 1e-4 and abs(x1 - length / 2) < 1e-4) or \
                   (abs(y0 + width / 2) < 1e-4 and abs(y1 + width / 2) < 1e-4) or \
                   (abs(y0 - width / 2) < 1e-4 and abs(y1 - width / 2) < 1e-4)
        if not on_outer:
            edges.append(curve)
    return edges


def _import_step(gmsh, tool: StepTool, key: str):
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


def build_tools(config: ToolsConfig | HemisphereTools | DoubleDomeTools | StepTools,
                mesh: ToolMeshing | None = None, comm=None) -> dict[str, TriangleSurface]:
    """Build the tools with gmsh (OpenCASCADE), mesh their surfaces and return one
    :class:`TriangleSurface` per tool, in working position, keyed 'punch', 'die', 'holder'.

    With an MPI communicator of more than one rank, rank 0 builds and the others receive the
    arrays (the tools are identical on every rank)."""
    if comm is not None and comm.size > 1:
        result = None
        if comm.rank == 0:
            try:
                result = build_tools(config, mesh)
            except InputError as error:     # every rank raises it, none waits for rank 0
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
    if isinstance(config, ToolsConfig):
        mesh = mesh or config.mesh
        config = {"hemisphere": config.hemisphere, "double_dome": config.double_dome,
                  "step": config.step}[config.kind]
    mesh = mesh or ToolMeshing()
    from drape.geometry._gmsh import (boundary_surfaces, extract_surface, mesh_surfaces,
                                      scratch_model)
    with scratch_model(options=_MESH_OPTIONS) as gmsh:
        sides = {}
        if isinstance(config, (HemisphereTools, DoubleDomeTools)):
            builder = _build_hemisphere if isinstance(config, HemisphereTools) else \
                _build_double_dome
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
                vols, surfs = _import_step(gmsh, tool, f"step.{name}")
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
        try:
            mesh_surfaces(mesh, sorted({f for fs in faces.values() for f in fs}))
        except Exception as error:
            raise InputError(f"gmsh could not mesh the tool surfaces ({error})",
                             expected="tools gmsh can mesh; try other [tools.mesh] sizes"
                             ) from None
        return {name: extract_surface(name, faces[name], sides.get(name, "solid"))
                for name in faces}


# --- output -----------------------------------------------------------------------------------

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
