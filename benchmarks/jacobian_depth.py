"""Newton's Jacobian against central differences of the residual deep in a forming stroke,
where friction slides and the law is plastic. Half a step beyond the converged state the
blank has moved down off the punch (only the die and holder touch); at the converged state
(``--beyond 0``) every point sits on the law's and friction's kinks (the step's plastic and
slip increments are zero there), so the one-sided derivatives differ.

    .venv/bin/python benchmarks/jacobian_depth.py configs/hemisphere.toml OUT 25 \
        --set output.xdmf=false

Runs the job with the consistent tangent (``solver.neutral_loading_band=0``: the band is by
design not the residual's derivative) to the stroke given (mm, ``process.stroke``), 1 rank,
and at its last step, half a step on from the committed state (Newton's ground; ``--beyond
0``: at the converged state), compares the assembled Jacobian's action J d with
(R(x + e d) - R(x - e d)) / 2e, e = 1e-6, for d = the last step's increment, the blank
1 mm down and 1 mm along x (tests/test_forming.py makes the same check at 5 mm). It prints
|J d|, |FD - J d| (inf-norms), how many law points are plastic there, and how many contact
points of each tool stick and slip.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

# the tests' residual and central differences (one implementation of each)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from fe_helpers import central_difference, residual  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config")
    parser.add_argument("folder")
    parser.add_argument("stroke", type=float)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--beyond", type=float, default=0.5, metavar="S",
                        help="check at the committed state plus S times the last increment "
                        "(beyond the converged state the blank has moved down past the punch, "
                        "and leaves it; tests/test_forming.py checks at -0.5, every tool "
                        "pressing)")
    args = parser.parse_args(argv)

    from petsc4py import PETSc

    from drape.forming.press import Forming
    from drape.job import load_job
    from drape.run import run_job

    parts = {}

    def check(record, p):
        if record.t < 1.0 - 1e-12:
            return
        increment = p.u_committed.vector.copy()
        increment.axpy(-1.0, p.u_previous.vector)
        x = p.u_committed.vector.copy()
        x.axpy(args.beyond, increment)
        residual(p, x)       # the law's and the tools' state at x: the counts and J below
        A = p.create_matrix()
        p.jacobian(None, x, A, A)
        plastic = int(np.sum(p.response.active_surface >= 0))
        tools = parts["run"].part(Forming).tool_contact
        states = {name: np.bincount(r.state, minlength=3)[1:].tolist()
                  for name, (_, r) in tools.last.items()}
        print(f"at {args.stroke:g} mm, {args.beyond:g} step on: {plastic} of "
              f"{p.response.tau.size} law points plastic in the step; contact points (stick, "
              f"slip): {states}")
        directions = {"increment": increment}
        for name, step in (("down", [0.0, 0.0, -1.0]), ("along x", [1.0, 0.0, 0.0])):
            directions[name] = x.duplicate()
            directions[name].array[:] = np.tile(step, x.array.size // 3)
        for name, d in directions.items():
            Jd = A.createVecLeft()
            A.mult(d, Jd)
            fd = central_difference(p, x, d)
            fd.axpy(-1.0, Jd)
            size, error = Jd.norm(PETSc.NormType.INFINITY), fd.norm(PETSc.NormType.INFINITY)
            print(f"  d = {name:9s} |J d| = {size:.4g}  |FD - J d| = {error:.3g}  "
                  f"({error / size:.2e} of |J d|)")
        residual(p, p.u_committed.vector)

    overrides = list(args.set) + [f"process.stroke={args.stroke}",
                                  "solver.neutral_loading_band=0"]
    run_job(load_job(args.config, overrides=overrides), output=args.folder, overwrite=True,
            on_start=lambda run: parts.update(run=run), on_step=check)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
