"""The tables of a job file other than the blank (:mod:`drape.job`): how the blank is meshed,
load-stepped and solved, its regularisation and bending, the named histories and prescribed
boundaries, the results, the picture-frame and bias-extension reports and the forming process.

Each is a frozen dataclass whose fields document the keys (``setting(default, doc, check,
unit)``, :mod:`drape.config`); cross-table rules live in :class:`drape.job.JobConfig`. Lengths
in mm, angles in degrees, forces in N.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

from drape.config import each, in_range, non_negative, positive, setting
from drape.errors import InputError


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
    across the element edges (drape/fe/bending.py). A flat blank has no bending energy."""

    rigidity: float | None = setting(
        None, "bending rigidity B, moment per unit width per unit curvature; unset: 0 for a "
        f"flat job, {DEFAULT_FORMING_BENDING:g} for a forming job (a membrane without bending "
        "has no stiffness against wrinkling: docs/forming.md)", non_negative, "N mm")


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
    holder_prediction: Literal["last", "trend"] = setting(
        "last", "where a step's first attempt puts the force-controlled holder: 'last': where "
        "the last step ended it (corrected by half its force's error); 'trend': carried on "
        "along the last three steps' holder positions, and its first re-solve scaled by the "
        "force's response measured before (fewer holder re-solves where the holder drifts, "
        "docs/forming.md)")
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
