"""Fit the nested-surface law to a measured picture-frame curve.

The input is a CSV file with one row per increment of the test, as for
`drape picture-frame --history`: a column gamma_t_deg (the frame's shear angle, degrees) and
either tau (the projected shear stress, N/mm) or force (the frame force, N, with --frame-side
giving the frame's side L in mm; tau = 2 F sin(pi/4 - gamma/2) / (L cos gamma)). The curve
must be cyclic: at least one loading and one unloading branch.

Published curves (a first column 'series', e.g. data/cao2008/) are read by drape.measured:
--series picks some, the measured column is converted to tau with --frame-side/--fabric-side
(energy normalisation); monotonic series fit the outer surface's loading edge within
--angle-range, the inner surfaces keeping the base material's ratios (docs/calibration.md,
"Published curves"); one series with unloading is fitted as below.

Stage 1, the outer surface: the one-surface model (Q_1..Q_d, A_1..A_d and Sy_0) is fitted with a
robust loss, first as a linear least-squares problem (the plastic angle follows from the data and
Ksh; loading rows lie on q + Sy_0 + alpha, unloading rows on q - Sy_0 - alpha), then by simulating
the history. Stage 2, the inner surfaces: with the outer surface fixed, Sy_1..Sy_n and the Table-2
coefficients a_k, h_k of each row are fitted by simulating the nested model, row after row in the
order the history reaches them. K1, K2, Ksh and mu are not fitted (taken from --material).

Writes material.toml (for --material), calibration.png (data and fitted curves) and
calibration.csv (the curves), and prints the RMS error in tau of each stage. See
docs/calibration.md.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from drape.errors import InputError, RunFailed
from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import (PAPER_GAMMA_MAX_DEG, MaterialParameters, SurfaceTable,
                                  load_material, material_toml, polynomial)
from drape.measured import QUANTITIES
from drape.picture_frame import frame_tau

HELP = "fit the law to a measured picture-frame curve (CSV) -> material TOML + PNG"

#: the grid on which MaterialParameters checks that the radii stay positive and nested
VALIDATION_GRID_RAD = np.radians(np.linspace(-60.0, 60.0, 1201))
DEFAULT_FIT_ROWS = 400
#: h_k (N/mm per rad) is fitted as log(h) within these bounds, relative to the data's tau range
H_RANGE = (1e-4, 1e3)
#: iterations (residual evaluations, besides the finite-difference Jacobians) per Table-2 row
MAX_NFEV_ROW = 20


# --- input -------------------------------------------------------------------------------------

@dataclasses.dataclass
class Curve:
    """A measured picture-frame curve: one increment per row."""

    gamma_deg: np.ndarray
    tau: np.ndarray
    source: str
    column: str          # 'tau' or 'force'

    def __len__(self):
        return self.gamma_deg.size


def read_curve(path: str | Path, frame_side: float | None = None) -> Curve:
    """Read gamma_t_deg and tau (N/mm), or force (N) converted with the frame side (mm)."""
    path = Path(path)
    expected = ("a CSV file with a header line naming gamma_t_deg and tau (N/mm), "
                "or gamma_t_deg and force (N) with --frame-side")
    if not path.is_file():
        raise InputError("file not found" if not path.exists() else "not a file",
                         source=str(path), expected=expected)
    if frame_side is not None and not (math.isfinite(frame_side) and frame_side > 0):
        raise InputError("not a frame side", key="--frame-side", value=frame_side,
                         expected="the side of the picture frame in mm, a number > 0")
    column = "force" if frame_side is not None else "tau"
    try:
        with path.open(newline="") as stream:
            reader = csv.reader(stream)
            header = next(reader, None)
            if not header:
                raise InputError("empty file", source=str(path), expected=expected)
            names = [name.strip() for name in header]
            if "gamma_t_deg" not in names:
                raise InputError("no 'gamma_t_deg' column", source=str(path), value=names,
                                 expected=expected)
            if column not in names:
                if column == "tau" and "force" in names:
                    raise InputError("no 'tau' column; a 'force' column needs the frame's size",
                                     source=str(path), value=names,
                                     expected="--frame-side L (mm) to convert force to tau")
                raise InputError(f"no '{column}' column", source=str(path), value=names,
                                 expected=("a column force (N) when --frame-side is given"
                                           if column == "force" else expected))
            i_gamma, i_value = names.index("gamma_t_deg"), names.index(column)
            gamma, value = [], []
            for line, row in enumerate(reader, start=2):
                if not row or all(not cell.strip() for cell in row):
                    continue
                for index, name, unit, out in ((i_gamma, "gamma_t_deg", "deg", gamma),
                                               (i_value, column,
                                                "N" if column == "force" else "N/mm",
                                                value)):
                    text = row[index].strip() if index < len(row) else ""
                    try:
                        number = float(text)
                    except ValueError:
                        number = math.nan
                    if not math.isfinite(number):
                        raise InputError(f"line {line}, column '{name}': {text!r} is not a number",
                                         source=str(path), expected=f"a finite number ({unit})")
                    if name == "gamma_t_deg" and abs(number) >= 90.0:
                        raise InputError(f"line {line}, column 'gamma_t_deg': {text} is not a "
                                         "shear angle", source=str(path),
                                         expected="a number of degrees within (-90, 90)")
                    out.append(number)
    except UnicodeDecodeError:
        raise InputError("not a text file", source=str(path), expected=expected) from None
    gamma_deg, values = np.asarray(gamma, dtype=float), np.asarray(value, dtype=float)
    if gamma_deg.size < 10:
        raise InputError(f"{gamma_deg.size} data rows", source=str(path),
                         expected="at least 10 rows, one per increment of a cyclic test")
    direction = np.sign(np.diff(np.r_[0.0, gamma_deg]))
    if not (np.any(direction * np.sign(gamma_deg) > 0)
            and np.any(direction * np.sign(gamma_deg) < 0)):
        raise InputError("the shear angle never goes back towards 0", source=str(path),
                         expected="a cyclic history: loading and unloading branches "
                                  "(the outer surface's centre and radius are told apart by both)")
    tau = frame_tau(values, gamma_deg, frame_side) if column == "force" else values
    return Curve(gamma_deg, tau, str(path), column)


def parse_rows(text: str) -> tuple[float, ...]:
    """'0,19,28,32,37' -> the Table-2 row bounds (deg), checked as SurfaceTable checks them."""
    try:
        bounds = tuple(float(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise InputError("not a list of numbers", key="--rows", value=text,
                         expected="comma-separated angles in degrees, e.g. 0,19,28,32,37") from None
    if (not bounds or bounds[0] != 0.0 or any(b1 <= b0 for b0, b1 in zip(bounds, bounds[1:]))
            or not all(math.isfinite(b) for b in bounds)):
        raise InputError("not increasing row bounds starting at 0", key="--rows", value=text,
                         expected="0 < b1 < b2 < ..., e.g. 0,19,28,32,37")
    return bounds


# --- simulation --------------------------------------------------------------------------------

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


def rms(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def _powers(x, degree: int) -> np.ndarray:
    """(len(x), degree) columns x^1 .. x^degree."""
    return np.asarray(x, dtype=float)[:, None] ** np.arange(1, degree + 1)[None, :]


def _robust_scale(residuals, floor: float) -> float:
    return max(1.4826 * float(np.median(np.abs(residuals))), floor)


# --- stage 1: the outer surface ----------------------------------------------------------------

class OuterFit:
    """The one-surface model's parameters theta = (Q_1..Q_d, A_1..A_d, Sy_0) and its residuals.

    Besides the residuals in tau, alpha(gp) >= -c Sy_0 on the validation grid is asked for by a
    penalty (c = 1 / (2 (n + 1)) with n inner surfaces to come), so that stage 2 can always nest
    n inner surfaces inside the outer one (see _InnerFit).
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
    from scipy.optimize import least_squares

    tau_range = float(np.ptp(curve.tau)) or 1.0
    model = OuterFit(base, degree, n_inner, tau_range)
    design = model.linear_design(curve.gamma_deg, curve.tau)
    target = curve.tau
    floor = 1e-4 * tau_range
    # (a) plain linear least squares, then a robust one (soft L1) that lets the rows off the
    #     outer surface (elastic unloading, inner surfaces) count as outliers
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
    info = {"linear_scale": scale}

    # (b) the one-surface model simulated on the (thinned) history, same robust loss
    history, data = curve.gamma_deg[fit_rows], curve.tau[fit_rows]
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

    started = time.perf_counter()
    result = least_squares(residual, theta, jac=jacobian, bounds=(lower, np.inf), loss="soft_l1",
                           f_scale=scale, x_scale="jac", method="trf", max_nfev=60)
    info.update(nfev=result.nfev, seconds=time.perf_counter() - started, status=result.status)
    log(f"  stage 1: {result.nfev} simulations of {history.size} rows in "
        f"{info['seconds']:.1f} s (robust scale {scale:.3g} N/mm)")
    return model.params(result.x), info


# --- stage 2: the inner surfaces ---------------------------------------------------------------

class _InnerFit:
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


def fit_inner(curve: Curve, outer: MaterialParameters, n: int, bounds_deg, fit_rows: np.ndarray,
              log=print) -> tuple[MaterialParameters, dict]:
    """Fit Sy_1..Sy_n and Table 2 row by row, in the order the history reaches the rows.

    Row r's coefficients act only once the largest angle reached is in row r's range, so row r
    is fitted to that stretch of the history, started from the state the rows before it left.
    Sy_1..Sy_n are fitted with the first row reached. Rows the history never reaches keep the
    coefficients of the row before them.
    """
    from scipy.optimize import least_squares

    tau_range = float(np.ptp(curve.tau)) or 1.0
    fit = _InnerFit(outer, n, bounds_deg, tau_range)
    history, data = curve.gamma_deg[fit_rows], curve.tau[fit_rows]
    row_of = np.searchsorted(np.asarray(bounds_deg), np.maximum.accumulate(np.abs(history)),
                             side="right") - 1
    # start: h of the order of the outer surface's slope d(q + alpha)/dgp where the data is
    gp = np.radians(np.linspace(-1.0, 1.0, 201) * np.max(np.abs(history)))
    outer_slope = np.abs(np.gradient(polynomial(outer.Q, gp) + polynomial(outer.A, gp), gp))
    h0 = np.clip(np.median(outer_slope), *np.exp(fit.h_bounds) * [10.0, 0.1])
    fit.eta[:] = np.log(h0 * 3.0 ** np.arange(n))[None, :]
    eps = 1e-3
    state, fitted_rows, info = None, [], {"rows": {}, "nfev": 0}
    started = time.perf_counter()
    for row in range(fit.rows):
        segment = np.nonzero(row_of == row)[0]
        if segment.size == 0:
            if row > 0:
                fit.u[row], fit.eta[row] = fit.u[row - 1], fit.eta[row - 1]
            continue
        first = not fitted_rows
        seg_history, seg_data = history[segment], data[segment]
        start_state = state

        def unpack(x, row=row, first=first):
            f = x[:n] if first else fit.f
            rest = x[n:] if first else x
            u, eta = fit.u.copy(), fit.eta.copy()
            u[row], eta[row] = rest[:n], rest[n:]
            return f, u, eta

        def residual(x):
            f, u, eta = unpack(x)
            tau, *_ = simulate(fit.params(f, u, eta), seg_history,
                               None if start_state is None else start_state.copy())
            return tau - seg_data

        lower = np.r_[np.full(n, eps), np.zeros(n), np.full(n, fit.h_bounds[0])]
        upper = np.r_[np.full(n, 1 - eps), np.ones(n), np.full(n, fit.h_bounds[1])]
        if not first:
            lower, upper = lower[n:], upper[n:]
        # starting points: the row before (its fit, or the generic start for the first row),
        # and the same with h scaled by 0.1, 0.3, 3 and 10
        base_u = fit.u[row - 1] if row > 0 else fit.u[row]
        base_eta = fit.eta[row - 1] if row > 0 else fit.eta[row]
        candidates = [np.r_[fit.f if first else [], base_u, base_eta + math.log(scale)]
                      for scale in (1.0, 0.1, 0.3, 3.0, 10.0)]
        best = None
        for x0 in candidates:
            x0 = np.clip(x0, lower, upper)
            cost = float(np.sum(residual(x0) ** 2))
            if best is None or cost < best[0]:
                best = (cost, x0)
        result = least_squares(residual, best[1], bounds=(lower, upper), method="trf",
                               diff_step=1e-6, x_scale=1.0, max_nfev=MAX_NFEV_ROW)
        fit.f, fit.u, fit.eta = unpack(result.x)
        _, _, _, state = simulate(fit.params(), seg_history,
                                  None if start_state is None else start_state.copy())
        fitted_rows.append(row)
        nfev = result.nfev * (result.x.size + 1) + len(candidates)
        info["nfev"] += nfev
        info["rows"][row] = {"rows": int(segment.size), "rms": rms(result.fun, 0.0),
                             "simulations": nfev}
        log(f"  stage 2, Table-2 row {row} (gamma_max >= {bounds_deg[row]:g} deg): "
            f"{segment.size} rows, RMS {rms(result.fun, 0.0):.4g} N/mm, ~{nfev} simulations")
    info["seconds"] = time.perf_counter() - started
    info["unreached_rows"] = [r for r in range(fit.rows) if r not in fitted_rows]
    return fit.params(), info


# --- the whole calibration ---------------------------------------------------------------------

@dataclasses.dataclass
class Calibration:
    one_surface: MaterialParameters
    nested: MaterialParameters
    tau_one_surface: np.ndarray     # on the full history
    tau_nested: np.ndarray
    rms_one_surface: float
    rms_nested: float
    info: dict


def calibrate(curve: Curve, base: MaterialParameters | None = None, degree: int = 8,
              n_inner: int = 2, rows=PAPER_GAMMA_MAX_DEG, max_fit_rows: int = DEFAULT_FIT_ROWS,
              name: str | None = None, log=print) -> Calibration:
    base = MaterialParameters() if base is None else base
    rows = tuple(float(b) for b in rows)
    fit_rows = fit_indices(curve.gamma_deg, max_fit_rows)
    log(f"drape calibrate: {len(curve)} rows from {curve.source}, fitting on {fit_rows.size}")
    outer, info1 = fit_outer(curve, base, degree, n_inner, fit_rows, log)
    name = name or f"calibrated from {Path(curve.source).name}"
    outer = dataclasses.replace(outer, name=f"{name} (one surface)")
    tau_one = simulate(outer, curve.gamma_deg)[0]
    if n_inner:
        nested, info2 = fit_inner(curve, outer, n_inner, rows, fit_rows, log)
        nested = dataclasses.replace(nested, name=name)
        tau_nested = simulate(nested, curve.gamma_deg)[0]
    else:
        nested, info2, tau_nested = dataclasses.replace(outer, name=name), {}, tau_one
    return Calibration(outer, nested, tau_one, tau_nested, rms(tau_one, curve.tau),
                       rms(tau_nested, curve.tau), {"stage1": info1, "stage2": info2,
                                                   "fit_rows": int(fit_rows.size)})


def plot_fit(path: Path, curve: Curve, result: Calibration) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=120)
    ax.plot(curve.gamma_deg, curve.tau, ".", color="0.55", ms=2.5,
            label=f"data ({len(curve)} rows)")
    ax.plot(curve.gamma_deg, result.tau_one_surface, color="tab:orange", lw=1.1, ls="--",
            label=f"stage 1, one surface (RMS {result.rms_one_surface:.3g} N/mm)", zorder=3)
    if result.nested.n:
        ax.plot(curve.gamma_deg, result.tau_nested, color="tab:blue", lw=1.5,
                label=f"stage 2, {result.nested.n + 1} nested surfaces "
                      f"(RMS {result.rms_nested:.3g} N/mm)")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.axvline(0.0, color="0.6", lw=0.6)
    ax.set_xlabel(r"shear angle $\gamma_t$ (deg)")
    ax.set_ylabel(r"projected shear stress $\tau$ (N/mm)")
    ax.set_title(f"drape calibrate: {Path(curve.source).name}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# --- command line ------------------------------------------------------------------------------

#: what it writes in --output (not overwritten without --overwrite)
RESULT_FILES = ("material.toml", "calibration.csv", "calibration.png")


def add_arguments(parser) -> None:
    parser.add_argument("data", metavar="CSV",
                        help="measured curve: columns gamma_t_deg and tau (N/mm), or "
                             "gamma_t_deg and force (N) with --frame-side; one increment per row; "
                             "or published curves: series, shear_angle_deg and a measured "
                             "column (docs/calibration.md)")
    parser.add_argument("--frame-side", default=None, metavar="MM",
                        help="side L of the picture frame (mm, hinge to hinge): read the force "
                             "column (N) and convert it, tau = 2 F sin(pi/4 - gamma/2) / "
                             "(L cos gamma); for a file with a series column, MM or "
                             "NAME=MM,NAME=MM per series (NAME: a series or its first word)")
    parser.add_argument("--fabric-side", default=None, metavar="MM",
                        help="series files: side of the sheared fabric square (mm), MM or "
                             "NAME=MM,... (needed with forces; tau = 2 F_s L_frame / "
                             "L_fabric^2, docs/calibration.md)")
    parser.add_argument("--series", default=None, metavar="A,B,...",
                        help="series files: the series to fit, comma-separated, CSV quoting "
                             "(e.g. HKUST,UN,\"KUL 3rd.\"); default every series")
    parser.add_argument("--quantity", default=None, metavar="NAME",
                        help="series files: what the measured column holds, when its name does "
                             "not say it: " + ", ".join(QUANTITIES))
    parser.add_argument("--angle-range", default="0,35", metavar="LO,HI",
                        help="series files with monotonic data: fit the points within LO..HI "
                             "degrees (default 0,35, where the labs of Cao et al. 2008 agree)")
    parser.add_argument("--material", default=None, metavar="FILE",
                        help="material TOML giving K1, K2, Ksh and mu, which are not fitted "
                             "(default: the paper's values)")
    parser.add_argument("--surfaces", type=int, default=2, metavar="N",
                        help="number of inner surfaces to fit (default 2, as the paper; "
                             "0: the one-surface model only)")
    parser.add_argument("--degree", type=int, default=8, metavar="D",
                        help="degree of the polynomials q and alpha (default 8, as the paper)")
    parser.add_argument("--rows", default=",".join(f"{b:g}" for b in PAPER_GAMMA_MAX_DEG),
                        metavar="B0,B1,...",
                        help="lower bounds (deg) of the Table-2 rows, from 0 "
                             "(default: the paper's 0,19,28,32,37)")
    parser.add_argument("--fit-rows", type=int, default=DEFAULT_FIT_ROWS, metavar="N",
                        help="simulate about N rows of the history while fitting (every m-th row "
                             f"plus each reversal; default {DEFAULT_FIT_ROWS}); the errors "
                             "reported are on every row")
    parser.add_argument("--name", default=None, help="name written into the material file")
    parser.add_argument("--output", default="results/calibrate", metavar="DIR",
                        help="folder for material.toml, calibration.png and calibration.csv "
                             "(default results/calibrate)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the results (material.toml, calibration.csv/png) already "
                             "in --output")


def main(args) -> int:
    from drape.io.folder import claim
    for key, value, lo, hi in (("--surfaces", args.surfaces, 0, 6),
                               ("--degree", args.degree, 1, 12),
                               ("--fit-rows", args.fit_rows, 20, 10 ** 6)):
        if not lo <= value <= hi:
            raise InputError("out of range", key=key, value=value,
                             expected=f"an integer from {lo} to {hi}")
    base = MaterialParameters() if args.material is None else load_material(args.material)
    rows = parse_rows(args.rows)
    from drape import measured
    if measured.is_series_file(args.data):
        measured.parse_angle_range(args.angle_range)
        data = measured.read_series(args.data, measured.parse_series(args.series), args.quantity,
                                    args.frame_side, args.fabric_side)
        cyclic = [s.name for s in data.series if not measured.is_monotonic(s)]
        if not cyclic:
            return measured.main(args, base, data)
        if len(data.series) > 1:
            raise InputError(f"series {', '.join(map(repr, cyclic))} have unloading",
                             key="--series", value=args.series, source=args.data,
                             expected="one series for a cyclic fit, or only monotonic series")
        only = data.series[0]
        if len(only.tau) < 10:
            raise InputError(f"{len(only.tau)} data rows", source=args.data,
                             expected="at least 10 rows, one per increment of a cyclic test")
        curve = Curve(only.gamma_deg, only.tau, f"{args.data} [{only.name}]", data.column)
        args.frame_side = None
    elif args.frame_side is not None:
        try:
            args.frame_side = float(args.frame_side)
        except ValueError:
            raise InputError("not a frame side (sides per series need a file with a series "
                             "column)", key="--frame-side", value=args.frame_side,
                             expected="the side of the picture frame in mm, a number > 0"
                             ) from None
    if not measured.is_series_file(args.data):
        curve = read_curve(args.data, args.frame_side)
    output = Path(args.output)
    claim(output, RESULT_FILES, overwrite=args.overwrite)
    output.mkdir(parents=True, exist_ok=True)

    result = calibrate(curve, base, degree=args.degree, n_inner=args.surfaces, rows=rows,
                       max_fit_rows=args.fit_rows, name=args.name)
    try:
        result.nested.validate()
    except InputError as error:  # pragma: no cover - valid by construction (see _InnerFit)
        raise RunFailed(f"the fitted parameters are not valid: {error.message}") from None

    tau_range = float(np.ptp(curve.tau))
    header = [f"# drape calibrate: fitted to {curve.source} ({len(curve)} rows, column "
              f"'{curve.column}'"
              f"{f', frame side {args.frame_side:g} mm' if args.frame_side else ''})",
              f"# RMS error in tau: one surface (stage 1) {result.rms_one_surface:.4g} N/mm"
              + (f", {result.nested.n + 1} nested surfaces (stage 2) {result.rms_nested:.4g} N/mm"
                 if result.nested.n else "") + f"; tau range {tau_range:.4g} N/mm",
              "# K1, K2, Ksh and mu are not fitted: they come from "
              f"{args.material or 'the paper (drape defaults)'}."]
    unreached = result.info["stage2"].get("unreached_rows") or []
    if unreached:
        header.append(f"# Table-2 rows {unreached} were not reached by the data: they repeat the "
                      "row before them.")
    (output / "material.toml").write_text("\n".join(header) + "\n" + material_toml(result.nested))
    with (output / "calibration.csv").open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["gamma_t_deg", "tau_data", "tau_one_surface", "tau_nested"])
        for row in zip(curve.gamma_deg, curve.tau, result.tau_one_surface, result.tau_nested):
            writer.writerow([repr(float(v)) for v in row])
    plot_fit(output / "calibration.png", curve, result)
    summary = (f"drape calibrate: RMS error in tau (range {tau_range:.4g} N/mm): stage 1, "
               f"one surface {result.rms_one_surface:.4g} N/mm "
               f"({100 * result.rms_one_surface / tau_range:.2f} %)")
    if result.nested.n:
        summary += (f"; stage 2, {result.nested.n + 1} nested surfaces "
                    f"{result.rms_nested:.4g} N/mm "
                    f"({100 * result.rms_nested / tau_range:.2f} %)")
    print(summary)
    print(f"drape calibrate: wrote {output / 'material.toml'}, {output / 'calibration.png'} and "
          f"{output / 'calibration.csv'}")
    return 0
