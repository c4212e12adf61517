"""The membrane's UFL forms: the kinematics in the yarn frame, the internal virtual work with
its Jacobian, and the regularisation's terms (the problem and its notation:
:mod:`drape.fe.membrane`).

Each function builds forms from the problem's functions and returns them; the problem keeps
the functions and constants it updates between evaluations (tau, its tangent, the damping and
inertia constants, the inertia's anchor).
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class Kinematics:
    """F (3x2), the yarn-frame components of C and the yarn frame G1, G2 (reference)."""

    F: object
    C11: object
    C22: object
    C12: object
    G1: object
    G2: object


def membrane_forms(mesh, blank_mesh, plies, u, tau, dtau, degree: int, v, du):
    """The kinematics, the internal virtual work int S : sym(F^T grad v) dA and its Jacobian:
    ``ufl.derivative`` with tau frozen plus the shear tangent dtau/dC12 dE12(du) 2 dE12(v)
    (tau and dtau: quadrature functions at the law's points of ``degree``). Returns
    (Kinematics, internal, jacobian, strip_reduced)."""
    import ufl
    G1, G2 = plies.yarn_frame()
    half_mu_K1, half_mu_K2 = plies.half_yarn_moduli()
    I32 = ufl.as_matrix([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    F = I32 + ufl.grad(u)
    C = F.T * F
    C11, C22, C12 = ufl.dot(G1, C * G1), ufl.dot(G2, C * G2), ufl.dot(G1, C * G2)

    def dE12(w):
        return ufl.dot(G1, ufl.sym(F.T * ufl.grad(w)) * G2)

    P = ufl.outer(G1, G2) + ufl.outer(G2, G1)
    S_yarn = (half_mu_K1 * (C11 - 1.0) * ufl.outer(G1, G1)
              + half_mu_K2 * (C22 - 1.0) * ufl.outer(G2, G2))
    S_shear = 0.5 * tau * P
    dx_law = ufl.dx(domain=mesh, metadata={"quadrature_degree": degree})
    virtual = ufl.sym(F.T * ufl.grad(v))
    internal, strip_reduced = internal_work(mesh, blank_mesh, S_yarn, S_shear, virtual, degree)
    jacobian = ufl.derivative(internal, u, du) + dtau * dE12(du) * 2.0 * dE12(v) * dx_law
    return Kinematics(F, C11, C22, C12, G1, G2), internal, jacobian, strip_reduced


def internal_work(mesh, blank_mesh, S_yarn, S_shear, virtual, degree: int):
    """int S : sym(F^T grad v) dA, and whether its yarn tension is reduced in strip cells: in
    the strip cells between a clipped yarn lattice and the outline, which are not yarn-aligned,
    the yarn tension at the 2x2 points locks (intra-ply shear locking, docs/blanks.md), so
    there it is integrated at the cell's centre only (selective reduced integration), the
    shear at the law's points as everywhere."""
    import ufl
    dx_law = ufl.dx(domain=mesh, metadata={"quadrature_degree": degree})
    strip = np.asarray(getattr(blank_mesh, "strip_cells", ()), dtype=np.int32)
    strip_reduced = (bool(mesh.comm.allreduce(len(strip)))
                     and mesh.topology.cell_type.name == "quadrilateral")
    if not strip_reduced:
        return ufl.inner(S_yarn + S_shear, virtual) * dx_law, False
    from dolfinx import mesh as dmesh
    n_all = mesh.topology.index_map(2).size_local + mesh.topology.index_map(2).num_ghosts
    marker = np.zeros(n_all, dtype=np.int32)
    marker[strip] = 1
    tags = dmesh.meshtags(mesh, 2, np.arange(n_all, dtype=np.int32), marker)
    dx_tag = ufl.Measure("dx", domain=mesh, subdomain_data=tags,
                         metadata={"quadrature_degree": degree})
    dx_centre = ufl.Measure("dx", domain=mesh, subdomain_data=tags,
                            metadata={"quadrature_degree": 1})
    return (ufl.inner(S_yarn, virtual) * dx_tag(0)
            + ufl.inner(S_yarn, virtual) * dx_centre(1)
            + ufl.inner(S_shear, virtual) * dx_law), True


@dataclasses.dataclass
class Regularisation:
    """The residual and Jacobian with the regularisation's terms, their work over the step,
    and what sets them: the damping k and inertia k_m constants (N/mm^3) and the inertia's
    anchor u_anchor (None without inertia)."""

    residual: object
    jacobian: object
    work: object
    damping_constant: object
    inertia_constant: object
    u_anchor: object


def regularisation_forms(mesh, V, u, u_committed, internal, jacobian, v, du, damping: float,
                         inertia: bool) -> Regularisation:
    """The out-of-plane damping k (u_z - u_z,last) and, with ``inertia``, the inertial term
    k_m (u - u_anchor), u_anchor the motion carried on from the last steps (a forming job sets
    k and k_m every step), added to ``internal`` and ``jacobian``; also their work over the
    step, 1/2 k int (u_z - u_z,last)^2 dA + 1/2 k_m int |u - u_anchor|^2 dA."""
    import ufl
    from dolfinx import fem
    from drape.fe.contributions import CONTRIBUTION_DEGREE
    dx_extra = ufl.dx(domain=mesh, metadata={"quadrature_degree": CONTRIBUTION_DEGREE})
    k = fem.Constant(mesh, float(damping))
    residual = internal + k * (u[2] - u_committed[2]) * v[2] * dx_extra
    jacobian = jacobian + k * du[2] * v[2] * dx_extra
    work = 0.5 * k * (u[2] - u_committed[2]) ** 2 * dx_extra
    k_m, u_anchor = fem.Constant(mesh, 0.0), None
    if inertia:
        u_anchor = fem.Function(V, name="inertia_anchor")
        lag = u - u_anchor
        residual += k_m * ufl.inner(lag, v) * dx_extra
        jacobian += k_m * ufl.inner(du, v) * dx_extra
        work += 0.5 * k_m * ufl.inner(lag, lag) * dx_extra
    return Regularisation(residual, jacobian, work, k, k_m, u_anchor)
