"""Helpers shared by the law tests: run histories, check nesting."""

from __future__ import annotations

import numpy as np

from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters, polynomial


def run_history(law: NestedSurfaceLaw, gamma_t_deg, n_points: int | None = None):
    """Drive points through shear histories, one increment per row (picture-frame kinematics).

    gamma_t_deg: (steps,) or (steps, points). Returns the committed states before each
    increment, the responses, and the final state.
    """
    history = np.asarray(gamma_t_deg, dtype=float)
    if history.ndim == 1:
        history = history[:, None] if n_points is None else np.repeat(history[:, None], n_points, 1)
    state = LawState.virgin(history.shape[1], law.n)
    before, responses = [], []
    for angles in history:
        before.append(state)
        ones = np.ones(angles.size)
        response = law.update(state, ones, ones, np.sin(np.radians(angles)))
        responses.append(response)
        state = response.trial
    return before, responses, state


def stack_states(states: list[LawState]) -> LawState:
    return LawState.stack(states)


def surfaces_of(params: MaterialParameters, state: LawState):
    """Centres c_0..c_n and radii R_0..R_n of a state (with its latched Table-2 row),
    (n+1, N) each."""
    gp = state.gamma_p
    a = params.a_rows()[state.row].T                    # (n+1, N)
    radii = np.asarray(params.Sy)[:, None] + a * polynomial(params.A, gp)[None, :]
    centres = np.vstack([polynomial(params.Q, gp)[None, :], state.centres])
    return centres, radii


def random_walk(rng, steps, points, sigma_deg=2.0, limit_deg=50.0):
    """Random shear histories reflected at +-limit (no repeated angle at the limit)."""
    walk = np.cumsum(rng.normal(0.0, sigma_deg, (steps, points)), axis=0)
    period = 4 * limit_deg
    walk = np.mod(walk + limit_deg, period)
    return np.where(walk > 2 * limit_deg, period - walk, walk) - limit_deg
