"""What a forming job's config must satisfy before anything is built: a stroke within the
tools, a blank on the die and over its opening, a mesh fine enough for the tools' fillets
(InputError naming the key). Config-level only: no DOLFINx, no contact; :mod:`drape.job`
calls :func:`check_forming` when it loads a job with a ``[process]`` table."""

from __future__ import annotations

import math

import numpy as np

from drape.errors import InputError


def tool_set(config):
    """The chosen tool dimensions ([tools.hemisphere], [tools.double_dome] or [tools.step])."""
    from drape.geometry.tools import ToolsConfig
    tools = config.tools or ToolsConfig()
    return tools, {"hemisphere": tools.hemisphere, "double_dome": tools.double_dome,
                   "step": tools.step}[tools.kind]


def holder_mode(config) -> str | None:
    """How the holder is driven: "force" (to process.holder_force; the built-in holders and a
    STEP holder by default), "position" (a STEP holder with control = "position") or None (no
    holder: none given, or a force-controlled one with holder_force = 0)."""
    tools, dims = tool_set(config)
    if tools.kind == "step":
        if not dims.holder.given:
            return None
        if dims.holder.control == "position":
            return "position"
    return "force" if config.process.holder_force > 0 else None


def full_stroke(config) -> float | None:
    tools, dims = tool_set(config)
    return None if tools.kind == "step" else dims.full_stroke


def stroke_of(config) -> float:
    stroke = config.process.stroke
    return stroke if stroke is not None else full_stroke(config)


def tool_clearance(config) -> float | None:
    """The room the built-in tools leave the fabric between punch and die (mm): the double
    dome's normal clearance at full stroke, the hemisphere's radial gap between punch and die
    opening; None for STEP tools."""
    tools, dims = tool_set(config)
    if tools.kind == "double_dome":
        return dims.clearance
    if tools.kind == "hemisphere":
        return dims.die_opening_radius - dims.punch_radius
    return None


def squeezed_thickness(thicknesses, smoothing: float) -> float:
    """The punch-to-die distance (mm) below which a stack of plies (``thicknesses``, mm) is
    squeezed where all of them overlap: the tools' contact touches the outer plies'
    mid-surfaces, adjacent mid-surfaces lie (t_i + t_j) / 2 apart, and every contact (the
    two tools' and each interface's) pushes from a gap of ``smoothing`` (g0, mm) on."""
    t = list(thicknesses)
    return sum(t) - 0.5 * (t[0] + t[-1]) + (len(t) + 1) * smoothing


def fitting_smoothing(thicknesses, clearance: float) -> float | None:
    """The largest contact smoothing g0 (mm) with which a stack of plies (``thicknesses``, mm)
    fits a punch-to-die distance ``clearance`` (mm) unsqueezed (:func:`squeezed_thickness`
    equal to it); None where even g0 = 0 does not fit."""
    t = list(thicknesses)
    room = clearance - squeezed_thickness(t, 0.0)
    return room / (len(t) + 1) if room > 0.0 else None


def smallest_wrapped_radius(config) -> float | None:
    """The smallest tool radius the fabric wraps around (mm): die entry and punch edge fillets."""
    tools, dims = tool_set(config)
    if tools.kind == "hemisphere":
        return min(dims.die_fillet_radius, dims.punch_radius)
    if tools.kind == "double_dome":
        return min(dims.die_entry_radius, dims.punch_edge_radius)
    return None


def blank_half_extents(blank) -> tuple[float, float]:
    if blank.shape == "disc":
        return blank.radius, blank.radius
    if blank.shape == "polygon":
        from drape.job import blank_outline
        outline = blank_outline(blank)
        return tuple(float(v) for v in np.abs(outline).max(axis=0))
    return blank.length / 2.0, blank.width / 2.0


def _polygon_radii(blank) -> tuple[float, float]:
    """A polygon blank's distance from the tools' axis to its nearest edge (negative when the
    axis is outside it) and to its farthest vertex (mm)."""
    from drape.geometry.outline import closest_on_polyline, inside_polygon
    from drape.job import blank_outline
    outline = blank_outline(blank)
    origin = np.zeros((1, 2))
    gap = float(closest_on_polyline(outline, origin)[0][0])
    reach = float(np.linalg.norm(outline, axis=1).max())
    return (gap if inside_polygon(outline, origin)[0] else -gap), reach


#: the start of the error for a blank that does not span the die's opening or cavity
COVER_PROBLEM = "the blank does not cover the die"


def check_forming(config, cover: bool = True) -> None:
    """Cross-checks of a forming job (InputError naming the key): stroke within the tools, blank
    on the die and over its opening (unless ``cover`` is False: a ply of a stack, which may
    rest on the others), mesh fine enough for the tools' fillets."""
    tools, dims = tool_set(config)
    _check_stroke(config, tools, dims)
    half_extents = blank_half_extents(config.blank)
    if config.blank.shape == "polygon":
        _check_polygon_blank(config, tools, dims, half_extents, cover)
    else:
        _check_blank(config, tools, dims, half_extents, cover)
    _check_mesh(config)
    _check_tool_friction(config, tools, dims)


def _check_tool_friction(config, tools, dims) -> None:
    """A tool's own friction coefficient is set only for a tool the job has."""
    for name in ("punch", "die", "holder"):
        if getattr(config.contact, f"{name}_friction") is None:
            continue
        if name == "holder":
            present = holder_mode(config) is not None
        else:
            present = tools.kind != "step" or getattr(dims, name).given
        if not present:
            raise InputError(f"set, but this job has no {name}", key=f"contact.{name}_friction",
                             value=getattr(config.contact, f"{name}_friction"),
                             expected=f"contact.{name}_friction unset, or a job with a {name} "
                                      + ("(process.holder_force > 0, or a STEP holder file)"
                                         if name == "holder" else f"(tools.step.{name}.file)"))


def _hemisphere_opening(dims) -> float:
    """The radius (mm) the blank must cover all round: the die's opening and its fillet."""
    return dims.die_opening_radius + dims.die_fillet_radius


def _double_dome_cavity(dims) -> tuple[float, float]:
    """The half length and half width (mm) of the die's cavity, entry fillets included."""
    return (dims.dome_offset + dims.punch_width / 2 + dims.clearance + dims.die_entry_radius,
            dims.punch_width / 2 + dims.clearance + dims.die_entry_radius)


def _blank_key(blank) -> str:
    """The key a blank's size error names."""
    return {"disc": "blank.radius", "polygon": "blank.points"}.get(blank.shape, "blank.length")


def _check_stroke(config, tools, dims) -> None:
    """A stroke for STEP tools, within the built-in tools' full stroke; a die under a
    force-controlled STEP holder."""
    process = config.process
    limit = full_stroke(config)
    if tools.kind == "step" and process.stroke is None:
        raise InputError("STEP tools have no known full stroke", key="process.stroke",
                         expected="the punch travel in mm")
    if tools.kind == "step" and holder_mode(config) == "force" and not dims.die.given:
        raise InputError("a force-controlled holder needs a die to press the blank against",
                         key="tools.step.holder.control", value=dims.holder.control,
                         expected="a [tools.step.die] file, control = \"position\", or "
                                  "process.holder_force = 0 (no holder)")
    if limit is not None and process.stroke is not None and process.stroke > limit + 1e-9:
        raise InputError("the stroke is larger than the tools allow", key="process.stroke",
                         value=process.stroke,
                         expected=f"<= {limit:g} mm, the full stroke of these {tools.kind} tools "
                                  "(the punch would hit the die)")


def _check_polygon_blank(config, tools, dims, half_extents, cover: bool = True) -> None:
    """A polygon blank covers the die's opening (cavity) and stays on the die."""
    key = _blank_key(config.blank)
    inner, reach = _polygon_radii(config.blank)
    if tools.kind == "hemisphere":
        opening = _hemisphere_opening(dims)
        if cover and inner <= opening:
            raise InputError(COVER_PROBLEM + " opening", key=key,
                             value=f"its edge {inner:.4g} mm from the tools' axis",
                             expected=f"a polygon around x = y = 0 reaching beyond r = "
                                      f"{opening:g} mm all round")
        if reach > dims.die_outer_radius:
            raise InputError("the blank reaches beyond the die", key=key,
                             value=f"a vertex at r = {reach:.4g} mm",
                             expected=f"vertices within r = {dims.die_outer_radius:g} mm")
    elif tools.kind == "double_dome":
        from drape.geometry.outline import inside_polygon
        from drape.job import blank_outline
        hx, hy = half_extents
        outline = blank_outline(config.blank)
        ox, oy = _double_dome_cavity(dims)
        corners = np.array([[ox, oy], [-ox, oy], [-ox, -oy], [ox, -oy]])
        if cover and (not inside_polygon(outline, corners).all() or min(hx, hy) <= min(ox, oy)):
            raise InputError(COVER_PROBLEM + " cavity", key=key,
                             expected=f"a polygon around the cavity |x| < {ox:g}, "
                                      f"|y| < {oy:g} mm")
        if hx > dims.die_length / 2 or hy > dims.die_width / 2:
            raise InputError("the blank reaches beyond the die", key=key,
                             expected=f"|x| <= {dims.die_length / 2:g} and |y| <= "
                                      f"{dims.die_width / 2:g} mm")


def _check_blank(config, tools, dims, half_extents, cover: bool = True) -> None:
    """A rectangle or disc blank covers the die's opening (cavity) and stays on the die,
    corners included."""
    blank = config.blank
    key = _blank_key(blank)
    hx, hy = half_extents
    if tools.kind == "hemisphere":
        reach = math.hypot(hx, hy) if blank.shape == "rectangle" else hx
        opening = _hemisphere_opening(dims)
        if cover and min(hx, hy) <= opening:
            raise InputError(COVER_PROBLEM + " opening", key=key,
                             value=2 * min(hx, hy) if blank.shape == "rectangle" else hx,
                             expected=f"a blank reaching beyond r = {opening:g} mm all round")
        if reach > dims.die_outer_radius:
            raise InputError("the blank reaches beyond the die", key=key,
                             value=getattr(blank, key.split(".")[1]),
                             expected=f"a blank within r = {dims.die_outer_radius:g} mm, corners "
                                      f"included (they are at r = {reach:.4g} mm)")
    elif tools.kind == "double_dome":
        opening_x, opening_y = _double_dome_cavity(dims)
        if cover and (hx <= opening_x or hy <= opening_y):
            raise InputError(COVER_PROBLEM + " cavity", key=key,
                             value=(2 * hx, 2 * hy),
                             expected=f"length > {2 * opening_x:g} and "
                                      f"width > {2 * opening_y:g} mm")
        if hx > dims.die_length / 2 or hy > dims.die_width / 2:
            raise InputError("the blank reaches beyond the die", key=key, value=(2 * hx, 2 * hy),
                             expected=f"length <= {dims.die_length:g} and width <= "
                                      f"{dims.die_width:g} mm")


def _check_mesh(config) -> None:
    """Two elements over the quarter arc of the smallest fillet the fabric wraps."""
    radius = smallest_wrapped_radius(config)
    if radius is not None:
        largest = math.pi / 4 * radius
        if config.mesh.size > largest:
            raise InputError("the mesh is too coarse for the tools", key="mesh.size",
                             value=config.mesh.size,
                             expected=f"<= {largest:.3g} mm: two elements over the quarter arc "
                                      "of the smallest fillet the fabric wraps "
                                      f"(R = {radius:g} mm)")
