"""Forming: the rigid tools press the blank (penalty contact with regularised Coulomb friction,
a force-controlled blank holder) while the punch moves down by the stroke; what a forming job
measures (punch force, penetration, draw-in, shear above the locking angle) and writes
(force_stroke.csv/.png, shear maps, summary.json). The method is in ``docs/forming.md``.

A job is a forming job when its config has a ``[process]`` table; its ``[tools]`` table
(default: the hemisphere tools) and ``[contact]`` table (penalty, friction) say the rest. The
blank (rectangle or disc) is centred on the tools' axis in the plane z = 0, where the die's top
face and the holder's lower face are (``tools.*.gap`` = 0).

* The punch and the die are rigid surfaces (:mod:`drape.tools`: exact for the hemisphere's
  surfaces of revolution, an exact closest point on the gmsh triangulation otherwise) queried at
  the membrane's quadrature points from their current positions; :func:`drape.contact.traction`
  gives traction and tangent. The punch moves by (0, 0, -stroke * t).
* The blank holder is force-controlled: its total force F (N) is a uniform pressure
  p = F / A on the part of the blank under the holder's flat face (area A, reference), pushing
  it onto the die, with the same friction law (:func:`drape.contact.pressure_traction`). The
  part under the holder is decided from the positions of the last converged step (so p is
  constant within a load step). A membrane has no thickness: the holder's position is the die's
  top face, and a force-controlled holder is exactly this pressure. STEP tool sets have no
  known flat face: their holder is a rigid surface in contact like the die.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from drape.contact import pressure_traction, traction
from drape.errors import InputError
from drape.membrane import PointContribution

FORCE_STROKE_FILE = "force_stroke.csv"
SUMMARY_FILE = "summary.json"
#: fabric counted as under the holder only when it lies on the die's top face (within this, mm)
ON_DIE_TOLERANCE = 1.0


# --- validation of a forming job -------------------------------------------------------------------

def tool_set(config):
    """The chosen tool dimensions ([tools.hemisphere], [tools.double_dome] or [tools.step])."""
    from drape.geometry.tools import ToolsConfig
    tools = config.tools or ToolsConfig()
    return tools, {"hemisphere": tools.hemisphere, "double_dome": tools.double_dome,
                   "step": tools.step}[tools.kind]


def full_stroke(config) -> float | None:
    tools, dims = tool_set(config)
    return None if tools.kind == "step" else dims.full_stroke


def stroke_of(config) -> float:
    stroke = config.process.stroke
    return stroke if stroke is not None else full_stroke(config)


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
    return blank.length / 2.0, blank.width / 2.0


def check_forming(config) -> None:
    """Cross-checks of a forming job (InputError naming the key): stroke within the tools, blank
    on the die and over its opening, mesh fine enough for the tools' fillets."""
    tools, dims = tool_set(config)
    process = config.process
    limit = full_stroke(config)
    if tools.kind == "step" and process.stroke is None:
        raise InputError("STEP tools have no known full stroke", key="process.stroke",
                         expected="the punch travel in mm")
    if limit is not None and process.stroke is not None and process.stroke > limit + 1e-9:
        raise InputError("the stroke is larger than the tools allow", key="process.stroke",
                         value=process.stroke,
                         expected=f"<= {limit:g} mm, the full stroke of these {tools.kind} tools "
                                  "(the punch would hit the die)")
    hx, hy = blank_half_extents(config.blank)
    reach = math.hypot(hx, hy) if config.blank.shape == "rectangle" else hx
    key = "blank.radius" if config.blank.shape == "disc" else "blank.length"
    if tools.kind == "hemisphere":
        opening = dims.die_opening_radius + dims.die_fillet_radius
        if min(hx, hy) <= opening:
            raise InputError("the blank does not cover the die opening", key=key,
                             value=2 * min(hx, hy) if config.blank.shape == "rectangle" else hx,
                             expected=f"a blank reaching beyond r = {opening:g} mm all round")
        if reach > dims.die_outer_radius:
            raise InputError("the blank reaches beyond the die", key=key,
                             value=getattr(config.blank, key.split(".")[1]),
                             expected=f"a blank within r = {dims.die_outer_radius:g} mm, corners "
                                      f"included (they are at r = {reach:.4g} mm)")
    elif tools.kind == "double_dome":
        opening_x = dims.dome_offset + dims.punch_width / 2 + dims.clearance + dims.die_entry_radius
        opening_y = dims.punch_width / 2 + dims.clearance + dims.die_entry_radius
        if hx <= opening_x or hy <= opening_y:
            raise InputError("the blank does not cover the die cavity", key=key,
                             value=(2 * hx, 2 * hy),
                             expected=f"length > {2 * opening_x:g} and width > {2 * opening_y:g} mm")
        if hx > dims.die_length / 2 or hy > dims.die_width / 2:
            raise InputError("the blank reaches beyond the die", key=key, value=(2 * hx, 2 * hy),
                             expected=f"length <= {dims.die_length:g} and width <= "
                                      f"{dims.die_width:g} mm")
    radius = smallest_wrapped_radius(config)
    if radius is not None:
        largest = math.pi / 4 * radius
        if config.mesh.size > largest:
            raise InputError("the mesh is too coarse for the tools", key="mesh.size",
                             value=config.mesh.size,
                             expected=f"<= {largest:.3g} mm: two elements over the quarter arc "
                                      f"of the smallest fillet the fabric wraps (R = {radius:g} mm)")


# --- the holder's region ---------------------------------------------------------------------------

def holder_region(config):
    """A function (P, 3) positions -> mask of the points under the holder's flat face, or None
    (STEP tools: the holder is a rigid surface)."""
    tools, dims = tool_set(config)
    if tools.kind == "hemisphere":
        inner = dims.holder_inner_radius + dims.holder_fillet_radius
        outer = dims.holder_outer_radius

        def region(x):
            r = np.hypot(x[:, 0], x[:, 1])
            return (r >= inner) & (r <= outer) & (x[:, 2] > -dims.gap - ON_DIE_TOLERANCE)
        return region
    if tools.kind == "double_dome":
        a = dims.dome_offset
        opening = dims.holder_opening_radius + dims.holder_edge_radius

        def region(x):
            d = np.hypot(x[:, 0] - np.clip(x[:, 0], -a, a), x[:, 1])
            return ((d >= opening) & (np.abs(x[:, 0]) <= dims.die_length / 2)
                    & (np.abs(x[:, 1]) <= dims.die_width / 2)
                    & (x[:, 2] > -dims.gap - ON_DIE_TOLERANCE))
        return region
    return None


# --- point contributions ---------------------------------------------------------------------------

class ToolContact(PointContribution):
    """Rigid tools in penalty contact with friction; the tools named in ``moving`` translate by
    (0, 0, -stroke(t))."""

    name = "tools"

    def __init__(self, surfaces: dict, moving: set, stroke: float, penalty: float,
                 friction: float, regularisation: float, cutoff: float):
        self.surfaces = surfaces
        self.moving = set(moving)
        self.stroke = float(stroke)
        self.penalty, self.friction, self.regularisation = penalty, friction, regularisation
        self.cutoff = cutoff
        self.offsets = {name: np.zeros(3) for name in surfaces}
        self.committed_offsets = dict(self.offsets)
        self.last = {}

    def setup(self, reference_points):
        super().setup(reference_points)
        self.committed_u = np.zeros((len(reference_points), 3))
        self._u = self.committed_u

    def set_load(self, t: float) -> None:
        for name in self.surfaces:
            self.offsets[name] = np.array([0.0, 0.0, -self.stroke * t]) if name in self.moving \
                else np.zeros(3)

    def evaluate(self, positions, displacements):
        f = np.zeros_like(positions)
        K = np.zeros(positions.shape + (3,))
        self.last = {}
        for name, surface in self.surfaces.items():
            offset = self.offsets[name]
            query = surface.query(positions, offset, cutoff=self.cutoff)
            slip = displacements - self.committed_u - (offset - self.committed_offsets[name])
            response = traction(query.gap, query.normal, slip, self.penalty, self.friction,
                                self.regularisation, touching_is_active=True)
            f += response.traction
            K -= response.tangent
            self.last[name] = (query.gap, response)
        self._u = displacements
        return f, K

    def commit(self) -> None:
        self.committed_u = np.array(self._u, copy=True)
        self.committed_offsets = {k: v.copy() for k, v in self.offsets.items()}

    def state(self) -> dict:
        return {"committed_u": self.committed_u,
                **{f"offset_{k}": v for k, v in self.committed_offsets.items()}}

    def load_state(self, state: dict) -> None:
        self.committed_u = np.array(state["committed_u"], copy=True)
        self._u = self.committed_u
        for k in self.committed_offsets:
            self.committed_offsets[k] = np.array(state[f"offset_{k}"], copy=True)


class HolderPressure(PointContribution):
    """The force-controlled blank holder: pressure F / A pushing down (-z) on the points under
    its flat face (decided at the last converged step), with regularised Coulomb friction
    against the fixed holder."""

    name = "holder"
    NORMAL = np.array([0.0, 0.0, -1.0])

    def __init__(self, region, force: float, friction: float, regularisation: float):
        self.region, self.force = region, float(force)
        self.friction, self.regularisation = friction, regularisation
        self.areas = None       # reference area per point (mm^2), set by Forming.bind
        self.comm = None
        self.last = None

    def setup(self, reference_points):
        super().setup(reference_points)
        n = len(reference_points)
        self.committed_u = np.zeros((n, 3))
        self._u = self.committed_u
        self._x = np.column_stack([reference_points, np.zeros(n)])
        self.mask = None

    def _update_pressure(self) -> None:
        self.mask = self.region(self._x)
        area = self.comm.allreduce(float(self.areas[self.mask].sum()))
        self.area = area
        self.pressure = self.force / area if area > 0 else 0.0

    def evaluate(self, positions, displacements):
        if self.mask is None:
            self._update_pressure()
        n = len(positions)
        p = np.where(self.mask, self.pressure, 0.0)
        slip = displacements - self.committed_u
        response = pressure_traction(p, np.broadcast_to(self.NORMAL, (n, 3)), slip,
                                     self.friction, self.regularisation)
        self._u, self._x_trial = displacements, positions
        self.last = response
        return response.traction, -response.tangent

    def commit(self) -> None:
        self.committed_u = np.array(self._u, copy=True)
        self._x = np.array(self._x_trial, copy=True)
        self._update_pressure()

    def state(self) -> dict:
        return {"committed_u": self.committed_u, "x": self._x}

    def load_state(self, state: dict) -> None:
        self.committed_u = np.array(state["committed_u"], copy=True)
        self._u = self.committed_u
        self._x = np.array(state["x"], copy=True)
        self._update_pressure()


# --- the forming job -------------------------------------------------------------------------------

class Forming:
    """Everything a forming job adds to ``drape run``: contributions, measurements, outputs."""

    def __init__(self, job, comm, log=None):
        from drape.geometry.tools import analytic_tools, build_tools
        from drape.tools import MeshedSurface

        self.job, self.comm = job, comm
        config = job.config
        self.config = config
        self.process = config.process
        tools, dims = tool_set(config)
        self.kind = tools.kind
        self.stroke = stroke_of(config)
        say = log or (lambda *_: None)
        if tools.kind == "hemisphere":
            surfaces = analytic_tools(dims)
            self.tool_description = "hemisphere tools (exact surfaces of revolution)"
        else:
            started = time.perf_counter()
            meshed = build_tools(tools, comm=comm)
            surfaces = {name: MeshedSurface(surface) for name, surface in meshed.items()}
            self.tool_description = (f"{tools.kind} tools meshed by gmsh (" + ", ".join(
                f"{name} {s.n_triangles} triangles" for name, s in surfaces.items())
                + f", {time.perf_counter() - started:.1f} s)")
        region = holder_region(config)
        contact_tools = {name: s for name, s in surfaces.items()
                         if name != "holder" or region is None}
        params = job.params
        h = config.mesh.size
        contact = config.contact
        self.penalty = contact.penalty_for(params.mu * max(params.K1, params.K2), h)
        self.tool_contact = ToolContact(contact_tools, {"punch"}, self.stroke, self.penalty,
                                        contact.friction, contact.slip_regularisation,
                                        self.process.contact_cutoff)
        self.contributions = [self.tool_contact]
        self.holder = None
        if region is not None and self.process.holder_force > 0:
            self.holder = HolderPressure(region, self.process.holder_force, contact.friction,
                                         contact.slip_regularisation)
            self.contributions.append(self.holder)
        self.force_rows = []
        say(f"drape run: {self.tool_description}; stroke {self.stroke:g} mm, holder force "
            f"{self.process.holder_force:g} N, penalty {self.penalty:.4g} N/mm^3, friction "
            f"{contact.friction:g}")

    # --- wiring ---------------------------------------------------------------------------------------
    def bind(self, problem) -> None:
        """Reference area of each contribution point (mm^2), once the problem exists."""
        import ufl
        from dolfinx import fem
        detJ = fem.Expression(ufl.JacobianDeterminant(problem.mesh), problem.extra_points)
        areas = np.abs(detJ.eval(problem.cells)).reshape(problem.n_cells, -1) * problem.extra_weights
        self.problem = problem
        self._committed = []
        self.areas = areas.ravel()
        self.n_extra = areas.shape[1]
        if self.holder is not None:
            self.holder.areas, self.holder.comm = self.areas, self.comm

    def set_load(self, t: float) -> None:
        self.tool_contact.set_load(t)

    def predict(self, t: float) -> None:
        """Start Newton from the last two converged steps extrapolated linearly to t, not from
        the last one: the punch has moved on, and the fabric in contact with it with it
        (without this, a step needs 15-25 Newton iterations instead of a handful)."""
        if len(self._committed) < 2:
            return
        (t0, u0), (t1, u1) = self._committed[-2:]
        if t1 <= t0:
            return
        u = self.problem.u
        u.x.array[:] = u1 + (t - t1) / (t1 - t0) * (u1 - u0)

    def committed(self, t: float) -> None:
        """Remember the converged displacement at load factor t (for :meth:`predict`)."""
        self._committed = (self._committed + [(t, self.problem.u.x.array.copy())])[-2:]

    # --- per step ---------------------------------------------------------------------------------------
    def measure(self, t: float) -> dict:
        """Forces (N), penetration (mm), contact areas (mm^2) at the converged state (collective)."""
        from mpi4py import MPI
        comm, A = self.comm, self.areas
        row = {"stroke": self.stroke * t}
        penetration = 0.0
        for name, (gap, response) in self.tool_contact.last.items():
            force = response.traction.T @ A
            force = comm.allreduce(force)
            row[f"{name}_force"] = -force[2] if name == "punch" else force[2]
            row[f"{name}_contact_area"] = comm.allreduce(float(A[gap < 0].sum()))
            penetration = max(penetration, float(-gap.min()) if gap.size else 0.0)
        if self.holder is not None and self.holder.last is not None:
            row["holder_force"] = -comm.allreduce(float(self.holder.last.traction[:, 2] @ A))
            row["holder_area"] = self.holder.area
        row["max_penetration"] = comm.allreduce(max(penetration, 0.0), op=MPI.MAX)
        self.force_rows.append(row)
        return row

    def contact_pressure(self) -> np.ndarray:
        """Contact pressure of all tools (N/mm^2, holder included) averaged over each local cell."""
        p = np.zeros(self.areas.size)
        for _, response in self.tool_contact.last.values():
            p += response.pressure
        if self.holder is not None and self.holder.last is not None:
            p += self.holder.last.pressure
        A = self.areas.reshape(-1, self.n_extra)
        return (p.reshape(-1, self.n_extra) * A).sum(axis=1) / A.sum(axis=1)

    # --- at the end ---------------------------------------------------------------------------------------
    def finish(self, folder: Path, rows: list, seconds: float) -> dict:
        """force_stroke.csv/.png, shear maps, summary.json (collective; rank 0 writes)."""
        from drape import forming_output
        problem = self.problem
        locking = self.process.locking_angle
        cells = forming_output.gather_cells(problem)
        summary = forming_output.shear_summary(problem, locking, self.comm)
        summary.update(forming_output.draw_in(problem, self.config.blank, self.comm))
        if self.comm.rank == 0:
            forces = [r.get("punch_force", 0.0) for r in rows]
            summary.update({
                "title": self.config.title, "tools": self.kind,
                "yarn_angle_deg": self.config.blank.yarn_angle,
                "stroke_mm": rows[-1].get("stroke", 0.0), "full_stroke_mm": self.stroke,
                "max_punch_force_N": float(max(forces)),
                "punch_force_at_end_N": float(forces[-1]),
                "holder_force_N": self.process.holder_force,
                "max_penetration_mm": float(max(r.get("max_penetration", 0.0) for r in rows)),
                "penalty_N_per_mm3": self.penalty,
                "regularisation_share": rows[-1].get("regularisation_share", 0.0),
                "steps": rows[-1]["step"], "newton_iterations": int(sum(
                    r.get("newton_iterations", 0) for r in rows)),
                "cutbacks": int(sum(r.get("cutbacks", 0) for r in rows)),
                "wall_time_s": seconds, "ranks": self.comm.size,
            })
            folder = Path(folder)
            forming_output.write_force_stroke(folder, rows)
            forming_output.plot_force_stroke(folder, rows, self.config.title)
            forming_output.plot_shear_maps(folder, cells, locking, self.config.title)
            with (folder / SUMMARY_FILE).open("w") as stream:
                json.dump(summary, stream, indent=2)
                stream.write("\n")
        return summary
