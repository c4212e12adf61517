"""Contact of the membrane with rigid tools: penalty normal law and regularised Coulomb friction,
with their consistent tangents, one point at a time compiled with numba (the loop over a
forming job's quadrature points runs at every residual).

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

import numba
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

jit = numba.njit(cache=True)


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
    eps = np.broadcast_to(np.asarray(penalty, dtype=float), g.shape).ravel()
    p, stiffness = np.empty(g.size), np.empty(g.size)
    _pressures(g.ravel(), eps, float(smoothing), p, stiffness)
    return p.reshape(g.shape), stiffness.reshape(g.shape)


@jit
def _pressure(g, eps, g0):
    """p(g) and -dp/dg at one point (normal_pressure)."""
    if g0 <= 0.0:
        return (-eps * g, eps) if g < 0.0 else (0.0, 0.0)
    if g < 0.0:
        return eps * (0.5 * g0 - g), eps
    if g < g0:
        return eps * (g0 - g) ** 2 / (2.0 * g0), eps * (g0 - g) / g0
    return 0.0, 0.0


@jit
def _pressures(g, eps, g0, p, stiffness):
    for i in range(g.shape[0]):
        p[i], stiffness[i] = _pressure(g[i], eps[i], g0)


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
    t = np.zeros(g.shape + (3,))
    tangent = np.zeros(g.shape + (3, 3))
    p = np.empty(g.shape)
    state = np.full(g.shape, SEPARATED)
    _traction_points(g, n, ds, np.ascontiguousarray(eps), np.ascontiguousarray(mu),
                     np.ascontiguousarray(delta), float(smoothing), bool(touching_is_active),
                     t, tangent, p, state)
    return ContactResponse(t, tangent, p, state)


@jit
def _traction_points(g, n, ds, eps, mu, delta, g0, touching_is_active, t, tangent, p, state):
    """traction() at every point (t, tangent zero and state SEPARATED on entry): the points the
    tool does not act on (no pressure, no stiffness; on a forming job most of the blank) are
    left so. Per point, with P = I - n n, ds_T = P ds, s = |ds_T|, phi = ds_T / scale:
    t = p (n - mu phi); dt/du = -mu p D(phi) P - k (n - mu phi) n, D(phi) = (I - phi phi) / s
    sliding (s > delta), I / delta sticking."""
    proj = np.empty((3, 3))
    base = np.empty((3, 3))
    ds_t = np.empty(3)
    phi = np.empty(3)
    for i in range(g.shape[0]):
        pressure, stiffness = _pressure(g[i], eps[i], g0)
        if g0 <= 0.0 and touching_is_active:
            stiffness = eps[i] if g[i] <= 0.0 else 0.0
        p[i] = pressure
        if not (pressure > 0.0 or stiffness > 0.0):
            continue
        for j in range(3):
            for k in range(3):
                proj[j, k] = (1.0 if j == k else 0.0) - n[i, j] * n[i, k]
        for j in range(3):
            ds_t[j] = proj[j, 0] * ds[i, 0] + proj[j, 1] * ds[i, 1] + proj[j, 2] * ds[i, 2]
        s = math.sqrt(ds_t[0] * ds_t[0] + ds_t[1] * ds_t[1] + ds_t[2] * ds_t[2])
        slip = pressure > 0.0 and s > delta[i]
        scale = s if slip else delta[i]
        for j in range(3):
            phi[j] = ds_t[j] / scale
            t[i, j] = pressure * (n[i, j] - mu[i] * phi[j])
        for j in range(3):
            for k in range(3):
                identity = 1.0 if j == k else 0.0
                base[j, k] = identity - phi[j] * phi[k] if slip else identity
        friction = -(mu[i] * pressure)
        for j in range(3):
            pushed = stiffness * (n[i, j] - mu[i] * phi[j])
            for k in range(3):
                dphi = (base[j, 0] * proj[0, k] + base[j, 1] * proj[1, k]
                        + base[j, 2] * proj[2, k]) / scale
                tangent[i, j, k] = friction * dphi - pushed * n[i, k]
        if pressure > 0.0:
            state[i] = SLIP if slip else STICK


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


def warm_up() -> None:
    """Compile (or load from numba's cache) the contact law's kernels for the argument types
    drape uses."""
    normal = np.array([[0.0, 0.0, 1.0]])
    traction(np.array([-0.01]), normal, np.zeros((1, 3)), 1.0, 0.2, 0.05, True, 0.1)
    normal_pressure(np.array([-0.01]), 1.0, 0.1)
