"""`drape calibrate`: fit the nested-surface law to a measured picture-frame curve.

The input is a CSV file with one row per increment of the test, as for
`drape picture-frame --history`: a column gamma_t_deg (the frame's shear angle, degrees) and
either tau (the projected shear stress, N/mm) or force (the frame force, N, with --frame-side
giving the frame's side L in mm; tau = 2 F sin(pi/4 - gamma/2) / (L cos gamma)). The curve
must be cyclic: at least one loading and one unloading branch.

Published curves (a first column 'series', e.g. data/cao2008/) are read by
drape.calibration.series: --series picks some, the measured column is converted to tau with
--frame-side/--fabric-side (energy normalisation); monotonic series fit the outer surface's
loading edge within --angle-range, the inner surfaces keeping the base material's ratios
(drape.calibration.monotonic; docs/calibration.md, "Published curves"); one series with
unloading is fitted as below.

Stage 1, the outer surface: the one-surface model (Q_1..Q_d, A_1..A_d and Sy_0) is fitted with a
robust loss, first as a linear least-squares problem (the plastic angle follows from the data and
Ksh; loading rows lie on q + Sy_0 + alpha, unloading rows on q - Sy_0 - alpha), then by simulating
the history. Stage 2, the inner surfaces: with the outer surface fixed, Sy_1..Sy_n and the Table-2
coefficients a_k, h_k of each row are fitted by simulating the nested model, row after row in the
order the history reaches them. K1, K2, Ksh and mu are not fitted (taken from --material).
The fits are in drape.calibration; this module holds the command line: its options, their
checks, and which fit runs on which data.

Writes material.toml (for --material), calibration.png (data and fitted curves) and
calibration.csv (the curves), and prints the RMS error in tau of each stage. See
docs/calibration.md.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from drape.calibration.curve import MIN_ROWS, Curve, read_curve
from drape.calibration.cyclic import DEFAULT_FIT_ROWS, calibrate
from drape.calibration.monotonic import fit_monotonic
from drape.calibration.output import (RESULT_FILES, monotonic_note, write_cyclic,
                                      write_monotonic)
from drape.calibration.series import (QUANTITIES, SeriesData, is_monotonic, is_series_file,
                                      parse_angle_range, parse_series, read_series)
from drape.errors import InputError, RunFailed
from drape.io.folder import claim
from drape.law.parameters import PAPER_GAMMA_MAX_DEG, MaterialParameters, load_material

HELP = "fit the law to a measured picture-frame curve (CSV) -> material TOML + PNG"


def add_arguments(parser) -> None:
    """The options of `drape calibrate`."""
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


def main(args) -> int:
    """Check the options, read the data, fit it (cyclic or monotonic) and write the results."""
    for key, value, lo, hi in (("--surfaces", args.surfaces, 0, 6),
                               ("--degree", args.degree, 1, 12),
                               ("--fit-rows", args.fit_rows, 20, 10 ** 6)):
        if not lo <= value <= hi:
            raise InputError("out of range", key=key, value=value,
                             expected=f"an integer from {lo} to {hi}")
    base = MaterialParameters() if args.material is None else load_material(args.material)
    rows = parse_rows(args.rows)
    if is_series_file(args.data):
        parse_angle_range(args.angle_range)
        data = read_series(args.data, parse_series(args.series), args.quantity,
                           args.frame_side, args.fabric_side)
        if all(is_monotonic(s) for s in data.series):
            return _calibrate_monotonic(args, base, data)
        frame_side, curve = None, _cyclic_series(args, data)
    else:
        frame_side = _frame_side(args.frame_side)
        curve = read_curve(args.data, frame_side)
    return _calibrate_cyclic(args, base, rows, curve, frame_side)


def _frame_side(text: str | None) -> float | None:
    """--frame-side for a file without a series column: one number (mm), checked by
    read_curve."""
    if text is None:
        return None
    try:
        return float(text)
    except ValueError:
        raise InputError("not a frame side (sides per series need a file with a series "
                         "column)", key="--frame-side", value=text,
                         expected="the side of the picture frame in mm, a number > 0") from None


def _cyclic_series(args, data: SeriesData) -> Curve:
    """The one selected series of a series file, which has unloading, as a cyclic curve;
    InputError if several series are selected and some have unloading."""
    cyclic = [s.name for s in data.series if not is_monotonic(s)]
    if len(data.series) > 1:
        raise InputError(f"series {', '.join(map(repr, cyclic))} have unloading",
                         key="--series", value=args.series, source=args.data,
                         expected="one series for a cyclic fit, or only monotonic series")
    only = data.series[0]
    if len(only.tau) < MIN_ROWS:
        raise InputError(f"{len(only.tau)} data rows", source=args.data,
                         expected="at least 10 rows, one per increment of a cyclic test")
    return Curve(only.gamma_deg, only.tau, f"{args.data} [{only.name}]", data.column)


def _calibrate_cyclic(args, base: MaterialParameters, rows, curve: Curve,
                      frame_side: float | None) -> int:
    """Both stages on a cyclic curve; writes the results and prints the RMS errors."""
    output = Path(args.output)
    claim(output, RESULT_FILES, overwrite=args.overwrite)
    output.mkdir(parents=True, exist_ok=True)
    result = calibrate(curve, base, degree=args.degree, n_inner=args.surfaces, rows=rows,
                       max_fit_rows=args.fit_rows, name=args.name)
    try:
        result.nested.validate()
    except InputError as error:  # pragma: no cover - valid by construction (InnerFit)
        raise RunFailed(f"the fitted parameters are not valid: {error.message}") from None
    write_cyclic(output, curve, result, frame_side, args.material)
    tau_range = float(np.ptp(curve.tau))
    summary = (f"drape calibrate: RMS error in tau (range {tau_range:.4g} N/mm): stage 1, "
               f"one surface {result.rms_one_surface:.4g} N/mm "
               f"({100 * result.rms_one_surface / tau_range:.2f} %)")
    if result.nested.n:
        summary += (f"; stage 2, {result.nested.n + 1} nested surfaces "
                    f"{result.rms_nested:.4g} N/mm "
                    f"({100 * result.rms_nested / tau_range:.2f} %)")
    print(summary)
    _print_written(output)
    return 0


def _calibrate_monotonic(args, base: MaterialParameters, data: SeriesData) -> int:
    """The loading edge fitted to monotonic series; writes the results and prints what was
    fitted and the RMS errors."""
    angle_range = parse_angle_range(args.angle_range)
    output = Path(args.output)
    claim(output, RESULT_FILES, overwrite=args.overwrite)
    print(f"drape calibrate: {len(data.series)} monotonic series from {data.source} "
          f"({', '.join(data.names)}), column '{data.column}' ({data.quantity}), fitted within "
          f"{angle_range[0]:g}..{angle_range[1]:g} deg")
    result = fit_monotonic(data, base, degree=args.degree, n_inner=args.surfaces,
                           angle_range=angle_range, name=args.name)
    result.nested.validate()
    output.mkdir(parents=True, exist_ok=True)
    base_name = args.material or "the paper (drape defaults)"
    write_monotonic(output, data, result, angle_range, base_name)
    tau_range = float(np.ptp(result.tau)) or 1.0
    print(f"drape calibrate: {monotonic_note(result, base_name)}")
    print(f"drape calibrate: RMS error in tau (range {tau_range:.4g} N/mm): loading edge "
          f"{result.rms_one_surface:.4g} N/mm ({100 * result.rms_one_surface / tau_range:.2f} %); "
          f"nested model {result.rms_nested:.4g} N/mm "
          f"({100 * result.rms_nested / tau_range:.2f} %)")
    _print_written(output)
    return 0


def _print_written(output: Path) -> None:
    print(f"drape calibrate: wrote {output / 'material.toml'}, {output / 'calibration.png'} and "
          f"{output / 'calibration.csv'}")
