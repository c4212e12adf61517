"""Several laws over disjoint sets of material points: the plies of a stack (no DOLFINx).

A stack's plies may each have their own material. :class:`PiecewiseLaw` holds one
:class:`~drape.law.nested_surface.NestedSurfaceLaw` per piece (ply) and the piece of every
point, and :meth:`PiecewiseLaw.update` runs each law on its own points only. The kernel is per
point, so a point's response depends on its own law, state and C alone: one piece covering
every point gives exactly the single law's response, and a point of a piece exactly what that
piece's law gives it on its own.

The state of all points is one :class:`~drape.law.nested_surface.LawState` with the largest
number of inner surfaces of the pieces (:attr:`PiecewiseLaw.n`); a law with fewer uses the
first of its points' centres, the others stay as they are (zero from the virgin state).
"""

from __future__ import annotations

import numpy as np

from drape.law.nested_surface import LawResponse, LawState


class PiecewiseLaw:
    """Law ``laws[k]`` at the points where ``piece == k`` (module docstring)."""

    def __init__(self, laws, piece):
        self.laws = tuple(laws)
        piece = np.asarray(piece, dtype=np.int64)
        if piece.size and (piece.min() < 0 or piece.max() >= len(self.laws)):
            raise ValueError(f"a point's piece lies outside 0..{len(self.laws) - 1}")
        self.piece = piece
        #: the points of each piece, None where one piece holds every point (no slicing)
        self.points = (None if len(self.laws) == 1 else
                       [np.flatnonzero(piece == k) for k in range(len(self.laws))])
        self.n = max(law.n for law in self.laws)

    def virgin(self) -> LawState:
        """The virgin state of every point: its own law's (the active surface of a fresh
        branch is that law's innermost, n of its own)."""
        state = LawState.virgin(self.piece.size, self.n)
        state.active[:] = self.per_point([law.n for law in self.laws]).astype(np.int64)
        return state

    def per_point(self, values) -> np.ndarray:
        """One value per piece -> one per point, (N,)."""
        return np.asarray(values, dtype=float)[self.piece]

    @property
    def two_mu_ksh(self) -> np.ndarray:
        """The elastic shear tangent 2 mu Ksh of every point (N/mm), (N,)."""
        return self.per_point([law.two_mu_ksh for law in self.laws])

    def yarn_stiffness(self) -> tuple[np.ndarray, np.ndarray]:
        """mu K1 and mu K2 of every point (N/mm): S_ii = mu K_i E_ii."""
        return (self.per_point([law.params.mu * law.params.K1 for law in self.laws]),
                self.per_point([law.params.mu * law.params.K2 for law in self.laws]))

    def update(self, state: LawState, C11, C22, C12) -> LawResponse:
        """Every piece's law on its points from the committed ``state`` (not modified), as
        :meth:`NestedSurfaceLaw.update`; returns the response of all points in their order."""
        if self.points is None:
            return self.laws[0].update(state, C11, C22, C12)
        C11, C22, C12 = (np.asarray(v, dtype=float) for v in (C11, C22, C12))
        size = C12.size
        trial = state.copy()
        trial.centres = trial.centres.reshape(self.n, size)
        out = {name: np.empty(size) for name in ("tau", "dtau_dC12", "S11", "S22",
                                                   "gamma_t_deg")}
        active_surface = np.empty(size, dtype=np.int64)
        for law, points in zip(self.laws, self.points):
            if not points.size:
                continue
            part = law.update(_points_of(state, points, law.n, size),
                              C11[points], C22[points], C12[points])
            for name, values in out.items():
                values[points] = getattr(part, name)
            active_surface[points] = part.active_surface
            for name in LawState.SCALARS + ("C",):
                getattr(trial, name)[..., points] = getattr(part.trial, name)
            trial.centres[: law.n, points] = part.trial.centres
        return LawResponse(active_surface=active_surface, trial=trial, **out)


def _points_of(state: LawState, points: np.ndarray, n: int, size: int) -> LawState:
    """The state of ``points`` only, with the first ``n`` centres."""
    centres = np.asarray(state.centres).reshape(-1, size)[:n, points]
    return LawState(state.gamma_p[points], centres, state.gamma_max_deg[points],
                    state.active[points], state.direction[points], state.row[points],
                    state.C[:, points])
