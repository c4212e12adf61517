"""The fit of monotonic published curves (no unloading): the outer surface's loading edge
q + Sy_0 + alpha fitted to every selected series resampled within an angle range, the inner
surfaces keeping a base material's ratios (docs/calibration.md, "Monotonic data fit the outer
surface only")."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy.optimize import lsq_linear

from drape.calibration.history import monotonic_tau, rms
from drape.calibration.series import SeriesData
from drape.errors import InputError
from drape.law.parameters import SurfaceTable, polynomial

#: defect-correction iterations of the monotonic fit's stage 2
STAGE2_ITERATIONS = 3


@dataclasses.dataclass
class MonotonicFit:
    """Both models fitted to monotonic series, their tau at the resampled points (N/mm) and
    RMS errors, and the factor applied to the base's h_k."""

    one_surface: object          # MaterialParameters: the loading edge alone
    nested: object               # MaterialParameters: with the inner surfaces of the base
    names: np.ndarray            # the resampled points the fit used
    gamma_deg: np.ndarray
    tau: np.ndarray
    tau_one_surface: np.ndarray  # the models at those points
    tau_nested: np.ndarray
    rms_one_surface: float
    rms_nested: float
    h_scale: float
    info: dict


def resample(data: SeriesData, angle_range, step_deg: float = 0.5):
    """Each series on its own grid of step_deg within angle_range (linear interpolation in
    angle): every series weighs the same per degree, however densely it was digitised.
    Returns (names, gamma_deg, tau) as flat arrays."""
    lo, hi = angle_range
    names, gammas, taus = [], [], []
    for s in data.series:
        g, t = np.abs(s.gamma_deg), s.tau * np.sign(np.where(s.gamma_deg == 0, 1, s.gamma_deg))
        order = np.argsort(g, kind="stable")
        g, t = g[order], t[order]
        first = max(lo, g.min())
        last = min(hi, g.max())
        if last <= first:
            continue
        grid = np.arange(math.ceil(first / step_deg) * step_deg, last + 1e-9, step_deg)
        if grid.size == 0:
            continue
        gammas.append(grid)
        taus.append(np.interp(grid, g, t))
        names += [s.name] * grid.size
    if not gammas:
        return np.array([]), np.array([]), np.array([])
    return np.asarray(names), np.concatenate(gammas), np.concatenate(taus)


class EdgeModel:
    """Material parameters from the loading edge's coefficients theta = (Sy_0, c_1..c_d),
    e(gp) = Sy_0 + sum c_i gp^i: the odd powers go into q, the even ones into alpha (the law
    is then the same for both signs of shear); the inner surfaces, if any, keep the base's
    Sy_k/Sy_0 and a_k, and its h_k times h_scale."""

    def __init__(self, base, degree: int, n_inner: int, h_scale: float, label: str):
        self.base, self.degree, self.n_inner = base, degree, n_inner
        self.base_n = base.with_surfaces(n_inner) if n_inner < base.n else base
        self.h_scale, self.label = h_scale, label
        self.ratios = np.asarray(self.base_n.Sy) / self.base_n.Sy[0]

    def params(self, theta, nested=True):
        degree, n_inner, base_n = self.degree, self.n_inner, self.base_n
        c = np.asarray(theta[1:], dtype=float)
        odd = np.where(np.arange(1, degree + 1) % 2 == 1, c, 0.0)
        even = np.where(np.arange(1, degree + 1) % 2 == 0, c, 0.0)
        common = dict(Q=tuple(map(float, odd)), A=tuple(map(float, even)))
        if not nested or n_inner == 0:
            return dataclasses.replace(self.base, name=f"{self.label} (one surface)",
                                       Sy=(float(theta[0]),), surfaces=SurfaceTable(), **common)
        table = base_n.surfaces
        table = dataclasses.replace(table, h=tuple(tuple(float(h * self.h_scale)
                                                         for h in row[:n_inner])
                                                   for row in table.h),
                                    a=tuple(tuple(row[:n_inner]) for row in table.a))
        return dataclasses.replace(base_n, name=self.label,
                                   Sy=tuple(float(theta[0] * r) for r in self.ratios),
                                   surfaces=table, **common)


def fit_monotonic(data: SeriesData, base, degree: int = 8, n_inner: int = 2,
                  angle_range=(0.0, 35.0), name: str | None = None, log=print) -> MonotonicFit:
    """Fit the loading edge q + Sy_0 + alpha of the outer surface to monotonic curves.

    Monotonic data fix the loading edge e(gp) = Sy_0 + sum c_i gp^i only: its split into the
    centre q (kinematic) and the radius alpha (isotropic) shows only on unloading. drape puts the
    odd powers into q and the even ones into alpha (the law is then the same for both signs of
    shear) and asks c_i >= 0 (e rises and stays convex beyond the data). The inner surfaces keep
    the base material's ratios: Sy_k / Sy_0 and a_k as they are, h_k scaled by the ratio of the
    fitted to the base's rise of e over the angle range. Stage 1 is linear (gp from the data,
    non-negative least squares); stage 2 refits Sy_0 and c_i with the nested model simulated on
    a monotonic history (the inner surfaces act first on virgin loading, so the nested curve is
    not the edge).
    """
    lo, hi = angle_range
    names, gamma, tau = resample(data, angle_range)
    _check_enough(data, gamma.size, base, degree, n_inner, lo, hi)
    k2 = 2.0 * base.mu * base.Ksh
    gp = np.arcsin(np.clip(np.sin(np.radians(gamma)) - tau / k2, -1.0, 1.0))
    design = np.hstack([np.ones((gp.size, 1)), gp[:, None] ** np.arange(1, degree + 1)[None, :]])
    tau_range = float(np.ptp(tau)) or 1.0
    floor = 1e-6 * tau_range
    theta1 = _fit_edge(design, tau, floor, degree)
    label = name or f"calibrated from {Path(data.source).name}"
    model = EdgeModel(base, degree, n_inner, _h_scale(base, theta1, hi), label)
    one = model.params(theta1, nested=False)
    tau_one = monotonic_tau(one, gamma)
    log(f"  stage 1 (linear, the loading edge): RMS {rms(tau_one, tau):.4g} N/mm on "
        f"{gamma.size} points")
    theta = theta1
    info = {"points": int(gamma.size), "series": sorted(set(names.tolist()))}
    if n_inner:
        theta = _defect_correction(model, design, gamma, tau, theta1, floor, log)
    nested = model.params(theta)
    tau_nested = monotonic_tau(nested, gamma) if n_inner else tau_one
    return MonotonicFit(one, nested, names, gamma, tau, tau_one, tau_nested,
                        rms(tau_one, tau), rms(tau_nested, tau), model.h_scale, info)


def _check_enough(data: SeriesData, points: int, base, degree: int, n_inner: int, lo: float,
                  hi: float) -> None:
    """InputError unless there are more points than coefficients and the base material has
    the inner surfaces asked for."""
    if points < degree + 2:
        raise InputError(f"{points} points of the selected series within {lo:g}..{hi:g} deg",
                         source=data.source, key="--angle-range",
                         expected=f"at least {degree + 2} (one every 0.5 deg): a wider range, "
                                  "more series or a lower --degree")
    if n_inner > base.n:
        raise InputError(f"the base material has {base.n} inner surfaces", key="--surfaces",
                         value=n_inner, expected=f"at most {base.n} (the inner surfaces keep the "
                                                 "base material's ratios: no unloading data)")


def _fit_edge(design, target, floor: float, degree: int) -> np.ndarray:
    """theta = (Sy_0, c_1..c_d) by bounded linear least squares, Sy_0 >= floor, c_i >= 0."""
    return lsq_linear(design, target, bounds=(np.r_[floor, np.zeros(degree)], np.inf),
                      method="bvls").x


def _h_scale(base, theta, hi_deg: float) -> float:
    """The ratio of the fitted to the base's rise of the loading edge from 0 to hi_deg (1 if
    either does not rise)."""
    edge_hi = np.radians(hi_deg)
    base_rise = float(polynomial(base.Q, [edge_hi])[0] + polynomial(base.A, [edge_hi])[0])
    fit_rise = float(polynomial(theta[1:], [edge_hi])[0])
    return fit_rise / base_rise if base_rise > 0 and fit_rise > 0 else 1.0


def _defect_correction(model: EdgeModel, design, gamma, tau, theta1, floor: float,
                       log) -> np.ndarray:
    """Stage 2: delta = nested - one-surface curve at the current parameters, and the linear
    fit again to data - delta (delta hardly depends on them); the best of the passes."""
    best = (rms(monotonic_tau(model.params(theta1), gamma), tau), theta1)
    for iteration in range(STAGE2_ITERATIONS):
        current = best[1]
        delta = (monotonic_tau(model.params(current), gamma)
                 - monotonic_tau(model.params(current, nested=False), gamma))
        x = _fit_edge(design, tau - delta, floor, model.degree)
        error = rms(monotonic_tau(model.params(x), gamma), tau)
        log(f"  stage 2, iteration {iteration + 1} (nested model simulated, {model.n_inner} "
            f"inner surfaces with the base's ratios, h x {model.h_scale:.3g}): "
            f"RMS {error:.4g} N/mm")
        if error < best[0]:
            best = (error, x)
    return best[1]
