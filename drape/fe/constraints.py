"""Prescribed displacements on named boundaries, as DOLFINx Dirichlet conditions.

:class:`PrescribedMotion` turns the job's :class:`~drape.fe.loading.Loading` (formulas of x, y, t
and the histories) into one Dirichlet condition per displacement component on the membrane's
space. Where two ``[[boundary]]`` entries prescribe the same component at a node, the later
entry wins. :meth:`PrescribedMotion.set_load` writes the values of load factor t.

It also measures what the boundaries do: the reaction force on each named boundary (the sum of
the internal nodal forces of its nodes, N: the force the boundary applies to the blank), and
the generalised force conjugate to a history value h, Q_h = sum_i f_i dg_i/dh over the prescribed
components (the work of the prescribed motion per unit change of h; a central difference of the
formulas in h).
"""

from __future__ import annotations

import numpy as np

from drape.fe.loading import COMPONENTS


class PrescribedMotion:
    def __init__(self, V, blank_mesh, loading):
        from dolfinx import fem

        self.loading = loading
        self.V = V
        comm = V.mesh.comm
        self.comm = comm
        bs = V.dofmap.index_map_bs
        self.n_owned = V.dofmap.index_map.size_local * bs
        self.values = []          # per component: Function on the collapsed subspace
        self._assignments = []    # per component: [(formula, dofs in V, dofs in the subspace)]
        self.bcs = []
        # in the order of the config (a set would differ between ranks: the reactions are
        # summed over ranks name by name)
        names = list(dict.fromkeys(p.boundary for p in loading.prescribed))
        facets = {name: blank_mesh.facets(name) for name in names}
        for i, component in enumerate(COMPONENTS):
            Vi, _ = V.sub(i).collapse()
            g = fem.Function(Vi, name=f"prescribed_{component}")
            coordinates = Vi.tabulate_dof_coordinates()[:, :2]
            claimed = np.zeros(0, dtype=np.int32)
            assignments = []
            for entry in reversed(loading.prescribed):          # later entries win
                formula = entry.components[i]
                if formula is None:
                    continue
                dofs_V, dofs_Vi = fem.locate_dofs_topological((V.sub(i), Vi), 1,
                                                              facets[entry.boundary])
                keep = ~np.isin(dofs_V, claimed)
                dofs_V, dofs_Vi = dofs_V[keep], dofs_Vi[keep]
                claimed = np.concatenate([claimed, dofs_V])
                assignments.append((formula, dofs_V, dofs_Vi, coordinates[dofs_Vi]))
            self.values.append(g)
            self._assignments.append(assignments)
            if comm.allreduce(len(claimed)) > 0:
                order = np.argsort(claimed)
                dofs_Vi = np.concatenate([a[2] for a in assignments]) if assignments else claimed
                self.bcs.append(fem.dirichletbc(g, [claimed[order], dofs_Vi[order]], V.sub(i)))
        prescribed = [a[1] for assignments in self._assignments for a in assignments]
        all_dofs = np.unique(np.concatenate(prescribed)) if prescribed else np.zeros(0, np.int32)
        self.prescribed_dofs = all_dofs[all_dofs < self.n_owned]   # owned, unrolled indices of V
        # reactions: every owned dof (all components) on each named boundary
        self.boundary_dofs = {}
        for name, local_facets in facets.items():
            blocks = fem.locate_dofs_topological(V, 1, local_facets)
            blocks = blocks[blocks < V.dofmap.index_map.size_local]
            self.boundary_dofs[name] = (blocks[:, None] * bs + np.arange(bs)).astype(np.int64)
        self.t = None

    def set_load(self, t: float) -> None:
        """Write the prescribed values of load factor t."""
        for g, assignments in zip(self.values, self._assignments):
            for formula, _, dofs_Vi, xy in assignments:
                g.x.array[dofs_Vi] = self.loading.evaluate(formula, xy, t)
        self.t = t

    def prescribed_values(self, t: float, overrides: dict | None = None) -> np.ndarray:
        """Values (owned prescribed dofs of V, in the order of :attr:`prescribed_dofs`) at t."""
        out = np.zeros(self.n_owned)
        for assignments in self._assignments:
            for formula, dofs_V, _, xy in assignments:
                owned = dofs_V < self.n_owned
                out[dofs_V[owned]] = self.loading.evaluate(formula, xy[owned], t, overrides)
        return out[self.prescribed_dofs]

    # --- what the boundaries do ------------------------------------------------------------------
    def reactions(self, internal_force) -> dict[str, np.ndarray]:
        """{boundary name: (Fx, Fy, Fz)} in N, summed over all ranks."""
        local = internal_force.array_r
        out = {}
        for name, dofs in self.boundary_dofs.items():
            out[name] = self.comm.allreduce(local[dofs].sum(axis=0) if dofs.size else np.zeros(3))
        return out

    def conjugate_force(self, internal_force, t: float, history: str) -> float:
        """Q_h = sum f_i dg_i/dh over the prescribed components at load factor t (N mm per unit
        of the history h), by a central difference of the formulas in h."""
        h = float(self.loading.histories[history](t))
        delta = 1e-5 * max(1.0, float(np.abs(self.loading.histories[history].values).max()))
        plus = self.prescribed_values(t, {history: h + delta})
        minus = self.prescribed_values(t, {history: h - delta})
        local = internal_force.array_r[self.prescribed_dofs] @ ((plus - minus) / (2.0 * delta))
        return self.comm.allreduce(float(local))
