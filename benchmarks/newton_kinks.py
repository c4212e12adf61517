"""Why a hard load step's Newton iterations crawl: along Newton's own direction, how far the
residual follows its linear model, and which points switch branch on the way.

    .venv/bin/python benchmarks/newton_kinks.py configs/hemisphere.toml OUT 0.9 \
        process.stroke=30 output.xdmf=false

Runs the job (``table.key=value`` overrides as ``drape run --set`` takes them) into the folder
OUT (1 rank) and records the Newton iterates of the first solve that starts from a committed
load factor at or above T (0.9 above: the step from 27.05 to 27.64 mm). At iterates 1, 3, 5 and 7
of that solve it rebuilds the Jacobian J and the residual F, takes Newton's direction
d = -J^-1 F, and for step lengths s from 1 down to 1e-4 prints

* |F(x + s d)| and the linear model's miss, |F(x + s d) - (1 - s) F(x)| / (s |F(x)|): about
  zero where F is smooth over s d (J the derivative of F), of order one where it is not;
* how many of the law's points switch between elastic and plastic (the law's
  ``active_surface``: -1 elastic) and how many contact points switch between separated, stick
  and slip, between x and x + s d;
* the largest in-plane and out-of-plane entries of d and the share of |F|^2 in the flange,
  the wall and the part inside the punch radius (hemisphere tools: r > 60, 50-60, <= 50 mm).

The figures in docs/benchmarks.md ("Where the slow stretch comes from") were taken with it.
"""

from __future__ import annotations

import sys

import numpy as np

ITERATES = (1, 3, 5, 7)
STEP_LENGTHS = (1.0, 0.5, 0.25, 1e-2, 1e-4)
REGIONS = (("flange r > 60", 60.0, np.inf), ("wall 50-60", 50.0, 60.0),
           ("inside r <= 50", -1.0, 50.0))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 3:
        sys.exit(__doc__)
    config, folder, threshold, *overrides = argv
    threshold = float(threshold)
    from petsc4py import PETSc

    from drape.forming.press import Forming
    from drape.job import load_job
    from drape.run import run_job

    parts, iterates = {}, []

    def watch(t):
        """Before each attempt: record Newton's iterates in the first solve from T or beyond."""
        newton = parts["run"].solver
        if "done" not in parts and newton.problem.t_committed >= threshold:
            iterates.clear()
            newton.snes.setMonitor(
                lambda snes, its, norm: iterates.append(snes.getSolution().copy()))
            parts["watching"] = True

    def diagnose(newton, result):
        if not parts.pop("watching", False):
            return
        newton.snes.cancelMonitor()
        parts["done"] = True
        problem = newton.problem
        print(f"step from t = {problem.t_committed:.6g}: {result.iterations} Newton iterations")
        report(newton, problem, parts["run"].part(Forming), iterates, PETSc)
        problem.residual(newton.snes, newton.x, newton.b)   # leave the problem at the solution

    run_job(load_job(config, overrides=overrides), output=folder,
            on_start=lambda run: parts.update(run=run), on_attempt=watch, on_solve=diagnose)
    return 0


def report(newton, problem, tools, iterates, PETSc) -> None:
    A, snes = newton.A, newton.snes
    ksp = PETSc.KSP().create(problem.comm)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    V = problem.V
    nodes = V.tabulate_dof_coordinates()[: V.dofmap.index_map.size_local]
    radius = np.hypot(nodes[:, 0], nodes[:, 1])

    def branches():
        contact = {name: response.state.copy()
                   for name, (_, response) in tools.tool_contact.last.items()}
        return problem.response.active_surface >= 0, contact

    for k in ITERATES:
        if k >= len(iterates):
            break
        x = iterates[k]
        F0 = newton.b.duplicate()
        problem.residual(snes, x, F0)
        plastic0, contact0 = branches()
        problem.jacobian(snes, x, A, A)
        d = x.duplicate()
        ksp.setOperators(A)
        ksp.solve(F0, d)
        d.scale(-1.0)
        f0 = F0.norm()
        print(f"  iterate {k}: |F| = {f0:.3e} N, max |d| = {np.abs(d.array).max():.3e} mm")
        for s in STEP_LENGTHS:
            y = x.copy()
            y.axpy(s, d)
            F = newton.b.duplicate()
            problem.residual(snes, y, F)
            plastic, contact = branches()
            miss = F.copy()
            miss.axpy(-(1.0 - s), F0)
            switched = ", ".join(f"{name} {int(np.sum(contact[name] != contact0[name]))}"
                                 for name in contact0)
            print(f"    s = {s:<6g} |F| = {F.norm():.3e}  miss {miss.norm() / (s * f0):.2e}  "
                  f"law: {int(np.sum(plastic & ~plastic0))} elastic->plastic, "
                  f"{int(np.sum(~plastic & plastic0))} plastic->elastic of {plastic.size}; "
                  f"contact switched: {switched}")
        step = d.array.reshape(-1, 3)
        force = F0.array.reshape(-1, 3)
        for name, lo, hi in REGIONS:
            inside = (radius > lo) & (radius <= hi)
            print(f"    {name}: max |d_xy| {np.abs(step[inside, :2]).max():.2e}, "
                  f"max |d_z| {np.abs(step[inside, 2]).max():.2e} mm, "
                  f"share of |F|^2 {np.sum(force[inside] ** 2) / f0 ** 2:.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
