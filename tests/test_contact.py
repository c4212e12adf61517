"""The contact law (drape.forming.contact): penalty normal traction and regularised Coulomb
friction.

Tangents against central differences of the traction itself (normal, stick and slip regimes,
plain and smoothed penalty), Coulomb's bound and direction, continuity at the end of the stick
zone, the smoothed penalty's continuity and its inverse, the penalty rule.
"""

import numpy as np
import pytest

from drape.config import from_mapping
from drape.forming.contact import (SEPARATED, SLIP, STICK, ContactParameters, gap_for_pressure,
                           normal_pressure, penetration_report, propose_penalty, traction)
from drape.errors import InputError

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial

RNG = np.random.default_rng(7)
EPS, MU, DELTA = 2500.0, 0.25, 0.05


def random_normals(n):
    v = RNG.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def tangential(normal, length):
    """Vectors of given lengths orthogonal to the normals, plus a random normal component."""
    v = RNG.normal(size=normal.shape)
    v -= np.sum(v * normal, axis=1, keepdims=True) * normal
    v *= (length / np.linalg.norm(v, axis=1))[:, None]
    return v + RNG.normal(size=(len(normal), 1)) * normal


def finite_difference(gap, normal, slip, mu, h=1e-7, smoothing=0.0):
    """d t / d u by central differences: u moves the point, so g changes by n . du and the slip
    increment by du (the normal held fixed, as in the law's tangent)."""
    n_pts = len(gap)
    fd = np.zeros((n_pts, 3, 3))
    for k in range(3):
        du = np.zeros((n_pts, 3))
        du[:, k] = h
        plus = traction(gap + np.sum(normal * du, axis=1), normal, slip + du, EPS, mu, DELTA,
                        smoothing=smoothing)
        minus = traction(gap - np.sum(normal * du, axis=1), normal, slip - du, EPS, mu, DELTA,
                         smoothing=smoothing)
        fd[:, :, k] = (plus.traction - minus.traction) / (2 * h)
    return fd


@pytest.mark.parametrize("regime, slip_length, mu", [
    ("normal only", 0.0, 0.0),
    ("stick", 0.5 * DELTA, MU),
    ("slip", 20 * DELTA, MU),
    ("frictionless slip", 20 * DELTA, 0.0),
])
def test_tangent_matches_finite_differences(regime, slip_length, mu):
    n_pts = 200
    normal = random_normals(n_pts)
    gap = -RNG.uniform(1e-4, 1e-2, n_pts)
    lengths = slip_length * RNG.uniform(0.2, 1.0, n_pts) if regime == "stick" else \
        np.full(n_pts, slip_length) * RNG.uniform(1.0, 3.0, n_pts)
    slip = tangential(normal, lengths)
    response = traction(gap, normal, slip, EPS, mu, DELTA)
    expected = {"normal only": STICK, "stick": STICK, "slip": SLIP, "frictionless slip": SLIP}
    assert np.all(response.state == expected[regime])
    fd = finite_difference(gap, normal, slip, mu)
    scale = EPS * (1 + mu) + mu * EPS * 1e-2 / DELTA
    np.testing.assert_allclose(response.tangent, fd, atol=1e-6 * scale, rtol=1e-6)
    asymmetry = np.abs(response.tangent - response.tangent.transpose(0, 2, 1)).max()
    if mu > 0:
        assert asymmetry > 1e-3 * EPS       # friction's tangent is not symmetric
    else:
        assert asymmetry < 1e-9 * EPS


def test_separated_points_carry_nothing():
    normal = random_normals(100)
    gap = np.concatenate([RNG.uniform(1e-6, 5.0, 99), [0.0]])
    slip = tangential(normal, np.ones(100))
    response = traction(gap, normal, slip, EPS, MU, DELTA)
    assert np.all(response.traction == 0.0) and np.all(response.tangent == 0.0)
    assert np.all(response.pressure == 0.0) and np.all(response.state == SEPARATED)


def test_normal_traction_is_the_penalty_pressure_along_the_normal():
    normal = random_normals(50)
    gap = -RNG.uniform(0.0, 0.1, 50)
    response = traction(gap, normal, np.zeros((50, 3)), EPS, MU, DELTA)
    np.testing.assert_allclose(response.pressure, -EPS * gap)
    np.testing.assert_allclose(response.traction, (-EPS * gap)[:, None] * normal)


def test_coulomb_bound_and_direction():
    """|t_T| <= mu p everywhere, = mu p when slipping, and t_T opposes the tangential slip."""
    n_pts = 1000
    normal = random_normals(n_pts)
    gap = -RNG.uniform(1e-4, 1e-1, n_pts)
    slip = tangential(normal, DELTA * RNG.uniform(0.0, 10.0, n_pts))
    r = traction(gap, normal, slip, EPS, MU, DELTA)
    t_n = np.sum(r.traction * normal, axis=1)
    t_t = r.traction - t_n[:, None] * normal
    s_t = slip - np.sum(slip * normal, axis=1, keepdims=True) * normal
    np.testing.assert_allclose(t_n, r.pressure, rtol=1e-12)
    magnitude = np.linalg.norm(t_t, axis=1)
    assert np.all(magnitude <= MU * r.pressure * (1 + 1e-12))
    sliding = r.state == SLIP
    assert 200 < np.count_nonzero(sliding) < 980
    np.testing.assert_allclose(magnitude[sliding], MU * r.pressure[sliding], rtol=1e-12)
    cos = np.sum(t_t * s_t, axis=1) / (magnitude * np.linalg.norm(s_t, axis=1))
    np.testing.assert_allclose(cos, -1.0, atol=1e-12)


def test_continuous_at_the_end_of_the_stick_zone():
    normal = random_normals(100)
    gap = -RNG.uniform(1e-3, 1e-2, 100)
    direction = tangential(normal, np.ones(100))
    direction -= np.sum(direction * normal, axis=1, keepdims=True) * normal
    before = traction(gap, normal, direction * DELTA * (1 - 1e-10), EPS, MU, DELTA)
    after = traction(gap, normal, direction * DELTA * (1 + 1e-10), EPS, MU, DELTA)
    assert np.all(before.state == STICK) and np.all(after.state == SLIP)
    np.testing.assert_allclose(before.traction, after.traction, atol=1e-9 * EPS * 1e-2)


def test_penalty_rule():
    """eps = c K / h^2; the penetration under a pressure p is then p h^2 / (c K)."""
    eps = propose_penalty(10000.0, 2.0, 1.0)
    assert eps == pytest.approx(2500.0)
    pressure = 1.0                                   # N/mm^2, a high forming pressure
    g = -pressure / eps
    assert traction(np.array([g]), np.array([[0, 0, 1.0]]), np.zeros((1, 3)),
                    eps).pressure[0] == pytest.approx(pressure)
    assert -g / 2.0 == pytest.approx(pressure * 2.0 / 10000.0)   # a fraction p h / K of h
    with pytest.raises(InputError):
        propose_penalty(0.0, 2.0)
    params = from_mapping(ContactParameters, {"friction": 0.3, "penalty_factor": 4.0})
    assert params.penalty_for(10000.0, 2.0) == pytest.approx(10000.0)
    assert from_mapping(ContactParameters, {"penalty": 50.0}).penalty_for(1e4, 2.0) == 50.0
    with pytest.raises(InputError, match="friction"):
        from_mapping(ContactParameters, {"friction": -0.1})


def test_penetration_report():
    report = penetration_report(np.array([0.1, -0.02, -0.005, 0.0]), np.array([1, 2, 3, 4.0]))
    assert report == {"max_penetration": 0.02, "points_in_contact": 2, "contact_area": 5.0}
    assert penetration_report(np.array([1.0]))["max_penetration"] == 0.0


G0 = 0.02   # smoothing distance (mm) of the C1 penalty in these tests


@pytest.mark.parametrize("where", ["penetrating", "within g0", "both"])
@pytest.mark.parametrize("slip_length, mu", [(0.5 * DELTA, MU), (20 * DELTA, MU), (0.0, 0.0)])
def test_smoothed_tangent_matches_finite_differences(where, slip_length, mu):
    n_pts = 200
    normal = random_normals(n_pts)
    gap = {"penetrating": -RNG.uniform(1e-4, 1e-2, n_pts),
           "within g0": RNG.uniform(0.05, 0.95, n_pts) * G0,
           "both": RNG.uniform(-0.5, 0.95, n_pts) * G0}[where]
    slip = tangential(normal, slip_length * RNG.uniform(0.2, 1.0, n_pts)) if slip_length else \
        np.zeros((n_pts, 3))
    response = traction(gap, normal, slip, EPS, mu, DELTA, smoothing=G0)
    assert np.all(response.pressure > 0.0)          # in contact within g0 already
    fd = finite_difference(gap, normal, slip, mu, h=1e-8, smoothing=G0)
    scale = EPS * (1 + mu) + mu * EPS * G0 / DELTA
    np.testing.assert_allclose(response.tangent, fd, atol=1e-6 * scale, rtol=1e-6)


def test_smoothed_penalty_is_c1_and_far_points_carry_nothing():
    """p and dp/dg are continuous at g = 0 and g = g0 (independent check: one-sided difference
    quotients of p itself); beyond g0 nothing; for g < 0 the plain law shifted by eps g0 / 2."""
    eps = EPS
    for g_star in (0.0, G0):
        left, right = g_star - 1e-9, g_star + 1e-9
        (p_l, p_r), (k_l, k_r) = normal_pressure(np.array([left, right]), eps, G0)
        assert p_l == pytest.approx(p_r, abs=1e-6 * eps * G0)
        assert k_l == pytest.approx(k_r, abs=1e-5 * eps)
        h = 1e-7
        slopes = [(normal_pressure(np.array([x + h]), eps, G0)[0][0]
                   - normal_pressure(np.array([x - h]), eps, G0)[0][0]) / (2 * h)
                  for x in (g_star - 1e-5, g_star + 1e-5)]
        assert slopes[0] == pytest.approx(slopes[1], abs=1e-3 * eps)
    p, k = normal_pressure(np.array([-0.01, G0, 2 * G0]), eps, G0)
    assert p[0] == pytest.approx(eps * (0.01 + G0 / 2)) and k[0] == eps
    assert p[1] == p[2] == 0.0 and k[1] == k[2] == 0.0
    r = traction(np.array([1.5 * G0]), np.array([[0, 0, 1.0]]), np.ones((1, 3)), eps, MU, DELTA,
                 smoothing=G0)
    assert np.all(r.traction == 0.0) and np.all(r.tangent == 0.0) and r.state[0] == SEPARATED


@pytest.mark.parametrize("pressure", [1e-6, 1e-3, 0.5 * EPS * G0, 10.0])
def test_gap_for_pressure_inverts_the_penalty(pressure):
    for smoothing in (0.0, G0):
        g = gap_for_pressure(pressure, EPS, smoothing)
        assert normal_pressure(np.array([g]), EPS, smoothing)[0][0] == pytest.approx(
            pressure, rel=1e-10)
    with pytest.raises(ValueError):
        gap_for_pressure(0.0, EPS, G0)


def test_smoothing_default_is_a_fraction_of_the_element_size():
    assert ContactParameters().smoothing_for(4.0) == pytest.approx(0.2)
    assert from_mapping(ContactParameters, {"smoothing": 0.0}).smoothing_for(4.0) == 0.0
    with pytest.raises(InputError, match="smoothing"):
        from_mapping(ContactParameters, {"smoothing": -1.0})
