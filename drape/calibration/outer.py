"""Stage 1 of the cyclic fit, the outer surface: the one-surface model's Q_1..Q_d, A_1..A_d
and Sy_0 fitted with a robust loss, first as a linear least-squares problem (the plastic angle
follows from the data and Ksh; loading rows lie on q + Sy_0 + alpha, unloading rows on
q - Sy_0 - alpha), then by simulating the history with its exact Jacobian
(docs/calibration.md, "Stage 1")."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from scipy.optimize import least_squares

from drape.calibration.curve import Curve
from drape.calibration.history import simulate
from drape.law.parameters import MaterialParameters, SurfaceTable

#: the grid on which MaterialParameters checks that the radii stay positive and nested
VALIDATION_GRID_RAD = np.radians(np.linspace(-60.0, 60.0, 1201))


def _powers(x, degree: int) -> np.ndarray:
    """(len(x), degree) columns x^1 .. x^degree."""
    return np.asarray(x, dtype=float)[:, None] ** np.arange(1, degree + 1)[None, :]


def _robust_scale(residuals, floor: float) -> float:
    """The soft-L1 loss's scale: 1.4826 x the median absolute residual (N/mm), at least
    ``floor``."""
    return max(1.4826 * float(np.median(np.abs(residuals))), floor)


class OuterFit:
    """The one-surface model's parameters theta = (Q_1..Q_d, A_1..A_d, Sy_0) and its residuals.

    Besides the residuals in tau, alpha(gp) >= -c Sy_0 on the validation grid is asked for by a
    penalty (c = 1 / (2 (n + 1)) with n inner surfaces to come), so that stage 2 can always nest
    n inner surfaces inside the outer one (drape.calibration.inner.InnerFit).
    """

    def __init__(self, base: MaterialParameters, degree: int, n_inner: int, tau_range: float):
        self.base, self.degree = base, degree
        self.k2 = 2.0 * base.mu * base.Ksh
        self.c = 1.0 / (2.0 * (n_inner + 1))
        self.grid_powers = _powers(VALIDATION_GRID_RAD, degree)
        # one penalty row per grid point where alpha is too low: 10 x the shortfall (N/mm)
        self.penalty_weight = 10.0

    def params(self, theta) -> MaterialParameters:
        d = self.degree
        return dataclasses.replace(self.base, Q=tuple(map(float, theta[:d])),
                                   A=tuple(map(float, theta[d:2 * d])), Sy=(float(theta[-1]),),
                                   surfaces=SurfaceTable())

    def penalty(self, theta):
        d = self.degree
        value = self.grid_powers @ theta[d:2 * d] + self.c * theta[-1]
        violated = value < 0.0
        jac = np.zeros((value.size, theta.size))
        jac[violated, d:2 * d] = self.penalty_weight * self.grid_powers[violated]
        jac[violated, -1] = self.penalty_weight * self.c
        return self.penalty_weight * np.minimum(value, 0.0), jac

    def linear_design(self, gamma_deg, tau):
        """Rows tau = q(gp) + sigma (Sy_0 + alpha(gp)), gp from the data, sigma the direction."""
        gp = np.arcsin(np.clip(np.sin(np.radians(gamma_deg)) - tau / self.k2, -1.0, 1.0))
        direction = np.sign(np.diff(np.r_[0.0, gamma_deg]))
        for i in range(1, direction.size):       # a repeated angle keeps the last direction
            if direction[i] == 0:
                direction[i] = direction[i - 1]
        powers = _powers(gp, self.degree)
        return np.hstack([powers, direction[:, None] * powers, direction[:, None]])

    def simulated(self, theta, gamma_deg):
        """tau along the history and its Jacobian d tau / d theta (forward sensitivities: a
        plastic increment ends where g(gp) = k2 (sin gt - sin gp) - q(gp) - sigma R(gp) = 0,
        whatever the state before it; an elastic one keeps gp)."""
        d = self.degree
        tau, gp, active, _ = simulate(self.params(theta), gamma_deg)
        powers = _powers(gp, d)
        dpowers = np.arange(1, d + 1)[None, :] * np.hstack([np.ones((gp.size, 1)), powers[:, :-1]])
        q, dq = powers @ theta[:d], dpowers @ theta[:d]
        dalpha = dpowers @ theta[d:2 * d]
        sigma = np.sign(tau - q)
        dg_dgp = -self.k2 * np.cos(gp) - dq - sigma * dalpha
        dg_dtheta = -np.hstack([powers, sigma[:, None] * powers, sigma[:, None]])
        dgp = np.zeros((gp.size, theta.size))
        previous = np.zeros(theta.size)
        for i in range(gp.size):
            if active[i] == 0:
                previous = -dg_dtheta[i] / dg_dgp[i]
            dgp[i] = previous
        return tau, -self.k2 * np.cos(gp)[:, None] * dgp


def fit_outer(curve: Curve, base: MaterialParameters, degree: int, n_inner: int,
              fit_rows: np.ndarray, log=print) -> tuple[MaterialParameters, dict]:
    """Stage 1: the one-surface model fitted to the curve, linear first, then simulated on the
    rows ``fit_rows`` of the history. Returns its parameters and what the fit took."""
    tau_range = float(np.ptp(curve.tau)) or 1.0
    model = OuterFit(base, degree, n_inner, tau_range)
    theta, lower, scale = _fit_linear(model, curve, tau_range)
    info = {"linear_scale": scale}
    history, data = curve.gamma_deg[fit_rows], curve.tau[fit_rows]
    started = time.perf_counter()
    result = _fit_simulated(model, history, data, theta, lower, scale)
    info.update(nfev=result.nfev, seconds=time.perf_counter() - started, status=result.status)
    log(f"  stage 1: {result.nfev} simulations of {history.size} rows in "
        f"{info['seconds']:.1f} s (robust scale {scale:.3g} N/mm)")
    return model.params(result.x), info


def _fit_linear(model: OuterFit, curve: Curve, tau_range: float):
    """Plain linear least squares, then a robust one (soft L1) that lets the rows off the
    outer surface (elastic unloading, inner surfaces) count as outliers. Returns theta, its
    lower bounds and the robust scale (N/mm)."""
    design = model.linear_design(curve.gamma_deg, curve.tau)
    target = curve.tau
    floor = 1e-4 * tau_range
    theta, *_ = np.linalg.lstsq(design, curve.tau, rcond=None)
    theta[-1] = max(theta[-1], floor)
    lower = np.full(theta.size, -np.inf)
    lower[-1] = 1e-12 * tau_range

    def linear(theta):
        pen, _ = model.penalty(theta)
        return np.r_[design @ theta - target, pen]

    def linear_jac(theta):
        return np.vstack([design, model.penalty(theta)[1]])

    scale = _robust_scale(design @ theta - target, floor)
    for _ in range(2):
        result = least_squares(linear, theta, jac=linear_jac, bounds=(lower, np.inf),
                               loss="soft_l1", f_scale=scale, x_scale="jac", method="trf")
        theta = result.x
        scale = _robust_scale(design @ theta - target, floor)
    return theta, lower, scale


def _fit_simulated(model: OuterFit, history, data, theta, lower, scale):
    """The one-surface model simulated on the (thinned) history, the same robust loss; one
    simulation gives both the residuals and their Jacobian."""
    cache = {}

    def evaluate(theta):
        key = theta.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = model.simulated(theta, history)
        return cache[key]

    def residual(theta):
        pen, _ = model.penalty(theta)
        return np.r_[evaluate(theta)[0] - data, pen]

    def jacobian(theta):
        return np.vstack([evaluate(theta)[1], model.penalty(theta)[1]])

    return least_squares(residual, theta, jac=jacobian, bounds=(lower, np.inf), loss="soft_l1",
                         f_scale=scale, x_scale="jac", method="trf", max_nfev=60)

