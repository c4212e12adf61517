"""STEP tools against the built-in ones: the same forming job run twice in one process.

    .venv/bin/python benchmarks/step_tools.py [--stroke 10] [--set key=value ...]
                                              [--margin 1.0] [--only step|builtin]
                                              [--tools hemisphere|double_dome]

Writes the default hemisphere's punch, die and holder as STEP files (gmsh's OpenCASCADE
kernel, tests/cad_helpers.py: a sphere fused with a cylinder, plates with a hole and fillets),
then runs configs/hemisphere.toml with its built-in tools and with ``[tools] kind = "step"``
on those files, with the same overrides, and prints per run: wall time, the time spent in the
tools' closest-point queries (and how many points were searched rather than answered from
their candidate lists), steps / Newton iterations, peak shear, mid-side draw-in, punch force
at the end, and the holder force's range over the converged steps. ``--margin 0`` turns the
meshed tools' candidate lists off (drape.forming.surfaces.MeshedSurface, docs/tools.md). ``--tools
double_dome``: configs/double_dome.toml, its tools written by drape's gmsh builder with the die
and holder plates 50 mm wider all round (tests/cad_helpers.py, write_double_dome_step).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))


def timed_queries(forming, clock):
    """Wrap every tool's query to add its time to clock["query"]."""
    for surface in forming.tool_contact.surfaces.values():
        plain = surface.query

        def query(*args, _plain=plain, **kwargs):
            started = time.perf_counter()
            try:
                return _plain(*args, **kwargs)
            finally:
                clock["query"] += time.perf_counter() - started
        surface.query = query


def run(config, folder, overrides, margin):
    from mpi4py import MPI

    from drape.forming.press import Forming
    from drape.job import load_job
    from drape.run import run_job

    clock = {"query": 0.0}

    def on_start(parts):
        """The run's forming part: its meshed tools' margin set, their queries timed."""
        forming = parts.part(Forming)
        for surface in forming.tool_contact.surfaces.values():
            if hasattr(surface, "margin"):
                surface.margin = margin
        timed_queries(forming, clock)
        clock["forming"] = forming

    job = load_job(config, overrides=overrides)
    started = time.perf_counter()
    summary = run_job(job, MPI.COMM_WORLD, output=str(folder), overwrite=True,
                      on_start=on_start)
    seconds = time.perf_counter() - started
    rows = summary.rows
    import json
    report = json.loads((Path(folder) / "summary.json").read_text())
    searched = sum(getattr(s, "searched", 0)
                   for s in clock["forming"].tool_contact.surfaces.values())
    return {"wall (s)": seconds, "queries (s)": clock["query"], "searched": searched,
            "steps": rows[-1].step, "iterations": report["newton_iterations"],
            "peak shear (deg)": report["max_shear_angle_deg"],
            "draw-in mid-side (mm)": report["draw_in_mm"]["mid_right"],
            "draw-in other mid-side (mm)": report["draw_in_mm"]["mid_top"],
            "punch force (N)": report["punch_force_at_end_N"],
            "holder force (N)": report["holder_force_measured_N"]}


def main():
    from cad_helpers import step_job, write_double_dome_step, write_hemisphere_step
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stroke", type=float, default=10.0)
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    parser.add_argument("--margin", type=float, default=None,
                        help="candidate-list margin of the meshed tools (mm; default: drape's)")
    parser.add_argument("--only", choices=("step", "builtin"))
    parser.add_argument("--tools", choices=("hemisphere", "double_dome"), default="hemisphere")
    args = parser.parse_args()
    overrides = [f"process.stroke={args.stroke:g}"] + args.overrides
    config = REPO / "configs" / f"{args.tools}.toml"
    write = write_hemisphere_step if args.tools == "hemisphere" else write_double_dome_step
    results = {}
    with tempfile.TemporaryDirectory(prefix="drape-step-bench-") as tmp:
        tmp = Path(tmp)
        paths = write(tmp / "cad")
        jobs = {"built-in": config, "STEP": step_job(config, tmp, paths)}
        for name, path in jobs.items():
            if args.only and args.only != ("step" if name == "STEP" else "builtin"):
                continue
            margin = args.margin
            if margin is None:
                from drape.forming.tool_contact import TOOL_LIST_MARGIN
                margin = TOOL_LIST_MARGIN
            results[name] = run(path, tmp / name, overrides, margin)
            print(name, results[name], flush=True)
    print(f"\n{args.tools}, {' '.join(overrides)}, 1 rank")
    print("| | " + " | ".join(results) + " |")
    print("|---|" + "---:|" * len(results))
    for key in next(iter(results.values())):
        cells = []
        for values in results.values():
            value = values[key]
            cells.append(f"{value[0]:.5g} – {value[1]:.5g}" if isinstance(value, list)
                         else f"{value:.4g}" if isinstance(value, float) else str(value))
        print(f"| {key} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
