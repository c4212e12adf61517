"""Where a double-dome run's shear map peaks, against a kinematic drape of the same ply.

    .venv/bin/python benchmarks/kinematic_comparison.py CONFIG RESULTS [--spacing 5] [--count 60]

CONFIG is the job's TOML, RESULTS the folder its run wrote (finished or stopped: the last
converged step's `result.npz` is used). The kinematic (fishnet) drape puts the same ply on the
die's exact surface (drape/forming/kinematic.py: inextensible yarns, no forces), crossing the
blank's
centre at the die's point nearest (0, 0, -40) mm, the saddle's floor. Prints the stroke reached
and `drape.forming.kinematic.compare_peaks`: the FE peak on the flat blank, the kinematic shear's
percentile there and over the FE's top 2 %, and the rank correlation of the two maps; then,
region by region of the flat blank (the saddle, the two ends on the x axis, the corners, the
middles of the long sides, the domes; mm from the blank's centre, in ZONES), the largest and
the 90th-percentile shear of the FE and of the kinematic drape. The figures in
docs/double-dome.md were taken with it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

#: a point above the die's floor at the saddle (mm); the drape starts at the die's point nearest it
ORIGIN = (0.0, 0.0, -40.0)

#: regions of the flat blank (mm, by |x| and |y|): name, then |x| and |y| ranges (the default
#: tools: domes' centres at x = +-100, punch half-width 90, cavity half-length 192)
ZONES = [("saddle", (0, 40), (0, 40)),
         ("ends (x axis)", (150, 1e9), (0, 40)),
         ("corners", (120, 1e9), (50, 1e9)),
         ("mid-sides", (0, 60), (60, 1e9)),
         ("domes", (60, 150), (0, 50))]


def zone_table(points, fe, kinematic) -> str:
    """Per region of ZONES: the largest and the 90th-percentile |shear| (deg) of the FE map and
    of the kinematic drape, at the same flat-blank points (those the drape covers)."""
    ok = np.isfinite(kinematic)
    points, fe, kinematic = np.asarray(points)[ok], np.abs(fe[ok]), kinematic[ok]
    x, y = np.abs(points[:, 0]), np.abs(points[:, 1])
    lines = [f"{'region':14s} {'FE max':>7s} {'FE p90':>7s} {'kin max':>8s} {'kin p90':>8s}"
             "  FE max at (mm)"]
    for name, (x0, x1), (y0, y1) in ZONES:
        inside = (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
        if not inside.any():
            continue
        i = np.flatnonzero(inside)[np.argmax(fe[inside])]
        lines.append(f"{name:14s} {fe[i]:7.1f} {np.percentile(fe[inside], 90):7.1f} "
                     f"{kinematic[inside].max():8.1f} {np.percentile(kinematic[inside], 90):8.1f}"
                     f"  ({points[i, 0]:.1f}, {points[i, 1]:.1f})")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("config", type=Path)
    parser.add_argument("results", type=Path)
    parser.add_argument("--spacing", type=float, default=5.0,
                        help="yarn length between crossings of the kinematic net (mm)")
    parser.add_argument("--count", type=int, default=60,
                        help="crossings each way from the centre (60 x 5 mm covers the blank)")
    args = parser.parse_args(argv)

    from drape.errors import InputError
    from drape.geometry.tools import analytic_double_dome_tools
    from drape.job import load_job
    from drape.forming.kinematic import compare_peaks, drape_fishnet

    try:
        job = load_job(args.config)
    except InputError as error:
        sys.exit(f"kinematic_comparison: {error}")
    if job.config.tools.kind != "double_dome":
        sys.exit(f"kinematic_comparison: {args.config} has tools.kind = "
                 f"{job.config.tools.kind!r}; this comparison is for kind = 'double_dome'")
    result = args.results / "result.npz"
    if not result.is_file():
        sys.exit(f"kinematic_comparison: no {result}: RESULTS must be a folder a run of "
                 f"{args.config} wrote (drape run CONFIG --output RESULTS)")
    data = np.load(result)
    summary = json.loads((args.results / "summary.json").read_text())
    die = analytic_double_dome_tools(job.config.tools.double_dome)["die"]
    drape = drape_fishnet(die, ORIGIN, job.config.blank.yarn_angle, args.spacing, args.count)
    comparison = compare_peaks(data["point_xy"], data["gamma_t_deg"], drape)
    print(f"{args.config}: stroke {summary['stroke_mm']:.1f} mm")
    print(json.dumps(comparison, indent=1))
    print(zone_table(data["point_xy"], data["gamma_t_deg"], drape.shear_at(data["point_xy"])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
