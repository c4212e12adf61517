"""Drive one material point through a picture-frame shear history (the paper's section 5).

The frame imposes F = cos(gt/2)(G1G1 + G2G2) + sin(gt/2)(G1G2 + G2G1), so C11 = C22 = 1 and
C12 = sin(gt): each row of the history is one increment of the law (no sub-stepping), so a
history file reproduces a result exactly. Writes a CSV (gamma_t_deg, tau, gamma_p_deg,
active_surface, the state's branch_surface, branch_direction and table_row, ...) and a PNG of
tau against the shear angle; by default the one-surface model (the paper's figure 6) is drawn
on the same history beside the nested-surface one (figure 8).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from drape.errors import InputError
from drape.law.nested_surface import LawState, NestedSurfaceLaw
from drape.law.parameters import MaterialParameters, load_material

HELP = "drive one material point through a picture-frame shear history (CSV + PNG)"
DEFAULT_CYCLES = "10,20,30,40,-40"


# --- histories ---------------------------------------------------------------------------------

def cyclic_history(amplitudes_deg, increment_deg: float) -> np.ndarray:
    """Shear angles (deg) of cycles 0 -> A -> 0 for each amplitude A, in equal increments of at
    most ``increment_deg``. The initial 0 is the virgin state and is not part of the history."""
    if not increment_deg > 0:
        raise InputError("increment must be positive", key="--increment", value=increment_deg,
                         expected="a shear-angle increment > 0 in degrees, e.g. 0.25")
    angles = [0.0]
    for amplitude in amplitudes_deg:
        for target in (amplitude, 0.0):
            steps = max(1, math.ceil(abs(target - angles[-1]) / increment_deg - 1e-9))
            angles.extend(np.linspace(angles[-1], target, steps + 1)[1:])
    return np.asarray(angles[1:])


def parse_cycles(text: str) -> list[float]:
    """'10,20,-40' -> [10.0, 20.0, -40.0], each |A| < 90 deg."""
    try:
        amplitudes = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise InputError("not a list of numbers", key="--cycles", value=text,
                         expected="comma-separated amplitudes in degrees, "
                                  "e.g. 10,20,30,40,-40") from None
    if not amplitudes or any(not math.isfinite(a) or a == 0 or abs(a) >= 90 for a in amplitudes):
        raise InputError("amplitudes must be non-zero and within (-90, 90) deg", key="--cycles",
                         value=text, expected="e.g. 10,20,30,40,-40")
    return amplitudes


def read_history(path: str | Path) -> np.ndarray:
    """Shear angles (deg) from a CSV file with a header ``gamma_t_deg``, one row per increment."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", source=str(path),
                         expected="a CSV file with a header 'gamma_t_deg' and one angle per row")
    with path.open(newline="") as stream:
        reader = csv.DictReader(stream)
        if not reader.fieldnames or "gamma_t_deg" not in [f.strip() for f in reader.fieldnames]:
            raise InputError("no 'gamma_t_deg' column", source=str(path), value=reader.fieldnames,
                             expected="a header line naming the column gamma_t_deg")
        column = next(f for f in reader.fieldnames if f.strip() == "gamma_t_deg")
        angles = []
        for line, row in enumerate(reader, start=2):
            text = (row.get(column) or "").strip()
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not math.isfinite(value) or abs(value) >= 90:
                raise InputError(f"line {line}: not a shear angle", source=str(path), value=text,
                                 expected="a number of degrees within (-90, 90)")
            angles.append(value)
    if not angles:
        raise InputError("no rows", source=str(path), expected="at least one shear angle")
    return np.asarray(angles)


# --- frame force and shear stress ----------------------------------------------------------------

def frame_force(tau, gamma_deg, side):
    """Force (N) pulling a picture frame of side ``side`` (mm) along its diagonal, from the
    projected shear stress ``tau`` (N/mm) at the shear angle ``gamma_deg``.

    The fabric fills the frame: a square of side L in the reference configuration, sheared
    uniformly (C11 = C22 = 1, C12 = sin gamma). Its internal power is L^2 tau cos(gamma) dgamma/2
    (tau = S:(G1G2 + G2G1), dC12 = cos(gamma) dgamma). The diagonal along which the frame is
    pulled is d = 2 L cos(pi/4 - gamma/2), so dd = L sin(pi/4 - gamma/2) dgamma and
    F dd = power gives F = L tau cos(gamma) / (2 sin(pi/4 - gamma/2)). Arrays broadcast.
    """
    gamma = np.radians(np.asarray(gamma_deg, dtype=float))
    return (side * np.asarray(tau, dtype=float) * np.cos(gamma)
            / (2.0 * np.sin(0.25 * np.pi - 0.5 * gamma)))


def frame_tau(force, gamma_deg, side):
    """The inverse of :func:`frame_force`: tau (N/mm) from the frame force (N), |gamma| < 90."""
    gamma = np.radians(np.asarray(gamma_deg, dtype=float))
    return (2.0 * np.asarray(force, dtype=float) * np.sin(0.25 * np.pi - 0.5 * gamma)
            / (side * np.cos(gamma)))


# --- the driver --------------------------------------------------------------------------------

def drive(params: MaterialParameters, history_deg) -> dict[str, np.ndarray]:
    """Run the law through the history, one increment per angle; return the columns."""
    law = NestedSurfaceLaw(params)
    state = LawState.virgin(1, params.n)
    history = np.asarray(history_deg, dtype=float)
    columns = {name: np.empty(history.size) for name in
               ("gamma_t_deg", "tau", "gamma_p_deg", "dtau_dC12", "gamma_max_deg")}
    for name in ("active_surface", "branch_surface", "branch_direction", "table_row"):
        columns[name] = np.empty(history.size, dtype=int)
    centres = np.empty((params.n, history.size))
    one = np.ones(1)
    for i, angle in enumerate(history):
        response = law.update(state, one, one, np.sin(np.radians([angle])))
        state = response.trial
        columns["gamma_t_deg"][i] = angle
        columns["tau"][i] = response.tau[0]
        columns["gamma_p_deg"][i] = np.degrees(state.gamma_p[0])
        columns["dtau_dC12"][i] = response.dtau_dC12[0]
        columns["gamma_max_deg"][i] = state.gamma_max_deg[0]
        columns["active_surface"][i] = response.active_surface[0]
        columns["branch_surface"][i] = state.active[0]
        columns["branch_direction"][i] = state.direction[0]
        columns["table_row"][i] = state.row[0]
        centres[:, i] = state.centres[:, 0]
    for k in range(params.n):
        columns[f"centre_{k + 1}"] = centres[k]
    return columns


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> None:
    names = list(columns)
    with path.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(names)
        for row in zip(*(columns[n] for n in names)):
            writer.writerow([v if isinstance(v, (int, np.integer)) else repr(float(v))
                             for v in row])


def reversal_indices(angle) -> np.ndarray:
    """Indices of the points where a shear-angle history turns back (the increment changes
    sign; repeated equal angles are skipped)."""
    angle = np.asarray(angle, dtype=float)
    moving = np.flatnonzero(np.diff(angle) != 0)
    if moving.size < 2:
        return np.zeros(0, dtype=int)
    signs = np.sign(np.diff(angle)[moving])
    turns = np.flatnonzero(signs[1:] != signs[:-1])
    return moving[turns + 1]


def cycle_starts(angle) -> np.ndarray:
    """Indices where a new cycle starts: the history is back at (or crosses) 0 after a reversal."""
    angle = np.asarray(angle, dtype=float)
    reversals = set(reversal_indices(angle).tolist())
    starts, turned = [0], False
    for i in range(1, angle.size):
        turned = turned or (i - 1) in reversals
        if turned and (angle[i] == 0 or angle[i] * angle[i - 1] < 0) and i < angle.size - 1:
            starts.append(i)
            turned = False
    return np.asarray(starts)


def _draw_cycles(ax, columns, *, label, colours, lw, zorder, mark=True):
    """tau against gamma_t, one colour per cycle, reversal points marked."""
    angle, tau = np.asarray(columns["gamma_t_deg"]), np.asarray(columns["tau"])
    angle = np.concatenate([[0.0], angle])
    tau = np.concatenate([[0.0], tau])                     # the virgin state
    starts = list(cycle_starts(angle)) + [angle.size - 1]
    handles = []
    for k, (a, b) in enumerate(zip(starts[:-1], starts[1:])):
        piece = slice(a, b + 1)
        peak = angle[piece][np.abs(angle[piece]).argmax()]
        line, = ax.plot(angle[piece], tau[piece], color=colours[k % len(colours)], lw=lw,
                        zorder=zorder, label=f"{label}: cycle to {peak:+.0f} deg")
        handles.append(line)
    if mark:
        turns = reversal_indices(angle)
        turns = turns[np.abs(angle[turns]) > 1e-9]        # the peaks, not the returns to 0
        ax.plot(angle[turns], tau[turns], ls="none", marker="o", ms=5, mfc="white",
                mec="black", mew=1.0, zorder=zorder + 1)
        for i in turns:
            ax.annotate(f"{angle[i]:+.0f}\u00b0, {tau[i]:.2f}", (angle[i], tau[i]),
                        textcoords="offset points", xytext=(-6 if angle[i] > 0 else 6, 6),
                        ha="right" if angle[i] > 0 else "left", fontsize=7.5, color="0.25")
    return handles


def plot(path: Path, curves: list[tuple[str, dict[str, np.ndarray]]], title: str) -> None:
    """tau against gamma_t: one panel per (label, columns), like the paper's figures 6 (one
    surface) and 8 (nested surfaces), on the same axes scales; each cycle in its own colour,
    the reversal points marked with their angle and tau, the other model in grey behind."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = list(reversed(curves)) if len(curves) > 1 else curves   # one surface first
    fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 5.2), dpi=120,
                             sharex=True, sharey=True, squeeze=False)
    colours = list(plt.get_cmap("tab10").colors)
    for ax, (label, columns) in zip(axes[0], panels):
        for other_label, other in panels:
            if other is not columns:
                ax.plot(other["gamma_t_deg"], other["tau"], color="0.7", lw=1.0, zorder=1,
                        label=f"{other_label.split(' (')[0]} (for comparison)")
        _draw_cycles(ax, columns, label=label.split(" (")[0], colours=colours, lw=1.6, zorder=3)
        ax.axhline(0.0, color="0.5", lw=0.6)
        ax.axvline(0.0, color="0.5", lw=0.6)
        ax.set_xlabel(r"shear angle $\gamma_t$ (deg)")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8, framealpha=0.9)
    axes[0][0].set_ylabel(r"projected shear stress $\tau$ (N/mm)")
    if len(panels) > 1:
        for ax, figure in zip(axes[0], ("paper fig. 6", "paper fig. 8")):
            ax.text(0.98, 0.02, figure, transform=ax.transAxes, ha="right", va="bottom",
                    fontsize=8, color="0.4")
    fig.suptitle(title + "; circles: reversal points (angle, tau in N/mm)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# --- command line ------------------------------------------------------------------------------

#: what it writes in --output (not overwritten without --overwrite)
RESULT_FILES = ("picture_frame.csv", "picture_frame.png", "picture_frame_one_surface.csv")


def add_arguments(parser) -> None:
    parser.add_argument("--material", default=None, metavar="FILE",
                        help="material TOML file (default: the paper's three-surface model, "
                             "Tables 1-3, as in configs/materials/paper_three_surface.toml)")
    parser.add_argument("--surfaces", type=int, default=None, metavar="N",
                        help="keep only the outer surface and the first N inner ones "
                             "(0: the one-surface model; default: all in the file)")
    history = parser.add_mutually_exclusive_group()
    history.add_argument("--cycles", default=None, metavar="A1,A2,...",
                         help=f"cycles 0 -> A -> 0 for each amplitude A in degrees "
                              f"(default {DEFAULT_CYCLES})")
    history.add_argument("--history", default=None, metavar="CSV",
                         help="CSV file with a header gamma_t_deg, one increment per row")
    parser.add_argument("--increment", type=float, default=0.1, metavar="DEG",
                        help="largest shear-angle increment of --cycles, degrees (default 0.1)")
    parser.add_argument("--no-compare", action="store_true",
                        help="do not draw the one-surface model on the same history")
    parser.add_argument("--output", default="results/picture-frame", metavar="DIR",
                        help="folder for picture_frame.csv and picture_frame.png "
                             "(default results/picture-frame)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the results (picture_frame.csv/png) already in --output")


def main(args) -> int:
    from drape.io.folder import claim
    if args.material is None:
        params = MaterialParameters()
        if args.surfaces is not None:
            params = params.with_surfaces(args.surfaces, key="--surfaces")
    else:
        params = load_material(args.material, surfaces=args.surfaces, surfaces_key="--surfaces")
    if args.history is not None:
        history = read_history(args.history)
    else:
        history = cyclic_history(parse_cycles(args.cycles or DEFAULT_CYCLES), args.increment)
    output = Path(args.output)
    claim(output, RESULT_FILES, overwrite=args.overwrite)
    output.mkdir(parents=True, exist_ok=True)

    columns = drive(params, history)
    write_csv(output / "picture_frame.csv", columns)
    label = "one surface" if params.n == 0 else f"{params.n + 1} nested surfaces"
    curves = [(f"{label} ({params.name})", columns)]
    if params.n > 0 and not args.no_compare:
        single = drive(params.with_surfaces(0), history)
        write_csv(output / "picture_frame_one_surface.csv", single)
        curves.append(("one surface (same outer surface)", single))
    plot(output / "picture_frame.png", curves, f"Picture frame, {len(history)} increments")
    print(f"drape picture-frame: {len(history)} increments, tau in "
          f"[{columns['tau'].min():.4g}, {columns['tau'].max():.4g}] N/mm; wrote "
          f"{output / 'picture_frame.csv'} and {output / 'picture_frame.png'}")
    return 0
