"""The stack of plies of a multi-ply forming job: ``[[plies]]`` and ``[[interfaces]]``.

Each ply has an orientation (its yarn angle, deg), a thickness (mm), an outline (the keys of
today's ``[blank]``: a rectangle, a disc or a polygon, so that a partial ply or a drop-off is a
smaller piece) and optionally its own material file. The plies are listed from the bottom (on
the die) to the top (under the holder); ply k's mid-surface lies (t_k-1 + t_k)/2 above ply
k-1's (:func:`ply_heights`), the bottom ply's at z = 0, where today's blank lies.

Interface k lies between ply k and ply k+1; its friction coefficient may depend on the contact
pressure p (N/mm²) and the slip rate v (mm/s) (:class:`InterfaceConfig`). Without any
``[[interfaces]]`` every adjacent pair gets the defaults.

:func:`single_ply_stack` maps today's ``[blank]`` onto a stack of one ply whose
:meth:`PlyConfig.blank` is that blank again (docs/plies.md).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from drape.config import from_mapping, in_range, non_negative, positive, setting
from drape.errors import InputError

#: Default ply-ply friction coefficient: dry woven fabric on fabric, measured at about 0.2-0.3
#: like fabric on metal (docs/plies.md, "Interfaces"); set it from a measurement.
DEFAULT_PLY_FRICTION = 0.2

#: the outline keys a ply shares with today's [blank] table
OUTLINE_KEYS = ("shape", "length", "width", "radius", "points")


@dataclasses.dataclass(frozen=True)
class PlyConfig:
    """One ply (a ``[[plies]]`` table): orientation, thickness, outline and material."""

    thickness: float = setting(None, "the ply's thickness (its mid-surface lies half of it "
                               "above its bottom)", positive, "mm")
    orientation: float = setting(0.0, "the ply's yarn angle: from x to its warp yarns, from "
                                 "-90 to 90 (as blank.yarn_angle)", in_range(-90.0, 90.0), "deg")
    shape: Literal["rectangle", "disc", "polygon"] = setting("rectangle", "outline of the ply "
                                                             "(as blank.shape)")
    length: float = setting(100.0, "rectangle: extent along x", positive, "mm")
    width: float = setting(100.0, "rectangle: extent along y", positive, "mm")
    radius: float = setting(50.0, "disc: radius", positive, "mm")
    points: tuple[tuple[float, ...], ...] = setting(
        (), "polygon: its vertices in order, [[x0, y0], [x1, y1], ...]", unit="mm")
    material: str = setting("", "material TOML file of this ply, relative to the job file "
                            "(default: the job's material)")

    def validate(self):
        if self.thickness is None:
            raise InputError("required key is missing", key="thickness",
                             expected="the ply's thickness in mm, a number > 0")
        self.blank()

    def blank(self):
        """The ply's outline and orientation as today's ``[blank]`` table (a BlankConfig, with
        its checks: a polygon's errors name ``points``)."""
        from drape.job import BlankConfig
        blank = BlankConfig(**{key: getattr(self, key) for key in OUTLINE_KEYS},
                            yarn_angle=self.orientation)
        blank.validate()
        return blank


@dataclasses.dataclass(frozen=True)
class InterfaceConfig:
    """The contact between two adjacent plies (an ``[[interfaces]]`` table): the friction
    coefficient

        mu(p, v) = friction * (1 + p / reference_pressure)^(-pressure_exponent)
                            * (1 + v / reference_slip_rate)^rate_exponent,

    p the contact pressure (N/mm² = MPa) and v the slip rate (mm/s). Both exponents 0 (the
    default) give Coulomb's constant mu; a positive pressure exponent lowers mu as the plies
    are pressed harder, a positive rate exponent raises it as they slide faster (docs/plies.md,
    "Interfaces"). The normal penalty, its smoothing and the stick zone are the tools'
    (``[contact]``)."""

    friction: float = setting(DEFAULT_PLY_FRICTION, "friction coefficient mu_0 between the two "
                              "plies at zero pressure and zero slip rate", non_negative)
    reference_pressure: float = setting(1.0, "p_ref of mu's pressure dependence", positive,
                                        "N/mm^2")
    pressure_exponent: float = setting(0.0, "a in (1 + p/p_ref)^-a (0: no pressure dependence)",
                                       non_negative)
    reference_slip_rate: float = setting(1.0, "v_ref of mu's slip-rate dependence", positive,
                                         "mm/s")
    rate_exponent: float = setting(0.0, "b in (1 + v/v_ref)^b (0: no slip-rate dependence)",
                                   non_negative)

    @property
    def rate_dependent(self) -> bool:
        return self.rate_exponent > 0.0


@dataclasses.dataclass(frozen=True)
class StackConfig:
    """The plies, bottom (on the die) to top (under the holder), and the interfaces between
    adjacent plies (interface k between ply k and ply k+1)."""

    plies: tuple[PlyConfig, ...] = setting((), "the plies, from the bottom (on the die) to the "
                                           "top (under the holder) ([[plies]])")
    interfaces: tuple[InterfaceConfig, ...] = setting(
        (), "the ply-ply interfaces, the first between plies 0 and 1 ([[interfaces]]; none: "
        "every pair gets the defaults)")

    def validate(self):
        if not self.plies:
            raise InputError("no ply", key="plies",
                             expected="at least one [[plies]] table (thickness, orientation, "
                                      "outline)")
        pairs = len(self.plies) - 1
        if self.interfaces and len(self.interfaces) != pairs:
            raise InputError(f"{len(self.interfaces)} interface(s) for {len(self.plies)} plies",
                             key="interfaces",
                             expected=f"{pairs} [[interfaces]] tables (one per adjacent pair, "
                                      "bottom first), or none for the defaults")

    def interface_list(self) -> tuple[InterfaceConfig, ...]:
        """One interface per adjacent pair: the given ones, or the defaults."""
        if self.interfaces:
            return self.interfaces
        return tuple(InterfaceConfig() for _ in range(len(self.plies) - 1))

    def heights(self) -> tuple[float, ...]:
        return ply_heights([ply.thickness for ply in self.plies])


def ply_heights(thicknesses) -> tuple[float, ...]:
    """The height (mm) of each ply's mid-surface: 0 for the bottom ply, then (t_k-1 + t_k)/2
    more for each ply above, so that adjacent plies just touch."""
    heights = [0.0]
    for below, above in zip(thicknesses[:-1], thicknesses[1:]):
        heights.append(heights[-1] + 0.5 * (below + above))
    return tuple(heights)


def load_stack(data: dict, source: str | None = None) -> StackConfig:
    """The stack of a job's TOML data (its ``plies`` and ``interfaces`` arrays of tables)."""
    tables = {key: data[key] for key in ("plies", "interfaces") if key in data}
    return from_mapping(StackConfig, tables, source=source)


def single_ply_stack(blank, thickness: float, material: str = "") -> StackConfig:
    """Today's single-blank job as a stack of one ply: the blank's outline and yarn angle, the
    given thickness (mm; a single ply touches no other, so it enters nothing yet)."""
    outline = {key: getattr(blank, key) for key in OUTLINE_KEYS}
    ply = PlyConfig(**outline, orientation=blank.yarn_angle, thickness=float(thickness),
                    material=material)
    stack = StackConfig(plies=(ply,))
    ply.validate()
    stack.validate()
    return stack


def ply_materials(stack: StackConfig, job_params, job_dir, surfaces: int | None = None) -> list:
    """The MaterialParameters of every ply, bottom first: its ``material`` file (relative to
    ``job_dir``, the job file's folder), else the job's (``job_params``). ``surfaces``: the
    job's ``surfaces`` (inner surfaces kept), applied to the plies' own files as to the job's
    material. A file several plies name is read once (the plies share its parameters)."""
    from pathlib import Path

    from drape.law.parameters import load_material
    read = {}
    out = []
    for k, ply in enumerate(stack.plies):
        if not ply.material:
            out.append(job_params)
            continue
        path = Path(job_dir) / ply.material
        if path not in read:
            if not path.is_file():
                raise InputError("material file not found", key=f"plies[{k}].material",
                                 value=ply.material,
                                 expected=f"a TOML file relative to {Path(job_dir)} "
                                          f"(looked for {path})")
            read[path] = load_material(path, surfaces, surfaces_key="surfaces")
        out.append(read[path])
    return out


def create_job_stack_problem(job, comm, law, damping: float, centred: bool, options: dict):
    """The StackProblem of a job with two or more ``[[plies]]`` (drape.fe.stack_problem): each
    ply's law from its material file (drape.forming.plies.ply_materials) when one sets it,
    else the job's ``law``; the ply-ply contact's penalty from ``[contact]``."""
    from drape.fe.stack_problem import create_stack_problem
    from drape.law.nested_surface import NestedSurfaceLaw
    config = job.config
    stack = config.stack
    if any(ply.material for ply in stack.plies):
        materials = ply_materials(stack, job.params, job.path.parent, config.surfaces)
        options = dict(options, ply_laws=[NestedSurfaceLaw(params) for params in materials])
    return create_stack_problem(comm, stack, config.mesh, config.contact, law, damping,
                                centred=centred, **options)
