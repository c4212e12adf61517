"""What a stack of plies reports: a summary per ply and per interface, and the XDMF fields that
show them (docs/plies.md, "Outputs").

* :func:`ply_summaries`: per ply, the shear summary of its cells (largest |shear angle|, area
  above the locking angle, as :func:`drape.forming.reports.shear_summary` for the blank) and
  the draw-in of its own outline (as :func:`drape.forming.reports.draw_in`).
* :func:`interface_summaries`: per interface, what :meth:`PlyContact.report` gives on each
  rank (nodes in contact, contact area, normal force, friction work, largest penetration)
  summed over the ranks, and the largest accumulated slip.
* :func:`gather_ply_cells` and :func:`plot_ply_shear_maps`: the shear maps (PNG) of each ply.
* :class:`StackFields`: a DG0 field ``ply`` (each cell's ply) and, per interface k, nodal (P1)
  fields ``interface{k}_pressure``, ``interface{k}_slip`` and ``interface{k}_accumulated_slip``
  for the results writer.

A node's interface fields come from the pairs it is the slave of: a node of ply k is the slave
against ply k + 1 (its value goes to interface k's fields) and against ply k - 1 (interface
k - 1's), so interface k's fields live on the nodes of plies k and k + 1 and are 0 elsewhere.
The pressure field is what the node carries, its pressure times its edge ramp (the weight of
its pair over half its nodal area), so that the integral of interface k's pressure over the
stack is twice the interface's normal force (each of the two plies carries it once).

Functions taking ``problem`` (a :class:`~drape.fe.stack_problem.StackProblem` after its step's
commit) are collective; the summaries are the same on every rank.
"""

from __future__ import annotations

import numpy as np

from drape.forming.reports import (edge_draw_in, edge_points, gather_cells, plot_shear_maps,
                                   shear_summary)


def owned_node_plies(problem) -> np.ndarray:
    """The ply of each node this rank owns (n_owned,): the plies are disconnected pieces of
    the mesh, so a node's cells all lie in one ply."""
    V = problem.V
    cells = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)
    cell_plies = problem.blank_mesh.cell_plies()
    plies = np.full(V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts, -1,
                    dtype=np.int32)
    plies[cells.ravel()] = np.repeat(cell_plies[: len(cells)], cells.shape[1])
    return plies[: V.dofmap.index_map.size_local]


def ply_summaries(problem, stack, locking_angle_deg: float, comm) -> list[dict]:
    """Per ply (bottom first): its orientation (deg), thickness and height (mm), its cells,
    the largest |shear angle| (deg) and where, its area above the locking angle and its area
    (mm²), and the draw-in (mm) of its outline at :func:`edge_points` of its blank."""
    cell_plies = problem.blank_mesh.cell_plies()[: problem.n_cells]
    node_plies = owned_node_plies(problem)
    owned = problem.V.dofmap.index_map.size_local
    X = problem.V.tabulate_dof_coordinates()[:owned, :2]
    u = problem.u.x.array.reshape(-1, 3)[:owned]
    heights = stack.heights()
    out = []
    for k, ply in enumerate(stack.plies):
        shear = shear_summary(problem, locking_angle_deg, comm, cells=cell_plies == k)
        shear = comm.bcast(shear, root=0)
        mine = node_plies == k
        entry = {"ply": k, "orientation_deg": ply.orientation, "thickness_mm": ply.thickness,
                 "height_mm": heights[k],
                 "cells": int(comm.allreduce(int(np.count_nonzero(cell_plies == k))))}
        entry.update({key: value for key, value in shear.items() if key != "blank_area_mm2"})
        entry["ply_area_mm2"] = shear["blank_area_mm2"]
        entry["draw_in_mm"] = edge_draw_in(X[mine], u[mine], edge_points(ply.blank()), comm)
        out.append(entry)
    return out


def gather_ply_cells(problem) -> dict | None:
    """:func:`drape.forming.reports.gather_cells` (every cell's outlines, shear angle, ...) and
    each cell's ply ("ply"), on rank 0 (None elsewhere)."""
    cells = gather_cells(problem)
    plies = problem.comm.gather(problem.blank_mesh.cell_plies()[: problem.n_cells], root=0)
    if cells is None:
        return None
    cells["ply"] = np.concatenate(plies)
    return cells


def plot_ply_shear_maps(folder, cells: dict, locking_angle: float, title: str) -> None:
    """Per ply k, shear_flat_ply{k}.png and shear_formed_ply{k}.png: the shear maps of its
    cells alone (``cells`` of :func:`gather_ply_cells`; rank 0)."""
    for k in np.unique(cells["ply"]):
        mine = cells["ply"] == k
        plot_shear_maps(folder, {name: values[mine] for name, values in cells.items()},
                        locking_angle, f"{title} ply {k}".strip(), suffix=f"_ply{k}")


def interface_summaries(problem, comm) -> list[dict]:
    """Per interface (interface k between plies k and k + 1), over every rank: the nodes in
    contact (both plies' nodes that carry pressure), the contact area they carry (mm²), the
    normal force (N) and the largest penetration (mm) of the last evaluation, the friction
    work up to the last commit (N mm) and the largest accumulated slip of a node (mm). Where a
    partial ply leaves plies j and k + 1 touching, that contact counts to interface k, which
    lists the pair under ``bridges``."""
    from mpi4py import MPI
    contact = problem.ply_contact
    report = contact.report()
    out = []
    for k in range(len(contact.friction_work)):
        mine = report.get(k, {"max_penetration": 0.0, "nodes_in_contact": 0,
                              "contact_area": 0.0, "normal_force": 0.0,
                              "friction_work": float(contact.friction_work[k])})
        slip = max((float(contact.accumulated_slip[i].max(initial=0.0))
                    for i, d in enumerate(contact.directions) if d.interface == k), default=0.0)
        bridges = sorted({tuple(sorted((d.slave, d.master))) for d in contact.directions
                          if d.interface == k and d.slaves is not None})
        out.append({"interface": k, "plies": [k, k + 1], "bridges": [list(b) for b in bridges],
                    "nodes_in_contact": int(comm.allreduce(mine["nodes_in_contact"])),
                    "contact_area_mm2": comm.allreduce(mine["contact_area"]),
                    "normal_force_N": comm.allreduce(mine["normal_force"]),
                    "friction_work_Nmm": comm.allreduce(mine["friction_work"]),
                    "max_penetration_mm": comm.allreduce(mine["max_penetration"], op=MPI.MAX),
                    "max_accumulated_slip_mm": comm.allreduce(slip, op=MPI.MAX)})
    return out


class StackFields:
    """The stack's fields for the XDMF output: ``functions`` by name (the DG0 ``ply`` and, per
    interface k, the P1 ``interface{k}_pressure`` (N/mm²), ``interface{k}_slip`` (the last
    step's tangential slip, mm) and ``interface{k}_accumulated_slip`` (mm)); :meth:`update`
    fills them from the contact's last evaluation (call it after the step's commit)."""

    QUANTITIES = ("pressure", "slip", "accumulated_slip")

    def __init__(self, problem):
        from dolfinx import fem
        self.problem = problem
        msh = problem.mesh
        W0 = fem.FunctionSpace(msh, ("DG", 0))
        P1 = fem.FunctionSpace(msh, ("CG", 1))
        ply = fem.Function(W0, name="ply")
        n = problem.n_cells
        ply.x.array[W0.dofmap.list.array[:n]] = problem.blank_mesh.cell_plies()[:n]
        ply.x.scatter_forward()
        self.functions = {"ply": ply}
        for k in range(len(problem.ply_contact.friction_work)):
            for quantity in self.QUANTITIES:
                name = f"interface{k}_{quantity}"
                self.functions[name] = fem.Function(P1, name=name)
        # the global node of each owned P1 dof, through the cells (both spaces have a dof
        # per vertex, perhaps numbered differently)
        cells_u = problem.V.dofmap.list.array.reshape(-1, problem.V.dofmap.dof_layout.num_dofs)
        cells_p = P1.dofmap.list.array.reshape(cells_u.shape)
        index_map = P1.dofmap.index_map
        node_of_dof = np.empty(index_map.size_local + index_map.num_ghosts, dtype=np.int64)
        node_of_dof[cells_p.ravel()] = problem.global_nodes[cells_u.ravel()]
        self._nodes = node_of_dof[: index_map.size_local]
        self.update()

    def nodal_values(self) -> dict[str, np.ndarray]:
        """Per field name, the values at every global node (N,) that this rank knows: those
        of the slave nodes it owns (the others 0)."""
        contact = self.problem.ply_contact
        area = contact.nodes.area
        n = len(area)
        out = {name: np.zeros(n) for name in self.functions if name != "ply"}
        for i, direction in enumerate(contact.directions):
            prefix = f"interface{direction.interface}_"
            slaves = contact.last("slaves", i).astype(np.int64)
            if len(slaves):     # a node may be the slave of a bridge too (PlyContact)
                weight, pressure = contact.last("weight", i), contact.last("pressure", i)
                out[prefix + "pressure"][slaves] += pressure * weight / (0.5 * area[slaves])
                out[prefix + "slip"][slaves] += np.linalg.norm(
                    contact.last("slip_increment", i), axis=1)
            on_slave_ply = contact.nodes.ply == direction.slave
            out[prefix + "accumulated_slip"][on_slave_ply] += \
                contact.accumulated_slip[i][on_slave_ply]
        return out

    def update(self) -> None:
        """The fields from the contact's last evaluation and accumulated slip."""
        for name, values in self.nodal_values().items():
            function = self.functions[name]
            function.x.array[: len(self._nodes)] = values[self._nodes]
            function.x.scatter_forward()
