"""The hemisphere tool set: its dimensions, its gmsh/OpenCASCADE solids and its exact twin.

A hemispherical punch on a cylindrical shank, a die plate with a circular opening and an entry
fillet, a blank-holder ring, in their working positions (mm; ``drape.geometry.tools`` says
where). :func:`build_hemisphere_solids` adds the three solids to a gmsh model (meshed by
``drape.geometry.tools.build_tools``); :func:`analytic_tools` gives the same tools as exact
:class:`~drape.forming.axisymmetric.AxisymmetricSurface` s, from their (r, z) profiles.
"""

from __future__ import annotations

import dataclasses
import math

from drape.config import non_negative, positive, setting
from drape.errors import InputError
from drape.forming.axisymmetric import Arc, AxisymmetricSurface, Profile, Segment
from drape.geometry._gmsh import edges_of


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


# --- gmsh solids ----------------------------------------------------------------------------------

def _circle_edges_at(gmsh, volume, radius, z, tol=1e-6):
    """Curves of a volume lying on the horizontal circle of given radius at height z."""
    found = []
    for curve in edges_of(gmsh, gmsh.model.getBoundary([(3, volume)], combined=False,
                                                       oriented=False)):
        x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(1, curve)
        scale = max(1.0, radius)
        if abs(z0 - z) < tol * scale and abs(z1 - z) < tol * scale and \
                abs(max(x1, y1, -x0, -y0) - radius) < 1e-5 * scale:
            found.append(curve)
    return found


def build_hemisphere_solids(gmsh, cfg: HemisphereTools) -> dict[str, int]:
    """Add the punch, die and holder solids to the current OCC model; their volume tags."""
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
