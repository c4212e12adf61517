"""Newton's method (PETSc SNES through petsc4py) and adaptive load stepping.

:class:`NewtonSolver` owns a SNES with the options prefix ``drape_``: drape's defaults (Newton
with a backtracking line search, LU with MUMPS, or GMRES + GAMG with the rigid-body near-nullspace)
are written to the PETSc options database under that prefix, then the job's ``[solver.petsc]``
table and the command line's ``--petsc-option`` on top, then ``setFromOptions``: any PETSc option
works. :meth:`NewtonSolver.close` removes them again.

:func:`run_load_steps` is the one step loop: it proposes the next load factor (landing on every
breakpoint of the histories), asks for a solve, and on success lets the caller commit and write
the step; on failure the caller restores the committed state and the step is cut back. Below
the minimum step it raises :class:`~drape.errors.RunFailed`.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from drape.errors import RunFailed

PREFIX = "drape_"


def default_options(config, force_scale: float) -> dict[str, str]:
    """drape's PETSc settings for a :class:`~drape.job.SolverConfig`."""
    options = {
        "snes_type": "newtonls",
        "snes_linesearch_type": "bt",
        "snes_max_it": config.max_iterations,
        "snes_rtol": config.rtol,
        "snes_atol": config.atol * force_scale,
        "snes_stol": 0.0,
        "snes_max_linear_solve_fail": 1,
    }
    if config.linear == "direct":
        options.update({"ksp_type": "preonly", "pc_type": "lu",
                        "pc_factor_mat_solver_type": "mumps",
                        # MUMPS: a singular pivot is a failed step, not a wrong answer
                        "mat_mumps_icntl_24": 0})
    else:
        # GMRES (the out-of-plane block is indefinite where the membrane is in compression)
        # preconditioned by a field split: the in-plane block by GAMG with the in-plane
        # rigid-body modes, the out-of-plane block (geometric stiffness and the tiny damping,
        # uncoupled from the in-plane one while the blank is flat) by its own GAMG. GAMG on the
        # whole field with the six rigid-body modes stalls on flat blanks: see docs/fe-solver.md.
        options.update({"ksp_type": "gmres", "ksp_pc_side": "right", "ksp_gmres_restart": 200,
                        "ksp_rtol": 1e-8, "ksp_atol": 0.1 * config.atol * force_scale,
                        "ksp_max_it": 2000, "pc_type": "fieldsplit",
                        "pc_fieldsplit_type": "multiplicative",
                        "fieldsplit_inplane_ksp_type": "preonly",
                        "fieldsplit_inplane_pc_type": "gamg",
                        "fieldsplit_inplane_pc_gamg_agg_nsmooths": 1,
                        "fieldsplit_outofplane_ksp_type": "preonly",
                        "fieldsplit_outofplane_pc_type": "gamg"})
    return {key: _option_text(value) for key, value in options.items()}


def jacobian_matrix_type(options: dict[str, str]) -> str | None:
    """The PETSc type of the Jacobian for these (final) options: "baij" (3x3 blocks, one per
    pair of nodes) under LU with MUMPS, else None (DOLFINx's AIJ).

    The bending hinges' interior-facet form inserts 24x24 values per edge, which AIJ looks up
    one by one, while BAIJ inserts a 3x3 block at a time: the hinges' assembly costs about half
    (docs/fe-solver.md, "Solver and PETSc options"). Other preconditioners keep AIJ: the field split
    takes the x, y and z components apart, through the blocks, and GAMG, or MUMPS's Cholesky,
    refuse BAIJ."""
    direct = (options.get("pc_type") == "lu"
              and options.get("pc_factor_mat_solver_type") == "mumps")
    return "baij" if direct else None


def _option_text(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def parse_option(text: str) -> tuple[str, str]:
    """'snes_monitor' or 'ksp_type=gmres' (a leading '-' and the prefix are allowed) -> pair."""
    from drape.errors import InputError
    name, _, value = text.partition("=")
    name = name.strip().lstrip("-")
    if name.startswith(PREFIX):
        name = name[len(PREFIX):]
    if not name or any(c.isspace() for c in name):
        raise InputError("not a PETSc option", key="--petsc-option", value=text,
                         expected="NAME or NAME=VALUE, e.g. snes_monitor or ksp_type=gmres")
    return name, value.strip()


def rigid_body_modes(V):
    """The six rigid-body motions of a 3-component field on the flat blank (3 translations,
    rotations about x, y, z through the origin), orthonormalised: a near-nullspace for GAMG on
    the whole field."""
    from dolfinx import la
    from petsc4py import PETSc

    index_map, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    n = index_map.size_local
    x = V.tabulate_dof_coordinates()[:n]
    basis = [la.create_petsc_vector(index_map, bs) for _ in range(6)]
    modes = np.zeros((6, n, bs))
    for i in range(3):
        modes[i, :, i] = 1.0
    modes[3, :, 1], modes[3, :, 2] = -x[:, 2], x[:, 1]   # rotation about x
    modes[4, :, 0], modes[4, :, 2] = x[:, 2], -x[:, 0]   # about y
    modes[5, :, 0], modes[5, :, 1] = -x[:, 1], x[:, 0]   # about z
    for vector, mode in zip(basis, modes):
        with vector.localForm() as local:
            local.array[: n * bs] = mode.ravel()
    la.orthonormalize(basis)
    return PETSc.NullSpace().create(vectors=basis)


def split_in_plane(V, pc) -> None:
    """Give a PCFIELDSPLIT the in-plane (x, y) and out-of-plane (z) dofs of V; the in-plane
    split carries its rigid-body modes (two translations, the rotation about z) for GAMG."""
    from dolfinx import la
    from petsc4py import PETSc

    index_map, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    n, first = index_map.size_local, index_map.local_range[0]
    blocks = (first + np.arange(n, dtype=np.int32)) * bs
    comm = V.mesh.comm
    in_plane = PETSc.IS().createGeneral(np.column_stack([blocks, blocks + 1]).ravel(), comm=comm)
    in_plane.setBlockSize(2)
    out_of_plane = PETSc.IS().createGeneral(blocks + 2, comm=comm)
    x = V.tabulate_dof_coordinates()[:n]
    modes = np.zeros((3, n, 2))
    modes[0, :, 0] = 1.0
    modes[1, :, 1] = 1.0
    modes[2, :, 0], modes[2, :, 1] = -x[:, 1], x[:, 0]
    basis = []
    for mode in modes:
        vector = PETSc.Vec().createMPI((2 * n, PETSc.DECIDE), bsize=2, comm=comm)
        vector.array[:] = mode.ravel()
        basis.append(vector)
    la.orthonormalize(basis)
    in_plane.compose("nearnullspace", PETSc.NullSpace().create(vectors=basis, comm=comm))
    pc.setType("fieldsplit")
    pc.setFieldSplitIS(("inplane", in_plane), ("outofplane", out_of_plane))


@dataclasses.dataclass
class SolveResult:
    converged: bool
    iterations: int
    reason: str
    residual: float
    seconds: float
    first_residual: float = 0.0   #: the residual norm Newton started from


class NewtonSolver:
    """SNES over a :class:`~drape.fe.membrane.MembraneProblem` (prefix ``drape_``)."""

    def __init__(self, problem, config, force_scale: float, extra_options: dict | None = None,
                 interrupted=None, on_solve=None):
        """``interrupted()``: this rank's own "stop now" flag (e.g. a signal arrived). The ranks
        combine their flags (an allreduce) before every residual evaluation; when one is set,
        the callback raises on every rank at once, which ends SNES there (not after the line
        search and the remaining iterations) with the reason "interrupted". ``on_solve(self,
        result)`` is called after every solve (a hook for benchmarks and tests)."""
        from petsc4py import PETSc

        self.problem = problem
        self.interrupted = interrupted
        self.on_solve = on_solve
        self.options = default_options(config, force_scale)
        self.options.update({k: _option_text(v) for k, v in config.petsc.items()})
        self.options.update({k: _option_text(v) for k, v in (extra_options or {}).items()})
        database = PETSc.Options()
        for name, value in self.options.items():
            database[PREFIX + name] = value
        self.snes = snes = PETSc.SNES().create(problem.comm)
        snes.setOptionsPrefix(PREFIX)
        self.b = problem.create_vector()
        self.A = problem.create_matrix(jacobian_matrix_type(self.options))
        # SNES's own iterate: the residual callback copies trial points (the line search's
        # too) into the problem's displacement, which must therefore not be this vector
        self.x = problem.u.vector.duplicate()
        if config.linear == "iterative":
            self.A.setNearNullSpace(rigid_body_modes(problem.V))
            split_in_plane(problem.V, snes.getKSP().getPC())
        snes.setConvergenceHistory(reset=True)   # its first entry: the residual started from
        snes.setFunction(self._residual, self.b)
        snes.setJacobian(problem.jacobian, self.A)
        snes.setFromOptions()
        self._reasons = {getattr(PETSc.SNES.ConvergedReason, name): name
                         for name in dir(PETSc.SNES.ConvergedReason) if name.isupper()
                         or name.startswith(("CONVERGED", "DIVERGED"))}

    def _residual(self, snes, x, b) -> None:
        if self.interrupted is not None:
            from mpi4py import MPI
            if self.problem.comm.allreduce(bool(self.interrupted()), op=MPI.LOR):
                self.stopped = True
                raise _Stop()
        self.problem.residual(snes, x, b)

    @property
    def rtol(self) -> float:
        """Newton's relative tolerance in force (solver.rtol, or a PETSc option's)."""
        return self.snes.getTolerances()[0]

    def solve(self, floor: float = 0.0) -> SolveResult:
        """Newton from the current displacement (the committed one) to the prescribed values.

        ``floor`` (N): a residual norm that counts as converged too, besides the tolerances; a
        step solved again (the holder moved, :func:`drape.forming.holder.hold_force`) passes
        rtol times the step's first residual, so that it stops where the first solve would have."""
        from petsc4py import PETSc
        start = time.perf_counter()
        u = self.problem.u
        u.vector.copy(self.x)
        self.problem.nonfinite.clear()
        self.stopped = False
        atol = self.snes.getTolerances()[1]
        self.snes.setTolerances(atol=max(atol, floor))
        try:
            self.snes.solve(None, self.x)
            reason = self.snes.getConvergedReason()
        except _Stop:                  # petsc4py re-raises the callback's exception
            reason, failure = -100, "interrupted"
        except PETSc.Error as error:   # a failure inside PETSc (e.g. a factorisation) = divergence
            reason, failure = -100, "interrupted" if self.stopped else str(error)
        else:
            failure = None
        finally:
            self.snes.setTolerances(atol=atol)
        history = self.snes.getConvergenceHistory()[0]
        self.x.copy(u.vector)
        u.x.scatter_forward()
        residual = self.snes.getFunctionNorm()
        name = failure or self._reasons.get(reason, str(reason))
        # a NaN/Inf in the law's output or the residual on any rank fails the attempt
        nonfinite = set().union(*self.problem.comm.allgather(self.problem.nonfinite))
        if nonfinite:
            reason = min(reason, -1)
            name = nonfinite_reason(nonfinite)
        result = SolveResult(reason > 0, self.snes.getIterationNumber(), name, float(residual),
                             time.perf_counter() - start,
                             float(history[0]) if len(history) else float(residual))
        if self.on_solve is not None:
            self.on_solve(self, result)
        return result

    def close(self) -> None:
        from petsc4py import PETSc
        database = PETSc.Options()
        for name in self.options:
            database.delValue(PREFIX + name)
        self.snes.destroy()
        self.A.destroy()
        self.b.destroy()
        self.x.destroy()


class _Stop(Exception):
    """Raised by the residual callback on every rank to end SNES (interrupted)."""


def nonfinite_reason(where: set[str]) -> str:
    """The reason of a failed attempt in which a NaN/Inf appeared (where: law, residual, ...)."""
    if "law" in where:
        place = "the law's output (tau, its tangent or the state)"
    elif where == {"residual"}:
        place = "the residual"
    else:
        place = "the point contribution(s) " + ", ".join(sorted(where - {"residual"}))
    return f"a NaN/Inf appeared in {place}"


# --- load stepping -------------------------------------------------------------------------------

@dataclasses.dataclass
class Step:
    """A converged load step."""
    number: int
    t: float
    dt: float
    iterations: int
    cutbacks: int
    residual: float
    seconds: float
    #: the step size the loop proposes next (after growth): what a resume starts with
    next_dt: float = 0.0


def next_load(t: float, dt: float, breakpoints: np.ndarray) -> float:
    """The next load factor: at most dt beyond t, landing on the next breakpoint in equal steps."""
    ahead = breakpoints[breakpoints > t + 1e-14]
    target = float(ahead[0]) if ahead.size else 1.0
    pieces = max(1, math.ceil((target - t) / dt - 1e-9))
    return target if pieces == 1 else t + (target - t) / pieces


def run_load_steps(config, breakpoints, attempt, accept, reject, *, t0: float = 0.0,
                   step0: int = 0, dt0: float | None = None, log=None) -> Step | None:
    """Adaptive load stepping from t0 to 1 (``config``: a :class:`~drape.job.StepsConfig`).

    attempt(t) -> SolveResult solves for load factor t from the committed state; accept(Step)
    commits and writes it; reject() restores the committed state. A failed attempt is retried
    with the step times ``cutback``; an easy one (at most ``easy_iterations``) lets the next
    grow by ``growth`` up to ``maximum``. ``t0``, ``step0``, ``dt0`` continue a run (resume)
    from step ``step0`` at ``t0`` with the step size ``dt0`` (default ``initial``; at most
    ``maximum``, which a resume may have lowered). Returns the last step.
    """
    t, dt, number, last = t0, min(dt0, config.maximum) if dt0 else config.initial, step0, None
    cutbacks = 0
    while t < 1.0 - 1e-12:
        t_next = next_load(t, dt, breakpoints)
        result = attempt(t_next)
        if result.converged:
            number += 1
            if result.iterations <= config.easy_iterations:
                dt = min(config.maximum, max(dt, t_next - t) * config.growth)
            last = Step(number, t_next, t_next - t, result.iterations, cutbacks, result.residual,
                        result.seconds, next_dt=dt)
            accept(last)
            cutbacks = 0
            t = t_next
            continue
        reject()
        cutbacks += 1
        dt = (t_next - t) * config.cutback
        if log is not None:
            log(f"step {number + 1}: no convergence at t = {t_next:.6g} ({result.reason}, "
                f"{result.iterations} iterations, residual {result.residual:.3e}); "
                f"cut back to dt = {dt:.3g}")
        if dt < config.minimum * (1 - 1e-12):
            raise RunFailed(
                f"step {number + 1}: Newton did not converge at load factor t = {t_next:.6g} "
                f"(from t = {t:.6g}; {cutbacks} failed attempt(s) at this step); a smaller step "
                f"{dt:.3g} would be below steps.minimum = {config.minimum:g}; last residual "
                f"norm {result.residual:.3e} ({result.reason})")
    return last
