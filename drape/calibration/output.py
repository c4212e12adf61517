"""What `drape calibrate` writes in its output folder: material.toml (the fitted material,
its header saying what it was fitted to and the RMS errors), calibration.csv (the data and
both fitted curves) and calibration.png, for a cyclic fit and for a monotonic one."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from drape.calibration.curve import Curve
from drape.calibration.cyclic import Calibration
from drape.calibration.history import monotonic_tau
from drape.calibration.monotonic import MonotonicFit
from drape.calibration.series import TAU_OF, SeriesData
from drape.law.parameters import material_toml

#: what it writes in --output (not overwritten without --overwrite)
RESULT_FILES = ("material.toml", "calibration.csv", "calibration.png")


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


# --- a cyclic curve ---------------------------------------------------------------------------

def write_cyclic(output: Path, curve: Curve, result: Calibration, frame_side: float | None,
                 material_source: str | None) -> None:
    """material.toml, calibration.csv and calibration.png of a cyclic fit;
    ``material_source`` is --material (None: the paper's values)."""
    tau_range = float(np.ptp(curve.tau))
    header = [f"# drape calibrate: fitted to {curve.source} ({len(curve)} rows, column "
              f"'{curve.column}'"
              f"{f', frame side {frame_side:g} mm' if frame_side else ''})",
              f"# RMS error in tau: one surface (stage 1) {result.rms_one_surface:.4g} N/mm"
              + (f", {result.nested.n + 1} nested surfaces (stage 2) {result.rms_nested:.4g} N/mm"
                 if result.nested.n else "") + f"; tau range {tau_range:.4g} N/mm",
              "# K1, K2, Ksh and mu are not fitted: they come from "
              f"{material_source or 'the paper (drape defaults)'}."]
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
    plot_cyclic(output / "calibration.png", curve, result)


def plot_cyclic(path: Path, curve: Curve, result: Calibration) -> None:
    """The data and the stage-1 and stage-2 curves against the shear angle."""
    plt = _pyplot()
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


# --- monotonic series -------------------------------------------------------------------------

def monotonic_note(result: MonotonicFit, base_name: str) -> str:
    """What a monotonic fit fitted and what it took from the base material (printed, and in
    material.toml's header)."""
    return ("monotonic data (no unloading): only the outer surface's loading edge "
            "q + Sy_0 + alpha is fitted (odd powers in q, even powers in alpha); "
            + (f"the {result.nested.n} inner surfaces keep the ratios of {base_name} "
               f"(Sy_k/Sy_0, a_k; h_k x {result.h_scale:.4g}, the ratio of the edges' rise)"
               if result.nested.n else "no inner surfaces (--surfaces 0)"))


def write_monotonic(output: Path, data: SeriesData, result: MonotonicFit, angle_range,
                    base_name: str) -> None:
    """material.toml, calibration.csv (on the resampled points) and calibration.png of a
    monotonic fit; ``base_name`` says where the inner surfaces' ratios come from."""
    names = ", ".join(data.names)
    tau_range = float(np.ptp(result.tau)) or 1.0
    header = [f"# drape calibrate: fitted to {data.source}, series {names} (column "
              f"'{data.column}', {data.quantity}, tau = {TAU_OF[data.quantity]}), "
              f"{result.gamma_deg.size} points every 0.5 deg within {angle_range[0]:g}.."
              f"{angle_range[1]:g} deg",
              f"# RMS error in tau: loading edge alone {result.rms_one_surface:.4g} N/mm, "
              f"nested model {result.rms_nested:.4g} N/mm; tau range {tau_range:.4g} N/mm",
              f"# {monotonic_note(result, base_name)}.",
              f"# K1, K2, Ksh and mu are not fitted: they come from {base_name}."]
    (output / "material.toml").write_text("\n".join(header) + "\n" + material_toml(result.nested))
    with (output / "calibration.csv").open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["series", "gamma_t_deg", "tau_data", "tau_one_surface", "tau_nested"])
        for row in zip(result.names, result.gamma_deg, result.tau, result.tau_one_surface,
                       result.tau_nested):
            writer.writerow([row[0]] + [repr(float(v)) for v in row[1:]])
    plot_monotonic(output / "calibration.png", data, result, angle_range)


def plot_monotonic(path: Path, data: SeriesData, result: MonotonicFit, angle_range) -> None:
    """Every series and both fitted curves (virgin loading) to the largest angle."""
    plt = _pyplot()
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
