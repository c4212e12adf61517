"""A measure of cell-to-cell shear oscillation (a checkerboard of alternating shear angles).

Each cell's mean shear angle gamma_c (deg, the area-weighted mean over its law points) is
compared with the mean of its edge neighbours'; for a cell whose every edge is shared,

    o_c = |gamma_c - mean over neighbours n of gamma_n| / 2,

which is the amplitude A of a checkerboard gamma = g0 +- A exactly, and zero for any shear
field varying linearly across the blank (for a smooth field, h^2/8 |laplacian gamma| on a
square lattice of size h). The measure is the largest o_c over the blank: what a shear map
would show as a spurious cell-to-cell pattern. Cells on the outline (fewer neighbours than
edges) are left out: there a one-sided mean is a gradient, not an oscillation. See
docs/blanks.md for the threshold and the figures it was set from.
"""

from __future__ import annotations

import numpy as np

#: deg: above this the log warns that the shear map oscillates from cell to cell
#: (docs/blanks.md, "The oscillation measure")
OSCILLATION_WARNING = 5.0


class ShearOscillation:
    """The cell-to-cell oscillation of a :class:`~drape.membrane.MembraneProblem`'s shear
    angles (collective: every rank calls :meth:`measure`, every rank gets the value)."""

    def __init__(self, problem):
        self.problem = problem
        V = problem.V
        n = problem.n_cells
        dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)[:n]
        X = V.tabulate_dof_coordinates()[:, :2]
        parts = problem.comm.gather(X[dofs], root=0)
        self.neighbours = None
        if problem.comm.rank == 0:
            self.neighbours = cell_neighbours(np.concatenate(parts))

    def measure(self) -> float:
        p = self.problem
        shear = p.cell_average(p.response.gamma_t_deg) if p.n_cells else np.zeros(0)
        parts = p.comm.gather(np.asarray(shear, dtype=float).reshape(-1), root=0)
        value = None
        if p.comm.rank == 0:
            value = oscillation(np.concatenate(parts), *self.neighbours)
        return p.comm.bcast(value, root=0)


def cell_neighbours(corners: np.ndarray):
    """From every cell's corner coordinates (cells, k, 2): for the cells whose every edge is
    shared with another cell, their indices (m,) and their neighbours' (m, k)."""
    cells, k = corners.shape[:2]
    scale = max(float(np.ptp(corners.reshape(-1, 2), axis=0).max()), 1.0)
    keys = np.round(corners / (1e-7 * scale)).astype(np.int64)
    _, node = np.unique(keys.reshape(-1, 2), axis=0, return_inverse=True)
    node = node.reshape(cells, k)
    if k == 4:       # DOLFINx quadrilaterals: tensor-product order; edges 0-1, 1-3, 3-2, 2-0
        pairs = [(0, 1), (1, 3), (3, 2), (2, 0)]
    else:
        pairs = [(0, 1), (1, 2), (2, 0)]
    owner: dict = {}
    for c in range(cells):
        for a, b in pairs:
            owner.setdefault(tuple(sorted((node[c, a], node[c, b]))), []).append(c)
    table = -np.ones((cells, len(pairs)), dtype=np.int64)
    for c in range(cells):
        for e, (a, b) in enumerate(pairs):
            sharing = owner[tuple(sorted((node[c, a], node[c, b])))]
            if len(sharing) == 2:
                table[c, e] = sharing[0] if sharing[1] == c else sharing[1]
    full = np.nonzero((table >= 0).all(axis=1))[0]
    return full, table[full]


def oscillation(shear: np.ndarray, cells: np.ndarray, neighbours: np.ndarray) -> float:
    """max over ``cells`` of |gamma_c - mean of its neighbours' gamma| / 2 (deg)."""
    if len(cells) == 0:
        return 0.0
    return float(np.max(np.abs(shear[cells] - shear[neighbours].mean(axis=1))) / 2.0)
