"""The PETSc side: options reach the SNES (config table and command line, prefix drape_), and
the iterative linear solver (GMRES, field split with GAMG and the in-plane rigid-body modes)
gives the direct solver's results."""

import numpy as np
import pytest

from conftest import CONFIGS
from drape.job import load_job
from drape.run import run_job

SHORT = ["output.xdmf=false", "history.d.values=[0.0, 3.0]", "steps.initial=0.1",
         "steps.maximum=0.25"]


def test_iterative_solver_matches_the_direct_one(comm, shared_tmp):
    results = {}
    for linear in ("direct", "iterative"):
        job = load_job(CONFIGS / "bias_extension.toml",
                       overrides=SHORT + [f"solver.linear={linear}"])
        summary = run_job(job, comm, output=shared_tmp / linear)
        results[linear] = [(r.t, r.reactions["right"][0]) for r in summary.rows]
    direct, iterative = np.array(results["direct"]), np.array(results["iterative"])
    assert direct.shape == iterative.shape and np.array_equal(direct[:, 0], iterative[:, 0])
    assert np.abs(direct[:, 1] - iterative[:, 1]).max() <= 1e-6 * np.abs(direct[:, 1]).max()
    if comm.rank == 0:
        a, b = (np.load(shared_tmp / name / "result.npz") for name in ("direct", "iterative"))
        # to the Newton tolerance (a residual of ~1e-6 N on shear modes of ~1 N/mm stiffness)
        assert np.abs(a["u"] - b["u"]).max() < 1e-5            # mm, of a 3 mm stroke
        assert np.abs(a["tau"] - b["tau"]).max() < 1e-6 * np.abs(a["tau"]).max()


def test_petsc_options_from_config_and_command_line_reach_the_solver(comm, shared_tmp, capfd):
    """The config's [solver.petsc] table and the command line's options land in SNES (prefix
    drape_): a monitor prints, and snes_max_it = 1 makes every step fail (exit 1 path)."""
    from drape.errors import RunFailed
    job = load_job(CONFIGS / "bias_extension.toml",
                   overrides=SHORT + ["solver.petsc.snes_monitor=\"\"", "steps.minimum=0.01"])
    run_job(job, comm, output=shared_tmp / "monitored",
            petsc_options={"snes_linesearch_type": "basic"})
    out = capfd.readouterr().out
    if comm.rank == 0:
        assert "SNES Function norm" in out
    with pytest.raises(RunFailed, match="DIVERGED_MAX_IT"):
        run_job(job, comm, output=shared_tmp / "capped", petsc_options={"snes_max_it": 1})
    # the options are removed again after a run: the next run is not capped
    run_job(load_job(CONFIGS / "bias_extension.toml", overrides=SHORT), comm,
            output=shared_tmp / "uncapped")


def test_the_jacobian_is_a_block_matrix_only_under_lu_with_mumps():
    """BAIJ for the direct solver (and options that keep LU with MUMPS), AIJ wherever the
    preconditioner cuts through the 3x3 blocks or does not take them (field split, GAMG, a
    Cholesky)."""
    from drape.job import SolverConfig
    from drape.fe.solver import default_options, jacobian_matrix_type
    direct = default_options(SolverConfig(linear="direct"), 1.0)
    assert jacobian_matrix_type(direct) == "baij"
    assert jacobian_matrix_type({**direct, "ksp_type": "gmres",
                                 "snes_lag_preconditioner": "-2"}) == "baij"
    assert jacobian_matrix_type(default_options(SolverConfig(linear="iterative"), 1.0)) is None
    assert jacobian_matrix_type({**direct, "pc_type": "gamg"}) is None
    assert jacobian_matrix_type({**direct, "pc_type": "cholesky"}) is None
    assert jacobian_matrix_type({**direct, "pc_factor_mat_solver_type": "petsc"}) is None


def test_run_hooks_see_every_attempt_solve_and_step(comm, shared_tmp):
    """The hooks benchmarks use instead of patching: on_start once with the run's parts;
    on_attempt before each Newton attempt, on_solve after it (no holder: one solve each);
    on_step once per converged step, with its record (the summary's). A step cut back counts one
    attempt more than it has rows."""
    from drape.forming.press import Forming
    calls = {"start": [], "attempt": [], "solve": [], "step": []}
    job = load_job(CONFIGS / "bias_extension.toml", overrides=SHORT)
    summary = run_job(
        job, comm, output=shared_tmp / "hooked",
        on_start=lambda run: calls["start"].append(run),
        on_attempt=lambda t: calls["attempt"].append(t),
        on_solve=lambda newton, result: calls["solve"].append(result),
        on_step=lambda record, problem: calls["step"].append(record))
    rows = summary.rows[1:]                      # step 0 is the unloaded state, not solved
    (run,) = calls["start"]
    assert run.part(Forming) is None and run.problem is run.solver.problem
    assert calls["step"] == rows
    cutbacks = sum(row.cutbacks for row in rows)
    assert len(calls["attempt"]) == len(rows) + cutbacks == len(calls["solve"])
    assert [r.converged for r in calls["solve"]].count(True) == len(rows)
    assert [r.iterations for r in calls["solve"] if r.converged] == [
        row.newton_iterations for row in rows]
    assert calls["attempt"][-1] == pytest.approx(1.0)
