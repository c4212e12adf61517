"""Forming: the rigid tools press the blank (penalty contact with regularised Coulomb friction,
a force-controlled blank holder) while the punch moves down by the stroke; what a forming job
measures (punch force, penetration, draw-in, shear above the locking angle) and writes
(force_stroke.csv/.png, shear maps, summary.json). The method is in ``docs/forming.md``.

A job is a forming job when its config has a ``[process]`` table; its ``[tools]`` table
(default: the hemisphere tools) and ``[contact]`` table (penalty, friction) say the rest. The
blank (rectangle or disc) is centred on the tools' axis in the plane z = 0, where the die's top
face and the holder's lower face are (``tools.*.gap`` = 0).

* The tools and their contact with the blank: :mod:`drape.forming.tool_contact`.
* The blank holder is a rigid tool too, force-controlled (:mod:`drape.forming.holder`): a
  converged step whose measured holder force is off F by more than the tolerance is solved again
  with the holder moved (:func:`~drape.forming.holder.hold_force`), and after every converged
  step the height is corrected by the measured force, as a press's cushion does. Unlike a
  prescribed pressure, a rigid holder keeps the flange from wrinkling under it. A STEP holder is
  force-controlled the same way (``tools.step.holder.control = "force"``, the default): the flat
  face is found on the tools themselves; with ``control = "position"`` it stays where its file
  puts it and its force is measured, not set. A converged step whose holder force is more than
  :data:`~drape.forming.holder.HOLDER_WARNING` off process.holder_force is a warning in the log.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drape.fe.job_part import JobPart
from drape.forming.checks import (fitting_smoothing, holder_mode, squeezed_thickness, stroke_of,
                                  tool_clearance, tool_set)
from drape.forming.holder import (HOLDER_WARNING, HolderControl, hold_force, holder_region,
                                  pinch_region)
from drape.forming.tool_contact import ToolContact, tool_surfaces
from drape.job import compose_title, describe_stack
from drape.job_tables import DEFAULT_FORMING_BENDING

# added to a quasi-static forming run's failure: where the steps shrink as the blank wrinkles
# or snaps into a clearance, inertia carried the runs of docs/forming.md through
INERTIA_HINT = ("; if the steps shrank where the blank wrinkles or is drawn into a narrow "
                "clearance, the blank's inertia may carry it through: set process.areal_density "
                "(kg/m^2, e.g. 1) and process.punch_speed (m/s, e.g. 3); docs/forming.md, "
                "'Inertia'")

#: out-of-plane damping (N/mm^3) of a forming job's first step when its config sets none: that
#: step lifts the blank as meshed off the die to where the smoothed penalty lets go, and the
#: parts with no tool pushing back have no out-of-plane stiffness there (docs/forming.md)
SETTLING_DAMPING = 1e-3


# --- the forming job ------------------------------------------------------------------------------

class Forming(JobPart):
    """Everything a forming job adds to ``drape run``: contributions, measurements, outputs."""

    files = "force_stroke.csv/.png, the shear maps and summary.json"
    finish_on_root = False

    #: a forming blank is meshed centred on the tools' axis
    centres_blank = True
    #: a membrane without bending has no stiffness against wrinkling (docs/forming.md)
    default_bending_rigidity = DEFAULT_FORMING_BENDING

    def __init__(self, job, comm, log=None):
        self.job, self.comm = job, comm
        config = job.config
        self.config = config
        self.process = config.process
        #: a stack of plies (None: one blank); its bottom ply is the job's blank, which the
        #: summary describes (per-ply reports: drape.forming.stack_reports)
        self.stack = config.stack if config.stacked else None
        self.blank = config.blank
        #: the problem carries the blank's inertia when the process gives it an areal density
        self.inertial = self.process.areal_density > 0
        tools, dims = tool_set(config)
        self.kind = tools.kind
        self.stroke = stroke_of(config)
        surfaces, self.tool_description = tool_surfaces(tools, dims, comm)
        self.holder_region = holder_region(config)
        #: "force", "position" or None (:func:`holder_mode`)
        self.holder_mode = holder_mode(config)
        if self.holder_mode is None:
            surfaces = {name: s for name, s in surfaces.items() if name != "holder"}
        params = job.params
        h = config.mesh.size
        contact = config.contact
        self.penalty = contact.penalty_for(params.mu * max(params.K1, params.K2), h)
        self.smoothing = contact.smoothing_for(h)
        self.tool_contact = ToolContact(surfaces, {"punch"}, self.stroke, self.penalty,
                                        {name: contact.friction_for(name)
                                         for name in surfaces},
                                        contact.slip_regularisation,
                                        self.process.contact_cutoff, self.smoothing)
        self.contributions = [self.tool_contact]
        self.cell_fields = {"contact_pressure": self.contact_pressure}
        #: a static run that stops may get further with the blank's inertia
        self.failure_hint = INERTIA_HINT if self.process.areal_density == 0 else ""
        #: force control of the holder (None: no holder, or a position-controlled STEP one)
        self.holder = None
        self._holder_force_controlled = self.holder_mode == "force" and "holder" in surfaces
        #: (step, measured force) of the converged steps off the target by > HOLDER_WARNING
        self.holder_warnings = []
        self.say = log or (lambda *_: None)
        self._describe("holder" in surfaces)
        self._warn_if_squeezed()

    def create_problem(self, job, comm, law, damping: float, centred: bool, options: dict):
        """A stack of two plies or more: its StackProblem (drape.forming.plies); one blank:
        None, the loop's MembraneProblem."""
        if self.stack is None:
            return None
        from drape.forming.plies import create_job_stack_problem
        return create_job_stack_problem(job, comm, law, damping, centred, options)

    def output_fields(self, problem):
        """A stack's XDMF fields: the ply of each cell, each interface's pressure and slips
        (drape.forming.stack_reports.StackFields); None for one blank."""
        if self.stack is None:
            return None
        from drape.forming.stack_reports import StackFields
        return StackFields(problem)

    def _describe(self, has_holder: bool) -> None:
        """The log's line on the tools, the holder, the contact and the inertia."""
        process = self.process
        holder = {"force": f"holder force {process.holder_force:g} N (force-controlled)",
                  "position": "holder position-controlled (where its STEP file puts it; its "
                              "force is measured, process.holder_force is not applied)",
                  None: "no holder"}[self.holder_mode if has_holder else None]
        self.say(f"drape run: {self.tool_description}; stroke {self.stroke:g} mm, {holder}, "
                 f"penalty {self.penalty:.4g} N/mm^3 (smoothed over "
                 f"{self.smoothing:.3g} mm), friction {self._friction_text()}"
                 + (f", inertia {process.areal_density:g} kg/m^2, the punch at "
                    f"{process.punch_speed:g} m/s after {process.punch_ramp:g} mm"
                    if process.areal_density > 0 else ""))

    def _warn_if_squeezed(self) -> None:
        """A stack that needs more room between punch and die than the tools leave is squeezed
        near full stroke, where its force is then the contact penalty's, not the fabric's: say
        so at the start (docs/plies-forming.md)."""
        clearance = tool_clearance(self.config)
        if self.stack is None or clearance is None:
            return
        thicknesses = [ply.thickness for ply in self.stack.plies]
        needed = squeezed_thickness(thicknesses, self.smoothing)
        if needed <= clearance:
            return
        contacts = len(thicknesses) + 1
        fits = fitting_smoothing(thicknesses, clearance)
        smaller = ("" if fits is None else f", and so does a contact.smoothing (g0, now "
                   f"{self.smoothing:.3g} mm) of at most {int(fits * 1000) / 1000:g} mm")
        self.say(f"drape run: warning: where its {len(thicknesses)} plies overlap the stack needs "
                 f"{needed:.3g} mm between punch and die (its outer mid-surfaces "
                 f"{squeezed_thickness(thicknesses, 0.0):.3g} mm apart, and {contacts} contacts "
                 f"each pushing from {self.smoothing:.3g} mm), the tools leave {clearance:g} mm: "
                 f"near full stroke the punch squeezes it, and the punch force and the shear "
                 f"there are the contact penalty's; a wider tools.{self.kind}.clearance (or die "
                 f"opening) gives it room{smaller}")

    def _friction_text(self) -> str:
        """μ for the log: one number, or one per tool where they differ."""
        mu = self.tool_contact.friction
        if len(set(mu.values())) > 1:
            return ", ".join(f"{name} {value:g}" for name, value in mu.items())
        return f"{next(iter(mu.values()), self.config.contact.friction):g}"

    @property
    def title(self) -> str:
        """The config's title followed by what the blank really is (its shape, size, yarns),
        so that a --set of the blank never leaves a title describing another one."""
        if self.stack is not None:
            described = describe_stack(self.stack)
            title = self.config.title
            return title if described in title else ", ".join(p for p in (title, described) if p)
        return compose_title(self.config.title, self.config.blank)

    # --- wiring -----------------------------------------------------------------------------------
    def bind(self, problem, motion=None) -> None:
        """Reference area of each contribution point (mm^2), once the problem exists."""
        import ufl
        from dolfinx import fem
        detJ = fem.Expression(ufl.JacobianDeterminant(problem.mesh), problem.extra_points)
        areas = (np.abs(detJ.eval(problem.cells)).reshape(problem.n_cells, -1)
                 * problem.extra_weights)
        self.problem = problem
        self.areas = areas.ravel()
        self.n_extra = areas.shape[1]
        point_plies = self._bind_plies(problem)
        if self._holder_force_controlled:
            reference = np.column_stack([self.tool_contact.reference_points,
                                         np.zeros(self.areas.size)])
            opening = 0.0
            if self.holder_region is not None:
                under = self.holder_region(reference)
            else:       # STEP tools: the flat faces of holder and die, found on the tools
                surfaces = self.tool_contact.surfaces
                under, opening = pinch_region(surfaces["holder"], surfaces["die"], reference,
                                              self.comm)
            if point_plies is None:
                contacts = 2
            else:       # the holder presses the highest ply it reaches (exposed from above)
                from mpi4py import MPI
                under = under & self.tool_contact.touched["holder"]
                top = self.comm.allreduce(float(self._point_heights[under].max(initial=-1.0)),
                                          op=MPI.MAX)
                if top >= 0.0:      # else no blank under the holder: HolderControl says so
                    at_top = under & (self._point_heights == top)
                    column = self.comm.allreduce(int(self._column_plies[at_top].max(initial=0)),
                                                 op=MPI.MAX)
                    opening, contacts = opening - top, column + 1
            area = self.comm.allreduce(float(self.areas[under].sum()))
            self.holder = HolderControl(self.process.holder_force, area, self.penalty,
                                        self.smoothing, opening, contacts,
                                        trend=self.process.holder_prediction == "trend")
            self.tool_contact.holder_control = self.holder

    def _bind_plies(self, problem):
        """A stack: the die touches every ply where no ply below covers it (the bottom ply,
        and an upper ply where it reaches past those below), the punch and the holder every
        ply where no ply above covers it (the top ply, and a lower one past a partial top
        ply; :class:`drape.forming.exposure.StackExposure`, followed after every converged
        step by :meth:`follow_exposure`), each point seen at its laid-up height
        (:mod:`drape.forming.layup`). Returns each contact point's ply (None for one blank)."""
        from drape.forming.exposure import StackExposure
        from drape.forming.layup import laid_heights
        mesh = problem.blank_mesh
        self.exposure = None
        if getattr(mesh, "n_plies", 1) < 2:
            return None
        point_plies = np.repeat(mesh.cell_plies()[: problem.n_cells], self.n_extra)
        nodes = problem.ply_contact.nodes
        self.exposure = StackExposure(nodes)
        self._point_plies = point_plies
        self._point_heights, self._column_plies = laid_heights(
            nodes.reference[:, :2], nodes.triangles, nodes.triangle_ply, mesh.thicknesses,
            self.tool_contact.reference_points[:, :2], point_plies)
        self.tool_contact.set_plies(self._point_heights, self._exposed(nodes.reference))
        return point_plies

    def _exposed(self, x_nodes) -> dict:
        """{tool: the mask of the points it touches}, the stack's nodes at x_nodes (N, 3) and
        the contact points where the last converged step left them."""
        contact = self.tool_contact
        points = np.column_stack([contact.reference_points, self._point_heights])
        points += contact.committed_u
        from_above, from_below = self.exposure.masks(x_nodes, self._point_plies, points)
        return {name: from_below if name == "die" else from_above for name in contact.surfaces}

    def follow_exposure(self) -> None:
        """A stack, after a converged step: the tools touch the points the plies leave
        exposed where that step left them (plies that draw in past each other's edges
        uncover or cover points). Collective (the displacements are gathered)."""
        if self.exposure is None:
            return
        problem = self.problem
        x_nodes = problem.ply_contact.nodes.reference + problem.gather(problem.u)
        self.tool_contact.set_exposure(self._exposed(x_nodes))

    def set_load(self, t: float) -> None:
        self.tool_contact.set_load(t)

    def predict(self, t: float) -> None:
        """Start Newton from the last two converged steps extrapolated linearly to t, not from
        the last one: the punch has moved on, and the fabric in contact with it with it
        (without this, a step needs 15-25 Newton iterations instead of a handful); the second
        step carries on the first one's downward motion only (below). The first step is damped
        with :data:`SETTLING_DAMPING` unless the config sets a damping.

        With inertia (areal density rho_A > 0) the problem gets the inertial force rho_A u''
        (u'' the acceleration in time: the punch travel s becomes time through
        ``process.punch_time``), with the backward second difference over this step and the
        last, u'' = 2 (u - u*) / (dtau (dtau + dtau')), dtau and dtau' their durations and u*
        the last two steps' motion carried on in time (exact for a motion quadratic in time):
        k = 2 rho_A / (dtau (dtau + dtau')) (1e-9 turns kg/m^2 mm/s^2 into N/mm^2). After the
        first step (which only settles the blank onto the die, and has no inertia) the blank
        starts from rest: u* the last step, dtau' = dtau."""
        p = self.problem
        if self.holder is not None:     # the holder's force target along its trend
            self.holder.predict(t)
            self.set_load(t)
        t1, t0 = p.t_committed, p.t_previous
        first = t1 == 0.0 and p.damping == 0.0
        p.set_damping(SETTLING_DAMPING if first else p.damping)
        plies = getattr(p, "ply_contact", None)
        if plies is not None:   # the slip rate of a rate-dependent ply-ply friction law
            time = self.process.punch_time
            plies.set_step_duration(time(self.stroke * t) - time(self.stroke * t1))
        moving = t0 is not None and t1 > t0
        if moving:
            u1, u0 = p.u_committed.x.array, p.u_previous.x.array
            increment = (t - t1) / (t1 - t0) * (u1 - u0)
            if t0 == 0.0:
                # the first step also lifts the blank (each ply of a stack) onto the smoothed
                # penalty of the die (the ply) below it; carried on, that lift pushes the blank
                # off the die as the punch comes down (on fine meshes Newton fails there and
                # then crawls in small steps) and parts a stack's plies (a singular first
                # matrix): the second step carries on the downward motion only
                increment[2::3] = np.minimum(increment[2::3], 0.0)
            p.set_initial_guess(u1 + increment)
        if not p.inertial:
            return
        from_rest = not moving or t0 == 0.0
        time = self.process.punch_time
        tau1 = time(self.stroke * t1)
        dtau = time(self.stroke * t) - tau1
        dtau_last = dtau if from_rest else tau1 - time(self.stroke * t0)
        k_m = (0.0 if t1 == 0.0 else
               2e-9 * self.process.areal_density / (dtau * (dtau + dtau_last)))
        anchor = p.u_committed.x.array.copy()
        if not from_rest:
            anchor += dtau / dtau_last * (u1 - u0)
        p.set_inertia(k_m, anchor)

    # --- per step ---------------------------------------------------------------------------------
    def resolve(self, t: float, solve, result):
        """The holder's force within its tolerance: :func:`drape.forming.holder.hold_force`."""
        return hold_force(self, t, solve, result)

    def measure(self, record, records: list, force) -> None:
        """A converged step's forming columns: the tools' forces and contact (:meth:`tool_row`),
        the holder's correction and (a stack) the tools' masks for the next step, the punch's
        work (trapezoidal in the stroke), which the record's external work includes (and so
        its regularisation share), and the bending energy's share of it."""
        columns = record.columns
        columns.update(self.tool_row(record.t, converged=record.step > 0))
        self.control_holder(record)
        self.follow_exposure()
        before = (records[-1].columns if records
                  else {"punch_work": 0.0, "punch_force": 0.0, "stroke": 0.0})
        columns["punch_work"] = before["punch_work"] + 0.5 * (
            before["punch_force"] + columns["punch_force"]) * (columns["stroke"] - before["stroke"])
        record.external_work += columns["punch_work"]
        work = abs(record.external_work)
        columns["bending_share"] = record.bending_energy / work if work != 0.0 else 0.0

    def tool_row(self, t: float, converged: bool = True) -> dict:
        """Forces (N), penetration (mm), contact areas (mm^2) at the converged state (collective).

        ``converged`` False (step 0, the flat blank as meshed): every force and area is 0. The
        smoothed penalty pushes from g0 off a tool's surface, so the blank meshed on the die is
        not yet in equilibrium; the first step lifts it by about g0."""
        from mpi4py import MPI
        comm, A = self.comm, self.areas
        row = {"stroke": self.stroke * t}
        penetration = 0.0
        for name, (gap, response) in self.tool_contact.last.items():
            row[f"{name}_force"] = self.tool_force(name) * converged
            row[f"{name}_contact_area"] = comm.allreduce(
                float(A[response.pressure > 0].sum())) * converged
            penetration = max(penetration, float(-gap.min()) if gap.size and converged else 0.0)
        row["max_penetration"] = comm.allreduce(max(penetration, 0.0), op=MPI.MAX)
        if self.holder is not None:
            row["holder_lowering"] = self.holder.lowering()
        return row

    def tool_force(self, name: str) -> float:
        """The force (N) of tool ``name`` on the blank at the last residual evaluation, positive
        in its own direction: punch and holder press down, the die up (collective)."""
        _, response = self.tool_contact.last[name]
        force_z = float(self.comm.allreduce(response.traction.T @ self.areas)[2])
        return force_z if name == "die" else -force_z

    def control_holder(self, record) -> None:
        """After a converged step (not the initial state): correct the holder's height for the
        next step from the force it measured (:class:`HolderControl`)."""
        if self.holder is not None and record.t > 0:
            measured = record.columns["holder_force"]
            self.holder.update(measured, record.t)
            target = self.process.holder_force
            if abs(measured - target) > HOLDER_WARNING * target:
                self.holder_warnings.append((record.step, measured))
                self.say(f"drape run: warning: step {record.step} (stroke "
                         f"{record.columns['stroke']:.4g} mm): the holder force is "
                         f"{measured:.5g} N, {100 * (measured / target - 1):+.1f} % off its "
                         f"target {target:g} N (process.holder_force)")

    def contact_pressure(self) -> np.ndarray:
        """Contact pressure of all tools (N/mm^2, holder included) averaged over each local cell."""
        p = np.zeros(self.areas.size)
        for _, response in self.tool_contact.last.values():
            p += response.pressure
        A = self.areas.reshape(-1, self.n_extra)
        return (p.reshape(-1, self.n_extra) * A).sum(axis=1) / A.sum(axis=1)

    # --- at the end -------------------------------------------------------------------------------
    def finish(self, folder: Path, records: list, seconds: float) -> dict:
        """force_stroke.csv/.png, shear maps, summary.json (collective; rank 0 writes):
        :func:`drape.forming.run_summary.write_reports`."""
        from drape.forming.run_summary import write_reports
        return write_reports(self, folder, records, seconds)
