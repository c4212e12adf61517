"""Measured picture-frame curves as published: a file with a series column, force or
normalised force against shear angle (e.g. data/cao2008/, Cao et al. 2008), read per series
and converted to the law's tau (docs/calibration.md, "Published curves").

The conversion is the energy normalisation of Cao et al. 2008 (their eq. 10): a frame of side
L_frame (hinge to hinge) pulled along its diagonal by the force F, the fabric a square of side
L_fabric in it that shears uniformly (its arms, beyond the square, carry no shear work). With
theta = pi/4 - gamma/2 the frame's half angle, d = 2 L_frame cos(theta) the corners' distance and
dd/dgamma = L_frame sin(theta), the power balance F dd = L_fabric^2 (tau/2) cos(gamma) dgamma
(tau as in docs/material-law.md: S = tau/2 (G1G2 + G2G1), 2 E12 = sin gamma) gives, with
cos(gamma) = 2 sin(theta) cos(theta),

    tau = 2 F_s L_frame / L_fabric^2 = 2 F_norm,   F_s = F / (2 cos theta)   (the shear force),

F_norm = F_s L_frame / L_fabric^2 being the paper's energy-normalised shear force. For
L_fabric = L_frame this is drape.picture_frame.frame_tau.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np

from drape.calibration.curve import check_shear_angle, csv_number
from drape.errors import InputError

#: the measured quantities a column can hold: (unit, sizes needed, description)
QUANTITIES = {
    "frame-force": ("N", ("frame", "fabric"), "the force F pulling the frame's diagonal"),
    "shear-force": ("N", ("frame", "fabric"), "the shear force F_s = F / (2 cos theta)"),
    "shear-force-per-frame-length": ("N/mm", ("frame", "fabric"), "F_s / L_frame"),
    "shear-force-per-area": ("N/mm2", ("frame",), "F_s / L_fabric^2"),
    "normalised-force": ("N/mm", (), "the energy-normalised force F_s L_frame / L_fabric^2"),
    "tau": ("N/mm", (), "the law's projected shear stress tau"),
}
#: column names recognised as each quantity (case-insensitive)
COLUMN_NAMES = {
    "frame-force": ("force", "force_n", "frame_force", "frame_force_n"),
    "shear-force": ("shear_force", "shear_force_n", "fs", "fs_n"),
    "shear-force-per-frame-length": ("fs_over_lframe_n_per_mm", "fs_over_lframe"),
    "shear-force-per-area": ("fs_over_area_n_per_mm2", "fs_over_area"),
    "normalised-force": ("fnorm_energy_n_per_mm", "fnorm", "normalised_force",
                         "normalized_force"),
    "tau": ("tau", "tau_n_per_mm"),
}
#: the conversion of each quantity, for the material file's header
TAU_OF = {"frame-force": "2 F L_frame / (2 cos(pi/4 - gamma/2) L_fabric^2)",
          "shear-force": "2 F_s L_frame / L_fabric^2",
          "shear-force-per-frame-length": "2 (F_s/L_frame) L_frame^2 / L_fabric^2",
          "shear-force-per-area": "2 (F_s/L_fabric^2) L_frame",
          "normalised-force": "2 F_norm", "tau": "tau"}
ANGLE_COLUMNS = ("shear_angle_deg", "gamma_t_deg", "gamma_deg")
SERIES_COLUMN = "series"


def shear_force(frame_force, gamma_deg):
    """F_s = F / (2 cos theta), theta = pi/4 - gamma/2 (N)."""
    theta = math.pi / 4 - np.radians(np.asarray(gamma_deg, dtype=float)) / 2
    return np.asarray(frame_force, dtype=float) / (2.0 * np.cos(theta))


def to_tau(quantity: str, values, gamma_deg, frame_side: float | None = None,
           fabric_side: float | None = None):
    """The law's tau (N/mm) from a measured quantity (QUANTITIES) at the frame angle gamma."""
    v = np.asarray(values, dtype=float)
    if quantity == "tau":
        return v.copy()
    if quantity == "normalised-force":
        return 2.0 * v
    if quantity == "shear-force-per-area":
        return 2.0 * v * frame_side
    ratio = frame_side / fabric_side ** 2
    if quantity == "shear-force-per-frame-length":
        return 2.0 * v * frame_side * ratio
    if quantity == "shear-force":
        return 2.0 * v * ratio
    if quantity == "frame-force":
        return 2.0 * shear_force(v, gamma_deg) * ratio
    raise ValueError(quantity)


@dataclasses.dataclass
class Series:
    """One published curve (a laboratory, a specimen): angle (deg), value as measured, tau."""

    name: str
    gamma_deg: np.ndarray
    value: np.ndarray        # as measured
    tau: np.ndarray          # N/mm


@dataclasses.dataclass
class SeriesData:
    """The selected series of one file, and what its measured column holds."""

    source: str
    quantity: str
    column: str
    series: list[Series]

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.series]


def is_series_file(path: str | Path) -> bool:
    """True if the first non-comment line of the file names a 'series' column first."""
    try:
        with Path(path).open(newline="") as stream:
            for line in stream:
                if line.strip() and not line.lstrip().startswith("#"):
                    first = next(csv.reader([line]))
                    return bool(first) and first[0].strip().lower() == SERIES_COLUMN
    except (OSError, UnicodeDecodeError):
        return False
    return False


def is_monotonic(series: Series) -> bool:
    """No reversal: the angle never moves back towards 0 (steps of 0 are allowed)."""
    g = np.abs(series.gamma_deg)
    return bool(np.all(np.diff(g) >= 0.0))


# --- the command line's options for series files ---------------------------------------------

def parse_series(text: str | None) -> list[str] | None:
    """'HKUST,UN,"KUL 3rd."' -> ['HKUST', 'UN', 'KUL 3rd.'] (CSV quoting)."""
    if text is None or not text.strip():
        return None
    return [name.strip() for name in next(csv.reader([text])) if name.strip()]


def parse_angle_range(text: str) -> tuple[float, float]:
    """--angle-range 'LO,HI' (deg), 0 <= LO < HI < 90."""
    try:
        lo, hi = (float(p) for p in text.split(","))
    except ValueError:
        lo = hi = math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi < 90.0):
        raise InputError("not an angle range", key="--angle-range", value=text,
                         expected="LO,HI in degrees with 0 <= LO < HI < 90, e.g. 0,35")
    return lo, hi


def _key(name: str) -> str:
    return "".join(name.split())


def parse_sizes(text, key: str):
    """--frame-side / --fabric-side: None, a number (every series) or 'NAME=MM,NAME=MM,...'
    (NAME a series, or its first word: 'KUL' for 'KUL 1st.' and 'KUL 3rd.')."""
    if text is None or isinstance(text, (int, float)):
        value = None if text is None else float(text)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError("not a side length", key=key, value=value,
                             expected="a length in mm > 0, or NAME=MM,NAME=MM per series")
        return value
    text = str(text).strip()
    try:
        value = float(text)
    except ValueError:
        value = None
    if value is not None:
        return parse_sizes(value, key)
    sizes = {}
    for part in text.split(","):
        name, sep, number = part.partition("=")
        try:
            size = float(number)
        except ValueError:
            size = math.nan
        if not sep or not name.strip() or not (math.isfinite(size) and size > 0):
            raise InputError("not a side length per series", key=key, value=text,
                             expected="a length in mm > 0, or NAME=MM,NAME=MM (e.g. "
                                      "HKUST=180,KUL=250)")
        sizes[_key(name)] = size
    return sizes


def _size_for(sizes, series: str):
    if sizes is None or isinstance(sizes, float):
        return sizes
    key = _key(series)
    if key in sizes:
        return sizes[key]
    first = _key(series.split()[0]) if series.split() else key
    return sizes.get(first)


# --- reading ------------------------------------------------------------------------------------

def read_series(path: str | Path, select: list[str] | None = None, quantity: str | None = None,
                frame_side=None, fabric_side=None) -> SeriesData:
    """Read a CSV with columns series, shear angle (deg) and one measured quantity; convert
    each selected series to tau. Comment lines (#) are skipped; rows of a series are read in
    file order (the order of the test)."""
    path = Path(path)
    names_known = ", ".join(n for names in COLUMN_NAMES.values() for n in names[:1])
    expected = (f"a CSV with a header line: {SERIES_COLUMN}, a shear angle column (deg; one of "
                f"{', '.join(ANGLE_COLUMNS)}) and a measured column ({names_known}, or any name "
                "with --quantity)")
    if not path.is_file():
        raise InputError("file not found" if not path.exists() else "not a file",
                         source=str(path), expected=expected)
    if quantity is not None and quantity not in QUANTITIES:
        raise InputError("unknown quantity", key="--quantity", value=quantity,
                         expected="one of " + ", ".join(QUANTITIES))
    frame_side = parse_sizes(frame_side, "--frame-side")
    fabric_side = parse_sizes(fabric_side, "--fabric-side")
    lines = _data_lines(path, expected)
    header = [h.strip() for h in next(csv.reader([lines[0][1]]))]
    angle, column, quantity = _columns(header, quantity, path, expected)
    rows = _rows_by_series(lines[1:], header, angle, column, path, expected)
    series = []
    for name in _chosen(list(rows), select, path):
        data = np.asarray(rows[name], dtype=float)
        sides = _sides(quantity, name, frame_side, fabric_side, path)
        tau = to_tau(quantity, data[:, 1], data[:, 0], sides["frame"], sides["fabric"])
        series.append(Series(name, data[:, 0], data[:, 1], tau))
    return SeriesData(str(path), quantity, header[column], series)


def _data_lines(path: Path, expected: str) -> list[tuple[int, str]]:
    """(line number, text) of the lines that are neither blank nor comments (#)."""
    try:
        with path.open(newline="") as stream:
            lines = [(i, line) for i, line in enumerate(stream, start=1)
                     if line.strip() and not line.lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise InputError("not a text file", source=str(path), expected=expected) from None
    if not lines:
        raise InputError("empty file", source=str(path), expected=expected)
    return lines


def _columns(header: list[str], quantity: str | None, path: Path,
             expected: str) -> tuple[int, int, str]:
    """The indices of the angle and the measured column, and the measured quantity (from the
    column's name unless --quantity says it)."""
    lower = [h.lower() for h in header]
    if not lower or lower[0] != SERIES_COLUMN:
        raise InputError(f"no '{SERIES_COLUMN}' column first", source=str(path), value=header,
                         expected=expected)
    angle = next((lower.index(a) for a in ANGLE_COLUMNS if a in lower), None)
    if angle is None:
        raise InputError("no shear angle column", source=str(path), value=header,
                         expected=expected)
    others = [i for i in range(1, len(header)) if i != angle]
    if quantity is None:
        found = [(i, q) for i in others for q, names in COLUMN_NAMES.items()
                 if lower[i] in names]
        if len(found) != 1:
            raise InputError("no measured column drape knows" if not found else
                             "more than one measured column", source=str(path), value=header,
                             expected=expected)
        column, quantity = found[0]
    else:
        if len(others) != 1:
            raise InputError("--quantity needs exactly one column besides series and angle",
                             source=str(path), value=header, expected=expected)
        column = others[0]
    return angle, column, quantity


def _rows_by_series(lines, header: list[str], angle: int, column: int, path: Path,
                    expected: str) -> dict[str, list]:
    """Series name -> [[angle, value], ...] in file order."""
    rows: dict[str, list] = {}
    for line, text in lines:
        row = next(csv.reader([text]))
        name = row[0].strip()
        numbers = [csv_number(row, index, line, header[index], str(path))
                   for index in (angle, column)]
        check_shear_angle(numbers[0], line, header[angle], str(path))
        rows.setdefault(name, []).append(numbers)
    if not rows:
        raise InputError("no data rows", source=str(path), expected=expected)
    return rows


def _chosen(available: list[str], select: list[str] | None, path: Path) -> list[str]:
    """The series --series asks for, in its order without repeats (whitespace does not
    count); every series by default."""
    if not select:
        return available
    keys = {_key(n): n for n in available}
    chosen = []
    for wanted in select:
        if _key(wanted) not in keys:
            raise InputError("unknown series", key="--series", value=wanted,
                             expected=f"series of {path.name}: " + ", ".join(available))
        if keys[_key(wanted)] not in chosen:
            chosen.append(keys[_key(wanted)])
    return chosen


def _sides(quantity: str, name: str, frame_side, fabric_side, path: Path) -> dict:
    """The frame's and the fabric's side (mm) of series ``name``; InputError when the
    quantity's conversion needs one that was not given."""
    sides = {"frame": _size_for(frame_side, name), "fabric": _size_for(fabric_side, name)}
    for which in QUANTITIES[quantity][1]:
        if sides[which] is None:
            raise InputError(
                f"series {name!r}: {QUANTITIES[quantity][2]} needs the {which} side",
                key=f"--{which}-side", source=str(path),
                expected=f"--{which}-side MM (every series) or NAME=MM,... per series")
    return sides
