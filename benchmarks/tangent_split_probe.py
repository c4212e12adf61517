"""`drape run` with one line per Newton solve, for the tangent-split experiment (issue 27).

    python benchmarks/tangent_split_probe.py run CONFIG.toml [drape run's arguments]

Prints after every Newton solve (rank 0): Newton's iterations, the GMRES iterations of the
solve in all and the most in one linear solve, and, under ``solver.linear = "tangent_split"``,
the preconditioner's set-ups, applications, GFlop per factorisation of each block (MUMPS
RINFOG(3)) and seconds by phase; under LU the factor's INFOG(20) and RINFOG(3). At the end
PETSc's event log of the factorisations, triangular solves, PC set-ups and applications.
``PROBE_SOLVES=N`` ends the process after N solves (a resumed run measured for a few steps).
The experiment's switches (environment): DRAPE_TS_KEEP=1 keeps the hinge entries in the
tangential block, DRAPE_TS_SWEEP=tnt|mn|mnm other sweeps, DRAPE_TS_SCHUR=1 a Schur estimate.
"""

import os
import sys
import time

EVENTS = ("MatLUFactorNum", "MatLUFactorSym", "MatSolve", "KSPSolve", "SNESJacobianEval",
          "PCSetUp", "PCApply", "MatMult")


def main() -> int:
    from petsc4py import PETSc
    PETSc.Log.begin()
    import drape.fe.solver as solver_module
    from drape import cli

    solve = solver_module.NewtonSolver.solve
    most, solves = [0], [0]

    def probed_solve(self, floor=0.0):
        started = time.perf_counter()
        if not getattr(self, "_probed", False):
            self._probed = True
            self.snes.getKSP().setMonitor(
                lambda ksp, its, norm: most.__setitem__(0, max(most[0], its)))
        most[0] = 0
        result = solve(self, floor)
        split = getattr(self, "tangent_split", None)
        pc = self.snes.getKSP().getPC()
        if split is not None and pc.getType() == "python":
            stats = split.stats
            seconds = {key: round(value, 2) for key, value in stats["seconds"].items()}
            extra = (f" setups {stats['setups']} apps {stats['applications']} gflop "
                     f"{stats['gflop']} entries {stats['factor_entries']} sec {seconds}")
        elif pc.getType() == "lu":
            factor = pc.getFactorMatrix()
            extra = (f" entries {factor.getMumpsInfog(20)} "
                     f"gflop {factor.getMumpsRinfog(3) / 1e9:.3f}")
        else:
            extra = ""
        if self.problem.comm.rank == 0:
            print(f"SOLVE newton {result.iterations} ksp_total "
                  f"{self.snes.getLinearSolveIterations()} {result.reason} "
                  f"res {result.residual:.3e} {time.perf_counter() - started:.1f}s "
                  f"max_ksp {most[0]}{extra}", flush=True)
        solves[0] += 1
        if solves[0] >= int(os.environ.get("PROBE_SOLVES", "1000000")):
            os._exit(0)
        return result

    solver_module.NewtonSolver.solve = probed_solve
    code = cli.main(sys.argv[1:])
    for name in EVENTS:
        info = PETSc.Log.Event(name).getPerfInfo()
        if PETSc.COMM_WORLD.rank == 0:
            print(f"EVENT {name} count {info['count']} s {info['time']:.2f}")
    return code


if __name__ == "__main__":
    sys.exit(main())
