"""The rigid tools of a forming job as a point contribution to the membrane problem: their
surfaces built from the config (:func:`tool_surfaces`), and :class:`ToolContact`, the penalty
contact with regularised Coulomb friction (with memory) at the membrane's quadrature points.

The punch and the die are rigid surfaces (exact for the hemisphere's surfaces of revolution,
:mod:`drape.forming.surfaces`, and for the double dome's rolling-ball constructions,
:mod:`drape.forming.double_dome`; an exact closest point on the gmsh triangulation of STEP
tools) queried at the quadrature points from their current positions;
:func:`drape.forming.contact.traction` gives traction and tangent. The punch moves by
(0, 0, -stroke * t); the holder by what its :class:`drape.forming.holder.HolderControl` says.
"""

from __future__ import annotations

import time

import numpy as np

from drape.fe.membrane import PointContribution
from drape.forming.contact import elastic_slip, traction

#: meshed (STEP) tools: the candidate lists' margin (mm, drape.forming.surfaces.MeshedSurface): a
#: point is
#: searched again once it has moved this far (in the tool's frame) since its last search
TOOL_LIST_MARGIN = 0.5


def tool_surfaces(tools, dims, comm) -> tuple[dict, str]:
    """The tools' surfaces {name: surface with ``query``} of the config's ``[tools]`` (``tools``
    and its dimensions ``dims``: drape.forming.checks.tool_set), and a line describing them."""
    from drape.forming.surfaces import MeshedSurface
    from drape.geometry.tools import analytic_double_dome_tools, analytic_tools, build_tools
    if tools.kind == "hemisphere":
        return analytic_tools(dims), "hemisphere tools (exact surfaces of revolution)"
    if tools.kind == "double_dome":
        return (analytic_double_dome_tools(dims),
                "double-dome tools (exact rolling-ball constructions)")
    started = time.perf_counter()
    meshed = build_tools(tools, comm=comm)
    surfaces = {name: MeshedSurface(surface, margin=TOOL_LIST_MARGIN)
                for name, surface in meshed.items()}
    return surfaces, (f"{tools.kind} tools meshed by gmsh (" + ", ".join(
        f"{name} {s.n_triangles} triangles" for name, s in surfaces.items())
        + f", {time.perf_counter() - started:.1f} s)")


class ToolContact(PointContribution):
    """Rigid tools in (smoothed) penalty contact with friction; the tools named in ``moving``
    translate by (0, 0, -stroke(t)); the holder, when ``holder_control`` (a
    :class:`~drape.forming.holder.HolderControl`) is set, is lowered by what it says (read by
    :meth:`set_load`)."""

    name = "tools"

    def __init__(self, surfaces: dict, moving: set, stroke: float, penalty: float,
                 friction: float | dict, regularisation: float, cutoff: float,
                 smoothing: float = 0.0):
        self.surfaces = surfaces
        self.moving = set(moving)
        self.stroke = float(stroke)
        self.penalty, self.regularisation = penalty, regularisation
        #: μ per tool (``friction``: one for all, or {tool name: μ})
        self.friction = (dict(friction) if isinstance(friction, dict)
                         else {name: float(friction) for name in surfaces})
        self.cutoff, self.smoothing = cutoff, float(smoothing)
        self.holder_control = None
        self.offsets = {name: np.zeros(3) for name in surfaces}
        self.committed_offsets = dict(self.offsets)
        self.last = {}
        #: a stack: each point's height z_k (mm, (P,)) and, per tool, the points it touches
        #: (a mask (P,)); None: one ply at z = 0, every tool touching every point
        self.heights = None
        self.touched = None
        #: a stack: how high (mm) each moving tool starts above z = 0, the height of the ply it
        #: comes down onto (the punch touches the top ply at t = 0, as it touches a blank)
        self.start = {}

    def set_plies(self, point_heights, tool_plies: dict) -> None:
        """A stack: ``point_heights`` (P,) the height (mm) of each point's ply there as laid up
        (:func:`drape.forming.layup.laid_heights`), ``tool_plies`` {tool name: a mask (P,) of
        the points it touches, those of every ply exposed to it
        (:class:`drape.forming.exposure.StackExposure`)}. A moving
        tool (the punch) starts at the height of the highest point it touches: it travels the
        stroke from touching the stack, and a stack ends with its bottom ply where one blank
        would."""
        self.heights = np.asarray(point_heights, dtype=float)
        masks = {name: np.asarray(mask, dtype=bool) for name, mask in tool_plies.items()}
        self.touched = {name: masks[name] for name in self.surfaces}
        self.start = {name: float(self.heights[masks[name]].max(initial=0.0))
                      for name in self.moving if name in masks}

    def set_exposure(self, tool_plies: dict) -> None:
        """A stack, between steps: the points each tool touches from now on ({tool name: a
        mask (P,)}). A point a tool stops touching forgets its friction memory there (it
        slides free of the tool); the moving tools keep their start."""
        for name, mask in tool_plies.items():
            self.touched[name] = np.asarray(mask, dtype=bool)
            self.elastic_slip[name][~self.touched[name]] = 0.0

    def setup(self, reference_points):
        super().setup(reference_points)
        self.committed_u = np.zeros((len(reference_points), 3))
        self._u = self.committed_u
        #: per tool, the tangential slip (mm) still held elastically in the stick zone at the
        #: last converged step: friction's memory (:meth:`commit`)
        self.elastic_slip = {name: np.zeros((len(reference_points), 3)) for name in self.surfaces}
        self._trial_slip = {}

    def set_load(self, t: float) -> None:
        for name in self.surfaces:
            down = self.stroke * t - self.start.get(name, 0.0) if name in self.moving else 0.0
            if name == "holder" and self.holder_control is not None:
                down += self.holder_control.lowering()
            self.offsets[name] = np.array([0.0, 0.0, -down])

    def evaluate(self, positions, displacements):
        if self.heights is not None:    # a stack: each point at its laid-up height
            positions = positions + np.column_stack([np.zeros((len(positions), 2)),
                                                     self.heights])
        f = np.zeros_like(positions)
        K = np.zeros(positions.shape + (3,))
        self.last = {}
        for name, surface in self.surfaces.items():
            mine = slice(None) if self.touched is None else self.touched[name]
            offset = self.offsets[name]
            query = surface.query(positions[mine], offset, cutoff=self.cutoff)
            # the slip since the last converged step plus the elastic slip held then: friction
            # with memory, so that a point drawn slowly over a tool reaches mu p whatever the
            # step size (without it a point drawn by less than the slip regularisation per step
            # never reaches mu p, and the forces depend on the steps; docs/forming-checks.md)
            slip = (displacements[mine] - self.committed_u[mine]
                    - (offset - self.committed_offsets[name]) + self.elastic_slip[name][mine])
            response = traction(query.gap, query.normal, slip, self.penalty, self.friction[name],
                                self.regularisation, touching_is_active=True,
                                smoothing=self.smoothing)
            f[mine] += response.traction
            K[mine] -= response.tangent
            gap, response, slip, normal = self._on_every_point(mine, query.gap, response, slip,
                                                               query.normal)
            self.last[name] = (gap, response)
            self._trial_slip[name] = (slip, normal)
        self._u = displacements
        return f, K

    def _on_every_point(self, mine, gap, response, slip, normal):
        """A stack: a tool's values on the points of its ply (``mine``) spread over every
        point, the others out of contact (infinite gap, no pressure); one blank: as they are."""
        if self.touched is None:
            return gap, response, slip, normal
        from drape.forming.contact import ContactResponse
        n = len(self.heights)
        whole_gap = np.full(n, np.inf)
        whole_gap[mine] = gap
        whole = ContactResponse(np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros(n),
                                np.zeros(n, dtype=response.state.dtype))
        for full, values in zip(whole, response):
            full[mine] = values
        whole_slip, whole_normal = np.zeros((n, 3)), np.zeros((n, 3))
        whole_slip[mine], whole_normal[mine] = slip, normal
        return whole_gap, whole, whole_slip, whole_normal

    def commit(self) -> None:
        """The converged step becomes the reference of the next; each point keeps the part of
        its tangential slip within the stick zone (:func:`drape.forming.contact.elastic_slip`)."""
        self.committed_u = np.array(self._u, copy=True)
        self.committed_offsets = {k: v.copy() for k, v in self.offsets.items()}
        for name, (slip, n) in self._trial_slip.items():
            self.elastic_slip[name] = elastic_slip(slip, n, self.last[name][1].pressure,
                                                   self.regularisation)

    def state(self) -> dict:
        state = {"committed_u": self.committed_u,
                 **{f"offset_{k}": v for k, v in self.committed_offsets.items()},
                 **{f"elastic_slip_{k}": v for k, v in self.elastic_slip.items()}}
        if self.touched is not None:        # a stack: the points each tool touches
            for name, mask in self.touched.items():
                state[f"touches_{name}"] = mask.astype(float)
        if self.holder_control is not None:
            state.update(self.holder_control.state())
        return state

    def load_state(self, state: dict) -> None:
        self.committed_u = np.array(state["committed_u"], copy=True)
        self._u = self.committed_u
        for k in self.committed_offsets:
            self.committed_offsets[k] = np.array(state[f"offset_{k}"], copy=True)
            self.elastic_slip[k] = np.array(state[f"elastic_slip_{k}"], copy=True)
            if self.touched is not None and f"touches_{k}" in state:
                self.touched[k] = np.asarray(state[f"touches_{k}"]) > 0.5
        if self.holder_control is not None:
            self.holder_control.load_state(state)
