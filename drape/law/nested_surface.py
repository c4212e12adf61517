"""The nested-surface elasto-plastic shear law for N material points (no DOLFINx).

The rules live once, in the compiled per-point kernel :mod:`drape.law.kernel` (reading:
docs/material-law.md, version 2). This module holds the state and the response as arrays and
calls the kernel. Per material point, with the yarn-frame components C11, C22, C12 of the
right Cauchy-Green tensor:

* yarn tension is elastic: S11 = mu K1 E11, S22 = mu K2 E22 (E = (C - I)/2), N/mm;
* the projected shear stress tau = 2 mu Ksh (C12 - sin gp) (N/mm) lives on nested intervals
  |tau - c_k| <= R_k(gp), k = 0 (outer, c_0 = q(gp)) .. n (innermost).

:meth:`NestedSurfaceLaw.update` never changes the committed state it is given: it returns the
response (stress, consistent tangent) and the trial state; the caller commits it (or not, e.g.
inside a Newton iteration or a line search of the finite-element solver).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drape.law import kernel
from drape.law.parameters import MaterialParameters

ELASTIC = kernel.ELASTIC


@dataclasses.dataclass
class LawState:
    """History variables of N material points (docs/material-law.md, "State").

    gamma_p: plastic shear angle (rad), (N,).
    centres: centres c_1..c_n of the inner surfaces (N/mm), (n, N).
    gamma_max_deg: largest |shear angle| reached so far (deg), (N,).
    active: the surface k active on the current branch (n at the start of a branch), (N,).
    direction: the branch's direction sigma, -1 or +1 (0: nothing has yielded yet), (N,).
    row: the Table-2 row latched at the branch's start, (N,).
    C: the yarn-frame C11, C22, C12 of this state (a new branch is split on the straight line
       from here to the next increment's C), (3, N).
    """

    gamma_p: np.ndarray
    centres: np.ndarray
    gamma_max_deg: np.ndarray
    active: np.ndarray
    direction: np.ndarray
    row: np.ndarray
    C: np.ndarray

    #: the per-point arrays, in the order of :meth:`columns`
    SCALARS = ("gamma_p", "gamma_max_deg", "active", "direction", "row")

    @classmethod
    def virgin(cls, n_points: int, n_inner: int) -> "LawState":
        C = np.zeros((3, n_points))
        C[:2] = 1.0
        integers = lambda value: np.full(n_points, value, dtype=np.int64)
        return cls(np.zeros(n_points), np.zeros((n_inner, n_points)), np.zeros(n_points),
                   integers(n_inner), integers(kernel.VIRGIN), integers(0), C)

    def copy(self) -> "LawState":
        return LawState(*(np.array(getattr(self, f.name)) for f in dataclasses.fields(self)))

    def columns(self) -> dict[str, np.ndarray]:
        """Every per-point quantity as one array of N values (for storage in the FE layer and
        checkpoints): the scalars, then centre_1..n and C11, C22, C12."""
        out = {name: getattr(self, name) for name in self.SCALARS}
        out.update({f"centre_{k + 1}": self.centres[k] for k in range(self.centres.shape[0])})
        out.update({f"C{ab}": self.C[i] for i, ab in enumerate(("11", "22", "12"))})
        return out

    @classmethod
    def from_columns(cls, columns: dict[str, np.ndarray], n_inner: int) -> "LawState":
        """The inverse of :meth:`columns` (integers are rounded back from floats)."""
        integer = lambda name: np.rint(columns[name]).astype(np.int64)
        size = np.asarray(columns["gamma_p"]).size
        centres = np.array([columns[f"centre_{k + 1}"] for k in range(n_inner)],
                           dtype=float).reshape(n_inner, size)
        C = np.array([columns[f"C{ab}"] for ab in ("11", "22", "12")], dtype=float)
        return cls(np.array(columns["gamma_p"], dtype=float), centres,
                   np.array(columns["gamma_max_deg"], dtype=float), integer("active"),
                   integer("direction"), integer("row"), C)

    @classmethod
    def stack(cls, states: list["LawState"]) -> "LawState":
        """The points of several states side by side."""
        fields = [f.name for f in dataclasses.fields(cls)]
        return cls(*(np.concatenate([getattr(s, name) for s in states], axis=-1)
                     for name in fields))

    def __len__(self) -> int:
        return self.gamma_p.shape[0]


@dataclasses.dataclass
class LawResponse:
    """Result of one increment for N points (nothing committed).

    tau: projected shear stress S:(G1 G2 + G2 G1) (N/mm); the yarn-frame S12 is tau / 2.
    dtau_dC12: consistent tangent d tau / d C12 (N/mm).
    S11, S22: yarn-frame normal PK2 components mu K1 E11, mu K2 E22 (N/mm).
    gamma_t_deg: total shear angle asin(C12 / sqrt(C11 C22)) (deg).
    active_surface: -1 where gp did not move in the increment, else the surface active at its end.
    trial: the state the increment ends in.
    """

    tau: np.ndarray
    dtau_dC12: np.ndarray
    S11: np.ndarray
    S22: np.ndarray
    gamma_t_deg: np.ndarray
    active_surface: np.ndarray
    trial: LawState


def shear_angle_deg(C11, C22, C12) -> np.ndarray:
    """Angle lost between the deformed yarns, asin(C12 / sqrt(C11 C22)), in degrees."""
    ratio = np.asarray(C12, dtype=float) / np.sqrt(np.maximum(np.multiply(C11, C22), 1e-300))
    return np.degrees(np.arcsin(np.clip(ratio, -1.0, 1.0)))


class NestedSurfaceLaw:
    """The law for one parameter set; :meth:`update` integrates one increment for N points."""

    def __init__(self, params: MaterialParameters):
        self.params = params
        self.n = params.n
        self.two_mu_ksh = 2.0 * params.mu * params.Ksh
        self._tables = (float(self.two_mu_ksh), np.asarray(params.Sy, dtype=float),
                        np.asarray(params.Q, dtype=float), np.asarray(params.A, dtype=float),
                        np.asarray(params.surfaces.gamma_max_deg, dtype=float),
                        np.ascontiguousarray(params.a_rows(), dtype=float),
                        np.ascontiguousarray(params.h_rows(), dtype=float))

    def update(self, state: LawState, C11, C22, C12) -> LawResponse:
        """Integrate one increment from the committed ``state`` to the current C (yarn frame).

        C11, C22, C12: arrays of shape (N,). ``state`` is not modified.
        """
        C11, C22, C12 = (np.ascontiguousarray(v, dtype=float) for v in (C11, C22, C12))
        trial = LawState(np.array(state.gamma_p, dtype=float),
                         np.array(state.centres, dtype=float).reshape(self.n, C12.size),
                         np.array(state.gamma_max_deg, dtype=float),
                         np.array(state.active, dtype=np.int64),
                         np.array(state.direction, dtype=np.int64),
                         np.array(state.row, dtype=np.int64),
                         np.array(state.C, dtype=float))
        tau, tangent = np.empty(C12.size), np.empty(C12.size)
        flow = np.empty(C12.size, dtype=np.int64)
        kernel.update_points(C11, C22, C12, trial.C, trial.gamma_p, trial.centres,
                             trial.gamma_max_deg, trial.active, trial.direction, trial.row,
                             *self._tables, tau, tangent, flow)
        mu = self.params.mu
        return LawResponse(tau=tau, dtau_dC12=tangent,
                           S11=mu * self.params.K1 * 0.5 * (C11 - 1.0),
                           S22=mu * self.params.K2 * 0.5 * (C22 - 1.0),
                           gamma_t_deg=shear_angle_deg(C11, C22, C12), active_surface=flow,
                           trial=trial)
