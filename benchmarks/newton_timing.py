"""Where a Newton iteration spends its time, on a blank of about 1e5 elements, with 1 and 2 ranks.

    .venv/bin/python benchmarks/newton_timing.py            # runs both, prints them side by side
    .venv/bin/python benchmarks/newton_timing.py --cells 2e4 --steps 1

The job is configs/bias_extension.toml (aligned quadrilaterals; yarns at +-45 deg) with the mesh
refined to about --cells elements and the first --steps load steps of 2 % of the stroke each
(plastic at every point, about five Newton iterations per step). Per Newton iteration (counted
as Jacobian evaluations) it reports the time in the law update (numpy, every residual
evaluation), in evaluating C at the quadrature points, in assembling residuals (the line search
and the convergence check evaluate several per iteration) and the Jacobian, and in the linear
solve (MUMPS factorisation and solve, from PETSc's log). Times are the maximum over ranks.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
ROWS = [("law update (numpy)", "law"), ("C at quadrature points", "quadrature_values"),
        ("residual assembly", "residual_assembly"), ("Jacobian assembly", "jacobian_assembly"),
        ("linear solve (MUMPS)", "linear_solve"), ("whole Newton iteration", "snes")]


def measure(cells: float, steps: int, output: str) -> None:
    """One run (under mpirun or not): write the timings as JSON on rank 0."""
    from mpi4py import MPI
    from petsc4py import PETSc

    from drape.job import load_job
    from drape.run import run_job

    PETSc.Log.begin()
    comm = MPI.COMM_WORLD
    # aligned +-45 lattice: about length * width / size^2 quadrilaterals
    size = math.sqrt(100.0 * 50.0 / cells)
    overrides = [f"mesh.size={size}", "output.xdmf=false", "output.snapshot=none",
                 f"steps.initial={0.02}", "steps.maximum=0.02", "steps.growth=1.0",
                 f"history.d.t=[0.0, {0.02 * steps}, 1.0]",
                 f"history.d.values=[0.0, {15.0 * 0.02 * steps}, {15.0 * 0.02 * steps}]"]
    job = load_job(REPO / "configs" / "bias_extension.toml", overrides=overrides)
    stop = {"after": steps}
    started = time.perf_counter()
    snes_time = [0.0]
    description = {}

    class Done(Exception):
        pass

    def on_step(record, problem):
        snes_time[0] += record.seconds
        description["cells"] = problem.mesh.topology.index_map(2).size_global
        description["dofs"] = problem.V.dofmap.index_map.size_global * 3
        description["points"] = comm.allreduce(problem.response.tau.size)
        if record.step >= stop["after"]:
            description["timings"] = dict(problem.timings)
            description["counts"] = dict(problem.counts)
            raise Done

    try:
        folder = comm.bcast(tempfile.mkdtemp(prefix="drape-bench-") if comm.rank == 0 else None)
        run_job(job, comm, output=folder, on_step=on_step)
    except Done:
        pass
    events = {name: PETSc.Log.Event(name).getPerfInfo()["time"]
              for name in ("KSPSetUp", "KSPSolve", "PCSetUp", "PCApply", "MatLUFactorNum",
                           "MatLUFactorSym")}
    linear = events["KSPSolve"] + events["KSPSetUp"]
    if events["PCSetUp"] > linear:      # PCSetUp logged outside KSPSolve/KSPSetUp
        linear += events["PCSetUp"]
    timings = description["timings"]
    timings["linear_solve"] = linear
    timings["snes"] = snes_time[0]
    maxima = {k: comm.allreduce(v, op=MPI.MAX) for k, v in timings.items()}
    if comm.rank == 0:
        result = {"ranks": comm.size, "cells": description["cells"], "dofs": description["dofs"],
                  "points": description["points"], "iterations": description["counts"]["jacobian"],
                  "residuals": description["counts"]["residual"], "timings": maxima,
                  "wall": time.perf_counter() - started}
        Path(output).write_text(json.dumps(result))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cells", type=float, default=1e5, help="about this many elements")
    parser.add_argument("--steps", type=int, default=2, help="load steps to time")
    parser.add_argument("--ranks", default="1,2", help="comma-separated rank counts")
    parser.add_argument("--measure", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        measure(args.cells, args.steps, args.measure)
        return 0
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    results = []
    for ranks in [int(r) for r in args.ranks.split(",")]:
        with tempfile.NamedTemporaryFile(suffix=".json") as handle:
            command = [sys.executable, __file__, "--cells", str(args.cells), "--steps",
                       str(args.steps), "--measure", handle.name]
            command = ["mpirun", "-n", str(ranks), "--oversubscribe", *command]
            print(f"running: {' '.join(command[:4])} ... ({ranks} rank(s))", flush=True)
            subprocess.run(command, check=True, env=env, cwd=REPO)
            results.append(json.loads(Path(handle.name).read_text()))
    first = results[0]
    print(f"\nbias extension, {first['cells']} quadrilaterals, {first['dofs']} dofs, "
          f"{first['points']} law points; {args.steps} load steps; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    header = "per Newton iteration (s)".ljust(28) + "".join(
        f"{r['ranks']} rank(s)".rjust(16) for r in results)
    print(header)
    print("-" * len(header))
    for label, key in ROWS:
        line = label.ljust(28)
        for r in results:
            per = r["timings"][key] / r["iterations"]
            share = 100.0 * r["timings"][key] / r["timings"]["snes"]
            line += f"{per:9.3f} ({share:3.0f}%)".rjust(16)
        print(line)
    print("Newton iterations".ljust(28) + "".join(f"{r['iterations']:>16d}" for r in results))
    print("residual evaluations".ljust(28) + "".join(f"{r['residuals']:>16d}" for r in results))
    print("wall time of the run (s)".ljust(28) + "".join(f"{r['wall']:>16.1f}" for r in results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
