"""The double-dome tool set: its dimensions, its gmsh/OpenCASCADE solids and its exact twin.

The woven-composites double-dome benchmark shape: two spherical domes joined by a saddle (a
concave rolling-ball blend between them) on a stadium footprint, the die cavity its offset by
the clearance, the holder a plate around the cavity (mm; working positions as in
``drape.geometry.tools``). :func:`build_double_dome_solids` adds the three solids to a gmsh
model; :func:`analytic_double_dome_tools` gives the same tools as exact signed distances
(:mod:`drape.forming.double_dome`); :func:`double_dome_height` is the shaped surface's height,
exact for the construction the builder uses.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np

from drape.config import non_negative, positive, setting
from drape.errors import InputError
from drape.forming.double_dome import double_dome_surfaces
from drape.forming.signed_distance import SignedDistanceSurface
from drape.geometry._gmsh import edges_of


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


# --- gmsh solids ----------------------------------------------------------------------------------

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


def double_dome_shape(gmsh, cfg: DoubleDomeTools, which: str) -> int:
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
    crease = [t for t in edges_of(gmsh, faces)
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
    rim = edges_of(gmsh, [(2, t) for t in shaped]) & edges_of(gmsh, [(2, t) for t in walls])
    volume = occ.fillet([volume], sorted(rim), [rk])[0][1]
    occ.synchronize()
    return volume


def build_double_dome_solids(gmsh, cfg: DoubleDomeTools) -> dict[str, int]:
    """Add the punch, die and holder solids to the current OCC model; their volume tags."""
    occ = gmsh.model.occ
    punch = double_dome_shape(gmsh, cfg, "punch")
    cavity = double_dome_shape(gmsh, cfg, "cavity")
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
    for curve in edges_of(gmsh, gmsh.model.getBoundary([(3, volume)], combined=False,
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
