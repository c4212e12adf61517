"""`drape run` with a breakdown of where its time went, for benchmarks/speed_10k.py.

    python benchmarks/_timed_run.py BREAKDOWN.json run CONFIG.toml [drape run's arguments]

Runs drape's command line as `drape run` does (under mpirun: on every rank), with PETSc's
event log on, and writes BREAKDOWN.json (rank 0): PETSc's counts and seconds of the
factorisations (MatLUFactorNum, MatCholeskyFactorNum), triangular solves (MatSolve), residual
and Jacobian evaluations (SNESFunctionEval, SNESJacobianEval), the slowest rank's; drape's own
timers (drape.fe.membrane.MembraneProblem.timings: the law, the point contributions, i.e. the
tools' contact, and the assemblies), the slowest rank's; the processor seconds of all ranks
(user + system: on a shared machine less noisy than wall time); and the drape package it ran
(``drape_file``), which PYTHONPATH may point at another checkout's.
"""

from __future__ import annotations

import json
import sys

EVENTS = ("MatLUFactorNum", "MatLUFactorSym", "MatCholeskyFactorNum", "MatSolve",
          "SNESFunctionEval", "SNESJacobianEval", "SNESSolve", "KSPSolve")


def own_geometry(drape) -> None:
    """Make ``drape.geometry`` the gmsh builders of the checkout whose drape runs. With
    PYTHONPATH at another checkout (speed_10k.py's baseline) its drape is found first, but the
    installed package maps ``drape.geometry`` to this checkout's geometry/, which need not match
    that drape (an older one imports modules this one moved)."""
    import importlib.util
    from pathlib import Path
    init = Path(drape.__file__).resolve().parent.parent / "geometry" / "__init__.py"
    if not init.is_file() or "drape.geometry" in sys.modules:
        return
    spec = importlib.util.spec_from_file_location(
        "drape.geometry", init, submodule_search_locations=[str(init.parent)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["drape.geometry"] = module
    spec.loader.exec_module(module)
    drape.geometry = module


def main() -> int:
    from petsc4py import PETSc
    PETSc.Log.begin()
    out, argv = sys.argv[1], sys.argv[2:]
    import drape
    own_geometry(drape)
    import drape.run
    from drape import cli

    captured = {}
    run_job = drape.run.run_job

    def timed_run_job(*args, **kwargs):
        summary = run_job(*args, **kwargs)
        captured["timings"] = summary.timings
        return summary

    drape.run.run_job = timed_run_job
    code = cli.main(argv)
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    events = {}
    for name in EVENTS:
        info = PETSc.Log.Event(name).getPerfInfo()
        events[name] = {"count": int(comm.allreduce(info["count"], op=MPI.MAX)),
                        "s": comm.allreduce(info["time"], op=MPI.MAX),
                        "flops": comm.allreduce(info["flops"], op=MPI.SUM)}
    import resource
    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu = comm.allreduce(usage.ru_utime + usage.ru_stime, op=MPI.SUM)
    timings = {key: comm.allreduce(value, op=MPI.MAX)
               for key, value in sorted(captured.get("timings", {}).items())}
    if comm.rank == 0:
        with open(out, "w") as stream:
            json.dump({"exit": code, "drape_file": drape.__file__, "cpu_s": cpu, "events": events,
                       "timings": timings}, stream, indent=1)
    return code


if __name__ == "__main__":
    sys.exit(main())
