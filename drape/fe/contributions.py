"""Point contributions: forces at quadrature points that the membrane's residual and Jacobian
include (the tools' contact, a test's spring), and the quadrature functions that carry them
into the forms.

A contribution sees only positions and displacements at points and returns a force per unit
reference area and its stiffness, so it needs no UFL: :class:`PointTerms` turns each into a
quadrature-space force f and stiffness K and adds ``-int f . v dA`` to the residual and
``int (K du) . v dA`` to the Jacobian (degree :data:`CONTRIBUTION_DEGREE` on every cell type).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: quadrature degree of the regularisation and point contributions (a one-point rule would
#: leave the out-of-plane mass of linear triangles singular)
CONTRIBUTION_DEGREE = 2


class PointContribution:
    """Forces at quadrature points that the residual and the Jacobian include (e.g. contact).

    Before every residual evaluation the problem calls :meth:`evaluate` with the current
    positions x = X + u and displacements u at its quadrature points (P, 3); it returns the
    force per unit reference area on the membrane f (P, 3), N/mm^2, and the stiffness
    K = -df/du (P, 3, 3), N/mm^3. :meth:`setup` is called once with the reference points
    (P, 2); :meth:`commit` after every converged step (friction history, say).
    """

    name = "contribution"

    def setup(self, reference_points: np.ndarray) -> None:
        self.reference_points = reference_points

    def evaluate(self, positions: np.ndarray, displacements: np.ndarray):
        raise NotImplementedError

    def commit(self) -> None:
        pass

    def state(self) -> dict:
        """The committed history (e.g. friction) as named numpy arrays, for a checkpoint;
        none by default. Arrays of this rank's points (the checkpoint is per rank)."""
        return {}

    def load_state(self, state: dict) -> None:
        """Take back what :meth:`state` returned (resume from a checkpoint)."""
        if state:
            raise NotImplementedError(f"{type(self).__name__} saved a state but cannot load it")


class PointTerm(NamedTuple):
    """One contribution and the quadrature functions (and their owned dofs) it writes."""
    contribution: PointContribution
    force: object
    stiffness: object
    force_dofs: np.ndarray
    stiffness_dofs: np.ndarray


class PointTerms:
    """The point contributions of a membrane problem: their quadrature functions, their terms
    in the residual and the Jacobian, and their evaluation before an assembly."""

    def __init__(self, msh, contributions, u, cells: np.ndarray, jit: dict):
        import basix
        import ufl
        from dolfinx import fem
        basix_cell = getattr(basix.CellType, msh.topology.cell_type.name)
        self.points, self.weights = basix.make_quadrature(basix_cell, CONTRIBUTION_DEGREE)
        self.cells = cells
        self.mesh = msh
        self.entries: list[PointTerm] = []
        if not contributions:
            return
        n_points = len(self.weights)
        fe = ufl.VectorElement("Quadrature", msh.ufl_cell(), CONTRIBUTION_DEGREE, dim=3,
                               quad_scheme="default")
        te = ufl.TensorElement("Quadrature", msh.ufl_cell(), CONTRIBUTION_DEGREE, shape=(3, 3),
                               quad_scheme="default")
        Qf, Qk = fem.FunctionSpace(msh, fe), fem.FunctionSpace(msh, te)
        x_ref = fem.Expression(ufl.SpatialCoordinate(msh), self.points, jit_params=jit)
        reference = x_ref.eval(cells).reshape(-1, 2)
        n_cells = len(cells)
        for contribution in contributions:
            force, stiffness = fem.Function(Qf), fem.Function(Qk)
            contribution.setup(reference)
            self.entries.append(PointTerm(
                contribution, force, stiffness,
                Qf.dofmap.list.array.reshape(-1, n_points)[:n_cells],
                Qk.dofmap.list.array.reshape(-1, n_points)[:n_cells]))
        X = ufl.as_vector([ufl.SpatialCoordinate(msh)[0], ufl.SpatialCoordinate(msh)[1], 0.0])
        self._state = fem.Expression(ufl.as_vector([X[i] + u[i] for i in range(3)]
                                                   + [u[i] for i in range(3)]),
                                     self.points, jit_params=jit)

    def add_to(self, residual, jacobian, v, du):
        """The residual and Jacobian forms with every contribution's terms added."""
        import ufl
        dx = ufl.dx(domain=self.mesh, metadata={"quadrature_degree": CONTRIBUTION_DEGREE})
        for term in self.entries:
            residual -= ufl.inner(term.force, v) * dx
            jacobian += ufl.inner(term.stiffness * du, v) * dx
        return residual, jacobian

    def evaluate(self) -> set[str]:
        """Evaluate every contribution at the current displacement and write its force and
        stiffness; returns the names of those whose output was not finite."""
        nonfinite = set()
        if not self.entries:
            return nonfinite
        values = self._state.eval(self.cells).reshape(-1, 6)
        for term in self.entries:
            f, K = term.contribution.evaluate(values[:, :3], values[:, 3:])
            if not all_finite(f, K):
                nonfinite.add(term.contribution.name)
            write_blocked(term.force, term.force_dofs, np.asarray(f).reshape(-1, 3))
            write_blocked(term.stiffness, term.stiffness_dofs, np.asarray(K).reshape(-1, 9))
        return nonfinite


def all_finite(*arrays) -> bool:
    """Whether every value of every array is finite."""
    return all(np.isfinite(np.asarray(a, dtype=float)).all() for a in arrays)


def write_blocked(function, dofs, values) -> None:
    """Write (cells*points, bs) values into a blocked quadrature function."""
    bs = function.function_space.dofmap.index_map_bs
    index = (dofs.reshape(-1, 1) * bs + np.arange(bs)).ravel()
    function.x.array[index] = values.ravel()
