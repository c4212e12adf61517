"""Contact of the membrane with rigid tools: penalty normal law and regularised Coulomb friction,
pointwise and vectorised (numpy only), with their consistent tangents.

At each quadrature point the finite-element layer supplies, from the current position, the
tool's gap g and unit normal n (pointing away from the tool, see :mod:`drape.forming.surfaces`) and
the
slip Δs of the fabric relative to the tool (a 3-vector: the displacement increment over the
current load step minus the tool's rigid motion, plus the elastic slip the point held in the
stick zone at the last converged step, :func:`elastic_slip`, which
:class:`drape.forming.press.ToolContact` keeps: so friction has memory, and a point drawn slowly
over a tool reaches μ p whatever the step size). :func:`traction` returns the traction t the
tool exerts on the fabric (N/mm², per unit reference area), its derivative
dt/du with respect to the fabric displacement (3×3 per point) and the contact pressure.

Normal law (penalty):   p = ε_N ⟨-g⟩,  t_N = p n        (⟨x⟩ = max(x, 0))
or, with a smoothing distance g0 > 0 (what forming jobs use), the C1 penalty

    p = ε_N (g0/2 - g)          for g < 0
    p = ε_N (g0 - g)² / (2 g0)  for 0 <= g < g0,     p = 0 beyond g0,

which starts to push a fraction of g0 before the fabric touches and has a continuous
stiffness -dp/dg (ε_N for g <= 0, falling linearly to 0 at g0): points entering and leaving
contact change Newton's tangent smoothly, not in one jump (docs/forming.md measures the effect).
Friction (regularised Coulomb, stick zone of width δ):
    Δs_T = (I - n⊗n) Δs,   s = |Δs_T|
    t_T = -μ p Δs_T / δ      if s <= δ   (stick: an elastic tangential spring μ p / δ)
    t_T = -μ p Δs_T / s      if s >  δ   (slip: |t_T| = μ p, opposite to the slip)
    t = t_N + t_T

Tangent (g, Δs depending on u through dg/du = n, dΔs/du = I; the tool's curvature term
dn/du is neglected: exact for flat tools, first order in g/R on curved ones):
    dt/du = -(-dp/dg) (n - μ φ) ⊗ n  -  μ p Dφ (I - n⊗n),   -dp/dg = ε_N H(-g) unsmoothed
with φ = Δs_T/δ and Dφ = I/δ (stick), φ = Δs_T/s and Dφ = (I - e⊗e)/s, e = Δs_T/s (slip).
The friction part is not symmetric (the term μ ε_N φ ⊗ n).

The finite-element layer adds ∫ t·δu dA to the external virtual work and
-∫ δu·(dt/du)·du dA to the stiffness. Parameters and the penalty rule: ``docs/contact.md``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from drape.config import non_negative, positive, setting
from drape.errors import InputError

#: Default tool-fabric friction coefficient: dry glass or carbon fabric on steel at room
#: temperature, at the low end of the measured 0.2-0.3 (docs/contact.md, "Friction coefficient").
DEFAULT_FRICTION = 0.2
#: Slip (mm) over which friction builds up to μ p.
DEFAULT_SLIP_REGULARISATION = 0.05
#: c in ε_N = c K / h² (docs/contact.md, "Penalty").
DEFAULT_PENALTY_FACTOR = 1.0
#: g0 / h of the smoothed penalty (docs/forming.md, "Contact").
DEFAULT_SMOOTHING_FACTOR = 0.05

SEPARATED, STICK, SLIP = 0, 1, 2


@dataclasses.dataclass(frozen=True)
class ContactParameters:
    """The ``[contact]`` table."""

    penalty: float | None = setting(None, "normal penalty ε_N, contact pressure per unit "
                                    "penetration; unset: propose_penalty(K, h, penalty_factor)",
                                    positive, "N/mm^3")
    penalty_factor: float = setting(DEFAULT_PENALTY_FACTOR, "c in ε_N = c K / h² (K the larger "
                                    "yarn stiffness, h the blank's element size)", positive)
    friction: float = setting(DEFAULT_FRICTION, "Coulomb friction coefficient μ between fabric "
                              "and tools", non_negative)
    punch_friction: float | None = setting(None, "μ between fabric and the punch; unset: "
                                           "friction", non_negative)
    die_friction: float | None = setting(None, "μ between fabric and the die; unset: friction",
                                         non_negative)
    holder_friction: float | None = setting(None, "μ between fabric and the blank holder; "
                                            "unset: friction", non_negative)
    slip_regularisation: float = setting(DEFAULT_SLIP_REGULARISATION, "slip δ over which "
                                         "friction builds up to μ p (the stick zone)", positive,
                                         "mm")
    smoothing: float | None = setting(None, "g0 of the C1 penalty: the gap at which the tool "
                                      "starts to push (0: the plain penalty); unset: "
                                      f"{DEFAULT_SMOOTHING_FACTOR:g} times the blank's element "
                                      "size", non_negative, "mm")

    def friction_for(self, tool: str) -> float:
        """μ between the fabric and the tool named ``tool`` (punch, die, holder): its own
        coefficient where set (a lubricated die, a holder of another finish), else ``friction``."""
        own = getattr(self, f"{tool}_friction", None)
        return self.friction if own is None else own

    def smoothing_for(self, element_size: float) -> float:
        """g0 (mm): the configured smoothing, or the default fraction of the element size."""
        if self.smoothing is not None:
            return self.smoothing
        return DEFAULT_SMOOTHING_FACTOR * element_size

    def penalty_for(self, yarn_stiffness: float, element_size: float) -> float:
        """ε_N: the configured penalty, or the proposed one for this fabric and mesh."""
        if self.penalty is not None:
            return self.penalty
        return propose_penalty(yarn_stiffness, element_size, self.penalty_factor)


def propose_penalty(yarn_stiffness: float, element_size: float,
                    factor: float = DEFAULT_PENALTY_FACTOR) -> float:
    """ε_N = c K / h² (N/mm³) for the larger yarn tension stiffness K (N/mm, e.g. the law's
    max(K1, K2)) and the blank's element size h (mm).

    The contact spring of one element, ε_N h², is then c K: as stiff as the element's own
    tension stiffness (K h / h), so contact adds no stiffer mode than the fabric already has,
    and the penetration under a pressure p is p h² / (c K), i.e. a fraction p h / (c K) of h
    (p h / K ~ 1e-4 for 10 kN/mm yarns, 1 mm elements and 1 MPa)."""
    if yarn_stiffness <= 0 or element_size <= 0 or factor <= 0:
        raise InputError("the penalty needs positive stiffness, element size and factor",
                         value=(yarn_stiffness, element_size, factor),
                         expected="K > 0 (N/mm), h > 0 (mm), c > 0")
    return factor * yarn_stiffness / element_size ** 2


class ContactResponse(NamedTuple):
    """Per point: traction (N, 3) on the fabric [N/mm²], dt/du (N, 3, 3) [N/mm³], contact
    pressure p (N,) [N/mm²], and state (N,): 0 separated, 1 stick, 2 slip."""

    traction: np.ndarray
    tangent: np.ndarray
    pressure: np.ndarray
    state: np.ndarray


def normal_pressure(gap, penalty, smoothing=0.0):
    """Contact pressure p(g) (N/mm²) and its stiffness -dp/dg (N/mm³) at N points: the plain
    penalty for ``smoothing`` g0 = 0, else the C1 law of the module docstring."""
    g = np.asarray(gap, dtype=float)
    eps, g0 = penalty, smoothing
    if g0 <= 0.0:
        return np.where(g < 0.0, -eps * g, 0.0), np.where(g < 0.0, eps, 0.0)
    near = (g >= 0.0) & (g < g0)
    p = np.where(g < 0.0, eps * (0.5 * g0 - g),
                 np.where(near, eps * (g0 - g) ** 2 / (2.0 * g0), 0.0))
    stiffness = np.where(g < 0.0, eps, np.where(near, eps * (g0 - g) / g0, 0.0))
    return p, stiffness


def gap_for_pressure(pressure: float, penalty: float, smoothing: float = 0.0) -> float:
    """The gap g (mm) at which :func:`normal_pressure` is the pressure p > 0 (its inverse)."""
    p, eps, g0 = float(pressure), float(penalty), float(smoothing)
    if p <= 0.0:
        raise ValueError(f"the pressure must be positive, not {p}")
    if g0 <= 0.0 or p >= 0.5 * eps * g0:
        return 0.5 * g0 - p / eps
    return g0 - math.sqrt(2.0 * g0 * p / eps)


def traction(gap, normal, slip_increment, penalty, friction=DEFAULT_FRICTION,
             regularisation=DEFAULT_SLIP_REGULARISATION, touching_is_active=False,
             smoothing=0.0) -> ContactResponse:
    """The penalty normal law with regularised Coulomb friction at N points (module docstring).

    gap (N,) mm; normal (N, 3) unit; slip_increment (N, 3) mm; penalty ε_N (N/mm³), friction μ
    and regularisation δ (mm): scalars or arrays of N; ``smoothing`` g0 (mm) selects the C1
    penalty. ``touching_is_active`` (plain penalty only): at g = 0 exactly (fabric lying on a
    tool) the tangent is the one-sided one of the contact side (ε_N n⊗n), so that Newton's
    first iteration sees the support; the traction there is 0 either way."""
    g = np.asarray(gap, dtype=float)
    n = np.asarray(normal, dtype=float)
    ds = np.asarray(slip_increment, dtype=float)
    eps = np.broadcast_to(np.asarray(penalty, dtype=float), g.shape)
    mu = np.broadcast_to(np.asarray(friction, dtype=float), g.shape)
    delta = np.broadcast_to(np.asarray(regularisation, dtype=float), g.shape)
    if n.shape != g.shape + (3,) or ds.shape != n.shape:
        raise ValueError(f"expected gap (N,), normal and slip (N, 3); got {g.shape}, {n.shape}, "
                         f"{ds.shape}")
    p, stiffness = normal_pressure(g, eps, smoothing)
    if smoothing <= 0.0 and touching_is_active:
        stiffness = np.where(g <= 0.0, eps, 0.0)
    # only the points the tool acts on (p > 0, or a stiffness at the contact's onset): the
    # others have no traction and no tangent, and on a forming job they are most of the blank
    on = np.nonzero((p > 0.0) | (stiffness > 0.0))[0]
    t = np.zeros(g.shape + (3,))
    tangent = np.zeros(g.shape + (3, 3))
    state = np.full(g.shape, SEPARATED)
    if on.size:
        n_on, mu_on, k_on = n[on], mu[on], stiffness[on]
        t[on], friction_tangent, phi, slip = _friction(p[on], n_on, ds[on], mu_on, delta[on])
        # normal part of the tangent: dp/du = -(-dp/dg) n, acting on (n - mu phi)
        tangent[on] = friction_tangent - k_on[:, None, None] * (
            n_on - mu_on[:, None] * phi)[:, :, None] * n_on[:, None, :]
        state[on] = np.where(p[on] > 0.0, np.where(slip, SLIP, STICK), SEPARATED)
    return ContactResponse(t, tangent, p, state)


def _friction(p, n, ds, mu, delta):
    """t = p (n - mu phi) and the friction part of dt/du, -mu p D(phi) (I - n n), for pressure
    p (N,), normal n (N, 3), slip increment ds (N, 3); also phi and the slipping mask."""
    eye = np.eye(3)
    proj = eye - n[:, :, None] * n[:, None, :]                       # I - n⊗n
    ds_t = np.einsum("nij,nj->ni", proj, ds)
    s = np.linalg.norm(ds_t, axis=1)
    slip = (p > 0.0) & (s > delta)
    scale = np.where(slip, s, delta)                                 # φ = Δs_T / scale
    phi = ds_t / scale[:, None]
    t = p[:, None] * (n - mu[:, None] * phi)
    e = phi  # in slip, |φ| = 1: e = φ
    dphi = np.where(slip[:, None, None], eye - e[:, :, None] * e[:, None, :], eye)
    dphi = np.einsum("nij,njk->nik", dphi, proj) / scale[:, None, None]
    return t, -(mu * p)[:, None, None] * dphi, phi, slip


def elastic_slip(slip, normal, pressure, regularisation) -> np.ndarray:
    """The slip (N, 3) a point keeps for the next step once a step converges with slip Δs
    (N, 3), normal n (N, 3) and pressure p (N,): friction's memory. Its tangential part Δs_T
    while it sticks (|Δs_T| <= δ), Δs_T cut to the length δ where it slides (the edge of the
    stick zone), nothing where it carries no pressure (off the tool)."""
    slip = np.asarray(slip, dtype=float)
    n = np.asarray(normal, dtype=float)
    tangential = slip - np.sum(slip * n, axis=1)[:, None] * n
    length = np.linalg.norm(tangential, axis=1)
    keep = np.minimum(1.0, regularisation / np.maximum(length, 1e-300))
    keep[np.asarray(pressure) <= 0.0] = 0.0
    return tangential * keep[:, None]


def penetration_report(gap, weights=None) -> dict:
    """Largest penetration (mm, >= 0), the number of points in contact and, with quadrature
    weights (reference area per point, mm²), the area in contact: to report at convergence."""
    g = np.asarray(gap, dtype=float)
    contact = g < 0.0
    report = {"max_penetration": float(max(0.0, -g.min())) if g.size else 0.0,
              "points_in_contact": int(np.count_nonzero(contact))}
    if weights is not None:
        report["contact_area"] = float(np.sum(np.asarray(weights, dtype=float)[contact]))
    return report
