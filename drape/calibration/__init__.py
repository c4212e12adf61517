"""The calibration stage: measured picture-frame curves in, the nested-surface law's
parameters out (docs/calibration.md). No DOLFINx; `drape calibrate` (drape/calibrate.py) is
its command.

- ``curve``: one cyclic curve (gamma_t_deg and tau, or force) read and checked;
- ``series``: published curves (a series column), converted to tau by the energy
  normalisation;
- ``history``: the law driven along a picture-frame history (what both fits simulate);
- ``outer``, ``inner``, ``cyclic``: the cyclic fit's stage 1 (the outer surface), stage 2 (the
  inner surfaces, row by row of Table 2) and the two together;
- ``monotonic``: the fit of monotonic curves (the loading edge only);
- ``output``: material.toml, calibration.csv and calibration.png.

The names below are the stage's public ones, importable from here.
"""

from drape.calibration.curve import Curve, check_shear_angle, csv_number, read_curve
from drape.calibration.cyclic import DEFAULT_FIT_ROWS, Calibration, calibrate
from drape.calibration.history import (fit_indices, monotonic_history, monotonic_tau, rms,
                                       simulate)
from drape.calibration.inner import InnerFit, fit_inner
from drape.calibration.monotonic import MonotonicFit, fit_monotonic, resample
from drape.calibration.outer import VALIDATION_GRID_RAD, OuterFit, fit_outer
from drape.calibration.series import (COLUMN_NAMES, QUANTITIES, TAU_OF, Series, SeriesData,
                                      is_monotonic, is_series_file, parse_angle_range,
                                      parse_series, parse_sizes, read_series, shear_force,
                                      to_tau)

__all__ = ["COLUMN_NAMES", "Calibration", "Curve", "DEFAULT_FIT_ROWS", "InnerFit",
           "MonotonicFit", "OuterFit", "QUANTITIES", "Series", "SeriesData", "TAU_OF",
           "VALIDATION_GRID_RAD", "calibrate", "check_shear_angle", "csv_number", "fit_indices",
           "fit_inner", "fit_monotonic", "fit_outer", "is_monotonic", "is_series_file",
           "monotonic_history", "monotonic_tau", "parse_angle_range", "parse_series",
           "parse_sizes", "read_curve", "read_series", "resample", "rms", "shear_force",
           "simulate", "to_tau"]
