"""The job configuration of ``drape run``: a TOML file read into frozen dataclasses.

The blank's table and the job as a whole are here, the other tables in :mod:`drape.job_tables`.
Every table and key is documented by its field (``setting(default, doc, check, unit)``); the
table of keys in ``docs/fe-solver.md`` is generated from these fields (:func:`key_table`).
Loading checks types, unknown keys, ranges, cross-field rules and the boundary formulas, and
raises :class:`~drape.errors.InputError` naming the file and key. Lengths in mm, angles in
degrees, forces in N.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from pathlib import Path
from typing import Literal

import numpy as np

from drape.config import (describe, from_mapping, in_range, non_negative, positive,
                          read_toml, setting)
from drape.forming.contact import ContactParameters
from drape.errors import InputError
from drape.forming.plies import InterfaceConfig, PlyConfig, StackConfig, single_ply_stack
from drape.geometry.tools import ToolsConfig
from drape.job_tables import (BendingConfig, BiasExtensionConfig, BoundaryConfig,
                               HistoryConfig, MeshConfig, OutputConfig, PictureFrameConfig,
                               ProcessConfig, RegularisationConfig, SolverConfig, StepsConfig)

#: boundary names of each blank shape (gmsh physical groups); "boundary" is the whole edge
BOUNDARY_NAMES = {"rectangle": ("left", "right", "bottom", "top"), "disc": ("edge",),
                  "polygon": ("edge",)}
WHOLE_BOUNDARY = "boundary"
#: the thickness (mm) of a job's only ply when it has no [[plies]] (unused: one ply touches no
#: other)
SINGLE_PLY_THICKNESS = 1.0
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


def describe_stack(stack) -> str:
    """A stack of plies in a few words: the orientations from the bottom and the bottom ply."""
    angles = "/".join(f"{ply.orientation:g}" for ply in stack.plies)
    return (f"{len(stack.plies)} plies at {angles} deg from the bottom, the bottom one a "
            + describe_blank(stack.plies[0].blank()).split(", yarns")[0])


def compose_title(title: str, blank) -> str:
    """The config's title followed by what the blank really is, so that a --set of the blank
    never leaves a title describing another one; a title that already says it is kept."""
    described = describe_blank(blank)
    return title if described in title else ", ".join(p for p in (title, described) if p)


def _ply_error(k: int, error: InputError, problem: str = "", expected: str = ""):
    """A ply's blank error (``error``, naming ``blank.*``) as the stack's: naming plies[k]."""
    key = error.key or ""
    if key.startswith("blank."):
        key = f"plies[{k}]." + key.removeprefix("blank.").replace("yarn_angle", "orientation")
    return InputError(f"{error.problem} (ply {k}){problem}", key=key, value=error.value,
                      expected=f"{error.expected}{expected}")


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
    plies: tuple[PlyConfig, ...] = setting(
        (), "a stack of plies instead of [blank], from the bottom (on the die) to the top "
        "(under the holder) ([[plies]], docs/plies.md; a forming job)")
    interfaces: tuple[InterfaceConfig, ...] = setting(
        (), "the ply-ply interfaces, the first between plies 0 and 1 ([[interfaces]]; none: "
        "every pair gets the defaults)")

    @property
    def stack(self) -> StackConfig:
        """The plies of the job: its ``[[plies]]``, else ``[blank]`` as a stack of one ply."""
        if self.plies:
            return StackConfig(plies=self.plies, interfaces=self.interfaces)
        # a single ply touches no other ply: its thickness enters nothing
        return single_ply_stack(self.blank, SINGLE_PLY_THICKNESS, self.material)

    @property
    def stacked(self) -> bool:
        """The job forms a stack of two or more plies (a StackProblem, ply-ply contact)."""
        return len(self.plies) > 1

    def validate(self):
        if self.plies or self.interfaces:
            self._validate_stack()
            return
        self._validate_blank_job()

    def _validate_stack(self):
        """``[[plies]]``: a forming job without boundaries; each ply checked as a blank is
        (mesh size, the tools), its errors naming ``plies[k]``."""
        StackConfig(plies=self.plies, interfaces=self.interfaces).validate()
        if self.process is None:
            raise InputError("a stack of plies without a [process] table", key="plies",
                             expected="a forming job: a [process] table (stroke, holder_force) "
                                      "with the [[plies]]")
        if self.boundary:
            raise InputError("prescribed displacements on a stack of plies", key="boundary",
                             expected="no [[boundary]] tables with [[plies]] (the tools hold "
                                      "the stack)")
        # a ply may stop short of the die's opening (a patch, a drop-off: it rests on the
        # plies that span it), but one ply at least must span it
        from drape.forming.checks import COVER_PROBLEM
        uncovered = []
        for k, ply in enumerate(self.plies):
            alone = dataclasses.replace(self, blank=ply.blank(), plies=(), interfaces=())
            try:
                alone._validate_blank_job()
            except InputError as error:
                if not error.problem.startswith(COVER_PROBLEM):
                    raise _ply_error(k, error) from None
                uncovered.append((k, error))
                try:                            # the checks after the cover's
                    alone._validate_blank_job(cover=False)
                except InputError as other:
                    raise _ply_error(k, other) from None
        if len(uncovered) == len(self.plies):
            k, error = uncovered[0]
            raise _ply_error(k, error, " and no other ply does",
                             " (one ply at least: the others may be partial)") from None

    def _validate_blank_job(self, cover: bool = True):
        from drape.fe.loading import CONSTANTS, FUNCTIONS, VARIABLES
        reserved = set(VARIABLES) | set(CONSTANTS) | set(FUNCTIONS)
        for name in self.history:
            if not name.isidentifier() or name in reserved:
                raise InputError("not a usable history name", key=f"history.{name}", value=name,
                                 expected="an identifier other than " + ", ".join(sorted(reserved)))
        if self.process is not None:
            self._validate_forming(cover)
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


    def _validate_forming(self, cover: bool = True):
        from drape.forming.checks import check_forming
        check_forming(self, cover=cover)


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


def override_key(text: str) -> str:
    """The dotted key of a ``table.key=value`` override, its names stripped of spaces."""
    return ".".join(n.strip() for n in text.partition("=")[0].split("."))


def _name_override(error: InputError, overrides: list[str] | None) -> InputError:
    """The error, its file followed by the ``--set`` that gave the key its value, if one did."""
    for text in reversed(overrides or []):
        key = override_key(text)
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
    if "plies" in data and "blank" in data:
        table = data["blank"] if isinstance(data["blank"], dict) and data["blank"] else None
        first = next(iter(table)) if table else None    # the key named: its --set, if one
        shown = {"key": f"blank.{first}", "value": table[first]} if table else {"key": "blank"}
        error = InputError("both a [blank] table and [[plies]]", source=str(path), **shown,
                           expected="either [blank] (one ply) or [[plies]] (a stack: each "
                                    "ply's outline and orientation in its own table), not both")
        raise _name_override(error, overrides)
    try:
        config = from_mapping(JobConfig, data, source=str(path))
    except InputError as error:
        raise _name_override(error, overrides) from None
    if config.plies:    # the bottom ply is the job's blank (meshed as such for one ply)
        config = dataclasses.replace(config, blank=config.plies[0].blank())
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


#: arrays of tables whose keys are listed on their own page: one line each in key_table()
TABLES_DOCUMENTED_ELSEWHERE = {
    "plies": "a stack of plies instead of [blank], bottom first: keys in docs/plies.md",
    "interfaces": "the ply-ply interfaces, bottom first: keys in docs/plies.md"}


def _first_key(table: str) -> str:
    """The first key of a JobConfig array of tables (``plies`` -> ``thickness``)."""
    hints = typing.get_type_hints(JobConfig)
    return dataclasses.fields(typing.get_args(hints[table])[0])[0].name


def key_table() -> str:
    """The Markdown table of every job key (for docs/fe-solver.md)."""
    lines = ["| key | type | default | meaning [unit] |", "|---|---|---|---|"]
    for key, kind, default, doc in describe(JobConfig):
        table = key.partition("[]")[0]
        if table in TABLES_DOCUMENTED_ELSEWHERE:
            if key.endswith("[]." + _first_key(table)):
                lines.append(f"| `[[{table}]]` | tables | | {TABLES_DOCUMENTED_ELSEWHERE[table]} |")
            continue
        lines.append(f"| `{key}` | {kind} | `{default}` | {doc} |")
    return "\n".join(lines)
