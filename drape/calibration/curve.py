"""Reading one measured, cyclic picture-frame curve (gamma_t_deg and tau, or force with the
frame's side) into a :class:`Curve`, and the checks of a CSV cell that every measured-data
reader shares; InputError naming the file, line and column otherwise."""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np

from drape.errors import InputError
from drape.picture_frame import frame_tau

EXPECTED_CURVE = ("a CSV file with a header line naming gamma_t_deg and tau (N/mm), "
                  "or gamma_t_deg and force (N) with --frame-side")
#: a cyclic fit needs at least this many rows (increments)
MIN_ROWS = 10


def csv_number(row: list, index: int, line: int, column: str, source: str,
               unit: str = "") -> float:
    """Cell ``index`` of a CSV ``row`` (file line ``line``) as a finite number; InputError
    naming the line and the column otherwise (angles: check_shear_angle as well)."""
    text = row[index].strip() if index < len(row) else ""
    try:
        number = float(text)
    except ValueError:
        number = math.nan
    if not math.isfinite(number):
        raise InputError(f"line {line}, column '{column}': {text!r} is not a number",
                         source=source, expected=f"a finite number ({unit})" if unit else
                         "a finite number")
    return number


def check_shear_angle(number: float, line: int, column: str, source: str) -> float:
    """A shear angle read from a file: within (-90, 90) degrees, else InputError."""
    if abs(number) >= 90.0:
        raise InputError(f"line {line}, column '{column}': {number:g} is not a shear angle",
                         source=source, expected="a number of degrees within (-90, 90)")
    return number


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
    if not path.is_file():
        raise InputError("file not found" if not path.exists() else "not a file",
                         source=str(path), expected=EXPECTED_CURVE)
    if frame_side is not None and not (math.isfinite(frame_side) and frame_side > 0):
        raise InputError("not a frame side", key="--frame-side", value=frame_side,
                         expected="the side of the picture frame in mm, a number > 0")
    column = "force" if frame_side is not None else "tau"
    try:
        with path.open(newline="") as stream:
            reader = csv.reader(stream)
            i_gamma, i_value = _column_indices(next(reader, None), column, path)
            gamma_deg, values = _read_rows(reader, i_gamma, i_value, column, path)
    except UnicodeDecodeError:
        raise InputError("not a text file", source=str(path), expected=EXPECTED_CURVE) from None
    if gamma_deg.size < MIN_ROWS:
        raise InputError(f"{gamma_deg.size} data rows", source=str(path),
                         expected="at least 10 rows, one per increment of a cyclic test")
    _check_cyclic(gamma_deg, path)
    tau = frame_tau(values, gamma_deg, frame_side) if column == "force" else values
    return Curve(gamma_deg, tau, str(path), column)


def _column_indices(header: list[str] | None, column: str, path: Path) -> tuple[int, int]:
    """The indices of gamma_t_deg and of ``column`` ('tau' or 'force') in the header line."""
    if not header:
        raise InputError("empty file", source=str(path), expected=EXPECTED_CURVE)
    names = [name.strip() for name in header]
    if "gamma_t_deg" not in names:
        raise InputError("no 'gamma_t_deg' column", source=str(path), value=names,
                         expected=EXPECTED_CURVE)
    if column not in names:
        if column == "tau" and "force" in names:
            raise InputError("no 'tau' column; a 'force' column needs the frame's size",
                             source=str(path), value=names,
                             expected="--frame-side L (mm) to convert force to tau")
        raise InputError(f"no '{column}' column", source=str(path), value=names,
                         expected=("a column force (N) when --frame-side is given"
                                   if column == "force" else EXPECTED_CURVE))
    return names.index("gamma_t_deg"), names.index(column)


def _read_rows(reader, i_gamma: int, i_value: int, column: str,
               path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The angle (deg) and value columns of the data rows; blank rows are skipped."""
    unit = "N" if column == "force" else "N/mm"
    gamma, value = [], []
    for line, row in enumerate(reader, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        angle = csv_number(row, i_gamma, line, "gamma_t_deg", str(path), "deg")
        gamma.append(check_shear_angle(angle, line, "gamma_t_deg", str(path)))
        value.append(csv_number(row, i_value, line, column, str(path), unit))
    return np.asarray(gamma, dtype=float), np.asarray(value, dtype=float)


def _check_cyclic(gamma_deg: np.ndarray, path: Path) -> None:
    """The history must move away from 0 and back towards it: the outer surface's centre and
    radius are told apart only by both branches."""
    direction = np.sign(np.diff(np.r_[0.0, gamma_deg]))
    if not (np.any(direction * np.sign(gamma_deg) > 0)
            and np.any(direction * np.sign(gamma_deg) < 0)):
        raise InputError("the shear angle never goes back towards 0", source=str(path),
                         expected="a cyclic history: loading and unloading branches "
                                  "(the outer surface's centre and radius are told apart by both)")
