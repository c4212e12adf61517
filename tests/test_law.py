"""The nested-surface law against independent expectations (docs/material-law.md).

Closed forms (virgin outer curve, Masing's rule of the degenerate Iwan model), symmetry,
finite differences, path independence, and a second implementation (drape.law.pointwise).
"""

import dataclasses

import numpy as np
import pytest

from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters, SurfaceTable, polynomial
from drape.law.pointwise import PointwiseLaw
from drape.picture_frame import cyclic_history
from law_helpers import random_walk, run_history, stack_states, surfaces_of

PAPER = MaterialParameters()


@pytest.fixture(params=[2, 1, 0], ids=["three surfaces", "two surfaces", "one surface"])
def params(request):
    return PAPER.with_surfaces(request.param)


# --- consistent tangent ----------------------------------------------------------------------

def test_tangent_matches_finite_difference_in_every_regime():
    """d tau/d C12 equals a central difference of tau(C12) from the same committed state, for
    elastic steps, each active surface, steps just after a reversal and negative branches."""
    law = NestedSurfaceLaw(PAPER)
    history = cyclic_history([10, 20, 30, 40, -40, 45], 0.5)
    before, responses, _ = run_history(law, history)
    # every increment of the history, and a tiny reversal after each one (elastic: the
    # elastic range is about 2 Sy_2 / (2 mu Ksh) = 2e-5 in C12)
    committed = stack_states(before + [r.trial for r in responses])
    direction = np.sign(np.diff(np.concatenate([[0.0], history])))
    history = np.concatenate([history, history])
    C12 = np.sin(np.radians(history))
    C12[history.size // 2:] -= 5e-6 * direction
    ones = np.ones_like(C12)
    h = 1e-6
    centre = law.update(committed, ones, ones, C12)
    plus = law.update(committed, ones, ones, C12 + h)
    minus = law.update(committed, ones, ones, C12 - h)
    row = lambda r: np.searchsorted(PAPER.surfaces.gamma_max_deg, r.trial.gamma_max_deg, "right")
    same_regime = (plus.active_surface == centre.active_surface) & \
                  (minus.active_surface == centre.active_surface) & (row(plus) == row(minus))
    assert same_regime.mean() > 0.9
    fd = (plus.tau - minus.tau) / (2 * h)
    # tau carries ~1e-13 of round-off, so the difference quotient ~1e-7
    error = np.abs(fd - centre.dtau_dC12) - (1e-5 * np.abs(centre.dtau_dC12) + 1e-6)
    assert np.all(error[same_regime] < 0), error[same_regime].max()

    # every regime is represented among the checked increments, negative branches too
    active = centre.active_surface[same_regime]
    plastic_down = (centre.active_surface >= 0) & (np.concatenate([direction, direction]) < 0)
    for regime in (-1, 0, 1, 2):
        assert np.count_nonzero(active == regime) >= 3, f"regime {regime} not covered"
    assert np.count_nonzero((plastic_down & (history < 0))[same_regime]) >= 3
    # the tangent is not trivially the elastic one on plastic steps
    assert np.all(centre.dtau_dC12[same_regime & (centre.active_surface >= 0)] < 0.5 * law.two_mu_ksh)


def test_tangent_right_after_reversal_matches_finite_difference():
    law = NestedSurfaceLaw(PAPER)
    for amplitude in (15.0, 33.0, -38.0):
        history = np.concatenate([np.linspace(0, amplitude, 200)[1:]])
        _, _, state = run_history(law, history)
        # first plastic increment after the reversal: step back until the innermost yields
        sign = -np.sign(amplitude)
        for back in np.linspace(0.01, 3.0, 300):
            C12 = np.sin(np.radians([amplitude + sign * back]))
            response = law.update(state, np.ones(1), np.ones(1), C12)
            if response.active_surface[0] >= 0:
                break
        h = 1e-8
        p = law.update(state, np.ones(1), np.ones(1), C12 + h)
        m = law.update(state, np.ones(1), np.ones(1), C12 - h)
        assert p.active_surface[0] == m.active_surface[0] == response.active_surface[0] == 2
        fd = (p.tau - m.tau) / (2 * h)
        assert fd[0] == pytest.approx(response.dtau_dC12[0], rel=1e-5)


# --- closed forms ----------------------------------------------------------------------------

def test_virgin_loading_on_the_outer_surface_follows_q_plus_sy0_plus_alpha(params):
    law = NestedSurfaceLaw(params)
    for sign in (1, -1):
        history = sign * np.linspace(0, 45, 451)[1:]
        _, responses, _ = run_history(law, history)
        tau = np.array([r.tau[0] for r in responses])
        gp = np.array([r.trial.gamma_p[0] for r in responses])
        outer = np.array([r.active_surface[0] == 0 for r in responses])
        assert outer.sum() > 200
        expected = polynomial(params.Q, gp) + sign * (params.Sy[0] + polynomial(params.A, gp))
        np.testing.assert_allclose(tau[outer], expected[outer], rtol=0, atol=1e-12)
        # before reaching the outer surface the stress is strictly inside it
        assert np.all(np.abs(tau[~outer] - polynomial(params.Q, gp[~outer]))
                      < params.Sy[0] + polynomial(params.A, gp[~outer]))


def iwan_params(h=(0.2, 2.0), sy=(0.0081, 0.006, 0.0025)):
    """alpha = 0, q = 0, one Table-2 row: a rigid-plastic multilinear kinematic (Iwan) model."""
    table = SurfaceTable(gamma_max_deg=(0.0,), a=((0.9, 0.85),), h=(tuple(h),))
    return MaterialParameters(name="Iwan", Q=(0.0,), A=(0.0,), Sy=tuple(sy), surfaces=table)


def iwan_virgin_gamma_p(tau, sy, h):
    """g(tau): plastic angle on the virgin curve of the Iwan model, tau < Sy_0 (closed form)."""
    tau = np.asarray(tau)
    gp = np.zeros_like(tau)
    for k in range(1, len(sy)):      # surface k moves while Sy_k < tau <= Sy_{k-1}
        gp += np.clip(tau - sy[k], 0.0, sy[k - 1] - sy[k]) / h[k - 1]
    return gp


@pytest.mark.parametrize("h", [(0.2, 2.0), (1.5, 4.0), (4.0, 10.0)])
def test_degenerate_law_is_iwan_with_masing_unloading(h):
    params = iwan_params(h)
    sy = params.Sy
    law = NestedSurfaceLaw(params)
    # virgin curve: load to just below the outer surface
    gp_top = iwan_virgin_gamma_p(sy[0] * 0.999, sy, h)
    C12_top = np.sin(gp_top) + sy[0] * 0.999 / law.two_mu_ksh
    loading = np.degrees(np.arcsin(np.linspace(0, C12_top, 400)[1:]))
    _, responses, state = run_history(law, loading)
    tau = np.array([r.tau[0] for r in responses])
    gp = np.array([r.trial.gamma_p[0] for r in responses])
    np.testing.assert_allclose(gp, iwan_virgin_gamma_p(tau, sy, h), rtol=0, atol=2e-14)
    # unloading from the reversal point (tau_r, gp_r): gp_r - gp = 2 g((tau_r - tau) / 2)
    tau_r, gp_r = tau[-1], gp[-1]
    C12_r = np.sin(np.radians(loading[-1]))
    C12_end = np.sin(gp_r - 2 * iwan_virgin_gamma_p(0.999 * sy[0], sy, h)) - 0.999 * sy[0] / law.two_mu_ksh
    unloading = np.degrees(np.arcsin(np.linspace(C12_r, C12_end, 400)[1:]))
    law_state = state
    branch_tau, branch_gp = [], []
    for angle in unloading:
        r = law.update(law_state, np.ones(1), np.ones(1), np.sin(np.radians([angle])))
        law_state = r.trial
        branch_tau.append(r.tau[0])
        branch_gp.append(law_state.gamma_p[0])
    branch_tau, branch_gp = np.array(branch_tau), np.array(branch_gp)
    assert branch_tau.min() < tau_r - 1.9 * sy[0]          # the branch spans all surfaces
    masing = gp_r - 2 * iwan_virgin_gamma_p((tau_r - branch_tau) / 2, sy, h)
    np.testing.assert_allclose(branch_gp, masing, rtol=0, atol=2e-14)


# --- nesting ---------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1])
def test_surfaces_stay_nested_and_contain_the_stress_point(params, seed):
    rng = np.random.default_rng(seed)
    law = NestedSurfaceLaw(params)
    history = random_walk(rng, steps=400, points=300, sigma_deg=2.5, limit_deg=55.0)
    _, responses, _ = run_history(law, history)
    worst_nesting = worst_inside = 0.0
    for response in responses:
        centres, radii = surfaces_of(params, response.trial)
        for j in range(1, params.n + 1):
            excess = np.abs(centres[j] - centres[j - 1]) - (radii[j - 1] - radii[j])
            worst_nesting = max(worst_nesting, excess.max())
        inside = np.abs(response.tau[None, :] - centres) - radii
        worst_inside = max(worst_inside, inside.max())
    assert worst_nesting <= 1e-12
    assert worst_inside <= 1e-12


# --- symmetry --------------------------------------------------------------------------------

def test_negated_history_gives_negated_stress_exactly():
    odd_q = tuple(q if i % 2 == 0 else 0.0 for i, q in enumerate(PAPER.Q))   # Q_1, Q_3, ...
    even_a = tuple(a if i % 2 == 1 else 0.0 for i, a in enumerate(PAPER.A))  # A_2, A_4, ...
    params = dataclasses.replace(PAPER, Q=odd_q, A=even_a)
    law = NestedSurfaceLaw(params)
    history = random_walk(np.random.default_rng(3), steps=300, points=200, limit_deg=45.0)
    _, plus, end_plus = run_history(law, history)
    _, minus, end_minus = run_history(law, -history)
    for p, m in zip(plus, minus):
        np.testing.assert_array_equal(m.tau, -p.tau)
        np.testing.assert_array_equal(m.dtau_dC12, p.dtau_dC12)
        np.testing.assert_array_equal(m.active_surface, p.active_surface)
    np.testing.assert_array_equal(end_minus.gamma_p, -end_plus.gamma_p)
    np.testing.assert_array_equal(end_minus.centres, -end_plus.centres)


# --- path independence on a monotonic branch -------------------------------------------------

@pytest.mark.parametrize("waypoints, end", [
    ([], 18.0),                 # virgin, Table-2 row 0, hands over 2 -> 1 -> 0
    ([22.0], -8.0),             # unloading after 22 deg, row 1
    ([-30.0, 0.0], 31.5),       # reloading after -30 deg, row 2
    ([40.0, 10.0], -45.0),      # a negative branch after 40 deg, row 4
], ids=["virgin", "unloading", "reloading", "negative"])
def test_one_increment_equals_many_on_one_branch(params, waypoints, end):
    law = NestedSurfaceLaw(params)
    _, _, state = run_history_from(law, LawState.virgin(1, law.n), polyline([0.0] + waypoints))
    start = ([0.0] + waypoints)[-1]
    _, _, one = run_history_from(law, state, [end])
    _, _, many = run_history_from(law, state, np.linspace(start, end, 2001)[1:])
    np.testing.assert_allclose(one.gamma_p, many.gamma_p, rtol=0, atol=1e-13)
    np.testing.assert_allclose(one.centres, many.centres, rtol=0, atol=1e-11)
    assert one.gamma_max_deg == pytest.approx(many.gamma_max_deg)


def polyline(points, per_leg=300):
    legs = [np.linspace(a, b, per_leg)[1:] for a, b in zip(points[:-1], points[1:])]
    return np.concatenate(legs) if legs else np.array([])


def run_history_from(law, state, history):
    responses = []
    for angle in history:
        r = law.update(state, np.ones(1), np.ones(1), np.sin(np.radians([angle])))
        responses.append(r)
        state = r.trial
    return None, responses, state


# --- a second implementation -----------------------------------------------------------------

def test_vectorised_law_matches_pointwise_loop(params):
    rng = np.random.default_rng(7)
    law, reference = NestedSurfaceLaw(params), PointwiseLaw(params)
    points = 40
    history = random_walk(rng, steps=150, points=points, limit_deg=50.0)
    # stretch the yarns a little too: gamma_t uses C11, C22
    C11 = 1.0 + 0.02 * rng.random(points)
    C22 = 1.0 + 0.02 * rng.random(points)
    state = LawState.virgin(points, params.n)
    ref_states = [(0.0, [0.0] * params.n, 0.0)] * points
    worst = 0.0
    for angles in history:
        C12 = np.sin(np.radians(angles)) * np.sqrt(C11 * C22)
        response = law.update(state, C11, C22, C12)
        state = response.trial
        for i in range(points):
            tau, tangent, gp, centres, gmax, active = reference.update(*ref_states[i], C11[i], C22[i], C12[i])
            ref_states[i] = (gp, centres, gmax)
            assert active == response.active_surface[i]
            worst = max(worst, abs(tau - response.tau[i]), abs(gp - state.gamma_p[i]),
                        abs(tangent - response.dtau_dC12[i]) / 284.0, abs(gmax - state.gamma_max_deg[i]),
                        *(abs(c - state.centres[j, i]) for j, c in enumerate(centres)))
    assert worst < 1e-11


def test_update_does_not_touch_the_committed_state():
    law = NestedSurfaceLaw(PAPER)
    _, _, state = run_history(law, np.linspace(0, 30, 50), n_points=5)
    saved = state.copy()
    law.update(state, np.ones(5), np.ones(5), np.full(5, -0.3))
    np.testing.assert_array_equal(state.gamma_p, saved.gamma_p)
    np.testing.assert_array_equal(state.centres, saved.centres)
    np.testing.assert_array_equal(state.gamma_max_deg, saved.gamma_max_deg)


def test_yarn_stresses_are_elastic_and_shear_angle_uses_stretch():
    law = NestedSurfaceLaw(PAPER)
    C11, C22 = np.array([1.02, 0.99]), np.array([1.0, 1.01])
    C12 = np.sin(np.radians([30.0, -20.0])) * np.sqrt(C11 * C22)
    r = law.update(LawState.virgin(2, 2), C11, C22, C12)
    np.testing.assert_allclose(r.S11, 10000.0 * 0.5 * (C11 - 1.0), rtol=1e-15)
    np.testing.assert_allclose(r.S22, 10000.0 * 0.5 * (C22 - 1.0), rtol=1e-15)
    np.testing.assert_allclose(r.gamma_t_deg, [30.0, -20.0], rtol=1e-13)
    np.testing.assert_allclose(r.trial.gamma_max_deg, [30.0, 20.0], rtol=1e-13)
