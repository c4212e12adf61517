"""Measured picture-frame curves as published: a series column, force or normalised force
against shear angle (e.g. data/cao2008/, Cao et al. 2008), converted to the law's tau and fitted
by `drape calibrate` when they are monotonic (docs/calibration.md, "Published curves").

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
ANGLE_COLUMNS = ("shear_angle_deg", "gamma_t_deg", "gamma_deg")
SERIES_COLUMN = "series"
#: defect-correction iterations of the monotonic fit's stage 2
STAGE2_ITERATIONS = 3


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
    name: str
    gamma_deg: np.ndarray
    value: np.ndarray        # as measured
    tau: np.ndarray          # N/mm


@dataclasses.dataclass
class SeriesData:
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
    try:
        with path.open(newline="") as stream:
            lines = [(i, line) for i, line in enumerate(stream, start=1)
                     if line.strip() and not line.lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise InputError("not a text file", source=str(path), expected=expected) from None
    if not lines:
        raise InputError("empty file", source=str(path), expected=expected)
    header = [h.strip() for h in next(csv.reader([lines[0][1]]))]
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
    rows: dict[str, list] = {}
    for line, text in lines[1:]:
        row = next(csv.reader([text]))
        name = row[0].strip()
        numbers = []
        for index in (angle, column):
            cell = row[index].strip() if index < len(row) else ""
            try:
                number = float(cell)
            except ValueError:
                number = math.nan
            if not math.isfinite(number):
                raise InputError(f"line {line}, column '{header[index]}': {cell!r} is not a "
                                 "number", source=str(path), expected="a finite number")
            numbers.append(number)
        if abs(numbers[0]) >= 90.0:
            raise InputError(f"line {line}, column '{header[angle]}': {numbers[0]} is not a "
                             "shear angle", source=str(path),
                             expected="a number of degrees within (-90, 90)")
        rows.setdefault(name, []).append(numbers)
    if not rows:
        raise InputError("no data rows", source=str(path), expected=expected)
    available = list(rows)
    if select:
        keys = {_key(n): n for n in available}
        chosen = []
        for wanted in select:
            if _key(wanted) not in keys:
                raise InputError("unknown series", key="--series", value=wanted,
                                 expected=f"series of {path.name}: " + ", ".join(available))
            if keys[_key(wanted)] not in chosen:
                chosen.append(keys[_key(wanted)])
    else:
        chosen = available
    series = []
    for name in chosen:
        data = np.asarray(rows[name], dtype=float)
        needs = QUANTITIES[quantity][1]
        sides = {"frame": _size_for(frame_side, name), "fabric": _size_for(fabric_side, name)}
        for which in needs:
            if sides[which] is None:
                raise InputError(
                    f"series {name!r}: {QUANTITIES[quantity][2]} needs the {which} side",
                    key=f"--{which}-side", source=str(path),
                    expected=f"--{which}-side MM (every series) or NAME=MM,... per series")
        tau = to_tau(quantity, data[:, 1], data[:, 0], sides["frame"], sides["fabric"])
        series.append(Series(name, data[:, 0], data[:, 1], tau))
    return SeriesData(str(path), quantity, header[column], series)


def parse_series(text: str | None) -> list[str] | None:
    """'HKUST,UN,"KUL 3rd."' -> ['HKUST', 'UN', 'KUL 3rd.'] (CSV quoting)."""
    if text is None or not text.strip():
        return None
    return [name.strip() for name in next(csv.reader([text])) if name.strip()]


def parse_angle_range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(p) for p in text.split(","))
    except ValueError:
        lo = hi = math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi < 90.0):
        raise InputError("not an angle range", key="--angle-range", value=text,
                         expected="LO,HI in degrees with 0 <= LO < HI < 90, e.g. 0,35")
    return lo, hi


def is_monotonic(series: Series) -> bool:
    """No reversal: the angle never moves back towards 0 (steps of 0 are allowed)."""
    g = np.abs(series.gamma_deg)
    return bool(np.all(np.diff(g) >= 0.0))


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


# --- the fit of monotonic data -----------------------------------------------------------------

@dataclasses.dataclass
class MonotonicFit:
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


def monotonic_history(hi_deg: float, bounds_deg=(), step_deg: float = 0.5) -> np.ndarray:
    """0 -> hi in steps of step_deg, with the Table-2 bounds inserted (the row is looked up with
    the largest angle at the end of an increment: a bound is an increment's end)."""
    grid = np.arange(step_deg, hi_deg + 1e-9, step_deg)
    extra = [b for b in bounds_deg if 0 < b < hi_deg]
    return np.unique(np.r_[grid, extra, hi_deg])


def monotonic_tau(params, gamma_deg, step_deg: float = 0.5):
    """tau of a virgin monotonic loading to every |gamma| (interpolated on a 0.5-deg history;
    one law increment per history angle, the picture frame's C11 = C22 = 1, C12 = sin gamma)."""
    from drape.law.nested_surface import LawState, NestedSurfaceLaw
    g = np.abs(np.asarray(gamma_deg, dtype=float))
    history = monotonic_history(float(g.max()) if g.size else step_deg,
                                params.surfaces.gamma_max_deg if params.n else (), step_deg)
    law, state, one = NestedSurfaceLaw(params), LawState.virgin(1, params.n), np.ones(1)
    tau = np.empty(history.size)
    for i, s in enumerate(np.sin(np.radians(history))):
        response = law.update(state, one, one, np.array([s]))
        state, tau[i] = response.trial, response.tau[0]
    return np.interp(g, np.r_[0.0, history], np.r_[0.0, tau])


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
    from scipy.optimize import lsq_linear

    from drape.law.parameters import SurfaceTable, polynomial

    lo, hi = angle_range
    names, gamma, tau = resample(data, angle_range)
    if gamma.size < degree + 2:
        raise InputError(f"{gamma.size} points of the selected series within {lo:g}..{hi:g} deg",
                         source=data.source, key="--angle-range",
                         expected=f"at least {degree + 2} (one every 0.5 deg): a wider range, "
                                  "more series or a lower --degree")
    if n_inner > base.n:
        raise InputError(f"the base material has {base.n} inner surfaces", key="--surfaces",
                         value=n_inner, expected=f"at most {base.n} (the inner surfaces keep the "
                                                 "base material's ratios: no unloading data)")
    base_n = base.with_surfaces(n_inner) if n_inner < base.n else base
    k2 = 2.0 * base.mu * base.Ksh
    gp = np.arcsin(np.clip(np.sin(np.radians(gamma)) - tau / k2, -1.0, 1.0))
    design = np.hstack([np.ones((gp.size, 1)), gp[:, None] ** np.arange(1, degree + 1)[None, :]])
    tau_range = float(np.ptp(tau)) or 1.0
    floor = 1e-6 * tau_range
    stage1 = lsq_linear(design, tau, bounds=(np.r_[floor, np.zeros(degree)], np.inf),
                        method="bvls")
    theta1 = stage1.x
    edge_hi = np.radians(hi)
    base_rise = float(polynomial(base.Q, [edge_hi])[0] + polynomial(base.A, [edge_hi])[0])
    fit_rise = float(polynomial(theta1[1:], [edge_hi])[0])
    h_scale = fit_rise / base_rise if base_rise > 0 and fit_rise > 0 else 1.0
    ratios = np.asarray(base_n.Sy) / base_n.Sy[0]
    label = name or f"calibrated from {Path(data.source).name}"

    def params(theta, nested=True):
        c = np.asarray(theta[1:], dtype=float)
        odd = np.where(np.arange(1, degree + 1) % 2 == 1, c, 0.0)
        even = np.where(np.arange(1, degree + 1) % 2 == 0, c, 0.0)
        common = dict(Q=tuple(map(float, odd)), A=tuple(map(float, even)))
        if not nested or n_inner == 0:
            return dataclasses.replace(base, name=f"{label} (one surface)", Sy=(float(theta[0]),),
                                       surfaces=SurfaceTable(), **common)
        table = base_n.surfaces
        table = dataclasses.replace(table, h=tuple(tuple(float(h * h_scale) for h in row[:n_inner])
                                                   for row in table.h),
                                    a=tuple(tuple(row[:n_inner]) for row in table.a))
        return dataclasses.replace(base_n, name=label,
                                   Sy=tuple(float(theta[0] * r) for r in ratios),
                                   surfaces=table, **common)

    one = params(theta1, nested=False)
    tau_one = monotonic_tau(one, gamma)
    log(f"  stage 1 (linear, the loading edge): RMS {_rms(tau_one, tau):.4g} N/mm on "
        f"{gamma.size} points")
    theta = theta1
    info = {"points": int(gamma.size), "series": sorted(set(names.tolist()))}
    if n_inner:
        # stage 2, a defect correction: delta = nested - one-surface curve at the current
        # parameters, and the linear fit again to data - delta (delta hardly depends on them)
        best = (_rms(monotonic_tau(params(theta1), gamma), tau), theta1)
        for iteration in range(STAGE2_ITERATIONS):
            current = best[1]
            delta = (monotonic_tau(params(current), gamma)
                     - monotonic_tau(params(current, nested=False), gamma))
            x = lsq_linear(design, tau - delta, method="bvls",
                           bounds=(np.r_[floor, np.zeros(degree)], np.inf)).x
            error = _rms(monotonic_tau(params(x), gamma), tau)
            log(f"  stage 2, iteration {iteration + 1} (nested model simulated, {n_inner} inner "
                f"surfaces with the base's ratios, h x {h_scale:.3g}): RMS {error:.4g} N/mm")
            if error < best[0]:
                best = (error, x)
        theta = best[1]
    nested = params(theta)
    tau_nested = monotonic_tau(nested, gamma) if n_inner else tau_one
    return MonotonicFit(one, nested, names, gamma, tau, tau_one, tau_nested,
                        _rms(tau_one, tau), _rms(tau_nested, tau), h_scale, info)


def _rms(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


# --- drape calibrate on a series file with monotonic data --------------------------------------

def main(args, base, data: SeriesData) -> int:
    """`drape calibrate` on monotonic series: fit, then material.toml, calibration.csv/png."""
    from drape.calibrate import RESULT_FILES
    from drape.io.folder import claim
    from drape.law.parameters import material_toml

    angle_range = parse_angle_range(args.angle_range)
    output = Path(args.output)
    claim(output, RESULT_FILES, overwrite=args.overwrite)
    names = ", ".join(data.names)
    print(f"drape calibrate: {len(data.series)} monotonic series from {data.source} "
          f"({names}), column '{data.column}' ({data.quantity}), fitted within "
          f"{angle_range[0]:g}..{angle_range[1]:g} deg")
    result = fit_monotonic(data, base, degree=args.degree, n_inner=args.surfaces,
                           angle_range=angle_range, name=args.name)
    result.nested.validate()
    output.mkdir(parents=True, exist_ok=True)
    base_name = args.material or "the paper (drape defaults)"
    tau_range = float(np.ptp(result.tau)) or 1.0
    note = ("monotonic data (no unloading): only the outer surface's loading edge "
            "q + Sy_0 + alpha is fitted (odd powers in q, even powers in alpha); "
            + (f"the {result.nested.n} inner surfaces keep the ratios of {base_name} "
               f"(Sy_k/Sy_0, a_k; h_k x {result.h_scale:.4g}, the ratio of the edges' rise)"
               if result.nested.n else "no inner surfaces (--surfaces 0)"))
    header = [f"# drape calibrate: fitted to {data.source}, series {names} (column "
              f"'{data.column}', {data.quantity}, tau = {TAU_OF[data.quantity]}), "
              f"{result.gamma_deg.size} points every 0.5 deg within {angle_range[0]:g}.."
              f"{angle_range[1]:g} deg",
              f"# RMS error in tau: loading edge alone {result.rms_one_surface:.4g} N/mm, "
              f"nested model {result.rms_nested:.4g} N/mm; tau range {tau_range:.4g} N/mm",
              f"# {note}.",
              f"# K1, K2, Ksh and mu are not fitted: they come from {base_name}."]
    (output / "material.toml").write_text("\n".join(header) + "\n" + material_toml(result.nested))
    with (output / "calibration.csv").open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["series", "gamma_t_deg", "tau_data", "tau_one_surface", "tau_nested"])
        for row in zip(result.names, result.gamma_deg, result.tau, result.tau_one_surface,
                       result.tau_nested):
            writer.writerow([row[0]] + [repr(float(v)) for v in row[1:]])
    plot(output / "calibration.png", data, result, angle_range)
    print(f"drape calibrate: {note}")
    print(f"drape calibrate: RMS error in tau (range {tau_range:.4g} N/mm): loading edge "
          f"{result.rms_one_surface:.4g} N/mm ({100 * result.rms_one_surface / tau_range:.2f} %); "
          f"nested model {result.rms_nested:.4g} N/mm "
          f"({100 * result.rms_nested / tau_range:.2f} %)")
    print(f"drape calibrate: wrote {output / 'material.toml'}, {output / 'calibration.png'} and "
          f"{output / 'calibration.csv'}")
    return 0


#: the conversion of each quantity, for the material file's header
TAU_OF = {"frame-force": "2 F L_frame / (2 cos(pi/4 - gamma/2) L_fabric^2)",
          "shear-force": "2 F_s L_frame / L_fabric^2",
          "shear-force-per-frame-length": "2 (F_s/L_frame) L_frame^2 / L_fabric^2",
          "shear-force-per-area": "2 (F_s/L_fabric^2) L_frame",
          "normalised-force": "2 F_norm", "tau": "tau"}


def plot(path: Path, data: SeriesData, result: MonotonicFit, angle_range) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=120)
    top = max(float(np.abs(s.gamma_deg).max()) for s in data.series)
    for s in data.series:
        ax.plot(np.abs(s.gamma_deg), np.abs(s.tau), lw=1.0, alpha=0.8, label=s.name)
    g = np.linspace(0.0, top, 200)
    ax.plot(g, monotonic_tau(result.nested, g), color="black", lw=2.0,
            label=f"fitted, nested model (RMS {result.rms_nested:.3g} N/mm)")
    ax.plot(g, monotonic_tau(result.one_surface, g), color="black", lw=1.0, ls="--",
            label=f"loading edge alone (RMS {result.rms_one_surface:.3g} N/mm)")
    ax.axvspan(*angle_range, color="0.9", zorder=0, label="fitted range")
    ax.set_xlabel(r"shear angle $\gamma$ (deg)")
    ax.set_ylabel(r"$\tau$ (N/mm)  [= 2 $\times$ energy-normalised force]")
    ax.set_title(f"drape calibrate: {Path(data.source).name} ({data.quantity})", fontsize=10)
    ax.set_ylim(0.0, 1.2 * max(float(np.abs(s.tau).max()) for s in data.series))
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
