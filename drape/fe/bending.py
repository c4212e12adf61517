"""The membrane's bending: hinges across the interior edges (a discrete-shell model).

    W_b = sum over interior edges e of int_e B / (2 h) |n+ - n-|^2 ds,

n the unit normal of the deformed surface (F e1 x F e2 normalised) on either side of the edge
and h the element size there: each edge is a hinge whose energy B theta^2 L / (2 h) is the
plate energy B kappa^2 / 2 of a curvature kappa = theta / h spread over the strip of width h.
It vanishes on a flat or rigidly moved blank, so it changes nothing in the flat jobs; in
forming it gives the membrane the bending stiffness a real fabric has (docs/forming.md,
"Bending"). Its interior-facet form couples each node with its neighbours' neighbours, which
is what makes a factorisation with bending dearer than without (docs/speed.md).
"""

from __future__ import annotations

import numpy as np


def hinge_energy(msh, F, areas: np.ndarray, rigidity: float):
    """W_b (N mm) as a UFL form over the interior facets, and the DG0 cell size h (mm) it
    uses.

    ``F`` the deformation gradient (3x2, UFL), ``areas`` the reference area (mm^2) of every
    local and ghost cell (the hinges on the edges a rank shares need the cell size on both
    sides), ``rigidity`` B (N mm). h is the edge length of a yarn-aligned element: sqrt(area)
    on quadrilaterals, sqrt(2 area) on triangles (the legs of the right triangles)."""
    import ufl
    from dolfinx import fem
    cell_name = msh.topology.cell_type.name
    n_all = len(areas)
    D0 = fem.FunctionSpace(msh, ("DG", 0))
    cell_size = fem.Function(D0, name="cell_size")
    dofs = D0.dofmap.list.array.reshape(-1)[:n_all]    # one dof per cell, in cell order
    cell_size.x.array[dofs] = np.sqrt(areas * (2.0 if cell_name == "triangle" else 1.0))
    a3 = ufl.cross(F[:, 0], F[:, 1])
    normal = a3 / ufl.sqrt(ufl.dot(a3, a3))
    h = 0.5 * (cell_size("+") + cell_size("-"))
    dS = ufl.dS(domain=msh, metadata={"quadrature_degree": 2})
    energy = rigidity / (2.0 * h) * ufl.inner(ufl.jump(normal), ufl.jump(normal)) * dS
    return energy, cell_size
