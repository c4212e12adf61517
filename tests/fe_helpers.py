"""Residuals, Jacobian actions and their central differences for a
:class:`drape.fe.membrane.MembraneProblem` (PETSc vectors; the problem's callbacks update x's
ghosts themselves); a field's values at the images of its points under a symmetry."""


def residual(problem, x):
    """R(x), a new vector."""
    b = problem.create_vector()
    problem.residual(None, x, b)
    return b


def jacobian_action(problem, x, direction):
    """J(x) d, a new vector."""
    A = problem.create_matrix()
    problem.jacobian(None, x, A, A)
    out = A.createVecLeft()
    A.mult(direction, out)
    return out


def central_difference(problem, x, direction, eps=1e-6):
    """(R(x + eps d) - R(x - eps d)) / (2 eps), a new vector."""
    plus, minus = x.copy(), x.copy()
    plus.axpy(eps, direction)
    minus.axpy(-eps, direction)
    difference = residual(problem, plus)
    difference.axpy(-1.0, residual(problem, minus))
    difference.scale(1.0 / (2 * eps))
    return difference


def mirror_images(xy, gamma):
    """transform -> gamma at the images of the points xy under it (a symmetry of the mesh: each
    image is a point, within 1e-6 mm)."""
    from scipy.spatial import cKDTree
    tree = cKDTree(xy)

    def mirrored(transform):
        d, j = tree.query(transform(xy))
        assert d.max() < 1e-6
        return gamma[j]
    return mirrored
