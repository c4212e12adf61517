"""Parameters of the nested-surface shear law, read from a TOML material file.

Defaults are the paper's values (Tables 1-3, three surfaces); see
``docs/material-law.md`` for the reading implemented. Stresses are thickness-integrated
(force per unit length, N/mm when lengths are in mm); angles in the tables are degrees, the
polynomials take the plastic shear angle in radians.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from drape.config import each, from_mapping, non_negative, positive, read_toml, setting, to_mapping
from drape.errors import InputError

# Paper, Table 1: coefficients of q (kinematic centre of the outer surface) and alpha
# (isotropic growth of the radii), Q_1..Q_8 and A_1..A_8.
PAPER_Q = (0.01, -0.00008, 0.0084, 0.000982, 2.853, -0.004, 3.184, 1.810)
PAPER_A = (0.0016, -0.018, -0.0002, 0.926, 0.0013, 3.962, -0.00126, 1.907)
# Paper, Table 2: rows by the largest shear angle reached (deg); a_1, a_2 and h_1, h_2 by row.
PAPER_GAMMA_MAX_DEG = (0.0, 19.0, 28.0, 32.0, 37.0)
PAPER_A_K = ((0.9, 0.85), (0.9, 0.75), (0.9, 0.6), (0.9, 0.5), (0.99, 0.45))
PAPER_H_K = ((0.2, 2.0), (1.0, 2.0), (1.5, 4.0), (2.0, 8.0), (4.0, 10.0))
# Paper, Table 3.
PAPER_SY = (0.0081, 0.006, 0.0025)


@dataclasses.dataclass(frozen=True)
class SurfaceTable:
    """The paper's Table 2: coefficients a_k (radius share) and h_k (centre speed) of the
    inner surfaces k = 1..n, one row per range of the largest shear angle reached."""

    gamma_max_deg: tuple[float, ...] = setting(
        PAPER_GAMMA_MAX_DEG, "lower bound of each row's range of the largest |shear angle| "
        "reached; first 0, strictly increasing", each(non_negative), "deg")
    a: tuple[tuple[float, ...], ...] = setting(
        PAPER_A_K, "radius factors a_1..a_n per row (a_0 = 1 is implied)")
    h: tuple[tuple[float, ...], ...] = setting(
        PAPER_H_K, "centre speeds h_1..h_n per row (dc_k/dgamma_p)", unit="N/mm per rad")

    def validate(self):
        bounds = self.gamma_max_deg
        if len(bounds) == 0 or bounds[0] != 0.0:
            raise InputError("the first range must start at 0", key="gamma_max_deg",
                             value=list(bounds), expected="[0, b1, b2, ...] with 0 < b1 < b2 < ...")
        if any(b1 <= b0 for b0, b1 in zip(bounds, bounds[1:])):
            raise InputError("range bounds are not strictly increasing", key="gamma_max_deg",
                             value=list(bounds), expected="[0, b1, b2, ...] with 0 < b1 < b2 < ...")
        for name in ("a", "h"):
            rows = getattr(self, name)
            if len(rows) != len(bounds):
                raise InputError(f"has {len(rows)} rows but gamma_max_deg has {len(bounds)} ranges",
                                 key=name, value=[list(r) for r in rows],
                                 expected=f"one row per range ({len(bounds)} rows)")
            widths = {len(r) for r in rows}
            if len(widths) > 1:
                raise InputError("rows of different lengths", key=name,
                                 value=[list(r) for r in rows],
                                 expected="the same number n of inner surfaces in every row")
        if len(self.a) and len(self.a[0]) != len(self.h[0]):
            raise InputError(f"a has {len(self.a[0])} columns but h has {len(self.h[0])}", key="h",
                             expected="one column per inner surface in both a and h")
        for i, row in enumerate(self.a):
            full = (1.0,) + tuple(row)
            if any(v < 0 for v in row) or any(y > x for x, y in zip(full, full[1:])):
                raise InputError("radius factors not nested", key=f"a[{i}]", value=list(row),
                                 expected="1 >= a_1 >= a_2 >= ... >= a_n >= 0")
        for i, row in enumerate(self.h):
            if any(v <= 0 for v in row):
                raise InputError("centre speeds must be positive", key=f"h[{i}]", value=list(row),
                                 expected="h_k > 0 for every inner surface")

    @property
    def n_inner(self) -> int:
        return len(self.a[0]) if self.a else 0


@dataclasses.dataclass(frozen=True)
class MaterialParameters:
    """Everything the law needs; ``n = len(Sy) - 1`` inner surfaces (0: the one-surface model)."""

    name: str = setting("paper, three surfaces (Tables 1-3)", "a label for plots and logs")
    K1: float = setting(10000.0, "warp tension stiffness", positive, "N/mm")
    K2: float = setting(10000.0, "weft tension stiffness", positive, "N/mm")
    Ksh: float = setting(142.0, "elastic shear stiffness", positive, "N/mm")
    mu: float = setting(1.0, "areal density factor multiplying the stress (paper eq. 9)", positive)
    Sy: tuple[float, ...] = setting(PAPER_SY, "initial radii Sy_0 (outer) > Sy_1 > ... > Sy_n > 0",
                                    each(positive), "N/mm")
    Q: tuple[float, ...] = setting(PAPER_Q, "coefficients Q_1.. of q(gp) = sum Q_i gp^i, the outer "
                                   "surface's centre", unit="N/mm")
    A: tuple[float, ...] = setting(PAPER_A, "coefficients A_1.. of alpha(gp) = sum A_i gp^i, the "
                                   "radius growth", unit="N/mm")
    surfaces: SurfaceTable = setting(SurfaceTable(), "Table 2 (needed when n >= 1)")

    def validate(self):
        sy = self.Sy
        if len(sy) == 0:
            raise InputError("no surface", key="Sy", value=[],
                             expected="[Sy_0] or [Sy_0, Sy_1, ...]")
        if any(b >= a for a, b in zip(sy, sy[1:])):
            raise InputError("surfaces not nested", key="Sy", value=list(sy),
                             expected="Sy_0 > Sy_1 > ... > Sy_n > 0")
        if len(self.Q) == 0 or len(self.A) == 0:
            raise InputError("empty polynomial", key="Q" if not self.Q else "A", value=[],
                             expected="at least one coefficient (Q_1, A_1, ...)")
        n = len(sy) - 1
        if n > 0 and self.surfaces.n_inner != n:
            raise InputError(f"Table 2 has {self.surfaces.n_inner} inner surfaces but Sy has {n}",
                             key="surfaces.a", value=[list(r) for r in self.surfaces.a],
                             expected=f"{n} columns in a and h (one per Sy_1..Sy_n)")
        self._check_radii_nested()

    def _check_radii_nested(self, limit_deg: float = 60.0):
        """Radii Sy_k + a_k alpha(gp) must stay positive and ordered for |gp| <= 60 deg."""
        gp = np.radians(np.linspace(-limit_deg, limit_deg, 1201))
        alpha = polynomial(self.A, gp)
        for row, a_row in enumerate(self.a_rows()):
            radii = np.array(self.Sy)[:, None] + a_row[:, None] * alpha[None, :]
            bad = (radii[-1] <= 0) | np.any(np.diff(radii, axis=0) > 0, axis=0)
            if np.any(bad):
                where = np.degrees(gp[np.argmax(bad)])
                raise InputError(
                    f"with Table-2 row {row}, the radii Sy_k + a_k*alpha(gp) are not positive and "
                    f"nested at gp = {where:.1f} deg", key="A",
                    expected=f"radii that stay positive and ordered for |gp| <= {limit_deg:g} deg")

    @property
    def n(self) -> int:
        """Number of inner surfaces (0 for the one-surface model)."""
        return len(self.Sy) - 1

    def a_rows(self) -> np.ndarray:
        """(rows, n+1) radius factors including a_0 = 1."""
        a = np.asarray(self.surfaces.a, dtype=float).reshape(len(self.surfaces.gamma_max_deg), -1)
        a = a[:, : self.n]
        return np.hstack([np.ones((a.shape[0], 1)), a])

    def h_rows(self) -> np.ndarray:
        """(rows, n+1) centre speeds; column 0 (the outer surface, which follows q) is unused."""
        h = np.asarray(self.surfaces.h, dtype=float).reshape(len(self.surfaces.gamma_max_deg), -1)
        h = h[:, : self.n]
        return np.hstack([np.ones((h.shape[0], 1)), h])

    def with_surfaces(self, n: int, key: str = "surfaces") -> "MaterialParameters":
        """The same material with only the outer surface and the first n inner ones (``key``
        names the setting of n in errors)."""
        if not 0 <= n <= self.n:
            raise InputError(f"this material has {self.n} inner surfaces", key=key, value=n,
                             expected=f"an integer from 0 to {self.n}")
        if n == self.n:
            return self
        table = self.surfaces
        table = dataclasses.replace(table, a=tuple(r[:n] for r in table.a),
                                    h=tuple(r[:n] for r in table.h))
        label = "one surface" if n == 0 else f"{n + 1} surfaces"
        return dataclasses.replace(self, name=f"{self.name} -> {label}", Sy=self.Sy[: n + 1],
                                   surfaces=table)


def polynomial(coefficients, x):
    """sum_{i>=1} c_i x^i (no constant term), by Horner's rule; x an array."""
    x = np.asarray(x, dtype=float)
    result = np.zeros_like(x)
    for c in reversed(coefficients):
        result += c
        result *= x
    return result


def load_material(path: str | Path, surfaces: int | None = None,
                  surfaces_key: str = "surfaces") -> MaterialParameters:
    """Read and validate a material TOML file; optionally keep only ``surfaces`` inner ones.
    ``surfaces`` is not a key of the material file: an error about it names ``surfaces_key``
    (the caller's setting: the job's key, a command-line option) and not the material file."""
    params = from_mapping(MaterialParameters, read_toml(path), source=str(path))
    if surfaces is not None:
        params = params.with_surfaces(surfaces, key=surfaces_key)
    return params


def material_toml(params: MaterialParameters) -> str:
    """The TOML text of a parameter set (for calibration output and tests)."""
    data = to_mapping(params)
    table = data.pop("surfaces")
    lines = [f"name = {_toml_value(data.pop('name'))}"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in data.items()]
    if params.n:
        lines += ["", "[surfaces]"] + [f"{k} = {_toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def _toml_value(value) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(float(value)) if isinstance(value, float) else repr(value)
