"""The job configuration of ``drape run``: a TOML file read into frozen dataclasses.

Every table and key is documented by its field (``setting(default, doc, check, unit)``); the
table of keys in ``docs/fe-solver.md`` is generated from these fields (:func:`key_table`).
Loading checks types, unknown keys, ranges, cross-field rules and the boundary formulas, and
raises :class:`~drape.errors.InputError` naming the file and key. Lengths in mm, angles in
degrees, forces in N.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal

import numpy as np

from drape.config import (describe, each, from_mapping, in_range, non_negative, positive,
                          read_toml, setting)
from drape.forming.contact import ContactParameters
from drape.errors import InputError
from drape.geometry.tools import ToolsConfig

#: boundary names of each blank shape (gmsh physical groups); "boundary" is the whole edge
BOUNDARY_NAMES = {"rectangle": ("left", "right", "bottom", "top"), "disc": ("edge",),
                  "polygon": ("edge",)}
WHOLE_BOUNDARY = "boundary"
#: a mesh.size giving fewer elements than this across the blank is refused (too coarse to
#: say anything: one element has no interior nodes)
MIN_ELEMENTS_ACROSS = 3


@dataclasses.dataclass(frozen=True)
class BlankConfig:
    """The flat blank: a rectangle [0, length] x [0, width], a disc centred at the origin or a
    polygon through given points (docs/blanks.md). A forming job centres the rectangle on the
    tools' axis; disc and polygon are where they are, the tools' axis at the origin."""

    shape: Literal["rectangle", "disc", "polygon"] = setting("rectangle", "outline of the blank")
    length: float = setting(100.0, "rectangle: extent along x", positive, "mm")
    width: float = setting(100.0, "rectangle: extent along y", positive, "mm")
    radius: float = setting(50.0, "disc: radius", positive, "mm")
    points: tuple[tuple[float, ...], ...] = setting(
        (), "polygon: its vertices in order, [[x0, y0], [x1, y1], ...] (at least 3; a forming "
        "job's tools have their axis at x = y = 0)", unit="mm")
    yarn_angle: float = setting(0.0, "angle theta from x to the warp yarns G1 = (cos, sin); "
                                "the weft G2 is at theta + 90; from -90 to 90 "
                                "(every direction: theta + 180 is the "
                                "same yarn)", in_range(-90.0, 90.0), "deg")

    def validate(self):
        if self.shape == "polygon":
            try:
                blank_outline(self)
            except InputError as error:     # keys relative to the [blank] table here
                raise InputError(error.problem, key=error.key.removeprefix("blank."),
                                 value=error.value, expected=error.expected) from None
        elif self.points:
            raise InputError(f"points given for a {self.shape}", key="points",
                             value=[list(p) for p in self.points],
                             expected="shape = \"polygon\" with these points, or no points")


def blank_outline(blank):
    """A polygon blank's vertices (n, 2) counter-clockwise (InputError naming blank.points)."""
    from drape.geometry.blank import polygon_outline
    for i, point in enumerate(blank.points):
        if len(point) != 2:
            raise InputError("not a point", key=f"blank.points[{i}]", value=list(point),
                             expected="[x, y] in mm")
    return polygon_outline(blank.points)


def describe_blank(blank) -> str:
    """The blank in a few words, for titles and summaries."""
    if blank.yarn_angle % 90 == 0:
        yarns = "yarns 0/90"
    elif math.isclose(abs(blank.yarn_angle), 45.0):
        yarns = "yarns +-45"
    else:
        yarns = f"yarns {blank.yarn_angle:g}/{blank.yarn_angle + 90:g}"
    if blank.shape == "rectangle":
        return f"{blank.length:g} x {blank.width:g} mm blank, {yarns}"
    if blank.shape == "disc":
        return f"disc blank R {blank.radius:g} mm, {yarns}"
    from drape.geometry.blank import polygon_area
    outline = blank_outline(blank)
    return (f"{len(outline)}-gon blank ({abs(polygon_area(outline)):.5g} mm^2, "
            f"{np.ptp(outline[:, 0]):.4g} x {np.ptp(outline[:, 1]):.4g} mm), {yarns}")


def compose_title(title: str, blank) -> str:
    """The config's title followed by what the blank really is, so that a --set of the blank
    never leaves a title describing another one; a title that already says it is kept."""
    described = describe_blank(blank)
    return title if described in title else ", ".join(p for p in (title, described) if p)


@dataclasses.dataclass(frozen=True)
class MeshConfig:
    """How gmsh meshes the blank."""

    cell: Literal["quadrilateral", "triangle"] = setting("quadrilateral", "element shape")
    pattern: Literal["aligned", "free"] = setting(
        "aligned", "'aligned': element edges follow the yarns (rectangle: theta a multiple of "
        "45; disc, polygon: a yarn lattice clipped to the outline, one strip of cells to it); "
        "'free': gmsh's unstructured mesh (may lock)")
    size: float = setting(5.0, "element edge length (aligned: along the yarns); at most a third "
                          "of the blank's smallest extent", positive, "mm")


@dataclasses.dataclass(frozen=True)
class StepsConfig:
    """Adaptive load stepping in the load factor t (0 to 1)."""

    initial: float = setting(0.01, "first step", in_range(0.0, 1.0, lo_open=True))
    minimum: float = setting(1e-6, "smallest step before the run fails",
                             in_range(0.0, 1.0, lo_open=True))
    maximum: float = setting(0.05, "largest step", in_range(0.0, 1.0, lo_open=True))
    growth: float = setting(1.5, "step growth after an easy step", in_range(1.0, 10.0))
    cutback: float = setting(0.5, "step reduction after a failed step",
                             in_range(0.0, 1.0, lo_open=True, hi_open=True))
    easy_iterations: int = setting(4, "a step converged in at most this many Newton iterations "
                                   "lets the next one grow", positive)

    def validate(self):
        if self.minimum > self.maximum:
            raise InputError("larger than steps.maximum", key="minimum", value=self.minimum,
                             expected=f"minimum <= maximum = {self.maximum:g}")
        if not self.minimum <= self.initial <= self.maximum:
            raise InputError("outside [minimum, maximum]", key="initial", value=self.initial,
                             expected=f"minimum = {self.minimum:g} <= initial <= maximum = "
                                      f"{self.maximum:g}")


@dataclasses.dataclass(frozen=True)
class SolverConfig:
    """Newton's method (PETSc SNES, options prefix ``drape_``) and its linear solver."""

    linear: Literal["direct", "iterative"] = setting(
        "direct", "'direct': LU with MUMPS; 'iterative' (large meshes): GMRES with a field "
        "split, GAMG with the rigid-body near-nullspace in the plane, GAMG out of it")
    max_iterations: int = setting(20, "Newton iterations per step before a cutback", positive)
    rtol: float = setting(1e-10, "convergence: residual norm relative to the step's first",
                          positive)
    atol: float = setting(1e-12, "convergence: absolute residual norm as a fraction of the force "
                          "scale mu*max(K1, K2)*sqrt(blank area)", positive)
    neutral_loading_band: float = setting(
        0.0, "Newton's Jacobian at law points plastic by less than this plastic shear in the "
        "step (near neutral loading, where the law switches branch between iterations): the "
        "geometric mean of the elastic and the consistent tangent; 0: the consistent tangent "
        "everywhere. The residual is unchanged", non_negative, "rad")
    petsc: dict[str, bool | int | float | str] = setting(
        {}, "any PETSc options, without the prefix (e.g. snes_monitor = \"\", "
        "snes_linesearch_type = \"basic\"); they override the settings above")

    def validate(self):
        for name in self.petsc:
            if not name or name.startswith("-") or any(c.isspace() for c in name):
                raise InputError("not a PETSc option name", key=f"petsc.{name}", value=name,
                                 expected="a name without the leading '-' or the drape_ prefix, "
                                          "e.g. snes_monitor")


@dataclasses.dataclass(frozen=True)
class RegularisationConfig:
    """Damping of the out-of-plane displacement against the last converged step."""

    out_of_plane_damping: float = setting(
        1e-3, "k in the residual term k (u_z - u_z,last) v_z; 0 disables it (a flat membrane "
        "is then singular)", non_negative, "N/mm^3")


#: bending rigidity B (N mm) of a forming job whose config does not set it (docs/forming.md,
#: "Bending": of the order measured on dry woven reinforcements)
DEFAULT_FORMING_BENDING = 10.0


@dataclasses.dataclass(frozen=True)
class BendingConfig:
    """The fabric's bending rigidity: not part of the paper's in-plane law, a hinge energy
    across the element edges (drape/fe/membrane.py). A flat blank has no bending energy."""

    rigidity: float | None = setting(
        None, "bending rigidity B, moment per unit width per unit curvature; unset: 0 for a "
        f"flat job, {DEFAULT_FORMING_BENDING:g} for a forming job (a membrane without bending "
        "has no stiffness against wrinkling: docs/forming.md)", non_negative, "N mm")

    def value(self, forming: bool) -> float:
        if self.rigidity is not None:
            return self.rigidity
        return DEFAULT_FORMING_BENDING if forming else 0.0


@dataclasses.dataclass(frozen=True)
class HistoryConfig:
    """A piecewise-linear function of the load factor, named in boundary formulas."""

    values: tuple[float, ...] = setting((), "waypoint values (the history's own unit)")
    t: tuple[float, ...] | None = setting(None, "waypoint load factors, from 0 to 1, increasing "
                                          "(default: equally spaced)", each(in_range(0.0, 1.0)))

    def validate(self):
        if len(self.values) < 2:
            raise InputError("needs at least two waypoints", key="values", value=list(self.values),
                             expected="an array of at least 2 numbers")
        if self.t is not None:
            t = self.t
            if len(t) != len(self.values):
                raise InputError(f"has {len(t)} entries but values has {len(self.values)}",
                                 key="t", value=list(t), expected="one load factor per value")
            if t[0] != 0.0 or t[-1] != 1.0 or any(b <= a for a, b in zip(t, t[1:])):
                raise InputError("not increasing from 0 to 1", key="t", value=list(t),
                                 expected="[0, ..., 1], strictly increasing")


@dataclasses.dataclass(frozen=True)
class BoundaryConfig:
    """Displacement components prescribed on a named boundary (formulas, mm); a component left
    out is free. Where two entries share nodes, the later entry wins there."""

    on: str = setting("", "boundary name: rectangle left/right/bottom/top, disc or polygon "
                      "edge, or "
                      "'boundary' (the whole outline)")
    ux: str | None = setting(None, "x displacement formula", unit="mm")
    uy: str | None = setting(None, "y displacement formula", unit="mm")
    uz: str | None = setting(None, "z displacement formula", unit="mm")

    def validate(self):
        if not self.on:
            raise InputError("required key is missing", key="on",
                             expected="the name of a boundary, e.g. \"left\"")
        if self.ux is None and self.uy is None and self.uz is None:
            raise InputError("no component prescribed", key="ux",
                             expected="at least one of ux, uy, uz")


@dataclasses.dataclass(frozen=True)
class OutputConfig:
    """What a run writes, and where."""

    folder: str = setting("", "results folder (default: results/<config name> in the current "
                          "directory)")
    xdmf: bool = setting(True, "write the XDMF time series (fields.xdmf/.h5)")
    xdmf_every: int = setting(1, "write the XDMF fields every N converged steps (and the last)",
                              positive)
    snapshot: Literal["final", "every", "none"] = setting(
        "final", "partition-independent result.npz (fields gathered on rank 0, sorted by "
        "coordinates): after the last step, after every step, or never")
    checkpoint_every: int = setting(
        10, "write checkpoint.npz (for drape run --resume) every N converged steps, and at the "
        "last converged step when a run stops (signal or failure); 0: never", non_negative)


@dataclasses.dataclass(frozen=True)
class PictureFrameConfig:
    """Report the frame force of a picture-frame test (square blank, boundary following eq. 25)."""

    angle: str = setting("", "name of the history giving the frame's shear angle (deg)")


@dataclasses.dataclass(frozen=True)
class BiasExtensionConfig:
    """Report a bias-extension test (rectangle, yarns at +-45 deg, one end pulled along x):
    force, central shear angle and the kinematic angle against the clamp displacement."""

    displacement: str = setting("", "name of the history giving the clamp displacement d (mm)")
    pulled: str = setting("right", "the end pulled along x by d, 'right' or 'left'; its x "
                          "reaction is the force")
    centre_radius: float | None = setting(
        None, "the central shear angle is the mean absolute gamma_t of the law's points within "
        "this distance of the blank's centre (default: a tenth of the width)", positive, "mm")
    speed: float = setting(5.0, "crosshead speed, for the time column (the law does not depend "
                           "on the rate)", positive, "mm/min")


@dataclasses.dataclass(frozen=True)
class ProcessConfig:
    """A forming job: the punch moves down by the stroke (linearly in the load factor t) while
    the blank holder presses the blank onto the die with a constant force (docs/forming.md)."""

    stroke: float | None = setting(None, "punch travel (default: the tools' full stroke)",
                                   positive, "mm")
    holder_force: float = setting(200.0, "total blank-holder force: the rigid holder's height "
                                  "is controlled to press the flange with it (0: no holder)",
                                  non_negative, "N")
    locking_angle: float = setting(40.0, "shear angle above which the fabric is reported as "
                                   "locked (summary.json, maps)", in_range(0.0, 90.0, lo_open=True,
                                                                           hi_open=True), "deg")
    contact_cutoff: float = setting(10.0, "hemisphere and meshed tools: exact closest "
                                    "points within this distance of the tool (farther points "
                                    "are out of contact)",
                                    positive, "mm")
    areal_density: float = setting(
        0.0, "the blank's mass per area, for its inertia (implicit dynamics, docs/forming.md, "
        "\"Inertia\"); 0: quasi-static, no inertia", non_negative, "kg/m^2")
    punch_speed: float = setting(1.0, "the punch's speed after its ramp, which turns the load "
                                 "steps into time steps (used only with areal_density > 0)",
                                 positive, "m/s")
    punch_ramp: float = setting(0.0, "punch travel over which the punch accelerates uniformly "
                                "from rest to punch_speed (a smooth start instead of an impact "
                                "on the blank at rest; used only with areal_density > 0)",
                                non_negative, "mm")

    def punch_time(self, s: float) -> float:
        """Time (s) at which the punch has travelled s mm: uniform acceleration from rest to
        punch_speed v over punch_ramp s_r (s = v^2 tau^2 / (4 s_r)), then constant speed."""
        v, ramp = 1e3 * self.punch_speed, self.punch_ramp          # mm/s, mm
        if s < ramp:
            return 2.0 * math.sqrt(s * ramp) / v
        return (s + ramp) / v


@dataclasses.dataclass(frozen=True)
class JobConfig:
    """A ``drape run`` job."""

    title: str = setting("", "a label for logs and plots")
    material: str = setting("", "material TOML file, relative to this file (default: the "
                            "paper's three-surface model)")
    surfaces: int | None = setting(None, "keep only the outer surface and this many inner ones",
                                   non_negative)
    blank: BlankConfig = setting(BlankConfig(), "the blank")
    mesh: MeshConfig = setting(MeshConfig(), "its mesh")
    steps: StepsConfig = setting(StepsConfig(), "load stepping")
    solver: SolverConfig = setting(SolverConfig(), "Newton and linear solver")
    regularisation: RegularisationConfig = setting(RegularisationConfig(),
                                                   "flat-membrane regularisation")
    bending: BendingConfig = setting(BendingConfig(), "the fabric's bending rigidity")
    history: dict[str, HistoryConfig] = setting({}, "named piecewise-linear histories of t")
    boundary: tuple[BoundaryConfig, ...] = setting((), "prescribed displacements ([[boundary]])")
    output: OutputConfig = setting(OutputConfig(), "results")
    picture_frame: PictureFrameConfig | None = setting(None, "frame-force report (optional)")
    bias_extension: BiasExtensionConfig | None = setting(
        None, "bias-extension report (optional)")
    process: ProcessConfig | None = setting(None, "a forming job: punch stroke, holder force, "
                                            "locking angle (optional; needs [tools])")
    tools: ToolsConfig | None = setting(None, "the rigid tools of a forming job "
                                        "(docs/tools.md)")
    contact: ContactParameters = setting(ContactParameters(), "tool-fabric contact and friction")

    def validate(self):
        from drape.fe.loading import CONSTANTS, FUNCTIONS, VARIABLES
        reserved = set(VARIABLES) | set(CONSTANTS) | set(FUNCTIONS)
        for name in self.history:
            if not name.isidentifier() or name in reserved:
                raise InputError("not a usable history name", key=f"history.{name}", value=name,
                                 expected="an identifier other than " + ", ".join(sorted(reserved)))
        if self.process is not None:
            self._validate_forming()
        elif self.tools is not None:
            raise InputError("tools without a [process] table", key="process",
                             expected="a [process] table (stroke, holder_force) to run a forming "
                                      "job with these tools")
        if not self.boundary and self.process is None:
            raise InputError("no prescribed displacement", key="boundary",
                             expected="at least one [[boundary]] table (a blank held nowhere "
                                      "is singular)")
        self._check_mesh_size()
        known = BOUNDARY_NAMES[self.blank.shape] + (WHOLE_BOUNDARY,)
        for i, entry in enumerate(self.boundary):
            if entry.on not in known:
                raise InputError(f"unknown boundary of a {self.blank.shape}",
                                 key=f"boundary[{i}].on",
                                 value=entry.on, expected="one of " + ", ".join(known))
        if self.picture_frame is not None:
            if self.picture_frame.angle not in self.history:
                raise InputError("not a history of this job", key="picture_frame.angle",
                                 value=self.picture_frame.angle,
                                 expected="one of the names under [history]: " +
                                 (", ".join(self.history) or "(none defined)"))
            blank = self.blank
            if blank.shape != "rectangle" or not math.isclose(blank.length, blank.width):
                raise InputError("the frame force needs a square blank", key="picture_frame",
                                 expected="blank.shape = \"rectangle\" with length = width")

        if self.bias_extension is not None:
            bias = self.bias_extension
            if bias.displacement not in self.history:
                raise InputError("not a history of this job", key="bias_extension.displacement",
                                 value=bias.displacement,
                                 expected="one of the names under [history]: " +
                                 (", ".join(self.history) or "(none defined)"))
            if bias.pulled not in ("left", "right"):
                raise InputError("not an end of the rectangle", key="bias_extension.pulled",
                                 value=bias.pulled, expected="'right' or 'left'")
            blank = self.blank
            if (blank.shape != "rectangle" or blank.length <= blank.width
                    or not math.isclose(abs(blank.yarn_angle), 45.0)):
                raise InputError("the bias-extension report needs a rectangle longer than wide "
                                 "with yarns at +-45 deg", key="bias_extension",
                                 expected="blank.shape = \"rectangle\", length > width, "
                                          "yarn_angle = 45 or -45")

    def _check_mesh_size(self):
        """At least MIN_ELEMENTS_ACROSS elements across the blank's smallest extent."""
        blank = self.blank
        if blank.shape == "rectangle":
            extent, what = min(blank.length, blank.width), "min(blank.length, blank.width)"
        elif blank.shape == "disc":
            extent, what = 2.0 * blank.radius, "2 * blank.radius"
        else:
            extent, what = min(np.ptp(blank_outline(blank), axis=0)), "the polygon's smaller extent"
        largest = extent / MIN_ELEMENTS_ACROSS
        if self.mesh.size > largest:
            raise InputError(f"too coarse: {extent / self.mesh.size:.2g} elements across the "
                             f"blank", key="mesh.size", value=self.mesh.size,
                             expected=f"at least {MIN_ELEMENTS_ACROSS} elements across the blank: "
                                      f"mesh.size <= {what} / {MIN_ELEMENTS_ACROSS} "
                                      f"= {largest:g} mm")


    def _validate_forming(self):
        from drape.forming.checks import check_forming
        check_forming(self)


@dataclasses.dataclass(frozen=True)
class Job:
    """A loaded job: its config, where it came from, and its material."""

    config: JobConfig
    path: Path
    params: object  # drape.law.parameters.MaterialParameters

    @property
    def name(self) -> str:
        return self.path.stem

    def results_folder(self, override: str | None = None) -> Path:
        if override:
            return Path(override)
        if self.config.output.folder:
            return Path(self.config.output.folder)
        return Path("results") / self.name


def apply_overrides(data: dict, overrides: list[str] | None) -> dict:
    """Set ``table.key=value`` entries (value in TOML syntax; a bare word is a string) in the
    TOML data of a job, e.g. ``mesh.size=2.5``, ``output.xdmf=false``, ``mesh.cell=triangle``."""
    import tomllib

    for text in overrides or []:
        key, sep, raw = text.partition("=")
        names = key.strip().split(".")
        if not sep or not all(n.strip() for n in names):
            raise InputError("not an override", key="--set", value=text,
                             expected="TABLE.KEY=VALUE, e.g. mesh.size=2.5")
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        table = data
        for name in names[:-1]:
            table = table.setdefault(name.strip(), {})
            if not isinstance(table, dict):
                raise InputError("not a table", key="--set", value=text,
                                 expected=f"'{name}' to be a table of the job")
        table[names[-1].strip()] = value
    return data


def _name_override(error: InputError, overrides: list[str] | None) -> InputError:
    """The error, its file followed by the ``--set`` that gave the key its value, if one did."""
    for text in reversed(overrides or []):
        key = ".".join(n.strip() for n in text.partition("=")[0].split("."))
        if error.key and (error.key == key or error.key.startswith((key + ".", key + "["))):
            return InputError(error.problem, source=f"{error.source} with --set {text}",
                              key=error.key, value=error.value, expected=error.expected)
    return error


def load_job(path: str | Path, overrides: list[str] | None = None) -> Job:
    """Read, validate and resolve a job file (material, formulas); raises InputError.
    ``overrides`` are ``table.key=value`` strings applied before validation."""
    from drape.law.parameters import MaterialParameters, load_material
    from drape.fe.loading import Loading

    path = Path(path)
    data = apply_overrides(read_toml(path), overrides)
    try:
        config = from_mapping(JobConfig, data, source=str(path))
    except InputError as error:
        raise _name_override(error, overrides) from None
    if config.material:
        material_path = (path.parent / config.material)
        if not material_path.is_file():
            raise InputError("material file not found", source=str(path), key="material",
                             value=config.material,
                             expected=f"a TOML file relative to {path.parent} "
                                      f"(looked for {material_path})")
        params = load_material(material_path)
    else:
        params = MaterialParameters()
    if config.surfaces is not None:
        try:
            params = params.with_surfaces(config.surfaces)
        except InputError as error:     # a key of the job file, not of the material's
            raise error.located(str(path)) from None
    Loading.from_config(config, source=str(path))   # parses and test-evaluates the formulas
    return Job(config, path, params)


def key_table() -> str:
    """The Markdown table of every job key (for docs/fe-solver.md)."""
    lines = ["| key | type | default | meaning [unit] |", "|---|---|---|---|"]
    for key, kind, default, doc in describe(JobConfig):
        lines.append(f"| `{key}` | {kind} | `{default}` | {doc} |")
    return "\n".join(lines)
