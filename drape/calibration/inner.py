"""Stage 2 of the cyclic fit, the inner surfaces: with the outer surface fixed, Sy_1..Sy_n and
the Table-2 coefficients a_k, h_k of each row fitted by simulating the nested model, row after
row in the order the history reaches them (docs/calibration.md, "Stage 2")."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from scipy.optimize import least_squares

from drape.calibration.curve import Curve
from drape.calibration.history import rms, simulate
from drape.calibration.outer import VALIDATION_GRID_RAD
from drape.errors import RunFailed
from drape.law.parameters import MaterialParameters, SurfaceTable, polynomial

#: h_k (N/mm per rad) is fitted as log(h) within these bounds, relative to the data's tau range
H_RANGE = (1e-4, 1e3)
#: iterations (residual evaluations, besides the finite-difference Jacobians) per Table-2 row
MAX_NFEV_ROW = 20
#: the f_k stay within (EPS, 1 - EPS)
EPS = 1e-3
#: each row starts from the row before's coefficients, h scaled by each of these
H_STARTS = (1.0, 0.1, 0.3, 3.0, 10.0)


class InnerFit:
    """Inner-surface parameters from unbounded-by-construction variables.

    With m = max(0, -min alpha) on the validation grid and T = Sy_0 - (n+1) m > 0:
    Sy_k = (n+1-k) m + T f_1...f_k (f in (0, 1)), so Sy_{k-1} - Sy_k > m and Sy_n > m; and
    a_k = u_1...u_k (u in [0, 1]), so 1 >= a_1 >= ... >= a_n >= 0. Then every radius
    Sy_k + a_k alpha is positive and the radii are nested wherever alpha >= -m: the set is valid
    whatever the variables (MaterialParameters' check). h_k = exp(eta_k) > 0.
    """

    def __init__(self, outer: MaterialParameters, n: int, bounds_deg, tau_range: float):
        self.outer, self.n, self.bounds = outer, n, tuple(bounds_deg)
        alpha = polynomial(outer.A, VALIDATION_GRID_RAD)
        self.m = max(0.0, -float(alpha.min()))
        self.slack = outer.Sy[0] - (n + 1) * self.m
        if not self.slack > 0:
            raise RunFailed(f"the fitted outer surface's alpha falls to {-self.m:.3g} N/mm within "
                            f"+-60 deg, too low to nest {n} inner surfaces of positive radius "
                            f"inside Sy_0 = {outer.Sy[0]:.3g}; try fewer --surfaces or a lower "
                            "--degree")
        self.rows = len(bounds_deg)
        self.f = np.full(n, 0.6)
        self.u = np.full((self.rows, n), 0.8)
        self.u[:, 0] = 0.9
        self.eta = np.zeros((self.rows, n))
        self.h_bounds = (math.log(H_RANGE[0] * tau_range), math.log(H_RANGE[1] * tau_range))

    def sy(self, f) -> tuple[float, ...]:
        n = self.n
        return (self.outer.Sy[0],) + tuple(
            (n + 1 - k) * self.m + self.slack * float(np.prod(f[:k])) for k in range(1, n + 1))

    def params(self, f=None, u=None, eta=None) -> MaterialParameters:
        f = self.f if f is None else f
        u = self.u if u is None else u
        eta = self.eta if eta is None else eta
        a = np.cumprod(u, axis=1)
        table = SurfaceTable(gamma_max_deg=self.bounds,
                             a=tuple(tuple(map(float, row)) for row in a),
                             h=tuple(tuple(map(float, row)) for row in np.exp(eta)))
        return dataclasses.replace(self.outer, Sy=self.sy(f), surfaces=table)

    def start_h(self, history) -> None:
        """Every row's h_k to start from: of the order of the outer surface's slope
        d(q + alpha)/dgp where the data is, times 3^k."""
        outer = self.outer
        gp = np.radians(np.linspace(-1.0, 1.0, 201) * np.max(np.abs(history)))
        outer_slope = np.abs(np.gradient(polynomial(outer.Q, gp) + polynomial(outer.A, gp), gp))
        h0 = np.clip(np.median(outer_slope), *np.exp(self.h_bounds) * [10.0, 0.1])
        self.eta[:] = np.log(h0 * 3.0 ** np.arange(self.n))[None, :]

    def fit_row(self, row: int, history, data, start_state, first: bool):
        """Fit Table-2 row ``row`` (and Sy_1..Sy_n if ``first``) to the stretch of the history
        during which it is the row in use, started from ``start_state``; keeps the result.
        Returns scipy's result and the number of starting points tried."""
        n = self.n

        def unpack(x):
            f = x[:n] if first else self.f
            rest = x[n:] if first else x
            u, eta = self.u.copy(), self.eta.copy()
            u[row], eta[row] = rest[:n], rest[n:]
            return f, u, eta

        def residual(x):
            f, u, eta = unpack(x)
            tau, *_ = simulate(self.params(f, u, eta), history,
                               None if start_state is None else start_state.copy())
            return tau - data

        lower = np.r_[np.full(n, EPS), np.zeros(n), np.full(n, self.h_bounds[0])]
        upper = np.r_[np.full(n, 1 - EPS), np.ones(n), np.full(n, self.h_bounds[1])]
        if not first:
            lower, upper = lower[n:], upper[n:]
        # starting points: the row before (its fit, or the generic start for the first row),
        # and the same with h scaled by 0.1, 0.3, 3 and 10
        base_u = self.u[row - 1] if row > 0 else self.u[row]
        base_eta = self.eta[row - 1] if row > 0 else self.eta[row]
        candidates = [np.r_[self.f if first else [], base_u, base_eta + math.log(scale)]
                      for scale in H_STARTS]
        best = None
        for x0 in candidates:
            x0 = np.clip(x0, lower, upper)
            cost = float(np.sum(residual(x0) ** 2))
            if best is None or cost < best[0]:
                best = (cost, x0)
        result = least_squares(residual, best[1], bounds=(lower, upper), method="trf",
                               diff_step=1e-6, x_scale=1.0, max_nfev=MAX_NFEV_ROW)
        self.f, self.u, self.eta = unpack(result.x)
        return result, len(candidates)


def fit_inner(curve: Curve, outer: MaterialParameters, n: int, bounds_deg, fit_rows: np.ndarray,
              log=print) -> tuple[MaterialParameters, dict]:
    """Fit Sy_1..Sy_n and Table 2 row by row, in the order the history reaches the rows.

    Row r's coefficients act only once the largest angle reached is in row r's range, so row r
    is fitted to that stretch of the history, started from the state the rows before it left.
    Sy_1..Sy_n are fitted with the first row reached. Rows the history never reaches keep the
    coefficients of the row before them.
    """
    tau_range = float(np.ptp(curve.tau)) or 1.0
    fit = InnerFit(outer, n, bounds_deg, tau_range)
    history, data = curve.gamma_deg[fit_rows], curve.tau[fit_rows]
    row_of = np.searchsorted(np.asarray(bounds_deg), np.maximum.accumulate(np.abs(history)),
                             side="right") - 1
    fit.start_h(history)
    state, fitted_rows, info = None, [], {"rows": {}, "nfev": 0}
    started = time.perf_counter()
    for row in range(fit.rows):
        segment = np.nonzero(row_of == row)[0]
        if segment.size == 0:
            if row > 0:
                fit.u[row], fit.eta[row] = fit.u[row - 1], fit.eta[row - 1]
            continue
        seg_history, seg_data = history[segment], data[segment]
        result, starts = fit.fit_row(row, seg_history, seg_data, state, first=not fitted_rows)
        _, _, _, state = simulate(fit.params(), seg_history,
                                  None if state is None else state.copy())
        fitted_rows.append(row)
        nfev = result.nfev * (result.x.size + 1) + starts
        info["nfev"] += nfev
        info["rows"][row] = {"rows": int(segment.size), "rms": rms(result.fun, 0.0),
                             "simulations": nfev}
        log(f"  stage 2, Table-2 row {row} (gamma_max >= {bounds_deg[row]:g} deg): "
            f"{segment.size} rows, RMS {rms(result.fun, 0.0):.4g} N/mm, ~{nfev} simulations")
    info["seconds"] = time.perf_counter() - started
    info["unreached_rows"] = [r for r in range(fit.rows) if r not in fitted_rows]
    return fit.params(), info
