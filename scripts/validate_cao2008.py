"""Validation on measured data: calibrate on picture frames, predict bias extensions.

    .venv/bin/python scripts/validate_cao2008.py [--fabric plain-weave] [--output DIR]
    .venv/bin/python scripts/validate_cao2008.py --docs docs/validation   # docs/validation.md

The chain (docs/validation.md), deterministic, serial, about 2 minutes on one core:

1. `drape calibrate` on the fabric's energy-normalised picture-frame curves of Cao et al. 2008
   (plain weave Fig. 28, balanced twill Fig. 29, unbalanced twill Fig. 30; every laboratory,
   0-35 deg) -> DIR/calibration/material.toml;
2. `drape run` of every config in configs/validation/ (bias-extension specimens) with that
   material -> DIR/<specimen>/bias_extension.csv;
3. the FE against the measurements: force against displacement (Fig. 38, the same specimen
   size), central shear angle against displacement (Fig. 36, 150 x 450 mm), and the normalised
   shear force of Cao's eq. for the bias extension computed alike from the FE and the measured
   forces, with Fig. 39 and the calibrated tau/2 -> DIR/*.png, and the deviations at the
   displacements where the kinematic central angle is 10, 20, 30 and 40 deg ->
   DIR/deviations.csv and DIR/deviations.md.

Only the plain weave was tested in bias extension: for the twills the chain runs the same
specimens and reports the predictions without measurements.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "data" / "cao2008"
FABRICS = {"plain-weave": "cao2008_fig28.csv", "balanced-twill": "cao2008_fig29.csv",
           "unbalanced-twill": "cao2008_fig30.csv"}
ANGLES = (10.0, 20.0, 30.0, 40.0)
sys.path.insert(0, str(REPO))

from drape.reports.bias_extension import displacement_at_angle  # noqa: E402


def read_series(path: Path) -> dict[str, np.ndarray]:
    rows = [r for r in csv.reader(line for line in path.open() if not line.startswith("#"))]
    data: dict[str, list] = {}
    for row in rows[1:]:
        data.setdefault(row[0].strip(), []).append((float(row[1]), float(row[2])))
    return {name: np.asarray(v) for name, v in data.items()}


def read_columns(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as stream:
        rows = list(csv.DictReader(stream))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def specimen_of(config: Path) -> tuple[float, float]:
    """(W, H) from the config's blank (width, length)."""
    import tomllib
    blank = tomllib.loads(config.read_text())["blank"]
    return float(blank["width"]), float(blank["length"])


def interp(x, curve, at):
    order = np.argsort(curve[:, 0], kind="stable")
    return float(np.interp(at, curve[order, 0], curve[order, 1], left=np.nan, right=np.nan))


def normalised_force(W, H, force_of_d, gammas_deg):
    """Cao et al.'s normalised shear force of a bias extension (their eq. for F_sh, the zones'
    energy): (2H - 3W) cos(g) F_sh(g) = (H/W - 1) F (cos(g/2) - sin(g/2)) - W F_sh(g/2) cos(g/2),
    F taken at the displacement where the kinematic angle is g; solved from small angles up."""
    g = np.asarray(gammas_deg, dtype=float)
    f = np.full(g.size, np.nan)
    for i, gi in enumerate(g):
        r = np.radians(gi)
        force = force_of_d(float(displacement_at_angle(H, W, gi)))
        half = np.interp(gi / 2, g[:i], f[:i]) if i and gi / 2 >= g[0] else force / (2 * W)
        f[i] = (((H / W - 1) * force * (np.cos(r / 2) - np.sin(r / 2)) - W * half * np.cos(r / 2))
                / ((2 * H - 3 * W) * np.cos(r)))
    return f


def run(command: list[str]) -> None:
    print("$", " ".join(command), flush=True)
    subprocess.run(command, check=True, cwd=REPO)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fabric", choices=sorted(FABRICS), default="plain-weave")
    parser.add_argument("--output", default="results/validation", metavar="DIR")
    parser.add_argument("--configs", default="configs/validation", metavar="DIR",
                        help="folder of the bias-extension configs (default configs/validation)")
    parser.add_argument("--specimens", default=None, metavar="A,B",
                        help="only these configs of --configs, by name (e.g. 115x230)")
    parser.add_argument("--docs", default=None, metavar="DIR",
                        help="also copy the PNGs and deviations.md there (docs/validation: the "
                             "figures of docs/validation.md)")
    parser.add_argument("--series", default=None, metavar="A,B",
                        help="calibrate on these laboratories only (drape calibrate --series)")
    args = parser.parse_args(argv)
    out = (REPO / args.output).resolve()
    out.mkdir(parents=True, exist_ok=True)
    exe = str(Path(sys.executable).parent / "drape")

    # 1. calibrate
    run([exe, "calibrate", str(DATA / FABRICS[args.fabric]), "--output", str(out / "calibration"),
         "--overwrite", "--name", f"Twintex {args.fabric}, Cao et al. 2008 {FABRICS[args.fabric]}"]
        + (["--series", args.series] if args.series else []))
    material = out / "calibration" / "material.toml"

    # 2. the bias extensions
    configs = sorted((REPO / args.configs).glob("*.toml"))
    if args.specimens:
        wanted = {name.strip() for name in args.specimens.split(",")}
        configs = [c for c in configs if c.stem in wanted]
        if not configs:
            parser.error(f"no config named {args.specimens} in {args.configs}")
    results = {}
    for config in configs:
        W, H = specimen_of(config)
        folder = out / config.stem
        run([exe, "run", str(config), "--output", str(folder), "--overwrite", "--quiet",
             "--set", f"material={material}", "--set", "output.xdmf=false"])
        results[(W, H)] = read_columns(folder / "bias_extension.csv")

    # 3. against the measurements
    measured = read_series(DATA / "cao2008_fig38.csv") if args.fabric == "plain-weave" else {}
    angle_measured = read_series(DATA / "cao2008_fig36.csv") if args.fabric == "plain-weave" else {}
    fig39 = read_series(DATA / "cao2008_fig39.csv") if args.fabric == "plain-weave" else {}
    labs = {spec: {name.split(" ", 3)[-1]: curve for name, curve in measured.items()
                   if name.startswith(f"{spec[0]:g} x {spec[1]:g} ")} for spec in results}
    rows = table(results, labs)
    write_table(out, rows, args.fabric)
    plot(out, results, labs, angle_measured, fig39, material, args.fabric)
    print(f"validate_cao2008: wrote {out}/force_displacement.png, central_angle.png, "
          f"normalised_force.png, deviations.csv, deviations.md")
    if args.docs:
        copy_to_docs(out, (REPO / args.docs).resolve())
    return 0


def copy_to_docs(out: Path, docs: Path) -> None:
    """The figures and deviations.md of docs/validation.md, from ``out`` into ``docs``."""
    import shutil
    docs.mkdir(parents=True, exist_ok=True)
    for name in ("force_displacement.png", "central_angle.png", "normalised_force.png",
                 "deviations.md"):
        shutil.copyfile(out / name, docs / name)
    shutil.copyfile(out / "calibration" / "calibration.png", docs / "calibration.png")
    print(f"validate_cao2008: copied the figures and the table to {docs}")


def table(results, labs) -> list[dict]:
    rows = []
    for (W, H), fe in results.items():
        for gamma in ANGLES:
            d = float(displacement_at_angle(H, W, gamma))
            if d > fe["displacement_mm"].max() + 1e-9:
                continue
            force = float(np.interp(d, fe["displacement_mm"], fe["force_N"]))
            centre = float(np.interp(d, fe["displacement_mm"], fe["central_shear_deg"]))
            lab_forces = {lab: interp(None, curve, d) for lab, curve in labs[(W, H)].items()}
            lab_forces = {k: v for k, v in lab_forces.items() if np.isfinite(v)}
            row = {"specimen": f"{W:g} x {H:g}", "gamma_kinematic_deg": gamma, "d_mm": d,
                   "fe_central_deg": centre, "fe_force_N": force,
                   "labs": ", ".join(f"{k} {v:.2f}" for k, v in lab_forces.items())}
            if lab_forces:
                values = np.array(list(lab_forces.values()))
                lo, hi, mean = values.min(), values.max(), values.mean()
                row.update(lab_min_N=lo, lab_max_N=hi, fe_over_lab_mean=force / mean,
                           within_spread=bool(lo <= force <= hi))
            rows.append(row)
    return rows


def write_table(out: Path, rows, fabric: str) -> None:
    names = ["specimen", "gamma_kinematic_deg", "d_mm", "fe_central_deg", "fe_force_N",
             "lab_min_N", "lab_max_N", "fe_over_lab_mean", "within_spread", "labs"]
    with (out / "deviations.csv").open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(names)
        for row in rows:
            writer.writerow([row.get(n, "") for n in names])
    lines = [f"Fabric: {fabric}. d: where the kinematic central angle is gamma;",
             "FE centre: the FE's central angle there.", "",
             "| specimen (mm) | γ kin. | d (mm) | FE centre | FE force (N) | labs (N) | "
             "FE/mean | inside |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ratio = f"{r['fe_over_lab_mean']:.2f}" if "fe_over_lab_mean" in r else "–"
        spread = ("yes" if r["within_spread"] else "no") if "within_spread" in r else "–"
        lines.append(f"| {r['specimen']} | {r['gamma_kinematic_deg']:.0f}° | {r['d_mm']:.1f} | "
                     f"{r['fe_central_deg']:.1f}° | {r['fe_force_N']:.2f} | "
                     f"{r['labs'] or 'not measured'} | {ratio} | {spread} |")
    (out / "deviations.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def plot(out: Path, results, labs, angle_measured, fig39, material: Path, fabric: str) -> None:
    """force_displacement.png, central_angle.png and normalised_force.png in ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plot_force_displacement(plt, out / "force_displacement.png", results, labs, fabric)
    plot_central_angle(plt, out / "central_angle.png", results, angle_measured)
    plot_normalised_force(plt, out / "normalised_force.png", results, labs, fig39, material)


def plot_force_displacement(plt, path: Path, results, labs, fabric: str) -> None:
    """The FE's force against displacement and the measured ones (Fig. 38), one panel per
    specimen, the kinematic 10/20/30/40 deg marked."""
    specs = list(results)
    fig, axes = plt.subplots(1, len(specs), figsize=(4.2 * len(specs), 4.0), dpi=110,
                             squeeze=False)
    for ax, (W, H) in zip(axes[0], specs):
        fe = results[(W, H)]
        ax.plot(fe["displacement_mm"], fe["force_N"], color="black", lw=2.0, label="drape (FE)")
        for lab, curve in labs[(W, H)].items():
            ax.plot(curve[:, 0], curve[:, 1], lw=1.0, label=f"measured, {lab}")
        for gamma in ANGLES:
            ax.axvline(float(displacement_at_angle(H, W, gamma)), color="0.8", lw=0.8, zorder=0)
        top = fe["displacement_mm"].max()
        ax.set_xlim(0, top)
        visible = [fe["force_N"].max()] + [np.nanmax(np.where(c[:, 0] <= top, c[:, 1], np.nan))
                                           for c in labs[(W, H)].values()]
        ax.set_ylim(0, 1.1 * max(visible))
        ax.set_title(f"{W:g} x {H:g} mm (grey: kinematic 10/20/30/40°)", fontsize=9)
        ax.set_xlabel("displacement d (mm)")
        ax.set_ylabel("force (N)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"Bias extension, {fabric}: drape calibrated on the picture frame against "
                 "Cao et al. 2008, Fig. 38", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_central_angle(plt, path: Path, results, angle_measured) -> None:
    """The FE's central shear angle and the three-zone kinematics against displacement, and
    the measured angles of Fig. 36."""
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    for (W, H), fe in results.items():
        line, = ax.plot(fe["displacement_mm"], fe["central_shear_deg"], lw=1.8,
                        label=f"drape, {W:g} x {H:g}")
        ax.plot(fe["displacement_mm"], fe["kinematic_shear_deg"], lw=0.8, ls="--",
                color=line.get_color())
    for name, curve in angle_measured.items():
        if name != "Theoretical":
            ax.plot(curve[:, 0], curve[:, 1], ls="none", marker="o" if "Image" in name else "D",
                    ms=4, mfc="none", label=f"measured 150 x 450, {name} (Fig. 36)")
    ax.set_xlabel("displacement d (mm)")
    ax.set_ylabel("central shear angle (deg)")
    ax.set_title("Central zone: drape (solid), three-zone kinematics (dashed), Fig. 36 (marks)",
                 fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_normalised_force(plt, path: Path, results, labs, fig39, material: Path) -> None:
    """Cao et al.'s normalised shear force of the bias extension, computed alike from the FE's
    and the measured forces, against Fig. 39 and the calibrated tau/2."""
    from drape.calibration import monotonic_tau
    from drape.law.parameters import load_material

    params = load_material(material)
    gammas = np.arange(1.0, 45.01, 1.0)
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    ax.plot(gammas, monotonic_tau(params, gammas) / 2, color="black", lw=2.5,
            label=r"calibrated on the picture frame: $\tau/2$")
    for (W, H), fe in results.items():
        f = normalised_force(W, H, lambda d, fe=fe: float(np.interp(d, fe["displacement_mm"],
                                                                   fe["force_N"], right=np.nan)),
                             gammas)
        line, = ax.plot(gammas, f, lw=1.2, ls="--", label=f"drape's force, {W:g} x {H:g}")
        for lab, curve in labs[(W, H)].items():
            fm = normalised_force(W, H, lambda d, c=curve: interp(None, c, d), gammas)
            ax.plot(gammas, fm, lw=0.8, color=line.get_color(), alpha=0.7,
                    label=f"Fig. 38's force, {W:g} x {H:g} {lab}")
    for name, curve in fig39.items():
        if any(name.startswith(f"{W:g} x {H:g} ") for W, H in results):
            ax.plot(curve[:, 0], curve[:, 1], lw=0.6, color="0.6")
    if fig39:
        ax.plot([], [], lw=0.6, color="0.6", label="Fig. 39 as published")
    ax.set_xlim(0, 45)
    ax.set_ylim(0, 0.2)
    ax.set_xlabel("kinematic shear angle (deg)")
    ax.set_ylabel("normalised shear force (N/mm)")
    ax.set_title("Bias extension normalised by Cao et al.'s zone energy (dashed: FE; thin: "
                 "measured)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc="upper left", ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
