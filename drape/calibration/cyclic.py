"""The fit of one cyclic curve: the history thinned (--fit-rows), stage 1 (the outer surface,
drape.calibration.outer), stage 2 (the inner surfaces, drape.calibration.inner), and both
models simulated on the whole history for the errors reported."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from drape.calibration.curve import Curve
from drape.calibration.history import fit_indices, rms, simulate
from drape.calibration.inner import fit_inner
from drape.calibration.outer import fit_outer
from drape.law.parameters import PAPER_GAMMA_MAX_DEG, MaterialParameters

DEFAULT_FIT_ROWS = 400


@dataclasses.dataclass
class Calibration:
    """Both stages' parameters, their tau on the full history and their RMS errors (N/mm)."""

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
    """Fit the law to a cyclic curve; K1, K2, Ksh and mu come from ``base``."""
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
