"""The yarn angle and the law of every ply of a mesh, as the membrane's forms and law need them.

A :class:`~drape.fe.mesh.BlankMesh` is one ply; a :class:`~drape.fe.stack_mesh.StackMesh`
has several, each with its own yarn angle theta (deg, from x to the warp) and its own law.
Where the plies share a value the forms get plain numbers and the law runs once, value for
value today's single ply; where they differ, cos theta, sin theta and mu K1 / 2, mu K2 / 2 are
DG0 functions (per cell, from its ply) and the law runs on each ply's points with that ply's
parameters (:class:`~drape.law.piecewise.PiecewiseLaw`).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


class PlyProperties:
    """One law and one yarn angle per ply of ``blank_mesh`` (:attr:`laws`,
    :attr:`yarn_angles_deg`) and the ply of every local cell (:attr:`cell_ply`, ghosts
    included). :attr:`uniform_law` / :attr:`uniform_angle`: the plies share them;
    :attr:`yarn_angle_deg` the shared angle (else None)."""

    def __init__(self, blank_mesh, law, yarn_angle_deg: float | Sequence[float]):
        self.mesh = blank_mesh.mesh
        n_plies = len(getattr(blank_mesh, "heights", ())) or 1
        laws = tuple(law) if isinstance(law, (list, tuple)) else (law,)
        angles = tuple(float(a) for a in np.atleast_1d(yarn_angle_deg))
        for name, values in (("law", laws), ("yarn_angle_deg", angles)):
            if len(values) not in (1, n_plies):
                raise ValueError(f"{len(values)} values of {name} for {n_plies} plies; expected "
                                 f"one, or one per ply")
        self.laws = laws * n_plies if len(laws) == 1 else laws
        self.yarn_angles_deg = angles * n_plies if len(angles) == 1 else angles
        index_map = self.mesh.topology.index_map(2)
        self.cell_ply = (np.asarray(blank_mesh.cell_plies(), dtype=np.int32)
                         if n_plies > 1 else
                         np.zeros(index_map.size_local + index_map.num_ghosts, dtype=np.int32))
        self.uniform_law = all(other is self.laws[0] or other.params == self.laws[0].params
                               for other in self.laws)
        self.uniform_angle = len(set(self.yarn_angles_deg)) == 1
        self.yarn_angle_deg = self.yarn_angles_deg[0] if self.uniform_angle else None
        self._dg0 = None

    def point_law(self, n_cells: int, points_per_cell: int):
        """The law of every local law point, a PiecewiseLaw (one piece when the plies share
        the law, else one per ply), and the law the problem exposes (the shared law, or that
        PiecewiseLaw)."""
        from drape.law.piecewise import PiecewiseLaw
        if self.uniform_law:
            return PiecewiseLaw(self.laws[:1], np.zeros(n_cells * points_per_cell)), self.laws[0]
        pieces = PiecewiseLaw(self.laws, np.repeat(self.cell_ply[:n_cells], points_per_cell))
        return pieces, pieces

    def per_cell(self, name: str, ply_values):
        """A DG0 function holding ``ply_values[k]`` on the cells of ply k (ghosts included)."""
        from dolfinx import fem
        if self._dg0 is None:
            self._dg0 = fem.FunctionSpace(self.mesh, ("DG", 0))
        function = fem.Function(self._dg0, name=name)
        cells = self._dg0.dofmap.list.array
        function.x.array[cells] = np.asarray(ply_values, dtype=float)[self.cell_ply]
        return function

    def yarn_frame(self):
        """G1 = (cos theta, sin theta), G2 = (-sin theta, cos theta): constants when the plies
        share theta, else from DG0 functions of cos theta and sin theta (per ply)."""
        import ufl
        if self.uniform_angle:
            theta = np.radians(self.yarn_angle_deg)
            cos, sin = np.cos(theta), np.sin(theta)
        else:
            theta = np.radians(self.yarn_angles_deg)
            cos = self.per_cell("cos_yarn_angle", np.cos(theta))
            sin = self.per_cell("sin_yarn_angle", np.sin(theta))
        return ufl.as_vector([cos, sin]), ufl.as_vector([-sin, cos])

    def half_yarn_moduli(self):
        """mu K1 / 2 and mu K2 / 2 (N/mm): numbers when the plies share the law, else DG0
        functions (per ply)."""
        if self.uniform_law:
            params = self.laws[0].params
            return params.mu * params.K1 * 0.5, params.mu * params.K2 * 0.5
        moduli = [(law.params.mu * law.params.K1 * 0.5, law.params.mu * law.params.K2 * 0.5)
                  for law in self.laws]
        return (self.per_cell("half_mu_K1", [m[0] for m in moduli]),
                self.per_cell("half_mu_K2", [m[1] for m in moduli]))
