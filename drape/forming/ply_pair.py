"""A ply-ply contact pair's geometry (drape.forming.ply_contact): for a slave node and its
master triangle, the gap, normal, barycentric coordinates and slip with their derivatives with
respect to the 12 coordinates (forward mode), the weight that fades a pair past the master
ply's outline; the interface's friction coefficient mu(p, v) and the partial derivatives of
the contact law's traction."""

from __future__ import annotations

import numpy as np

from drape.forming.ply_surfaces import closest_on_outline
from drape.forming.surfaces import closest_point_on_triangles


class FrictionLaw:
    """mu(p, v) = mu0 (1 + p/p_ref)^-a (1 + v/v_ref)^b with its partial derivatives
    (p in N/mm², v in mm/s; :class:`drape.forming.plies.InterfaceConfig`)."""

    def __init__(self, friction, reference_pressure=1.0, pressure_exponent=0.0,
                 reference_slip_rate=1.0, rate_exponent=0.0):
        self.mu0, self.p_ref, self.a = float(friction), float(reference_pressure), \
            float(pressure_exponent)
        self.v_ref, self.b = float(reference_slip_rate), float(rate_exponent)

    @classmethod
    def of(cls, interface) -> "FrictionLaw":
        return cls(interface.friction, interface.reference_pressure,
                   interface.pressure_exponent, interface.reference_slip_rate,
                   interface.rate_exponent)

    @property
    def rate_dependent(self) -> bool:
        return self.b != 0.0

    def __call__(self, pressure, rate):
        """mu, dmu/dp (mm²/N), dmu/dv (s/mm) at N points."""
        p, v = np.asarray(pressure, dtype=float), np.asarray(rate, dtype=float)
        mu = self.mu0 * (1.0 + p / self.p_ref) ** -self.a * (1.0 + v / self.v_ref) ** self.b
        return mu, -self.a * mu / (self.p_ref + p), self.b * mu / (self.v_ref + v)


# --- forward-mode derivatives of a pair's geometry ----------------------------------------------

def selector(node: int) -> np.ndarray:
    """d x_node / d (x_s, x_a, x_b, x_c): (3, 12)."""
    out = np.zeros((3, 12))
    out[:, 3 * node: 3 * node + 3] = np.eye(3)
    return out


SELECTORS = [selector(k) for k in range(4)]


def cross_rows(u, v):
    """u x v over axis 1 (the components), broadcast over the others: np.cross's products,
    without its copies."""
    u0, u1, u2 = u[:, 0], u[:, 1], u[:, 2]
    v0, v1, v2 = v[:, 0], v[:, 1], v[:, 2]
    return np.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=1)


def cross(a, da, b, db):
    """a x b and its derivative, for a, b (P, 3) with derivatives (P, 3, 12)."""
    return (cross_rows(a, b),
            cross_rows(da, b[:, :, None]) + cross_rows(a[:, :, None], db))


def dot(a, da, b, db):
    return (np.sum(a * b, axis=1),
            np.einsum("pik,pi->pk", da, b) + np.einsum("pi,pik->pk", a, db))


def pair_geometry(x, du, sign, offset, memory):
    """For P pairs with node positions x (P, 4, 3) (slave, a, b, c) and displacement increments
    du (P, 4, 3): gap g (P,), normal n (P, 3), barycentric coordinates lambda (P, 3) and slip ds
    (P, 3), each followed by its derivative with respect to the 12 coordinates (P, ..., 12)."""
    count = len(x)
    xs, xa, xb, xc = (x[:, k] for k in range(4))
    const = lambda e: np.broadcast_to(e, (count, 3, 12))               # noqa: E731
    e1, de1 = xb - xa, const(SELECTORS[2] - SELECTORS[1])
    e2, de2 = xc - xa, const(SELECTORS[3] - SELECTORS[1])
    r, dr = xs - xa, const(SELECTORS[0] - SELECTORS[1])
    N, dN = cross(e1, de1, e2, de2)
    NN, dNN = dot(N, dN, N, dN)
    length = np.sqrt(NN)
    n_up = N / length[:, None]
    dn_up = (dN - n_up[:, :, None] * np.einsum("pi,pik->pk", n_up, dN)[:, None, :]) \
        / length[:, None, None]
    n, dn = sign * n_up, sign * dn_up
    d, dd = dot(r, dr, n, dn)
    g, dg = d - offset, dd
    rb, drb = cross(r, dr, e2, de2)
    qb, dqb = dot(rb, drb, N, dN)
    rc, drc = cross(e1, de1, r, dr)
    qc, dqc = dot(rc, drc, N, dN)
    lb, lc = qb / NN, qc / NN
    dlb = (dqb - lb[:, None] * dNN) / NN[:, None]
    dlc = (dqc - lc[:, None] * dNN) / NN[:, None]
    lam = np.column_stack([1.0 - lb - lc, lb, lc])
    dlam = np.stack([-dlb - dlc, dlb, dlc], axis=1)
    ds = du[:, 0] - np.einsum("pk,pki->pi", lam, du[:, 1:]) + memory
    dds = (const(SELECTORS[0]) - np.einsum("pk,kij->pij", lam, np.stack(SELECTORS[1:]))
           - np.einsum("pki,pkj->pij", du[:, 1:], dlam))
    return g, dg, n, dn, lam, dlam, ds, dds


def law_partials(response, n, ds, mu):
    """The partial derivatives of the law's traction t(g, n, ds, mu) read off its tangent
    dt/du = dt/dg n^T + dt/dds (contact.traction, n fixed there):

        dt/dg  = tangent n,     dt/dds = tangent (I - n n),
        dt/dn  = p I - (n.ds) dt/dds + c n ((n.ds) n + ds)^T,   c = mu p / (delta or s),
        dt/dmu = (t - p n) / mu,

    c from dt/dds applied to a tangent direction w across the slip: dt/dds w = -c w."""
    K, t, p = response.tangent, response.traction, response.pressure
    eye = np.eye(3)
    projector = eye - n[:, :, None] * n[:, None, :]
    dt_dg = np.einsum("pij,pj->pi", K, n)
    dt_dds = np.einsum("pij,pjk->pik", K, projector)
    tangential = np.einsum("pij,pj->pi", projector, ds)
    across = np.cross(n, tangential)
    # no slip direction yet: any tangent direction (the axis least aligned with n crossed in)
    axis = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    fallback = np.cross(n, axis)
    small = np.linalg.norm(across, axis=1) < 1e-200
    across = np.where(small[:, None], fallback, across)
    across /= np.linalg.norm(across, axis=1)[:, None]
    c = -np.einsum("pi,pij,pj->p", across, dt_dds, across)
    normal_slip = np.sum(n * ds, axis=1)
    dt_dn = (p[:, None, None] * eye - normal_slip[:, None, None] * dt_dds
             + c[:, None, None] * n[:, :, None]
             * (normal_slip[:, None] * n + ds)[:, None, :])
    mu = np.broadcast_to(mu, p.shape)
    tangential_traction = t - p[:, None] * n
    dt_dmu = np.where(mu[:, None] > 0.0,
                      tangential_traction / np.where(mu > 0.0, mu, 1.0)[:, None], 0.0)
    return dt_dg, dt_dn, dt_dds, dt_dmu


def edge_ramp(x, n, dn, outline_edges, outline_vertices, width):
    """The weight of each of P pairs (x (P, 4, 3): slave, a, b, c; n, dn the triangle's normal
    and its derivative) by how far the slave lies past the master ply's outline, and its
    derivative (P, 12). d is the distance, in the triangle's plane, from the slave to the
    triangle's closest point c when c lies on an edge of the outline (``outline_edges``
    (P, 3): the edge opposite each vertex is one) or at a vertex of it (``outline_vertices``
    (P, 3)), else 0; the weight is 1 for d = 0, 0 for d >= ``width`` (mm) and 3 s^2 - 2 s^3,
    s = 1 - d / width, between: a C1 ramp, so that a node crossing a ply's edge makes no jump.

    d is the same whichever triangle next to the outline is the closest (they share the
    closest point), so the weight does not jump when that choice changes under a sliding
    node. Inner edges do not count: where the master ply folds convexly the closest point of
    a slave lies on an inner edge, just outside the plane's projection, which would cut the
    weight (and jump with the choice of triangle; a frictionless interface stalled so)."""
    count = len(x)
    ramp, d_ramp = np.ones(count), np.zeros((count, 12))
    if not count:
        return ramp, d_ramp
    xs, corners = x[:, 0], x[:, 1:]
    _, bary, _ = closest_point_on_triangles(xs, corners[:, 0], corners[:, 1], corners[:, 2])
    outside, on_edge, edge = closest_on_outline(bary, outline_edges, outline_vertices)
    if not outside.any():
        return ramp, d_ramp
    rows = np.flatnonzero(outside)
    # the closest point c and its derivative: a vertex, or the foot on the edge (i, j)
    cornerselectors = np.stack(SELECTORS[1:])                     # (3, 3, 12): d corner / d x
    c = np.einsum("pk,pki->pi", bary[rows], corners[rows])
    dc = np.einsum("pk,kij->pij", bary[rows], cornerselectors)
    along = rows[on_edge[rows]]
    if len(along):
        k = edge[along]
        i, j = (k + 1) % 3, (k + 2) % 3
        xi, xj = corners[along, i], corners[along, j]
        e, r = xj - xi, xs[along] - xi
        ee = np.sum(e * e, axis=1)
        tau = np.sum(r * e, axis=1) / ee
        Ei, Ej = cornerselectors[i], cornerselectors[j]
        de, dr = Ej - Ei, SELECTORS[0] - Ei
        dtau = ((np.einsum("pik,pi->pk", dr, e) + np.einsum("pi,pik->pk", r, de)) / ee[:, None]
                - 2.0 * tau[:, None] * np.einsum("pi,pik->pk", e, de) / ee[:, None])
        where = np.searchsorted(rows, along)
        dc[where] = Ei + e[:, :, None] * dtau[:, None, :] + tau[:, None, None] * de
    r = xs[rows] - c
    dr = SELECTORS[0] - dc
    nr, dnr = n[rows], dn[rows]
    height = np.sum(r * nr, axis=1)
    dheight = np.einsum("pik,pi->pk", dr, nr) + np.einsum("pi,pik->pk", r, dnr)
    q = r - height[:, None] * nr
    dq = dr - nr[:, :, None] * dheight[:, None, :] - height[:, None, None] * dnr
    d = np.linalg.norm(q, axis=1)
    dd = np.einsum("pi,pik->pk", q / np.where(d > 0.0, d, 1.0)[:, None], dq)
    s = np.clip(1.0 - d / width, 0.0, 1.0)
    ramp[rows] = s * s * (3.0 - 2.0 * s)
    d_ramp[rows] = -(6.0 * s * (1.0 - s) / width)[:, None] * dd
    return ramp, d_ramp


def barycentric(x, a, b, c) -> np.ndarray:
    """The barycentric coordinates (P, 3) of the points x's projections on the planes of the
    triangles (a, b, c) (each (P, 3)), as :func:`pair_geometry` has them."""
    e1, e2, r = b - a, c - a, x - a
    normal = np.cross(e1, e2)
    nn = np.sum(normal * normal, axis=1)
    lb = np.sum(np.cross(r, e2) * normal, axis=1) / nn
    lc = np.sum(np.cross(e1, r) * normal, axis=1) / nn
    return np.column_stack([1.0 - lb - lc, lb, lc])
