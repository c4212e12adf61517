"""The law driven along a picture-frame history, one law increment per row (C11 = C22 = 1,
C12 = sin gamma): what both fits simulate, the thinned history they simulate it on, and the
RMS error they report."""

from __future__ import annotations

import math

import numpy as np

from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters


def simulate(params: MaterialParameters, gamma_deg, state: LawState | None = None):
    """tau, plastic angle (rad) and active surface along the history, and the final state."""
    law = NestedSurfaceLaw(params)
    state = LawState.virgin(1, params.n) if state is None else state
    sines = np.sin(np.radians(np.asarray(gamma_deg, dtype=float)))
    tau, gamma_p = np.empty(sines.size), np.empty(sines.size)
    active = np.empty(sines.size, dtype=int)
    one = np.ones(1)
    for i, s in enumerate(sines):
        response = law.update(state, one, one, np.array([s]))
        state = response.trial
        tau[i], gamma_p[i], active[i] = (response.tau[0], state.gamma_p[0],
                                         response.active_surface[0])
    return tau, gamma_p, active, state


def fit_indices(gamma_deg, max_rows: int) -> np.ndarray:
    """Rows of the history that the fit simulates: every m-th row (about max_rows in all), every
    reversal and the last row.

    The law's result does not depend on how a history is cut into increments
    (docs/material-law.md, version 2), so the thinned history gives the same tau at the kept
    rows as the full one, as long as it keeps the turning points of the path.
    """
    gamma = np.asarray(gamma_deg, dtype=float)
    n = gamma.size
    if n <= max_rows:
        return np.arange(n)
    step = math.ceil(n / max_rows)
    keep = set(range(step - 1, n, step)) | {n - 1}
    direction = np.sign(np.diff(np.r_[0.0, gamma]))
    keep |= set(np.nonzero(direction[:-1] != direction[1:])[0].tolist())
    return np.asarray(sorted(keep))


def monotonic_history(hi_deg: float, bounds_deg=(), step_deg: float = 0.5) -> np.ndarray:
    """0 -> hi in steps of step_deg, with the Table-2 bounds inserted (the row is looked up with
    the largest angle at the end of an increment: a bound is an increment's end)."""
    grid = np.arange(step_deg, hi_deg + 1e-9, step_deg)
    extra = [b for b in bounds_deg if 0 < b < hi_deg]
    return np.unique(np.r_[grid, extra, hi_deg])


def monotonic_tau(params, gamma_deg, step_deg: float = 0.5):
    """tau of a virgin monotonic loading to every |gamma| (interpolated on a 0.5-deg history;
    one law increment per history angle, the picture frame's C11 = C22 = 1, C12 = sin gamma)."""
    g = np.abs(np.asarray(gamma_deg, dtype=float))
    history = monotonic_history(float(g.max()) if g.size else step_deg,
                                params.surfaces.gamma_max_deg if params.n else (), step_deg)
    law, state, one = NestedSurfaceLaw(params), LawState.virgin(1, params.n), np.ones(1)
    tau = np.empty(history.size)
    for i, s in enumerate(np.sin(np.radians(history))):
        response = law.update(state, one, one, np.array([s]))
        state, tau[i] = response.trial, response.tau[0]
    return np.interp(g, np.r_[0.0, history], np.r_[0.0, tau])


def rms(a, b) -> float:
    """Root mean square of a - b."""
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))
