"""The nested-surface law against independent expectations (docs/material-law.md).

Closed forms (virgin outer curve, Masing's rule of the degenerate Iwan model), symmetry,
finite differences, increment independence, the rules of version 2 of the reading, and the
compiled kernel against the same code interpreted (NUMBA_DISABLE_JIT=1).
"""

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters, SurfaceTable, polynomial
from drape.picture_frame import cyclic_history
from law_helpers import random_walk, run_history, stack_states, surfaces_of

# no MPI in these tests: under mpirun each rank would do the same (tests/conftest.py)
pytestmark = pytest.mark.serial

PAPER = MaterialParameters()


@pytest.fixture(params=[2, 1, 0], ids=["three surfaces", "two surfaces", "one surface"])
def params(request):
    return PAPER.with_surfaces(request.param)


# --- consistent tangent ----------------------------------------------------------------------

def test_tangent_matches_finite_difference_in_every_regime():
    """d tau/d C12 equals a central difference of tau(C12) from the same committed state, for
    elastic steps, each active surface, steps just after a reversal and negative branches
    (away from events: the three evaluations end in the same regime)."""
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
    same_regime = ((plus.active_surface == centre.active_surface)
                   & (minus.active_surface == centre.active_surface)
                   & (plus.trial.row == minus.trial.row)
                   & (plus.trial.direction == minus.trial.direction))
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
    plastic = same_regime & (centre.active_surface >= 0)
    assert np.all(centre.dtau_dC12[plastic] < 0.5 * law.two_mu_ksh)


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


# --- version 2: increment independence, the loading branch, the state -----------------------

def random_cycles(rng, points, reversals=10, limit_deg=45.0):
    """Seeded cyclic histories: each point reverses at random amplitudes up to +-limit, each leg
    cut into 2-20 uneven increments; also a slight random yarn stretch that varies linearly."""
    rows = []
    for _ in range(points):
        turns = np.concatenate([[0.0], rng.uniform(-limit_deg, limit_deg, reversals)])
        legs = [a + (b - a) * np.sort(rng.random(rng.integers(2, 21)))
                for a, b in zip(turns[:-1], turns[1:])]
        rows.append(np.concatenate(legs + [turns[-1:]]))
    steps = min(r.size for r in rows)
    angles = np.array([r[:steps] for r in rows]).T
    stretch = 1.0 + 0.01 * np.cumsum(rng.normal(0.0, 0.1, (steps, points, 2)), axis=0) ** 2
    return angles, stretch


def yarn_C(angles, stretch):
    C11, C22 = stretch[..., 0], stretch[..., 1]
    return C11, C22, np.sin(np.radians(angles)) * np.sqrt(C11 * C22)


def drive(law, C11, C22, C12):
    """Run (steps, points) histories of C; return tau, gp, centres per step."""
    state = LawState.virgin(C12.shape[1], law.n)
    tau, gp, centres = [], [], []
    for c11, c22, c12 in zip(C11, C22, C12):
        r = law.update(state, c11, c22, c12)
        state = r.trial
        tau.append(r.tau)
        gp.append(state.gamma_p)
        centres.append(state.centres)
    return np.array(tau), np.array(gp), np.array(centres)


@pytest.mark.parametrize("m", [2, 7, 100])
def test_increments_cut_into_m_parts_give_the_same_answer(params, m):
    """Every increment of random cyclic histories up to +-45 deg (yarns stretching too) split
    into m equal parts on the straight line in C: tau, gp and the centres agree at the original
    points to 1e-10 of the history's largest |tau| (version 1 of the reading: 2.6 %)."""
    rng = np.random.default_rng(11 + m)
    law = NestedSurfaceLaw(params)
    angles, stretch = random_cycles(rng, points=24 if m == 100 else 60)
    coarse = np.stack(yarn_C(angles, stretch))                       # (3, steps, points)
    start = np.concatenate([np.stack([np.ones((1, coarse.shape[2]))] * 2
                                     + [np.zeros((1, coarse.shape[2]))]), coarse[:, :-1]], 1)
    parts = np.arange(1, m + 1) / m
    fine = start[:, :, None, :] + (coarse - start)[:, :, None, :] * parts[None, None, :, None]
    fine = fine.reshape(3, -1, coarse.shape[2])
    tau, gp, centres = drive(law, *coarse)
    tau_m, gp_m, centres_m = (v[m - 1::m] for v in drive(law, *fine))
    scale = np.abs(tau).max()
    assert np.abs(tau_m - tau).max() <= 1e-10 * scale
    assert np.abs(centres_m - centres).max(initial=0.0) <= 1e-10 * scale
    # gp: tau = 2 mu Ksh (C12 - sin gp) turns a 1e-10 of tau into 1e-10 / 284 of gp
    assert np.abs(gp_m - gp).max() <= 1e-10 * scale / law.two_mu_ksh
    assert np.abs(tau).max() > 1.0                                    # beyond 37 deg


@pytest.mark.parametrize("angle", [5.0, 28.5, 33.0, 37.5, 41.0])
@pytest.mark.parametrize("increments", [1, 10, 1000])
def test_virgin_loading_is_the_one_surface_model(angle, increments):
    """Once the outer surface is active (from about 0.75 deg with the paper's values), a virgin
    loading gives the one-surface model's tau, in 1 increment or in 1000."""
    history = np.linspace(0.0, angle, increments + 1)[1:]
    three = run_history(NestedSurfaceLaw(PAPER), history)[1][-1]
    one = run_history(NestedSurfaceLaw(PAPER.with_surfaces(0)), [angle])[1][-1]
    assert three.tau[0] == pytest.approx(one.tau[0], rel=0, abs=1e-12)
    assert three.active_surface[0] == 0


def test_virgin_loading_values_of_the_reading():
    """The figures docs/material-law.md gives for the paper's values."""
    law = NestedSurfaceLaw(PAPER)
    tau = [run_history(law, [angle])[1][-1].tau[0] for angle in (28.5, 41.0)]
    assert tau == pytest.approx([0.249338, 1.759205], abs=5e-7)
    # the outer surface takes over between 0.7 and 0.8 deg
    _, responses, _ = run_history(law, np.linspace(0.0, 1.0, 101)[1:])
    active = np.array([r.active_surface[0] for r in responses])
    first_outer = np.argmax(active == 0)
    assert 0.7 <= (first_outer + 1) * 0.01 <= 0.8
    assert np.all(np.diff(active[active >= 0]) <= 0)                   # hand-over outward only


def test_the_active_surface_only_moves_outward_within_a_branch():
    """Rule 6 and rule 1: within a branch (between reversals) the stored active surface never
    increases; every reversal starts at the innermost surface."""
    law = NestedSurfaceLaw(PAPER)
    angles, _ = random_cycles(np.random.default_rng(5), points=50)
    state = LawState.virgin(angles.shape[1], law.n)
    starts, previous = 0, np.zeros(angles.shape[1])
    for row in angles:
        r = law.update(state, np.ones(row.size), np.ones(row.size), np.sin(np.radians(row)))
        same = r.trial.direction == state.direction
        assert np.all(r.trial.active[same] <= state.active[same])
        new = ~same
        starts += np.count_nonzero(new)
        # a new branch goes the way the increment goes
        assert np.all(r.trial.direction[new] == np.sign(row - previous)[new])
        state, previous = r.trial, row
    assert starts > 200


def test_table_2_row_is_latched_per_branch():
    """Rule 7: a branch keeps the row of the amplitude it started from. Load to 30 deg (row 2
    latched at the reversal), unload to -36 deg: the whole unloading branch uses row 2 although
    it passes 32 deg; the next reversal latches row 3 (gamma_max 36)."""
    law = NestedSurfaceLaw(PAPER)
    history = np.concatenate([np.linspace(0, 30, 61)[1:], np.linspace(30, -36, 133)[1:],
                              np.linspace(-36, -20, 33)[1:]])
    _, responses, _ = run_history(law, history)
    rows = np.array([r.trial.row[0] for r in responses])
    directions = np.array([r.trial.direction[0] for r in responses])
    assert np.all(rows[:60] == 0)                                     # virgin: row of ~0 deg
    assert np.all(rows[directions == -1] == 2)
    assert np.all(rows[60 + 132:][directions[60 + 132:] == 1] == 3)
    assert np.array([r.trial.gamma_max_deg[0] for r in responses]).max() == pytest.approx(36.0)


def test_compiled_kernel_equals_the_same_code_interpreted(tmp_path, params):
    """NUMBA_DISABLE_JIT=1 runs the kernel's Python source: the same numbers to 1e-14."""
    script = tmp_path / "histories.py"
    script.write_text(INTERPRETED.format(n=params.n))
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    subprocess.run([sys.executable, str(script), str(tmp_path / "python.npz")], check=True,
                   env=env, cwd=tmp_path)
    subprocess.run([sys.executable, str(script), str(tmp_path / "numba.npz")], check=True,
                   cwd=tmp_path)
    python, compiled = np.load(tmp_path / "python.npz"), np.load(tmp_path / "numba.npz")
    assert python["interpreted"] and not compiled["interpreted"]
    scale = np.abs(python["tau"]).max()
    for name in ("tau", "gp", "centres"):
        assert np.abs(python[name] - compiled[name]).max(initial=0.0) <= 1e-14 * max(scale, 1)
    np.testing.assert_array_equal(python["flow"], compiled["flow"])


INTERPRETED = """
import sys
import numpy as np
from drape.law import kernel
from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters
law = NestedSurfaceLaw(MaterialParameters().with_surfaces({n}))
rng = np.random.default_rng(3)
walk = np.cumsum(rng.normal(0.0, 2.5, (240, 6)), axis=0)
angles = 45.0 * np.sin(np.radians(walk * 3.0))
state = LawState.virgin(6, law.n)
out = {{"tau": [], "gp": [], "centres": [], "flow": []}}
for row in angles:
    r = law.update(state, np.ones(6), np.ones(6), np.sin(np.radians(row)))
    state = r.trial
    for name, value in zip(out, (r.tau, state.gamma_p, state.centres, r.active_surface)):
        out[name].append(value)
interpreted = not hasattr(kernel.update_points, "py_func")
np.savez(sys.argv[1], interpreted=interpreted, **{{k: np.array(v) for k, v in out.items()}})
"""


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
    C12_end = (np.sin(gp_r - 2 * iwan_virgin_gamma_p(0.999 * sy[0], sy, h))
               - 0.999 * sy[0] / law.two_mu_ksh)
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


def test_update_does_not_touch_the_committed_state():
    law = NestedSurfaceLaw(PAPER)
    _, _, state = run_history(law, np.linspace(0, 30, 50), n_points=5)
    saved = state.copy()
    law.update(state, np.ones(5), np.ones(5), np.full(5, -0.3))
    np.testing.assert_array_equal(state.gamma_p, saved.gamma_p)
    np.testing.assert_array_equal(state.centres, saved.centres)
    for name in ("gamma_max_deg", "active", "direction", "row", "C"):
        np.testing.assert_array_equal(getattr(state, name), getattr(saved, name))


def test_yarn_stresses_are_elastic_and_shear_angle_uses_stretch():
    law = NestedSurfaceLaw(PAPER)
    C11, C22 = np.array([1.02, 0.99]), np.array([1.0, 1.01])
    C12 = np.sin(np.radians([30.0, -20.0])) * np.sqrt(C11 * C22)
    r = law.update(LawState.virgin(2, 2), C11, C22, C12)
    np.testing.assert_allclose(r.S11, 10000.0 * 0.5 * (C11 - 1.0), rtol=1e-15)
    np.testing.assert_allclose(r.S22, 10000.0 * 0.5 * (C22 - 1.0), rtol=1e-15)
    np.testing.assert_allclose(r.gamma_t_deg, [30.0, -20.0], rtol=1e-13)
    np.testing.assert_allclose(r.trial.gamma_max_deg, [30.0, 20.0], rtol=1e-13)
